"""``netsense train``: train a parameter-shared, action-masked policy on a scenario."""

from __future__ import annotations

import argparse
import json

from netsense.commands._args import (
    finite_float,
    nonnegative_float,
    nonnegative_int,
    positive_float,
    positive_int,
)

NAME = "train"
HELP = ("Train a parameter-shared, action-masked policy on a scenario: batched MAPPO / IPPO "
        "on TorchRL components (--backend torchrl, default; 'torchrl' extra) or MaskablePPO "
        "through SB3 + SuperSuit (--backend sb3; 'rl' extra). Saves policies, logs and "
        "curves; --resume continues a killed run from its last checkpoint.")

ALGOS = ("maskable_ppo", "mappo", "ippo")
BACKENDS = ("sb3", "torchrl")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario id, e.g. fig1_scalar-v0 (see `netsense list`)")
    parser.add_argument("--backend", choices=BACKENDS, default=None,
                        help="torchrl: batched MAPPO / IPPO over BatchedCore (netsense.rl.ppo; "
                             "default, needs the 'torchrl' extra); sb3: MaskablePPO through "
                             "SuperSuit ('rl' extra)")
    parser.add_argument("--algo", choices=ALGOS, default=None,
                        help="maskable_ppo (sb3) or mappo / ippo (torchrl; default mappo)")
    parser.add_argument("--steps", type=positive_int, default=None,
                        help="agent-steps of experience (one env-step is N agent-steps), "
                             "rounded up to whole iterations (default: sb3 50000, torchrl "
                             "2000000)")
    parser.add_argument("--out", default=None,
                        help="output directory (default: runs/SCENARIO; torchrl writes "
                             "OUT/seed_<s>/policy.pt, sb3 OUT/policy.zip, the paths "
                             "`netsense benchmark --policies learned:PATH` reads). A folder "
                             "that holds another run is refused unless --resume or "
                             "--overwrite is given")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out from its last checkpoint (torchrl: "
                             "optimiser, schedules, random generators, step count and log "
                             "restored; the run ends where an uninterrupted one would); with "
                             "--seeds, finished seeds are kept and unfinished ones resumed")
    parser.add_argument("--overwrite", action="store_true",
                        help="remove the run files --out holds (policies, checkpoints, logs, "
                             "seed_* folders) and train afresh")
    parser.add_argument("--seed", type=nonnegative_int, default=0, help="seed (default: 0)")
    parser.add_argument("--seeds", type=nonnegative_int, nargs="+", default=None,
                        metavar="SEED",
                        help="torchrl: train one run per seed into OUT/seed_<s> (default: "
                             "--seed); --workers or --ray trains them at once")
    parser.add_argument("--num-envs", type=positive_int, default=None,
                        help="environment copies stepped together, N agents each (default: "
                             "sb3 4, torchrl 256)")
    parser.add_argument("--rollout", "--n-steps", dest="rollout", type=positive_int,
                        default=None,
                        help="env-steps per environment per iteration, both backends (sb3: "
                             "PPO's n_steps, default 128; torchrl: T, default 32)")
    parser.add_argument("--batch-size", "--minibatch", dest="batch_size", type=positive_int,
                        default=None,
                        help="PPO minibatch: sb3 in agent-steps (every agent is a vector "
                             "slot; default 256), torchrl in env-steps of N agents each, a "
                             "recurrent actor takes it in whole sequences of --rollout "
                             "env-steps (default 2048)")
    parser.add_argument("--lr", type=positive_float, default=None,
                        help="learning rate (default: sb3 3e-4, torchrl 1e-3)")
    parser.add_argument("--gamma", type=finite_float, default=None,
                        help="discount (default: sb3 0.95, torchrl 0.99)")
    parser.add_argument("--ent-coef", type=finite_float, default=None,
                        help="entropy bonus (default 0.01; torchrl decays it linearly to 0 "
                             "over the run)")
    parser.add_argument("--torch-threads", type=positive_int, default=None, metavar="T",
                        help="torch threads of the learner, both backends (default: sb3 1; "
                             "torchrl torch's own count, one per core unless "
                             "OMP_NUM_THREADS says otherwise: give 1 on cores other jobs "
                             "keep busy, see docs/performance.md)")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=JSON",
                        help="scenario override passed to netsense.make, e.g. horizon=40 "
                             "(repeatable; the value is parsed as JSON)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    tr = parser.add_argument_group("torchrl backend (refused with --backend sb3)")
    tr.add_argument("--network", choices=("mlp", "set"), default=None,
                    help="actor: shared MLP (default) or the set network over message slots")
    tr.add_argument("--set-slots", action=argparse.BooleanOptionalAction, default=None,
                    help="set network: pool the message-slot tokens (default) or, with "
                         "--no-set-slots, read the substate and agent tokens only (control "
                         "modes transmit and substates; much cheaper)")
    tr.add_argument("--control", choices=("full", "transmit", "substates"), default=None,
                    help="control mode (default: the scenario's): full, or communication "
                         "only with one bit (transmit) or one bit per substate (substates); "
                         "the scenario's fusion rule adopts")
    tr.add_argument("--reward", choices=("scenario", "team", "own_cost", "agent",
                                         "counterfactual", "lifetime"),
                    default=None, help="credit assignment (docs/rl.md; default: team)")
    tr.add_argument("--critic", choices=("team", "state", "joint", "local"), default=None,
                    help="mappo: team (default with the team reward: V(s) once per "
                         "environment), state, joint; ippo: local")
    tr.add_argument("--memory", type=nonnegative_int, default=None, metavar="M",
                    help="GRU state size of the actor over the agent's own history (default: "
                         "0, a feed-forward actor)")
    tr.add_argument("--clock", type=positive_int, nargs="+", default=None, metavar="P",
                    help="MLP actor: also read sin and cos of 2 pi k / P for each period P "
                         "(steps, >= 2), k the step read from the observation's time entry "
                         "(default: none)")
    tr.add_argument("--clock-shift", action="store_const", const=True, default=None,
                    help="with --clock: each agent reads the clock in its own frame, the "
                         "phases of k - i for agent i (default: the common clock)")
    tr.add_argument("--clock-only", action="store_const", const=True, default=None,
                    help="with --clock: the actor reads only the clock, the time entry and "
                         "its own substate, a learned schedule blind to the state (default: "
                         "the whole observation)")
    tr.add_argument("--comm-fields-only", action="store_const", const=True, default=None,
                    help="MLP actor, communication-only modes: read only the observation's "
                         "communication fields (news, silence, acks, ...) and the time entry, "
                         "the measurements and estimates held at 0 (default: the whole "
                         "observation)")
    tr.add_argument("--ages", type=positive_int, nargs="+", default=None, metavar="TAU",
                    help="MLP actor, communication-only modes: also read exp(-a / TAU) for "
                         "each scale TAU (steps) of every age a in the observation's news "
                         "and silence entries (default: none)")
    tr.add_argument("--news-gate", action="store_const", const=True, default=None,
                    help="send only what is news: in control modes transmit and substates, "
                         "the choice to send a substate (or to transmit) is closed where the "
                         "agent's observation holds no news for it (default: off)")
    tr.add_argument("--epochs", type=positive_int, default=None,
                    help="PPO epochs per iteration (default: 4)")
    tr.add_argument("--eval-interval", type=positive_int, default=None,
                    help="evaluate + checkpoint every this many iterations (default: 10)")
    tr.add_argument("--eval-envs", type=positive_int, default=None,
                    help="evaluation episodes (default: 32)")
    tr.add_argument("--bc", default=None, metavar="POLICY",
                    help="behaviour-cloning warm start from a scripted policy (freshness, "
                         "uniform, open_loop, random, or a communication baseline such as "
                         "event:2 in a communication-only mode), then conservative "
                         "fine-tuning")
    tr.add_argument("--device", default=None,
                    help="learner device: auto (default: CUDA when available), cpu, cuda or "
                         "cuda:<index>; checked before anything runs")
    tr.add_argument("--precision", default=None, choices=("auto", "fp32", "bf16"),
                    help="arithmetic of the PPO loss: bf16 (mixed precision, bfloat16 "
                         "matrix products) or fp32; auto (default): bf16 on a CPU with "
                         "native bfloat16 products (AVX512-BF16), fp32 elsewhere")
    tr.add_argument("--no-overlap", dest="overlap", action="store_const", const=False,
                    default=None,
                    help="collect and learn one after the other, plain PPO (default: the "
                         "next rollout is collected in a second thread while the learner "
                         "trains, with the actor's parameters one update behind, and the "
                         "loss is PPO's decoupled objective for such data)")
    many = parser.add_argument_group(
        "many runs (torchrl backend; the learning library is --backend's choice, these "
        "choose where the runs of --seeds train)")
    many.add_argument("--workers", type=positive_int, default=1, metavar="K",
                      help="runs trained at once on this machine, each in its own process "
                           "with one thread per thread pool (an overlapped run keeps up to "
                           "two cores busy: its collection thread beside its learner; "
                           "--no-overlap, one) (default: 1, one run after another in this "
                           "process)")
    many.add_argument("--ray", default=None, metavar="ADDRESS",
                      help="train each run as a Ray task instead: 'local' starts Ray on "
                           "this machine, 'auto' joins the cluster of `ray start` on this "
                           "machine, HOST:6379 a cluster's head, ray://HOST:10001 connects a "
                           "Ray client. The runs' files come back to OUT on this machine "
                           "(docs/rl.md, 'Many runs: worker processes and a Ray cluster')")
    many.add_argument("--cpus-per-run", type=positive_int, default=1, metavar="CPUS",
                      help="--ray: CPU cores each run reserves, and the threads of each of "
                           "its thread pools (default: 1)")
    many.add_argument("--gpus-per-run", type=nonnegative_float, default=0.0, metavar="GPUS",
                      help="--ray: GPUs each run reserves, a fraction shares one (default: "
                           "0, the learner on the CPU)")



