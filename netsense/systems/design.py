"""Observer gain design for the source nodes (Theorem 1 and Corollary 1).

Each source node ``j`` owns substate ``j`` and runs the local Luenberger update eq. (7)
with gain ``L_j``. Theorem 1's design picks rates ``0 < rho_1 < ... < rho_N < rho`` and
places the eigenvalues of ``A_jj - L_j C_jj`` at distinct real values with spectral radius
exactly ``rho_j`` (so ``||(A_jj - L_j C_jj)^k|| <= alpha_j rho_j^k``, eq. (18)).
Corollary 1's deadbeat design places every eigenvalue at 0, which makes the error of
every node vanish after at most ``n + 2N(N-1)T`` steps.

Pole placement uses :func:`scipy.signal.place_poles` on the dual pair. Deadbeat gains for
multi-output blocks cannot come from ``place_poles`` (a pole's multiplicity may not exceed
the number of outputs), so they use Heymann's lemma: a random output feedback ``K_0``
makes ``(A - K_0 C, C)`` cyclic, a random output combination ``v`` leaves it observable
through the single output ``v^T C``, and Ackermann's formula on that single-output pair
finishes the design. The result is checked (``||(A - L C)^{n_j}||`` small) and redrawn a
few times if rounding spoiled it.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from netsense.systems.decomposition import Decomposition, decompose, observable_subspace


@dataclass(frozen=True, eq=False)
class ObserverDesign:
    """A decomposition plus the source gains: everything a distributed observer needs.

    Attributes
    ----------
    decomposition : Decomposition
        Lemma 1's coordinates and blocks.
    gains : tuple of arrays
        ``L_j`` of shape ``(n_j, r_j)`` for each agent (empty when ``n_j = 0``).
    rates : tuple of float
        Spectral radius of ``A_jj - L_j C_jj`` per agent (``nan`` for ``n_j = 0``).
    deadbeat : bool
        Whether all closed-loop eigenvalues were placed at 0 (Corollary 1).
    """

    decomposition: Decomposition
    gains: tuple[np.ndarray, ...]
    rates: tuple[float, ...]
    deadbeat: bool

    @property
    def num_agents(self) -> int:
        return self.decomposition.num_agents

    @property
    def n(self) -> int:
        return self.decomposition.n

    def closed_loop(self, j: int) -> np.ndarray:
        """``A_jj - L_j C_jj`` of source ``j``."""
        d = self.decomposition
        return d.A_jj(j) - self.gains[j] @ d.C_jj(j)

    def gain_padded(self, max_outputs: int) -> np.ndarray:
        """``(N, n, r_max)`` array: ``L_j`` in the rows of block ``j`` of agent ``j``.

        Multiplying by agent ``j``'s innovation ``y_j - C_bar_j z_j`` gives the output
        injection term of eq. (7) in full ``z`` coordinates (zero outside block ``j``).
        """
        d = self.decomposition
        out = np.zeros((d.num_agents, d.n, max_outputs))
        for j, L in enumerate(self.gains):
            if L.size:
                out[j, d.block(j), : L.shape[1]] = L
        return out


def _ackermann_deadbeat(A: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Gain ``l`` (n x 1) with ``A - l c`` nilpotent for a single output row ``c``."""
    n = A.shape[0]
    O = np.empty((n, n))
    row = c.reshape(1, n)
    for k in range(n):
        O[k] = row
        row = row @ A
    e_n = np.zeros((n, 1))
    e_n[-1] = 1.0
    # l = A^n O^{-1} e_n (Ackermann with characteristic polynomial z^n).
    return np.linalg.matrix_power(A, n) @ np.linalg.solve(O, e_n)


def deadbeat_gain(A, C, *, rng: np.random.Generator | int | None = 0,
                  max_tries: int = 20, rtol: float = 1e-8) -> np.ndarray:
    """Gain ``L`` with every eigenvalue of ``A - L C`` at 0 (Corollary 1).

    Works for any number of outputs (Heymann's lemma + Ackermann, see module docstring).

    Raises
    ------
    ValueError
        If ``(A, C)`` is not observable or no accurate deadbeat gain was found.
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n, r = A.shape[0], C.shape[0]
    if C.ndim != 2 or C.shape[1] != n:
        raise ValueError(f"C must have shape (r, {n}), got {C.shape}")
    scale = max(np.linalg.norm(A, 2), np.linalg.norm(C, 2), 1.0)
    if observable_subspace(A, C, 1e-9 * scale).shape[1] < n:
        raise ValueError("deadbeat design needs an observable (A_jj, C_jj) pair")
    rng = np.random.default_rng(rng)
    best, best_res = None, np.inf
    for attempt in range(max_tries):
        if r == 1 and attempt == 0:
            K0, v = np.zeros((n, 1)), np.ones((1, 1))
        else:
            K0 = (0 if attempt == 0 else 1) * rng.standard_normal((n, r)) * scale / max(
                np.linalg.norm(C, 2), 1e-12)
            v = rng.standard_normal((r, 1))
        A1 = A - K0 @ C
        c = v.T @ C
        if observable_subspace(A1, c, 1e-9 * scale).shape[1] < n:
            continue
        L = K0 + _ackermann_deadbeat(A1, c) @ v.T
        res = np.linalg.norm(np.linalg.matrix_power(A - L @ C, n), 2)
        if res < best_res:
            best, best_res = L, res
        if res <= rtol * scale ** n:
            return L
    if best is not None and best_res <= 1e-4 * scale ** n:
        return best
    raise ValueError(f"no accurate deadbeat gain found (best ||(A-LC)^n|| = {best_res:.3g}); "
                     "the block is numerically close to unobservable")


def rate_gain(A, C, rho_j: float) -> np.ndarray:
    """Gain ``L`` such that ``A - L C`` has distinct real eigenvalues, spectral radius ``rho_j``.

    The eigenvalues are ``rho_j * (n - k) / n`` for ``k = 0..n-1`` (distinct, positive,
    largest exactly ``rho_j``).
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    n = A.shape[0]
    if not 0 < rho_j < 1:
        raise ValueError(f"rho_j must be in (0, 1), got {rho_j}")
    poles = rho_j * (n - np.arange(n)) / n
    if n == 1:
        c = C.reshape(-1)
        if np.allclose(c, 0):
            raise ValueError("rate design needs an observable (A_jj, C_jj) pair")
        # Minimum-norm gain for the scalar block: a - l.c = rho_j.
        return ((A[0, 0] - rho_j) * c / (c @ c)).reshape(1, -1)
    try:
        with warnings.catch_warnings():
            # YT's robustness iteration may stop early; the poles are still placed, which
            # is checked below.
            warnings.simplefilter("ignore", UserWarning)
            from scipy.signal import place_poles  # 0.5 s to import: only when used

            res = place_poles(A.T, C.T, poles, method="YT", maxiter=10)
    except ValueError as exc:
        raise ValueError(f"pole placement failed for a block of size {n}: {exc}") from exc
    L = res.gain_matrix.T
    got = np.sort(np.real(sla.eigvals(A - L @ C)))
    if np.max(np.abs(got - np.sort(poles))) > 1e-6 * max(1.0, np.linalg.norm(A, 2)):
        raise ValueError(f"pole placement for a block of size {n} is inaccurate: asked for "
                         f"{np.sort(poles)}, got {got}")
    return L


