"""``netsense policy``: check a policy file without running it, or convert one you trust.

``check`` reads each file as data (``.pt``: :func:`netsense.rl.checkpoint.read_policy`;
``.zip``: :func:`netsense.rl.sb3_policy.read_sb3_policy`), verifies its checksum and
weights and prints what it is. ``convert --trust`` makes a file netsense refuses to load
into one it reads: a ``.pt`` written before policy files carried a checksum gets one
(:func:`netsense.rl.checkpoint.seal_policy`; read with ``weights_only=True``), an SB3
``.zip`` without netsense's metadata is unpickled once and written with it
(:func:`netsense.rl.sb3_policy.convert_sb3_policy`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "policy"
HELP = ("Check a policy file (.pt of `netsense train --backend torchrl`, .zip of MaskablePPO) "
        "without running anything in it, or convert a file you trust into the format "
        "netsense loads (checksummed; SB3 zips with netsense's metadata).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("check", "convert"),
                        help="check: verify and describe; convert: add what netsense "
                             "needs to load the file (needs --trust)")
    parser.add_argument("paths", nargs="+", metavar="PATH", help="policy files (.pt, .zip)")
    parser.add_argument("--out", default=None,
                        help="convert: where to write (one PATH only; default: a .pt in "
                             "place, a .zip as PATH with the suffix .netsense.zip)")
    parser.add_argument("--trust", action="store_true",
                        help="convert: you trust the file (a .zip is unpickled, which runs "
                             "any code it holds; a .pt is read as data, but sealing vouches "
                             "for its weights)")


def _kind(path: Path) -> str:
    if path.suffix == ".pt":
        return "pt"
    if path.suffix == ".zip":
        return "zip"
    raise ValueError(f"{path}: a policy file ends in .pt (batched trainer) or .zip "
                     "(MaskablePPO)")


def _describe(path: Path) -> str:
    if _kind(path) == "pt":
        from netsense.rl.checkpoint import policy_config, policy_control, read_policy

        state = read_policy(path)
        cfg = policy_config(state, path)
        ctl = policy_control(state)
        trained = state.get("trained_on") or {}
        return (f"{path}: ok (checksum verified, weights finite): {cfg.algo}/{cfg.network} "
                f"on {cfg.scenario}, control {ctl}, trained on N = {trained.get('N', '?')}, "
                f"nvec {trained.get('nvec', '?')}; {state.get('agent_steps', '?')} "
                "agent-steps")
    from netsense.rl.sb3_policy import read_sb3_policy

    meta, _ = read_sb3_policy(path)
    return (f"{path}: ok (checksum verified, weights finite): MaskablePPO "
            f"{meta['net_arch']} {meta['activation']} on {meta.get('scenario', '?')}, "
            f"observations {meta['observation_dim']}, actions MultiDiscrete({meta['nvec']})")


def _convert(path: Path, out: Path | None) -> Path:
    if _kind(path) == "pt":
        from netsense.rl.checkpoint import seal_policy

        return seal_policy(path, out)
    from netsense.rl.sb3_policy import convert_sb3_policy

    dst = out if out is not None else path.with_name(path.stem + ".netsense.zip")
    return convert_sb3_policy(path, dst, trust=True)


def run(args: argparse.Namespace) -> int:
    paths = [Path(p) for p in args.paths]
    for p in paths:
        _kind(p)
    if args.action == "check":
        if args.out is not None or args.trust:
            raise ValueError("--out and --trust belong to `netsense policy convert`")
        for p in paths:
            print(_describe(p))
        return 0
    if not args.trust:
        raise ValueError("convert needs --trust: converting vouches for the file (a .zip is "
                         "unpickled, which runs any code it holds); convert only files you "
                         "trust, e.g. your own")
    if args.out is not None and len(paths) > 1:
        raise ValueError("--out takes one PATH; convert several files without --out")
    for p in paths:
        dst = _convert(p, None if args.out is None else Path(args.out))
        print(f"wrote {dst}")
        print(_describe(dst))
    return 0
