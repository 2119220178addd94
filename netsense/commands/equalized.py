"""``netsense equalized``: design an equalized-recovery observer for delayed/missing data."""

from __future__ import annotations

import argparse

from netsense.commands._args import json_value, nonnegative_float, positive_float

NAME = "equalized"
HELP = ("Design the prefix-based equalized-recovery observer (Proposition 1 of the "
        "delayed-data paper) for a plant and a delay language; prints mu_1, the "
        "intermediate levels and the LP size and solve time.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--A", required=True, type=json_value,
                        help="system matrix as JSON, e.g. '[[2.0]]'")
    parser.add_argument("--C", required=True, type=json_value,
                        help="output matrix as JSON, e.g. '[[1.0]]'")
    parser.add_argument("--language", required=True,
                        help="'each:M:T' (each datum delayed by at most M over horizon T), "
                             "'missing:M:T' (at most M of T missing) or a comma-separated "
                             "word list such as '21210' or '060000,006000' ('x' = missing)")
    parser.add_argument("--eta-v", type=nonnegative_float, default=0.0, help="bound on ||v||_inf")
    parser.add_argument("--eta-w", type=nonnegative_float, default=0.0,
                        help="bound on ||w||_inf (W = I when > 0)")
    parser.add_argument("--mu1", type=positive_float, default=None,
                        help="fixed recovery level (default: searched)")


def parse_language(spec: str):
    """Language from ``each:M:T``, ``missing:M:T`` or a comma-separated word list."""
    from netsense.sensing.delays import DelayLanguage

    kind, _, rest = spec.partition(":")
    if kind in ("each", "missing"):
        try:
            m, T = (int(v) for v in rest.split(":"))
        except ValueError:
            raise ValueError(f"--language {spec!r}: expected {kind}:M:T with integers") from None
        if kind == "each":
            return DelayLanguage.each_delayed_at_most(m, T)
        return DelayLanguage.at_most_missing(m, T)
    return DelayLanguage.from_words(w.strip() for w in spec.split(","))


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from netsense.estimators.equalized_design import EqualizedProblem, design

    try:
        A = np.asarray(args.A, dtype=float)
    except (ValueError, TypeError):
        raise ValueError(f"--A must be a matrix of numbers, got {args.A!r}") from None
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not A.size:
        raise ValueError(f"--A must be a square matrix, got shape {A.shape}")
    try:
        C = np.asarray(args.C, dtype=float)
    except (ValueError, TypeError):
        raise ValueError(f"--C must be a matrix of numbers, got {args.C!r}") from None
    if C.ndim != 2 or C.shape[1] != A.shape[0]:
        raise ValueError(f"--C must be a matrix with n = {A.shape[0]} columns (the size of "
                         f"--A), got shape {C.shape}")
    lang = parse_language(args.language)
    P = EqualizedProblem(A=A, C=C, language=lang, eta_v=args.eta_v,
                         eta_w=args.eta_w, W=np.eye(A.shape[0]) if args.eta_w else None)
    d = design(P, mu1=args.mu1)
    s = d.stats
    print(f"|L| = {len(lang.words)} words, |L^E'| = {len(d.events)} event sequences, "
          f"{len(d.tree)} prefix-tree nodes")
    print(f"mu_1 = {d.mu1:.6g}   max mu_2 = {d.mu2.max():.6g}   J = {d.cost:.6g}")
    print(f"LP: {s['n_vars']} variables, {s['n_eq']} equalities, {s['n_ub']} inequalities, "
          f"{s['nnz']} non-zeros; {s['n_solves']} solves, {s['total_solve_seconds']:.2f} s")
    return 0