def design_observer(A, Cs: Sequence | None = None, *, rho: float | None = 0.5,
                    rates: Sequence[float] | None = None, deadbeat: bool = False,
                    decomposition: Decomposition | None = None,
                    rng: np.random.Generator | int | None = 0) -> ObserverDesign:
    """Decompose ``(A, C)`` (Lemma 1) and design every source gain.

    Parameters
    ----------
    A : (n, n) array_like or Plant
        System matrix, or a :class:`~netsense.systems.plants.Plant` (then ``Cs`` is taken from it).
    Cs : sequence of (r_i, n) arrays
        Output matrices (omit when ``A`` is a Plant).
    rho : float in (0, 1)
        Target convergence rate of Theorem 1; the default rates are
        ``rho_j = rho * k / (m + 1)`` for the ``k``-th of the ``m`` non-empty substates,
        so ``0 < rho_1 < ... < rho_N < rho``.
    rates : sequence of float, optional
        Explicit ``rho_j`` per agent (entries for empty substates are ignored); they must
        be strictly increasing over the non-empty substates and below ``rho``.
    deadbeat : bool
        Place every eigenvalue at 0 (Corollary 1) instead.
    decomposition : Decomposition, optional
        Reuse a decomposition computed earlier.
    rng : Generator or int
        Randomness for the multi-output deadbeat design.

    Raises
    ------
    ValueError
        If ``rho`` or ``rates`` are out of range or not increasing, or a block's design is
        impossible (the message names the agent).
    """
    if Cs is None:
        from netsense.systems.plants import Plant

        if not isinstance(A, Plant):
            raise ValueError("give either a Plant or both A and Cs")
        A, Cs = A.A, A.C
    dec = decomposition if decomposition is not None else decompose(A, Cs)
    active = [j for j, s in enumerate(dec.sizes) if s > 0]
    if not deadbeat:
        if rho is None or not 0 < rho < 1:
            raise ValueError(f"rho must be in (0, 1), got {rho}")
        if rates is None:
            m = len(active)
            rate_of = {j: rho * (k + 1) / (m + 1) for k, j in enumerate(active)}
        else:
            if len(rates) != dec.num_agents:
                raise ValueError(f"rates must have one entry per agent ({dec.num_agents}), "
                                 f"got {len(rates)}")
            rate_of = {j: float(rates[j]) for j in active}
            seq = [rate_of[j] for j in active]
            increasing = all(b > a for a, b in zip(seq, seq[1:], strict=False))
            if any(not 0 < r < rho for r in seq) or not increasing:
                raise ValueError(f"rates of the non-empty substates must satisfy "
                                 f"0 < rho_1 < ... < rho_N < rho = {rho}, got {seq}")
    gains, rates_out = [], []
    for j in range(dec.num_agents):
        if dec.sizes[j] == 0:
            gains.append(np.zeros((0, dec.C_bar[j].shape[0])))
            rates_out.append(float("nan"))
            continue
        Ajj, Cjj = dec.A_jj(j), dec.C_jj(j)
        try:
            if deadbeat:
                L = deadbeat_gain(Ajj, Cjj, rng=rng)
                rates_out.append(0.0)
            else:
                L = rate_gain(Ajj, Cjj, rate_of[j])
                rates_out.append(rate_of[j])
        except ValueError as exc:
            raise ValueError(f"gain design for agent {j} (block size {dec.sizes[j]}): {exc}") \
                from exc
        gains.append(L)
    return ObserverDesign(decomposition=dec, gains=tuple(gains), rates=tuple(rates_out),
                          deadbeat=deadbeat)


def spectral_radius(M: np.ndarray) -> float:
    """Largest eigenvalue modulus of a square matrix (0 for an empty one)."""
    return float(np.max(np.abs(sla.eigvals(M)))) if M.size else 0.0
