"""Run-time equalized-recovery observer with prefix-selected gains (Hassaan, Shen, Yong).

:class:`EqualizedRecoveryEstimator` runs the estimator of eqs. (4)-(5): at step ``k`` it
records which measurements of the current horizon have arrived, forms the observed event
``e_k`` (Definition 2), walks one step down the prefix tree of ``L^E'`` and applies the
gains of that prefix. Two schedules follow the implementation strategy of section III-B3:

* periodic: the same gains are reused on every block ``[jT, (j+1)T)``; data arriving after
  its block are ignored (they count as missing);
* switching: an equalized-performance design (horizon 1, data on time) runs while data
  arrive on time; the first late step starts a horizon-``T`` recovery window with the
  design of ``L.first_delayed()``; after ``T`` steps the performance mode resumes.

The module also holds the checks of the design against the paper's own formulation: the
constraint sets C(L^E') (eq. (6)) and D(L^E') (eq. (7)) on stacked gains, and the error
map of eq. (9) built from the Appendix's stacked matrices (:func:`worst_case_levels`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from netsense.estimators.equalized_design import EqualizedDesign, EqualizedProblem, design
from netsense.sensing.delays import DelayLanguage, EventLanguage

__all__ = ["EqualizedRecoveryEstimator", "causality_mask", "constraint_violation",
           "design_switching", "error_map", "prefix_constraints", "worst_case_levels"]


# ----------------------------------------------------------------- constraints (6), (7)
def prefix_constraints(lang: EventLanguage) -> list[tuple[int, int, int]]:
    """Triples ``(alpha, beta, length)`` of C(L^E'), eq. (6): ``E'_alpha`` and ``E'_beta``
    share their first ``length`` events, so ``BM_length`` of their ``M`` and ``L`` and the
    first ``length n`` entries of ``nu`` must agree (longest shared length only)."""
    out = []
    for a in range(len(lang)):
        for b in range(a + 1, len(lang)):
            sa, sb = lang.sequences[a], lang.sequences[b]
            m = next((k for k in range(lang.T) if sa[k] != sb[k]), lang.T)
            if m > 0:
                out.append((a, b, m))
    return out


def causality_mask(E: np.ndarray, n: int, p: int) -> np.ndarray:
    """Allowed non-zeros of ``M^alpha`` (``nT x pT``) under D(L^E'), eq. (7): block
    ``(k, i)`` may be non-zero only if ``E_alpha[k, i] = 1`` (data ``i`` known at ``k``);
    for ``L^alpha`` only the diagonal blocks of this mask apply."""
    return np.kron(np.asarray(E), np.ones((n, p))).astype(bool)


def constraint_violation(d: EqualizedDesign) -> tuple[float, float]:
    """Largest violation of C(L^E') and of D(L^E') by the stacked gains of a design."""
    n, p = d.problem.n, d.problem.p
    st = [d.stacked(a) for a in range(len(d.events))]
    c_viol = 0.0
    for a, b, m in prefix_constraints(d.events):
        (Ma, La, va), (Mb, Lb, vb) = st[a], st[b]
        r, c = m * n, m * p
        c_viol = max(c_viol, np.abs(Ma[:r, :c] - Mb[:r, :c]).max(),
                     np.abs(La[:r, :c] - Lb[:r, :c]).max(), np.abs(va[:r] - vb[:r]).max())
    d_viol = 0.0
    for a, (M, L, _) in enumerate(st):
        mask = causality_mask(d.events.event_matrix(a), n, p)
        dmask = mask & np.kron(np.eye(d.problem.T), np.ones((n, p))).astype(bool)
        d_viol = max(d_viol, np.abs(M[~mask]).max(initial=0), np.abs(L[~dmask]).max(initial=0))
    return float(c_viol), float(d_viol)


# ----------------------------------------------------------------- eq. (9)
def _prod(A: np.ndarray, i: int, k: int) -> np.ndarray:
    """``A_i^k = A_{k-1} ... A_i`` of the Appendix (identity when ``k == i``)."""
    out = np.eye(A.shape[1])
    for j in range(i, k):
        out = A[j] @ out
    return out


def _blkdiag(blocks: np.ndarray) -> np.ndarray:
    T, r, c = blocks.shape
    out = np.zeros((T * r, T * c))
    for k in range(T):
        out[k * r:(k + 1) * r, k * c:(k + 1) * c] = blocks[k]
    return out


def error_map(problem: EqualizedProblem, M: np.ndarray, L: np.ndarray, nu: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """``G = [Theta Psi Xi]`` and ``c = H nu + Upsilon s0`` of eq. (9), from the stacked
    matrices ``A, H, C, Phi, Gamma, W, V`` of the Appendix; ``x~ = G [w; v; x~_0] + c``.

    ``M`` and block-diagonal ``L`` are ``nT x pT``, ``nu`` is ``(nT,)``.
    """
    P, T, n, p = problem, problem.T, problem.n, problem.p
    A_bar = np.vstack([np.eye(n)] + [_prod(P.A, 0, k) for k in range(1, T + 1)])
    Lk = np.stack([L[k * n:(k + 1) * n, k * p:(k + 1) * p] for k in range(T)])
    Phi_k = P.A - Lk @ P.C
    Phi = np.vstack([np.eye(n)] + [_prod(Phi_k, 0, k) for k in range(1, T + 1)])
    H = np.zeros((n * (T + 1), n * T))
    Gam = np.zeros_like(H)
    for k in range(1, T + 1):
        for i in range(1, k + 1):
            H[k * n:(k + 1) * n, (i - 1) * n:i * n] = _prod(P.A, i, k)
            Gam[k * n:(k + 1) * n, (i - 1) * n:i * n] = _prod(Phi_k, i, k)
    Cb = np.hstack([_blkdiag(P.C), np.zeros((p * T, n))])
    F = np.eye(n * (T + 1)) + H @ (M + L) @ Cb
    Theta = F @ Gam @ _blkdiag(P.W)
    Psi = (H @ (M + L) @ (np.eye(p * T) - Cb @ Gam @ L) - Gam @ L) @ _blkdiag(P.V)
    Xi = F @ Phi
    return np.hstack([Theta, Psi, Xi]), H @ nu + (A_bar - Xi) @ P.s0


def worst_case_levels(problem: EqualizedProblem, M, L, nu, mu1: float) -> np.ndarray:
    """Exact worst case of ``||x~_k||_inf`` (``k = 0..T``) over ``||w|| <= eta_w``,
    ``||v|| <= eta_v``, ``||x~_0|| <= mu1``, via eq. (9): what Proposition 1 bounds by
    ``mu^alpha_{2,k}`` (and ``mu_1`` at ``k = T``)."""
    G, c = error_map(problem, M, L, nu)
    T = problem.T
    b = np.concatenate([np.full(problem.W.shape[2] * T, problem.eta_w),
                        np.full(problem.V.shape[2] * T, problem.eta_v),
                        np.full(problem.n, mu1)])
    return (np.abs(c) + np.abs(G) @ b).reshape(T + 1, problem.n).max(axis=1)


# ----------------------------------------------------------------- run time, eqs. (4)-(5)
def design_switching(problem: EqualizedProblem, **search) -> tuple[EqualizedDesign,
                                                                    EqualizedDesign]:
    """Designs for the switching schedule of section III-B3 with one common ``mu_1``.

    Returns ``(recovery, performance)``: the recovery design uses
    ``problem.language.first_delayed()``; the performance design is the horizon-1 design
    with the data on time (equalized performance). Each ``mu_1`` is first optimised on its
    own; the smaller design is then re-solved at the larger ``mu_1`` (feasible by the
    monotonicity shown in :func:`~netsense.estimators.equalized_design.design`), so that
    both modes hand over the same level.
    """
    for name in ("A", "C", "W", "V", "L"):
        M = getattr(problem, name)
        if not np.allclose(M, M[0]):
            raise ValueError(f"the switching schedule needs a time-invariant plant; {name} "
                             "varies over the horizon")
    rec_p = replace(problem, language=problem.language.first_delayed())
    perf_p = EqualizedProblem(A=problem.A[0], C=problem.C[0], W=problem.W[0],
                              V=problem.V[0], L=problem.L[0], s0=problem.s0,
                              eta_w=problem.eta_w, eta_v=problem.eta_v,
                              language=DelayLanguage.from_words(["0"]))
    rec, perf = design(rec_p, **search), design(perf_p, **search)
    mu = max(rec.mu1, perf.mu1)
    if rec.mu1 < mu:
        rec = design(rec_p, mu1=mu)
    else:
        perf = design(perf_p, mu1=mu)
    return rec, perf


class EqualizedRecoveryEstimator:
    """Estimator (4)-(5) with gains chosen from the observed prefix of data availability.

    Parameters
    ----------
    recovery : EqualizedDesign
        Horizon-``T`` design; used periodically, or for the recovery windows when
        ``performance`` is given (its words must then all start late, ``tau(0) >= 1``).
    performance : EqualizedDesign, optional
        Horizon-1 design for data on time (``language == {"0"}``) with the same ``mu_1``;
        enables the switching schedule (see :func:`design_switching`).
    B : (n, m) array, optional
        Input matrix of a known input ``u``.

    Attributes
    ----------
    estimate : (n,) array
        ``x^_k``.
    bound : float
        Guaranteed bound on ``||x_k - x^_k||_inf`` when ``||x_0 - x^_0||_inf <= mu_1`` and
        the noise and the delays obey the design (``mu^alpha_{2,k}`` of the observed prefix).
    mode : str
        ``"recovery"`` or ``"performance"``.
    """

    def __init__(self, recovery: EqualizedDesign, performance: EqualizedDesign | None = None,
                 *, B: np.ndarray | None = None) -> None:
        P = recovery.problem
        self.rec, self.perf = recovery, performance
        self.n, self.p, self.T = P.n, P.p, P.T
        if performance is not None:
            Q = performance.problem
            if Q.language.words != ((0,),):
                raise ValueError("performance design must have horizon 1 and the language "
                                 f"{{'0'}}, got words {Q.language.words}")
            if (Q.n, Q.p) != (P.n, P.p):
                raise ValueError(f"performance design has (n, p) = {(Q.n, Q.p)}, the recovery "
                                 f"design {(P.n, P.p)}")
            if abs(performance.mu1 - recovery.mu1) > 1e-9 * max(1.0, recovery.mu1):
                raise ValueError(f"both designs need the same mu1, got {recovery.mu1} "
                                 f"(recovery) and {performance.mu1} (performance)")
            if any(w[0] == 0 for w in P.language.words):
                raise ValueError("in the switching schedule every recovery word must start "
                                 "late (tau(0) >= 1); use language.first_delayed()")
        self.B = None if B is None else np.asarray(B, dtype=float)
        if self.B is not None and (self.B.ndim != 2 or self.B.shape[0] != P.n):
            raise ValueError(f"B must have shape ({P.n}, m), got {self.B.shape}")
        self.reset(np.zeros(P.n))

    def reset(self, x_hat0: np.ndarray, k0: int = 0) -> None:
        """Start at step ``k0`` with estimate ``x_hat0`` (assumed within ``mu_1``)."""
        x_hat0 = np.asarray(x_hat0, dtype=float)
        if x_hat0.shape != (self.n,):
            raise ValueError(f"x_hat0 must have shape ({self.n},), got {x_hat0.shape}")
        self.k, self.estimate, self.bound = int(k0), x_hat0.copy(), self.rec.mu1
        self.mode = "recovery" if self.perf is None else "performance"
        self._open_window()

    def _open_window(self) -> None:
        self.k0, self.node = self.k, 0
        self.s = self.rec.problem.s0.copy()
        self._pred: dict[int, np.ndarray] = {}
        self._innov: dict[int, np.ndarray] = {}

    def _check(self, arrivals: Mapping[int, np.ndarray] | None, u) -> dict[int, np.ndarray]:
        out = {}
        for i, z in dict(arrivals or {}).items():
            if not isinstance(i, (int, np.integer)) or i > self.k:
                raise ValueError(f"arrival keys must be step indices <= k = {self.k}, got {i!r}")
            z = np.asarray(z, dtype=float).reshape(-1)
            if z.shape != (self.p,) or not np.all(np.isfinite(z)):
                raise ValueError(f"measurement of step {i} must be {self.p} finite numbers, "
                                 f"got shape {z.shape}")
            if int(i) - self.k0 in self._innov:
                raise ValueError(f"measurement of step {i} arrived twice")
            out[int(i)] = z
        if u is not None:
            if self.B is None:
                raise ValueError("an input u was given but the estimator has no B matrix")
            if np.shape(u) != (self.B.shape[1],):
                raise ValueError(f"u must have shape ({self.B.shape[1]},), got {np.shape(u)}")
        return out

    def step(self, arrivals: Mapping[int, np.ndarray] | None = None,
             u: np.ndarray | None = None) -> np.ndarray:
        """Process the measurements arriving at step ``k`` (``{i: z_i}``, ``i <= k``) and
        return ``x^_{k+1}`` (eqs. (4)-(5)); ``self.bound`` then bounds its error."""
        got = self._check(arrivals, u)
        Bu = 0.0 if u is None else self.B @ np.asarray(u, dtype=float)
        if self.mode == "performance":
            if self.k in got:
                d = self.perf
                q = d.tree.children[0][1]
                s0 = d.problem.s0
                zt = got[self.k] - d.problem.C[0] @ (self.estimate + s0)
                u_e = d.nu[q] + d.M_rows[q] @ zt
                self.estimate = d.problem.A[0] @ self.estimate + Bu - u_e
                self.bound, self.k = float(d.level[q]), self.k + 1
                return self.estimate.copy()
            self.mode = "recovery"
            self._open_window()
        d, P, t = self.rec, self.rec.problem, self.k - self.k0
        pred = {**self._pred, t: self.estimate + self.s}
        innov = dict(self._innov)
        for i, z in got.items():
            if i >= self.k0:
                innov[i - self.k0] = z - P.C[i - self.k0] @ pred[i - self.k0]
        j = int("".join("1" if ell in innov else "0" for ell in range(t + 1)), 2)
        q = d.tree.children[self.node].get(j)
        if q is None:
            seen = "".join("1" if ell in innov else "0" for ell in range(t + 1))
            raise RuntimeError(f"observed availability prefix {d.tree.prefixes[self.node]} "
                               f"then event {seen!r} at step {t} of the window starting at "
                               f"k = {self.k0} is not in the design's language")
        u_e = d.nu[q].copy()
        for ell, zt in innov.items():
            u_e += d.M_rows[q][:, ell * self.p:(ell + 1) * self.p] @ zt
        s_next = P.A[t] @ self.s + u_e
        if t in innov:
            s_next += d.L_eff[q] @ innov[t]
        self.estimate = P.A[t] @ self.estimate + Bu - u_e
        self.s, self.node, self._pred, self._innov = s_next, q, pred, innov
        self.bound, self.k = float(d.level[q]), self.k + 1
        if t + 1 == self.T:
            if self.perf is not None:
                self.mode = "performance"
            self._open_window()
        return self.estimate.copy()
