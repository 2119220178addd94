"""Plants: a linear system observed by N sensor agents.

.. math::  x[k+1] = A x[k] + B u[k] + W w[k], \\qquad y_i[k] = C_i x[k] + v_i[k]

eqs. (1)-(2) of the freshness-index paper, with the optional input ``B`` and process-noise
input ``W`` added. Agent ``i`` measures ``r_i`` outputs; ``r_i = 0`` is allowed (a sensor
that sees nothing and only relays).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from netsense.kernels import checks
from netsense.sensing.noise import NoiseModel, NoNoise

#: Largest magnitude of a plant matrix entry (squares of larger numbers overflow float64).
MAX_ENTRY = 1e150


def _as_matrix(name: str, M, rows: int | None, cols: int | None) -> np.ndarray:
    try:
        M = np.asarray(M, dtype=float)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{name} must be a matrix of numbers: {exc}") from None
    if M.ndim == 1 and rows == 0:
        M = M.reshape(0, cols)
    if M.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got an array with shape {M.shape}")
    if (rows is not None and M.shape[0] != rows) or (cols is not None and M.shape[1] != cols):
        want = f"({'*' if rows is None else rows}, {'*' if cols is None else cols})"
        raise ValueError(f"{name} must have shape {want}, got {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains NaN or infinite entries")
    if M.size and np.abs(M).max() > MAX_ENTRY:
        raise ValueError(f"{name} has entries up to {np.abs(M).max():.3g}; |entries| must be "
                         f"<= {MAX_ENTRY:g} (norms of states and errors would overflow "
                         "float64): rescale the state or the outputs")
    return M


@dataclass(frozen=True, eq=False)
class Plant:
    """A linear plant with one output matrix per sensor agent.

    Parameters
    ----------
    A : (n, n) array
        System matrix; may be unstable.
    C : sequence of N arrays, each (r_i, n)
        Output matrix of agent ``i`` (``r_i`` may be 0).
    B : (n, m) array, optional
        Input matrix for a known input ``u`` (shared by every agent).
    W : (n, p) array, optional
        Process-noise input matrix; defaults to the identity when process noise is set.
    process_noise, measurement_noise : NoiseModel
        Additive noise models (see :mod:`netsense.sensing.noise`).
    name : str
        A label used in reports.
    """

    A: np.ndarray
    C: tuple[np.ndarray, ...]
    B: np.ndarray | None = None
    W: np.ndarray | None = None
    process_noise: NoiseModel = field(default_factory=NoNoise)
    measurement_noise: NoiseModel = field(default_factory=NoNoise)
    name: str = "plant"

    def __post_init__(self) -> None:
        A = _as_matrix("A", self.A, None, None)
        if A.shape[0] != A.shape[1]:
            raise ValueError(f"A must be square, got shape {A.shape}")
        n = A.shape[0]
        if n == 0:
            raise ValueError("A must have at least one state (n >= 1)")
        if isinstance(self.C, (str, bytes)) or not isinstance(self.C, (Sequence, np.ndarray)):
            raise ValueError(f"C must be a sequence with one output matrix per agent, got "
                             f"{type(self.C).__name__}")
        if isinstance(self.C, np.ndarray) and self.C.ndim == 2:
            raise ValueError("C must be a sequence with one output matrix per agent, "
                             "not a single stacked matrix")
        if len(self.C) == 0:
            raise ValueError("C must hold at least one agent's output matrix")
        Cs = tuple(_as_matrix(f"C[{i}]", Ci, None, n) for i, Ci in enumerate(self.C))
        B = None if self.B is None else _as_matrix("B", self.B, n, None)
        W = None if self.W is None else _as_matrix("W", self.W, n, None)
        for label, model in (("process_noise", self.process_noise),
                             ("measurement_noise", self.measurement_noise)):
            if not isinstance(model, NoiseModel):
                raise ValueError(f"{label} must be a NoiseModel, got {type(model).__name__}")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "C", Cs)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "W", W)

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    @property
    def num_agents(self) -> int:
        """Number of sensor agents N."""
        return len(self.C)

    @property
    def output_sizes(self) -> tuple[int, ...]:
        """``r_i`` for every agent."""
        return tuple(Ci.shape[0] for Ci in self.C)

    @property
    def max_outputs(self) -> int:
        """``max_i r_i``: the padded width of stacked measurements."""
        return max(self.output_sizes)

    @property
    def C_stacked(self) -> np.ndarray:
        """``C = [C_1; ...; C_N]`` as one ``(sum r_i, n)`` matrix."""
        return np.vstack(self.C)

    @property
    def C_padded(self) -> np.ndarray:
        """``(N, r_max, n)`` array; rows beyond ``r_i`` are zero."""
        out = np.zeros((self.num_agents, self.max_outputs, self.n))
        for i, Ci in enumerate(self.C):
            out[i, : Ci.shape[0]] = Ci
        return out

    @property
    def output_mask(self) -> np.ndarray:
        """``(N, r_max)`` boolean mask of the real (unpadded) measurement rows."""
        r = np.asarray(self.output_sizes)
        return np.arange(self.max_outputs)[None, :] < r[:, None]

    @property
    def W_effective(self) -> np.ndarray:
        """``W`` or the identity when none was given."""
        return np.eye(self.n) if self.W is None else self.W

    # ------------------------------------------------------------- simulation
    def step(self, x: np.ndarray, rng: np.random.Generator | None = None,
             u: np.ndarray | None = None) -> np.ndarray:
        """Advance ``x`` (shape ``(..., n)``) one step; eq. (1) plus input and noise."""
        x_next = x @ self.A.T
        if u is not None:
            if self.B is None:
                raise ValueError("an input u was given but the plant has no B matrix")
            x_next = x_next + np.asarray(u) @ self.B.T
        if not isinstance(self.process_noise, NoNoise):
            if rng is None:
                raise ValueError("a Generator is required to draw process noise")
            W = self.W_effective
            w = self.process_noise.sample(rng, x.shape[:-1] + (W.shape[1],))
            x_next = x_next + w @ W.T
        return x_next

    def measure(self, x: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Every agent's measurement, eq. (2), padded to ``(..., N, r_max)``.

        Padded rows (beyond ``r_i``) are exactly zero, also under noise.
        """
        y = np.einsum("irn,...n->...ir", self.C_padded, x)
        if not isinstance(self.measurement_noise, NoNoise):
            if rng is None:
                raise ValueError("a Generator is required to draw measurement noise")
            v = self.measurement_noise.sample(rng, y.shape)
            y = y + v * self.output_mask
        return y

    def pad_measurements(self, ys: Sequence[np.ndarray]) -> np.ndarray:
        """Stack per-agent measurement vectors into the padded ``(N, r_max)`` layout."""
        if len(ys) != self.num_agents:
            raise ValueError(f"expected {self.num_agents} measurement vectors, got {len(ys)}")
        out = np.zeros((self.num_agents, self.max_outputs))
        for i, (yi, ri) in enumerate(zip(ys, self.output_sizes, strict=True)):
            yi = np.asarray(yi, dtype=float).reshape(-1)
            if yi.shape[0] != ri:
                raise ValueError(f"measurement of agent {i} must have {ri} entries, "
                                 f"got {yi.shape[0]}")
            out[i, :ri] = yi
        return out