#: Options of the torchrl backend only (``None`` in the parser, so that an option given with
#: ``--backend sb3`` is refused instead of ignored; what is not given takes
#: :class:`netsense.rl.config.PPOConfig`'s default).
TORCHRL_ONLY = ("network", "set_slots", "control", "reward", "critic", "memory", "clock",
                "clock_shift", "clock_only", "comm_fields_only", "ages", "news_gate", "epochs",
                "eval_interval", "eval_envs", "bc", "device", "precision", "overlap", "seeds")
#: Flags both backends take, as ``(PPOConfig field, TrainConfig field)``; what is not given
#: takes the backend's config default (``--help`` names both).
SHARED = {"steps": ("steps", "steps"), "num_envs": ("num_envs", "num_vec_envs"),
          "rollout": ("rollout", "n_steps"), "batch_size": ("minibatch", "batch_size"),
          "lr": ("lr", "learning_rate"), "gamma": ("gamma", "gamma"),
          "ent_coef": ("entropy_coef", "ent_coef"),
          "torch_threads": ("torch_threads", "torch_threads")}


def given_fields(args: argparse.Namespace, backend: str) -> dict:
    """The shared flags the user gave, under the backend config's field names."""
    i = 0 if backend == "torchrl" else 1
    return {names[i]: getattr(args, flag) for flag, names in SHARED.items()
            if getattr(args, flag) is not None}


