"""``netsense sweep``: freshness-observer measurements over graph families vs the paper's bounds.

Every combination of ``--family``, ``--N``, ``--T``, ``--n`` and ``--param`` is one case;
each case runs ``--seeds`` graph sequences at once through the batched observer (see
:func:`netsense.studies.sweep.run_case`) and the cases run in ``--workers`` processes.
"""

from __future__ import annotations

import argparse
import itertools

from netsense.commands._args import nonnegative_int, positive_float, positive_int

NAME = "sweep"
HELP = ("Sweep graph families, N, T and plant size; measure trigger step, worst freshness "
        "index, steps to a relative error, messages, AoI against Lemma 3/5 and Corollary 1.")


def _ints(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") \
            from exc


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") \
            from exc


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--family", default="ring,random_jsc",
                        help="comma-separated families: ring, ring_backward, random_jsc, "
                             "gossip, markov, mobility")
    parser.add_argument("--N", type=_ints, default=[4, 6], help="numbers of agents, e.g. 4,6,8")
    parser.add_argument("--T", type=_ints, default=[1, 2],
                        help="periods (ring, ring_backward, random_jsc; T <= N for rings)")
    parser.add_argument("--n", type=_ints, default=[4], help="plant dimensions")
    parser.add_argument("--param", type=_floats, default=None,
                        help="family parameter: extra_edge_prob (random_jsc), p_fail "
                             "(markov), radius (mobility); default 0.1 / 0.3 / 0.4")
    parser.add_argument("--seeds", type=positive_int, default=8, help="runs per case (batched)")
    parser.add_argument("--steps", type=positive_int, default=200, help="horizon K")
    parser.add_argument("--eps", type=positive_float, default=1e-6, help="relative-error tolerance")
    parser.add_argument("--rho", type=float, default=0.5, help="Theorem 1 rate")
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="master seed")
    parser.add_argument("--workers", type=positive_int, default=1, help="processes")
    parser.add_argument("--out", default=None, help="CSV of per-seed rows (optional)")
    parser.add_argument("--summary", default=None, help="CSV of per-case medians (optional)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


_DEFAULT_PARAM = {"random_jsc": 0.1, "markov": 0.3, "mobility": 0.4}
_PERIODIC = ("ring", "ring_backward", "random_jsc")


def build_cases(args: argparse.Namespace) -> list:
    """The list of :class:`netsense.studies.sweep.SweepCase` the arguments describe."""
    from netsense.graphs.families import FAMILIES
    from netsense.studies.sweep import SweepCase

    fams = [f.strip() for f in args.family.split(",") if f.strip()]
    for f in fams:
        if f not in FAMILIES:
            raise ValueError(f"--family: unknown family {f!r}; known: {sorted(FAMILIES)}")
    cases = []
    for fam in fams:
        params = args.param if args.param is not None else [_DEFAULT_PARAM.get(fam, 0.0)]
        Ts = args.T if fam in _PERIODIC else [1]
        for N, T, n, p in itertools.product(args.N, Ts, args.n, params):
            if fam.startswith("ring") and T > N:
                continue
            cases.append(SweepCase(fam, N, T, n=n, param=p, seeds=args.seeds,
                                   steps=args.steps, seed=args.seed, eps=args.eps,
                                   rho=args.rho))
    if not cases:
        raise ValueError("no case to run (rings need T <= N)")
    return cases


def run(args: argparse.Namespace) -> int:
    from netsense.studies.sweep import run_sweep, summarize, write_csv

    cases = build_cases(args)
    rows = run_sweep(cases, workers=args.workers, progress=not args.quiet)
    summary = summarize(rows)
    if args.out:
        write_csv(rows, args.out)
    if args.summary:
        write_csv(summary, args.summary)
    head = (f"{'family':<14}{'N':>3}{'T':>3}{'n':>4}{'param':>7} | {'trigger':>8}/"
            f"{'(N-1)T':<7}{'worst':>6}/{'2(N-1)T':<8}{'deadbeat':>9}/{'n+2N(N-1)T':<11}"
            f"{'rho':>5}{'msgs':>7}{'AoI':>6}{'A1':>5}")
    print(head)
    print("-" * len(head))
    for s in summary:
        print(f"{s['family']:<14}{s['N']:>3}{s['T']:>3}{s['n']:>4}{s['param']:>7.2g} | "
              f"{s['trigger_median']:>8.0f}/{s['bound_lemma3_median']:<7.0f}"
              f"{s['worst_after_lemma3_median']:>6.0f}/{s['bound_lemma5_median']:<8.0f}"
              f"{s['steps_deadbeat_median']:>9.0f}/{s['bound_corollary1_median']:<11.0f}"
              f"{s['steps_rho_median']:>5.0f}{s['messages_per_step']:>7.1f}"
              f"{s['aoi_mean']:>6.1f}{s['assumption1_frac']:>5.2f}")
    print("medians over seeds; T for gossip/markov/mobility is the smallest period of the "
          "realised sequence (A1 = fraction of runs where Assumption 1 held on the horizon)")
    for path in (args.out, args.summary):
        if path:
            print(f"wrote {path}")
    return 0
