"""Design of the prefix-based equalized-recovery observer (Hassaan, Shen and Yong).

The estimator (4)-(5) has error ``x~ = x - x^`` and auxiliary error ``e = x~ - s`` with

.. math::  e_{k+1} = (A_k - L_k C_k) e_k + W_k w_k - L_k V_k v_k, \\qquad
           x~_{k+1} = A_k x~_k + W_k w_k + \\nu_k + \\sum_{i \\le k} M_{(k,i)} (C_i e_i + V_i v_i),

which stacked over the horizon is ``x~ = G [w; v; x~_0] + H nu + Upsilon s_0`` with
``G = [Theta Psi Xi]`` of eq. (9) (:func:`netsense.estimators.equalized.error_map` builds it
from the Appendix's stacked matrices). With ``L`` and ``s_0`` fixed, Proposition 1 at a fixed
``mu_1`` is a linear program (:func:`solve_fixed`); :func:`design` searches ``mu_1``
(bisection on feasibility, which is monotone, then a line search on the cost).

How the LP is laid out: the gains that act at step ``k`` and the error ``x~_k`` depend on
the data seen up to step ``k-1`` only, so every node of the prefix tree of ``L^E'`` owns
one copy of them. Sharing variables along the tree *is* the prefix constraint C(L^E') of
eq. (6); creating ``M_(k,i)`` only where ``E_alpha[k, i] = 1`` *is* the causality
constraint D(L^E') of eq. (7). Each node's error map ``X`` (rows of ``G`` at one step)
follows the recursion above, and ``|X| <= P`` linearises the robust counterpart of
Proposition 1 (the two nonnegative parts of ``P`` are the dual matrices ``Pi``). The
intermediate level of a node stands for ``mu^alpha_{2,k}`` of every sequence through it,
so the cost ``mu_1 + sum_{k, alpha} mu^alpha_{2,k}`` weights it by that count.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from netsense.sensing.delays import DelayLanguage, EventLanguage, PrefixTree, event_string

__all__ = ["EqualizedDesign", "EqualizedProblem", "LPTemplate", "build_lp", "design",
           "solve_fixed"]


def _seq(name: str, M, T: int, rows: int | None, cols: int | None) -> np.ndarray:
    M = np.asarray(M, dtype=float)
    if M.ndim == 2:
        M = np.broadcast_to(M, (T, *M.shape)).copy()
    if M.ndim != 3 or M.shape[0] != T:
        raise ValueError(f"{name} must be a matrix or a sequence of T = {T} matrices, "
                         f"got shape {M.shape}")
    if (rows is not None and M.shape[1] != rows) or (cols is not None and M.shape[2] != cols):
        raise ValueError(f"{name} must have blocks of shape ({rows}, {cols}), got {M.shape[1:]}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains NaN or infinite entries")
    return M


@dataclass(frozen=True, eq=False)
class EqualizedProblem:
    """Plant (1), noise bounds and delay language of Problem 1.

    Parameters
    ----------
    A : (n, n) or (T, n, n) array
        ``A_k`` (a single matrix means time-invariant).
    C : (p, n) or (T, p, n) array
        ``C_k``.
    language : DelayLanguage
        Allowed delay patterns over the horizon ``T = language.T``.
    W : (n, n_w) or (T, n, n_w) array, optional
        Process-noise input ``W_k``; default none (``n_w = 0``, the paper's ``W = []``).
    V : (p, n_v) or (T, p, n_v) array, optional
        Measurement-noise input ``V_k``; default ``I_p``.
    eta_w, eta_v : float
        Infinity-norm bounds on ``w_k`` and ``v_k``.
    L : (n, p) or (T, n, p) array, optional
        Fixed Luenberger gains ``L_k`` (default zero); ``L_k`` acts only on sequences whose
        data of step ``k`` is on time (D(L^E') for ``L``).
    s0 : (n,) array, optional
        Fixed initial auxiliary state (default zero, as in section IV).
    """

    A: np.ndarray
    C: np.ndarray
    language: DelayLanguage
    W: np.ndarray | None = None
    V: np.ndarray | None = None
    eta_w: float = 0.0
    eta_v: float = 0.0
    L: np.ndarray | None = None
    s0: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.language, DelayLanguage):
            raise ValueError("language must be a DelayLanguage, "
                             f"got {type(self.language).__name__}")
        T = self.language.T
        A = _seq("A", self.A, T, None, None)
        n = A.shape[1]
        if A.shape[2] != n:
            raise ValueError(f"A must be square, got blocks of shape {A.shape[1:]}")
        C = _seq("C", self.C, T, None, n)
        p = C.shape[1]
        W = _seq("W", np.zeros((n, 0)) if self.W is None else self.W, T, n, None)
        V = _seq("V", np.eye(p) if self.V is None else self.V, T, p, None)
        L = _seq("L", np.zeros((n, p)) if self.L is None else self.L, T, n, p)
        s0 = np.zeros(n) if self.s0 is None else np.asarray(self.s0, dtype=float)
        if s0.shape != (n,):
            raise ValueError(f"s0 must have shape ({n},), got {s0.shape}")
        for name in ("eta_w", "eta_v"):
            val = getattr(self, name)
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {val!r}")
        for name, val in (("A", A), ("C", C), ("W", W), ("V", V), ("L", L), ("s0", s0)):
            object.__setattr__(self, name, val)

    @property
    def T(self) -> int:
        return self.language.T

    @property
    def n(self) -> int:
        return self.A.shape[1]

    @property
    def p(self) -> int:
        return self.C.shape[1]


# ----------------------------------------------------------------- results
@dataclass(frozen=True, eq=False)
class EqualizedDesign:
    """Gains and levels of a solved design.

    Attributes
    ----------
    problem : EqualizedProblem
    events : EventLanguage
        The reduced language ``L^E'``.
    tree : PrefixTree
        Its prefix tree; node ``q`` at depth ``k >= 1`` owns the gains of step ``k-1``.
    mu1 : float
        Equalized recovery level ``mu_1``.
    M_rows : tuple of arrays
        ``M_rows[q]`` is ``[M_(k-1,0) ... M_(k-1,k-1)]`` (``n x p k``) for node ``q``.
    nu, L_eff : tuple of arrays
        ``nu_{k-1}`` and the effective ``L_{k-1}`` of node ``q``.
    level : (nodes,) array
        Bound on ``||x~_k||_inf`` once node ``q`` (depth ``k``) is reached (``mu_1`` at the
        root and the leaves).
    cost : float
        ``J = mu_1 + sum_{k, alpha} mu^alpha_{2,k}``.
    stats : dict
        LP size and solve times; ``search`` lists ``(mu1, feasible, cost)`` of every solve.
    """

    problem: EqualizedProblem
    events: EventLanguage
    tree: PrefixTree
    mu1: float
    M_rows: tuple[np.ndarray, ...]
    nu: tuple[np.ndarray, ...]
    L_eff: tuple[np.ndarray, ...]
    level: np.ndarray
    cost: float
    stats: dict = field(default_factory=dict)

    @property
    def mu2(self) -> np.ndarray:
        """``mu^alpha_{2,k}`` as an ``(|L^E'|, T+1)`` array."""
        return np.array([self.level[self.tree.path(s)] for s in self.events.sequences])

    def stacked(self, alpha: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stacked ``(M^alpha, L^alpha, nu^alpha)`` of the Appendix for sequence ``alpha``."""
        T, n, p = self.problem.T, self.problem.n, self.problem.p
        M, L, nu = np.zeros((n * T, p * T)), np.zeros((n * T, p * T)), np.zeros(n * T)
        for k, q in enumerate(self.tree.path(self.events.sequences[alpha])[1:]):
            M[k * n:(k + 1) * n, :p * (k + 1)] = self.M_rows[q]
            L[k * n:(k + 1) * n, k * p:(k + 1) * p] = self.L_eff[q]
            nu[k * n:(k + 1) * n] = self.nu[q]
        return M, L, nu


# ----------------------------------------------------------------- LP template
@dataclass(eq=False)
class LPTemplate:
    """Sparse LP of Proposition 1 for a problem, with ``mu_1`` left as a parameter.

    Entries that scale with ``mu_1`` (the ``x~_0`` columns of the robust rows, the terminal
    right-hand sides and the lower bounds ``mu_2 >= mu_1``) are flagged so that
    :meth:`at` assembles the LP of any ``mu_1`` without rebuilding it.
    """

    events: EventLanguage
    tree: PrefixTree
    n_var: int
    obj: np.ndarray
    eq: tuple[np.ndarray, np.ndarray, np.ndarray]
    b_eq: np.ndarray
    ub: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    b_ub: tuple[np.ndarray, np.ndarray]
    lower: np.ndarray
    upper: np.ndarray
    mu_lower: np.ndarray
    layout: list[dict]
    problem: EqualizedProblem
    build_seconds: float = 0.0

    @property
    def size(self) -> dict:
        return {"n_vars": self.n_var, "n_eq": len(self.b_eq), "n_ub": len(self.b_ub[0]),
                "nnz": len(self.eq[2]) + len(self.ub[2]), "tree_nodes": len(self.tree),
                "sequences": len(self.events), "words": len(self.problem.language.words)}

    def at(self, mu1: float):
        """``(c, A_ub, b_ub, A_eq, b_eq, bounds)`` for ``scipy.optimize.linprog`` at ``mu1``."""
        import scipy.sparse as sp  # scipy's solvers load on first use

        r, c, v, scaled = self.ub
        A_ub = sp.csr_matrix((np.where(scaled, v * mu1, v), (r, c)),
                             shape=(len(self.b_ub[0]), self.n_var))
        b_ub = np.where(self.b_ub[1], self.b_ub[0] * mu1, self.b_ub[0])
        A_eq = sp.csr_matrix((self.eq[2], (self.eq[0], self.eq[1])),
                             shape=(len(self.b_eq), self.n_var))
        lb = np.where(self.mu_lower, mu1, self.lower)
        bounds = np.column_stack([lb, self.upper])
        return self.obj, A_ub, b_ub, A_eq, self.b_eq, bounds

    def unpack(self, x: np.ndarray, mu1: float):
        """Per-node gains ``M_rows``, ``nu``, ``L_eff`` and levels from an LP solution."""
        P = self.problem
        n, p = P.n, P.p
        M_rows, nus, Ls = [np.zeros((n, 0))], [np.zeros(n)], [np.zeros((n, p))]
        level = np.full(len(self.tree), float(mu1))
        for q, lay in enumerate(self.layout[1:], start=1):
            k = lay["depth"]
            M = np.zeros((n, p * k))
            for a, i in enumerate(lay["avail"]):
                s = lay["M"] + a * n * p
                M[:, i * p:(i + 1) * p] = x[s:s + n * p].reshape(n, p)
            M_rows.append(M)
            nus.append(x[lay["nu"]:lay["nu"] + n].copy())
            Ls.append(lay["L"])
            if lay["mu"] is not None:
                level[q] = x[lay["mu"]]
        return tuple(M_rows), tuple(nus), tuple(Ls), level


def build_lp(problem: EqualizedProblem) -> LPTemplate:
    """Assemble the LP of Proposition 1 (``L``, ``s0`` fixed) over the prefix tree of ``L^E'``.

    Per node ``q`` of depth ``k >= 1`` (event ``e_{k-1}`` just observed): variables
    ``M_(k-1,i)`` for the available ``i`` (D(L^E')), ``nu_{k-1}``, the error map ``X_q``
    (``n x (n + k(n_w + n_v))``, columns ``[x~_0, w_0, v_0, ..., w_{k-1}, v_{k-1}]``), the
    constant ``c_q``, ``P_q >= |X_q|`` and the level ``mu_q`` (``mu_1`` at the leaves).

    When ``s0 = 0`` the offsets ``nu`` are fixed to zero. This loses nothing: the
    uncertainty set is symmetric, so with ``(M, nu)`` feasible ``(M, -nu)`` is too, and so is
    their average ``(M, 0)`` with levels no larger. It also stops the LP from parking an
    arbitrary constant offset in the slack of the terminal constraints, which would cost
    typical-case accuracy without changing the guarantee.
    """
    t0 = time.perf_counter()
    P = problem
    affine = bool(np.any(P.s0 != 0))
    T, n, p = P.T, P.n, P.p
    nw, nv = P.W.shape[2], P.V.shape[2]
    nc = [n + k * (nw + nv) for k in range(T + 1)]
    events = P.language.event_language()
    tree = events.prefix_tree()
    bcol = np.concatenate([np.ones(n)] + [np.r_[np.full(nw, P.eta_w), np.full(nv, P.eta_v)]] * T)
    bscaled = np.arange(nc[T]) < n
    eq_r, eq_c, eq_v, b_eq = [], [], [], []
    ub_r, ub_c, ub_v, ub_s, b_ub, b_sc = [], [], [], [], [], []
    obj: list[float] = []
    lower: list[float] = []
    upper: list[float] = []
    mu_lower: list[bool] = []
    nvar = [0]

    def new(count: int, lb: float = -np.inf, cost: float = 0.0, mu: bool = False,
            ub: float = np.inf) -> int:
        start = nvar[0]
        nvar[0] += count
        obj.extend([cost] * count)
        lower.extend([lb] * count)
        upper.extend([ub] * count)
        mu_lower.extend([mu] * count)
        return start

    e0 = np.zeros((n, nc[T]))
    e0[:, :n] = np.eye(n)
    layout: list[dict] = [{"depth": 0, "X": None, "c": None, "e": e0, "e0": -P.s0, "Z": [],
                           "z0": []}]
    for q in range(1, len(tree)):
        par = layout[tree.parent[q]]
        k = tree.depth(q)
        t = k - 1
        d = event_string(t, tree.prefixes[q][-1])
        avail = [i for i in range(k) if d[i] == "1"]
        Sw = np.zeros((nw, nc[T]))
        Sv = np.zeros((nv, nc[T]))
        off = n + t * (nw + nv)
        Sw[:, off:off + nw] = np.eye(nw)
        Sv[:, off + nw:off + nw + nv] = np.eye(nv)
        Z = par["Z"] + [P.C[t] @ par["e"] + P.V[t] @ Sv]
        z0 = par["z0"] + [P.C[t] @ par["e0"]]
        L = P.L[t] if d[t] == "1" else np.zeros((n, p))
        Phi = P.A[t] - L @ P.C[t]
        lay = {"depth": k, "avail": avail, "L": L, "Z": Z, "z0": z0,
               "e": Phi @ par["e"] + P.W[t] @ Sw - L @ P.V[t] @ Sv, "e0": Phi @ par["e0"]}
        m = nc[k]
        lay["M"] = new(len(avail) * n * p)
        lay["nu"] = new(n) if affine else new(n, lb=0.0, ub=0.0)
        lay["X"] = new(n * m)
        lay["c"] = new(n)
        lay["P"] = new(n * m, lb=0.0)
        leaf = k == T
        lay["mu"] = None if leaf else new(1, lb=0.0, cost=float(len(tree.sequences[q])), mu=True)
        layout.append(lay)
        # X_q = A_t X_par + W_t S^w_t + sum_i M_(t,i) Z_i  (one equality per entry)
        base = len(b_eq)
        rows = base + np.arange(n * m).reshape(n, m)
        rhs = (P.W[t] @ Sw)[:, :m].copy()
        eq_r.append(rows.ravel())
        eq_c.append(lay["X"] + np.arange(n * m))
        eq_v.append(np.ones(n * m))
        mp = nc[k - 1]
        if par["X"] is None:
            rhs[:, :n] += P.A[t]
        else:
            rr = np.broadcast_to(rows[:, None, :mp], (n, n, mp))
            cc = par["X"] + (np.arange(n)[None, :, None] * mp + np.arange(mp)[None, None, :])
            vv = np.broadcast_to(-P.A[t][:, :, None], (n, n, mp))
            _add(eq_r, eq_c, eq_v, rr, np.broadcast_to(cc, (n, n, mp)), vv)
        for a, i in enumerate(avail):
            Zi = Z[i][:, :m]
            rr = np.broadcast_to(rows[:, None, :], (n, p, m))
            cc = (lay["M"] + a * n * p + np.arange(n)[:, None, None] * p
                  + np.arange(p)[None, :, None])
            _add(eq_r, eq_c, eq_v, rr, np.broadcast_to(cc, (n, p, m)),
                 np.broadcast_to(-Zi[None], (n, p, m)))
        b_eq.extend(rhs.ravel())
        # c_q = A_t c_par + nu_t + sum_i M_(t,i) z0_i
        rows_c = len(b_eq) + np.arange(n)
        _add(eq_r, eq_c, eq_v, rows_c, lay["c"] + np.arange(n), np.ones(n))
        _add(eq_r, eq_c, eq_v, rows_c, lay["nu"] + np.arange(n), -np.ones(n))
        if par["c"] is not None:
            _add(eq_r, eq_c, eq_v, np.repeat(rows_c, n), par["c"] + np.tile(np.arange(n), n),
                 -P.A[t].ravel())
        for a, i in enumerate(avail):
            cc = lay["M"] + a * n * p + np.arange(n * p)
            _add(eq_r, eq_c, eq_v, np.repeat(rows_c, p), cc, -np.tile(z0[i], n))
        b_eq.extend(np.zeros(n))
        # robust counterpart: |X| <= P, +-c + P b <= mu (or <= mu_1 at the leaves)
        for sign in (1.0, -1.0):
            rows = len(b_ub) + np.arange(n * m)
            _add(ub_r, ub_c, ub_v, rows, lay["X"] + np.arange(n * m), np.full(n * m, sign),
                 ub_s, False)
            _add(ub_r, ub_c, ub_v, rows, lay["P"] + np.arange(n * m), -np.ones(n * m),
                 ub_s, False)
            b_ub.extend(np.zeros(n * m))
            b_sc.extend([False] * (n * m))
        bk = np.tile(bcol[:m], n)
        keep = bk != 0
        pr = np.repeat(np.arange(n), m)[keep]
        pc = lay["P"] + np.arange(n * m)[keep]
        for sign in (1.0, -1.0):
            rows = len(b_ub) + np.arange(n)
            _add(ub_r, ub_c, ub_v, rows, lay["c"] + np.arange(n), np.full(n, sign), ub_s, False)
            _add(ub_r, ub_c, ub_v, rows[pr], pc, bk[keep], ub_s,
                 np.tile(bscaled[:m], n)[keep])
            if leaf:
                b_ub.extend(np.ones(n))
                b_sc.extend([True] * n)
            else:
                _add(ub_r, ub_c, ub_v, rows, np.full(n, lay["mu"]), -np.ones(n), ub_s, False)
                b_ub.extend(np.zeros(n))
                b_sc.extend([False] * n)
    cat = np.concatenate
    return LPTemplate(
        events=events, tree=tree, n_var=nvar[0], obj=np.asarray(obj),
        eq=(cat(eq_r).astype(np.int64), cat(eq_c).astype(np.int64), cat(eq_v)),
        b_eq=np.asarray(b_eq),
        ub=(cat(ub_r).astype(np.int64), cat(ub_c).astype(np.int64), cat(ub_v),
            cat(ub_s).astype(bool)),
        b_ub=(np.asarray(b_ub, dtype=float), np.asarray(b_sc, dtype=bool)),
        lower=np.asarray(lower), upper=np.asarray(upper), mu_lower=np.asarray(mu_lower),
        layout=layout, problem=P,
        build_seconds=time.perf_counter() - t0)


def _add(R: list, Cc: list, Vv: list, rows, cols, vals, S: list | None = None,
         scaled=False) -> None:
    """Append the non-zero COO triplets (and their ``mu_1``-scaling flags) to the lists."""
    rows, cols, vals = (np.asarray(x).ravel() for x in np.broadcast_arrays(rows, cols, vals))
    nz = vals != 0
    R.append(rows[nz])
    Cc.append(cols[nz])
    Vv.append(vals[nz].astype(float))
    if S is not None:
        S.append(np.broadcast_to(np.asarray(scaled, dtype=bool), nz.shape)[nz])


# ----------------------------------------------------------------- solving
def solve_fixed(problem: EqualizedProblem, mu1: float, *, template: LPTemplate | None = None,
                feasibility_only: bool = False) -> EqualizedDesign | None:
    """Proposition 1 with ``L``, ``s0`` and ``mu_1`` fixed: one LP; ``None`` if infeasible.

    Parameters
    ----------
    problem : EqualizedProblem
    mu1 : float
        Equalized recovery level ``mu_1 >= 0`` (Definition 1).
    template : LPTemplate, optional
        A prebuilt :func:`build_lp` of ``problem`` (reused across ``mu_1`` values).
    feasibility_only : bool
        Drop the objective (a cheaper phase-1 solve); the returned gains are feasible but
        their intermediate levels are not minimised.

    Returns
    -------
    EqualizedDesign or None
        ``None`` when HiGHS proves the LP infeasible.

    Raises
    ------
    ValueError
        If ``mu1`` is negative or not finite.
    RuntimeError
        If HiGHS stops for another reason than optimality or infeasibility.
    """
    if not np.isfinite(mu1) or mu1 < 0:
        raise ValueError(f"mu1 must be a finite number >= 0, got {mu1!r}")
    from scipy.optimize import linprog

    tpl = template or build_lp(problem)
    c, A_ub, b_ub, A_eq, b_eq, bounds = tpl.at(mu1)
    t0 = time.perf_counter()
    res = linprog(0 * c if feasibility_only else c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq,
                  b_eq=b_eq, bounds=bounds, method="highs")
    dt = time.perf_counter() - t0
    if res.status == 2:
        return None
    if res.status != 0:
        raise RuntimeError(f"HiGHS failed at mu1 = {mu1}: {res.message}")
    M_rows, nu, L_eff, level = tpl.unpack(res.x, mu1)
    N = len(tpl.events)
    cost = mu1 * (1 + 2 * N) + float(c @ res.x)
    stats = dict(tpl.size, solve_seconds=dt, build_seconds=tpl.build_seconds)
    return EqualizedDesign(problem, tpl.events, tpl.tree, float(mu1), M_rows, nu, L_eff,
                           level, cost, stats)


def design(problem: EqualizedProblem, mu1: float | None = None, *, rtol: float = 1e-3,
           span: float = 3.0, grid: int = 5, refine: int = 6) -> EqualizedDesign:
    """Solve Problem 1 through Proposition 1 with ``L`` and ``s0`` fixed.

    With ``mu1`` given, one LP (fixed-``mu_1`` mode). Otherwise: (i) bisection for the
    smallest feasible ``mu_1`` (phase-1 solves). Feasibility is monotone: if gains are
    feasible at ``mu_1``, each terminal row obeys ``a + mu_1 ||Xi_r||_1 <= mu_1`` with
    ``a >= 0``, so ``||Xi_r||_1 <= 1`` and the same gains stay feasible for every larger
    ``mu_1`` (the intermediate levels are free). (ii) The optimal cost ``J(mu_1)`` need
    not be monotone, so it is sampled on a geometric grid over ``[mu_min, span mu_min]``
    and refined by golden-section search next to the best grid point.
    ``stats["search"]`` records ``(mu1, feasible, cost)`` of every solve (cost ``nan`` for
    phase-1 solves).

    Parameters
    ----------
    problem : EqualizedProblem
    mu1 : float, optional
        Fixed recovery level (fixed-``mu_1`` mode); default: searched.
    rtol : float
        Relative width of the final bisection bracket of the smallest feasible ``mu_1``.
    span, grid : float, int
        The cost is sampled at ``grid`` geometric points of ``[mu_min, span mu_min]``.
    refine : int
        Golden-section iterations around the best grid point.

    Returns
    -------
    EqualizedDesign
        The design with the lowest cost ``J = mu_1 + sum_{k, alpha} mu^alpha_{2,k}``.

    Raises
    ------
    ValueError
        If the fixed ``mu1`` is infeasible, or no ``mu_1 <= 1e8`` is.
    """
    tpl = build_lp(problem)
    trace: list[tuple[float, bool, float]] = []
    total = [0.0]

    def run(m: float, feas: bool = False) -> EqualizedDesign | None:
        d = solve_fixed(problem, m, template=tpl, feasibility_only=feas)
        total[0] += d.stats["solve_seconds"] if d else 0.0
        trace.append((float(m), d is not None, d.cost if d and not feas else float("nan")))
        return d

    def cost(m: float) -> float:
        if m not in cands:
            cands[m] = run(m)
        return cands[m].cost if cands[m] is not None else np.inf

    cands: dict[float, EqualizedDesign | None] = {}
    if mu1 is not None:
        best = run(mu1)
        if best is None:
            raise ValueError(f"the design is infeasible at the fixed mu1 = {mu1}")
    else:
        lo, hi = 0.0, 1.0
        while run(hi, feas=True) is None:
            lo, hi = hi, 4.0 * hi
            if hi > 1e8:
                raise ValueError("no feasible mu1 up to 1e8: the language/plant admits no "
                                 "equalized recovery with these fixed L and s0")
        for _ in range(200):  # noise-free problems are feasible at every mu1 > 0
            if hi - lo <= rtol * hi or hi < 1e-12:
                break
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if run(mid, feas=True) is not None else (mid, hi)
        keys = [float(m) for m in hi * np.geomspace(1.0, span, grid)]
        i = int(np.argmin([cost(m) for m in keys]))
        a, b = keys[max(i - 1, 0)], keys[min(i + 1, len(keys) - 1)]
        g = (np.sqrt(5.0) - 1.0) / 2.0
        x1, x2 = b - g * (b - a), a + g * (b - a)
        for _ in range(refine):
            if cost(x1) <= cost(x2):
                b, x2 = x2, x1
                x1 = b - g * (b - a)
            else:
                a, x1 = x1, x2
                x2 = a + g * (b - a)
        best = min((d for d in cands.values() if d is not None), key=lambda d: d.cost)
    stats = dict(best.stats, search=trace, total_solve_seconds=total[0], n_solves=len(trace))
    object.__setattr__(best, "stats", stats)
    return best