def parse_overrides(items: list[str]) -> dict:
    """``["horizon=40", 'reward={"message_cost": 0.1}']`` -> dict (values parsed as JSON;
    a value that is not JSON is kept as a string, unless it looks like JSON: one starting
    with ``{``, ``[`` or ``"`` must parse). A key given twice is refused."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--override must look like KEY=VALUE, got {item!r}")
        if key in out:
            raise ValueError(f"--override {key}= is given twice; give each key once (a "
                             "table's keys go in one JSON object)")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError as exc:
            if value.lstrip()[:1] in ("{", "[", '"'):
                raise ValueError(f"--override {key}=: not valid JSON ({exc.msg} at column "
                                 f"{exc.colno}): {value!r}") from None
            out[key] = value
    return out


#: Options whose flag is not the field's name.
_FLAGS = {"overlap": "no_overlap"}


def _given(args: argparse.Namespace, names) -> list[str]:
    return ["--" + _FLAGS.get(n, n).replace("_", "-") for n in names
            if getattr(args, n) is not None]


#: What ``--backend torchrl`` (the default) imports: the 'torchrl' extra.
TORCHRL_MODULES = ("torch", "torchrl", "tensordict")


def resolve_backend(backend: str | None) -> str:
    """``--backend`` as given, else ``"torchrl"``; a TorchRL backend whose extra is not
    installed is a ``ValueError`` naming the extra and the SB3 alternative."""
    import importlib.util

    if backend == "sb3":
        return backend
    missing = [m for m in TORCHRL_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        how = "--backend torchrl" if backend == "torchrl" else "netsense train (by default)"
        raise ValueError(f"{how} trains with the batched TorchRL trainer, whose extra is not "
                         f"installed (no {', '.join(missing)}): install it with "
                         "pip install -e \".[torchrl]\" (or pip install \"netsense[torchrl]\"), "
                         "or train MaskablePPO through SB3 instead with --backend sb3 "
                         "(the 'rl' extra)")
    return "torchrl"


def _check_inputs(args: argparse.Namespace) -> dict:
    """Unknown scenario, bad overrides and options of the other backend fail before any
    learning stack is imported."""
    from netsense.env.registry import list_scenarios, unknown_scenario

    if args.scenario not in list_scenarios():
        raise unknown_scenario(args.scenario)
    overrides = parse_overrides(args.override)
    from netsense.env.vector import load_model

    load_model(args.scenario, **overrides)  # bad override values name their field here
    if args.backend is None and args.algo == "maskable_ppo":
        args.backend = "sb3"  # the algorithm only SB3 trains
    args.backend = resolve_backend(args.backend)
    if args.backend == "sb3":
        wrong = _given(args, TORCHRL_ONLY)
        if wrong:
            raise ValueError(f"{', '.join(wrong)} belong{'s' if len(wrong) == 1 else ''} to "
                             "--backend torchrl; the sb3 backend would ignore "
                             f"{'it' if len(wrong) == 1 else 'them'}")
    return overrides


def run(args: argparse.Namespace) -> int:
    overrides = _check_inputs(args)
    if args.backend == "torchrl":
        return _run_torchrl(args, overrides)
    if args.seeds or args.workers != 1 or args.ray is not None:
        raise ValueError("--seeds, --workers and --ray train several runs with --backend "
                         "torchrl; --backend sb3 trains one (--seed)")
    if args.algo not in (None, "maskable_ppo"):
        raise ValueError(f"--algo {args.algo} needs --backend torchrl")
    args.algo = "maskable_ppo"
    if args.resume:
        raise ValueError("--resume continues runs of --backend torchrl; an SB3 run starts "
                         "afresh (--overwrite replaces the run in --out)")
    from netsense.benchmark.baselines import baseline_returns
    from netsense.rl.run_folder import claim
    from netsense.rl.sb3 import TrainConfig, train

    cfg = TrainConfig(scenario=args.scenario, seed=args.seed, overrides=overrides,
                      **given_fields(args, "sb3"))
    out = args.out if args.out is not None else f"runs/{args.scenario}"
    claim(out, overwrite=args.overwrite)  # before anything is written
    asked_refs = ("freshness", "uniform_consensus")
    refs = baseline_returns(cfg, asked_refs)
    left = [r for r in asked_refs if r not in refs]
    if left:
        import sys

        print(f"note: {', '.join(left)} do{'es' if len(left) == 1 else ''} not apply to "
              f"{args.scenario} (not drawn as reference on the training curve)",
              file=sys.stderr)
    res = train(cfg, out, progress=not args.no_progress, baselines=refs)
    last = res.curve[-1]["mean_episode_reward"] if res.curve else float("nan")
    asked = ("" if res.agent_steps == cfg.steps
             else f" ({cfg.steps} asked, whole rollouts)")
    print(f"trained {args.algo} on {args.scenario} for {res.agent_steps} agent-steps{asked} "
          f"in {res.wall_s:.1f} s; final mean episode return {last:.4g}; "
          f"masked actions taken: {res.mask_violations}/{res.actions_checked}")
    print(f"wrote {res.policy_path}, {res.curve_csv}, {res.curve_png}")
    return 0


def _launch_options(args: argparse.Namespace) -> dict:
    """The launcher flags as :func:`netsense.rl.launch.launch` keywords (checked)."""
    if args.ray is not None and args.workers != 1:
        raise ValueError("--workers K runs K processes on this machine; with --ray, Ray "
                         "places the runs (use --cpus-per-run)")
    if args.ray is None and (args.cpus_per_run != 1 or args.gpus_per_run):
        raise ValueError("--cpus-per-run and --gpus-per-run reserve Ray resources; they "
                         "need --ray ADDRESS")
    if args.ray is None:
        return {"workers": args.workers}
    resources = {"num_cpus": args.cpus_per_run}
    if args.gpus_per_run:
        resources["num_gpus"] = args.gpus_per_run
    return {"ray_address": args.ray, "resources": resources, "threads": args.cpus_per_run}


def _check_resumable(out, runs) -> None:
    """``--resume``: each run's folder, if started, was started with the configuration
    given now (its ``config.json``); else a ``ValueError`` naming the folder and the
    fields that differ, before anything is written."""
    import json
    from dataclasses import asdict

    for r in runs:
        path = out / r.folder / "config.json"
        if not path.is_file():
            continue
        try:
            then = json.loads(path.read_text())
        except ValueError as exc:
            raise ValueError(f"{path}: unreadable ({exc}); --overwrite trains the run "
                             "again") from None
        now = json.loads(json.dumps(asdict(r.config), default=list))
        diff = sorted(k for k in set(now) | set(then) if now.get(k) != then.get(k))
        if diff:
            parts = [f"{k}: {then.get(k)!r} in the run, {now.get(k)!r} now"
                     for k in diff[:5]]
            raise ValueError(f"{out / r.folder}: --resume needs the flags the run was "
                             f"started with; they differ in {'; '.join(parts)}")


def _run_torchrl(args: argparse.Namespace, overrides: dict) -> int:
    from pathlib import Path

    from netsense.rl.config import PPOConfig, device_of
    from netsense.rl.launch import launch, make_runs
    from netsense.rl.run_folder import claim

    algo = args.algo or "mappo"
    if algo == "maskable_ppo":
        raise ValueError("--algo maskable_ppo needs --backend sb3")
    where = _launch_options(args)
    if args.seeds and args.seed != 0:
        raise ValueError("give --seed or --seeds, not both (--seeds trains one run per seed)")
    seeds = args.seeds if args.seeds else [args.seed]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds lists a seed twice: {seeds}")
    out = Path(args.out if args.out is not None else f"runs/{args.scenario}")
    own = {k: getattr(args, k) for k in TORCHRL_ONLY if k != "seeds"
           and getattr(args, k) is not None}  # what is not given: PPOConfig's defaults
    cfg = PPOConfig(scenario=args.scenario, algo=algo, seed=seeds[0], overrides=overrides,
                    **own, **given_fields(args, "torchrl"))
    if args.bc:
        cfg = cfg.conservative()
    runs = make_runs(cfg, seeds)  # every seed's config checked before the first run
    device_of(cfg.device)  # a device torch does not have fails here, not mid-run
    if args.resume:
        _check_resumable(out, runs)
    claim(out, resume=args.resume, overwrite=args.overwrite)  # before anything is written
    _say_adjusted(cfg, args)
    summary = launch(runs, out, progress=not args.no_progress, resume=args.resume, **where)
    for e in summary:
        if e["status"] != "ok":
            print(f"seed {e['seed']}: FAILED: {e['error']}")
            continue
        asked = ("" if e["agent_steps"] == cfg.steps
                 else f" ({cfg.steps} asked, whole iterations)")
        print(f"seed {e['seed']}: {algo}/{cfg.network} on {args.scenario}, "
              f"{e['agent_steps']} agent-steps{asked} in {e['wall_s']:.1f} s; eval return "
              f"{e['eval_return']:.4g}, error {e['eval_error']:.3g}, messages/agent-step "
              f"{e['eval_messages']:.3g}; masked actions taken: {e['mask_violations']}")
    print(f"wrote {out}/seed_*/(log.csv, policy.pt, checkpoints) and {out / 'summary.json'}")
    failed = [e["seed"] for e in summary if e["status"] != "ok"]
    if failed:
        print(f"{len(failed)} of {len(summary)} runs failed (seeds {failed}); their errors "
              f"and configs are in {out / 'summary.json'}")
        return 1
    return 0


def _say_adjusted(cfg, args: argparse.Namespace) -> None:
    """Say (on stderr) where the run will differ from what was asked: the warm start's
    conservative settings, a minibatch larger than one iteration's data."""
    import sys

    frames = cfg.num_envs * cfg.rollout
    if cfg.minibatch > frames:
        print(f"note: --batch-size {cfg.minibatch} is more than one iteration's "
              f"{frames} env-steps (--num-envs {cfg.num_envs} x --rollout {cfg.rollout}); "
              f"each minibatch is the whole iteration", file=sys.stderr)
    if args.bc:
        print(f"note: --bc {args.bc}: behaviour cloning first, then fine-tuning with clip "
              f"{cfg.clip:g}, lr {cfg.lr:g}, entropy {cfg.entropy_coef:g} and "
              f"{cfg.critic_warmup} critic-only iterations (PPOConfig.conservative)",
              file=sys.stderr)