# --------------------------------------------------------------------- named plants
def fig1_scalar(a: float = 2.0) -> Plant:
    """The scalar plant of Fig. 1: ``x[k+1] = a x[k]``, node 1 measures ``x``, 2-3 see nothing."""
    a = checks.number("a", a)
    return Plant(A=[[a]], C=(np.ones((1, 1)), np.zeros((0, 1)), np.zeros((0, 1))),
                 name=f"fig1_scalar(a={a:g})")


def random_structured(n: int, num_agents: int, *, num_sources: int | None = None,
                      outputs_per_source: int | None = None, spectral_radius: float = 1.2,
                      rng: np.random.Generator | int | None = None,
                      max_tries: int = 100) -> Plant:
    """A random observable plant in which each sensing agent sees only part of the state.

    The plant is built in the coordinates of Lemma 1 and then rotated by a random
    orthogonal matrix, so the decomposition has ``num_sources`` non-empty substates owned
    by different agents (chosen at random); the remaining agents measure nothing.
    The eigenvalues of ``A`` are real or complex with modulus up to
    ``spectral_radius`` (so the plant is unstable when it is > 1).

    Parameters
    ----------
    n, num_agents : int
        State dimension and number of agents N.
    num_sources : int, optional
        How many agents own a substate; default ``min(n, max(2, N // 2))``.
    outputs_per_source : int, optional
        Rows of each sensing agent's ``C_i``; default ``ceil(n_j / 4)`` for a block of
        size ``n_j`` (single outputs make large blocks numerically near-unobservable).
    spectral_radius : float
        Largest eigenvalue modulus of ``A``.
    rng : Generator or int, optional
        Randomness source or seed.
    """
    n, num_agents = checks.integer("n", n, 1), checks.integer("num_agents", num_agents, 1)
    if num_sources is not None:
        num_sources = checks.integer("num_sources", num_sources, 1)
    if outputs_per_source is not None:
        outputs_per_source = checks.integer("outputs_per_source", outputs_per_source, 1)
    spectral_radius = checks.number("spectral_radius", spectral_radius, 0, lo_open=True)
    rng = np.random.default_rng(rng)
    if num_sources is None:
        num_sources = min(n, num_agents, max(2, num_agents // 2))
    if not 1 <= num_sources <= min(n, num_agents):
        raise ValueError(f"num_sources must be in [1, min(n, N)] = [1, {min(n, num_agents)}], "
                         f"got {num_sources}")
    from netsense.systems.decomposition import decompose  # local import: avoids a cycle

    for _ in range(max_tries):
        cuts = np.sort(rng.choice(np.arange(1, n), size=num_sources - 1, replace=False))
        sizes = np.diff(np.concatenate([[0], cuts, [n]]))
        offs = np.concatenate([[0], np.cumsum(sizes)])
        A_bar = np.zeros((n, n))
        for j, s in enumerate(sizes):
            blk = slice(offs[j], offs[j + 1])
            eig = rng.uniform(-spectral_radius, spectral_radius, size=s)
            eig[np.argmax(np.abs(eig))] = spectral_radius * rng.choice([-1.0, 1.0])
            Q, _ = np.linalg.qr(rng.standard_normal((s, s)))
            A_bar[blk, blk] = Q @ np.diag(eig) @ Q.T
            A_bar[blk, : offs[j]] = 0.3 * rng.standard_normal((s, offs[j]))
        owners = rng.choice(num_agents, size=num_sources, replace=False)
        owners.sort()
        C_bar = [np.zeros((0, n)) for _ in range(num_agents)]
        for j, agent in enumerate(owners):
            rows = outputs_per_source or int(np.ceil(sizes[j] / 4))
            Cj = np.zeros((rows, n))
            Cj[:, : offs[j + 1]] = rng.standard_normal((rows, offs[j + 1]))
            C_bar[agent] = Cj
        T, _ = np.linalg.qr(rng.standard_normal((n, n)))
        A = T @ A_bar @ T.T
        Cs = tuple(Ci @ T.T for Ci in C_bar)
        try:
            dec = decompose(A, Cs, refine=False)  # only the sizes are needed
        except ValueError:
            continue
        if sum(1 for s in dec.sizes if s > 0) == num_sources:
            return Plant(A=A, C=Cs, name=f"random_structured(n={n}, N={num_agents})")
    raise ValueError(f"could not draw an observable structured plant in {max_tries} tries")


#: Rotation angles of the five oscillators of ``comm_process_noise-v0``, cycled by
#: :func:`oscillator_bank` over any number of oscillators.
OSCILLATOR_THETAS = (0.1, 0.2, 0.3, 0.5, 0.7)


def oscillator_bank(num_agents: int, *, agents_per_oscillator: int = 2,
                    spectral_radius: float = 0.99,
                    thetas: Sequence[float] = OSCILLATOR_THETAS) -> Plant:
    """A bank of independent damped oscillators, one measured by each group of agents.

    With ``p`` = ``agents_per_oscillator`` and ``m = N / p`` oscillators,

    .. math::  x_j[k+1] = \\rho R(\\theta_j) x_j[k] (+ w_j[k]), \\qquad
               y_{p j}[k] = x_j[k] (+ v_{p j}[k]), \\qquad j = 0, \\dots, m - 1,

    where :math:`R(\\theta)` is the 2-D rotation by :math:`\\theta` and :math:`\\theta_j`
    = ``thetas[j mod len(thetas)]``: ``A`` (``n = 2m``) is block diagonal with ``2 x 2``
    blocks, agent ``p j`` (a source) measures block ``j`` and the other ``p - 1`` agents
    of its group measure nothing (relays). Every eigenvalue has modulus :math:`\\rho`
    (``spectral_radius``). With ``N = 10`` and the defaults this is the plant of
    ``comm_process_noise-v0``; it exists so that the tasks at scale (``N`` up to 1000)
    need no matrix written into their scenario files.

    Parameters
    ----------
    num_agents : int
        ``N``, a positive multiple of ``agents_per_oscillator``.
    agents_per_oscillator : int
        Agents per oscillator ``p >= 1`` (one source and ``p - 1`` relays).
    spectral_radius : float
        :math:`\\rho > 0`, the modulus of every eigenvalue.
    thetas : sequence of float
        Rotation angles per step (radians), cycled over the oscillators.

    Returns
    -------
    Plant
        Without noise models (a scenario adds them from its ``[noise]`` section).

    Raises
    ------
    ValueError
        Naming the parameter, before any matrix is allocated: ``num_agents`` not a
        positive multiple of ``agents_per_oscillator``, ``spectral_radius <= 0``, an empty
        or non-finite ``thetas``.
    """
    p = checks.integer("agents_per_oscillator", agents_per_oscillator, 1)
    N = checks.integer("num_agents", num_agents, 1)
    if N % p:
        raise ValueError(f"num_agents must be a multiple of agents_per_oscillator = {p}, "
                         f"got {N}")
    rho = checks.number("spectral_radius", spectral_radius, 0, lo_open=True)
    if isinstance(thetas, (str, bytes)) or not isinstance(thetas, (Sequence, np.ndarray)):
        raise ValueError(f"thetas must be a sequence of numbers, got {thetas!r:.60}")
    th = [checks.number(f"thetas[{i}]", t) for i, t in enumerate(thetas)]
    if not th:
        raise ValueError("thetas must hold at least one angle")
    m = N // p
    n = 2 * m
    ang = np.asarray(th, dtype=float)[np.arange(m) % len(th)]
    c, s = rho * np.cos(ang), rho * np.sin(ang)
    A = np.zeros((n, n))
    i0, i1 = np.arange(0, n, 2), np.arange(1, n, 2)
    A[i0, i0], A[i0, i1], A[i1, i0], A[i1, i1] = c, -s, s, c
    empty = np.zeros((0, n))
    Cs = []
    for i in range(N):
        if i % p:
            Cs.append(empty)
        else:
            Ci = np.zeros((2, n))
            Ci[0, 2 * (i // p)] = Ci[1, 2 * (i // p) + 1] = 1.0
            Cs.append(Ci)
    return Plant(A=A, C=tuple(Cs), name=f"oscillator_bank(N={N}, m={m}, rho={rho:g})")
