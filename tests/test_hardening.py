"""The error contract of ``docs/errors.md``, held to a catalogue of bad inputs.

Every public entry point kind is covered: library functions and classes, the compiled
kernels of ``netsense.kernels``, scenario files, the PettingZoo env, the batched core, the
vector envs, the command line, learned-policy files, and the training surfaces (the
batched trainer's ``PPOConfig``, ``make_core`` and TorchRL env, the communication-only
control modes, the channel, devices). Policy files that run code when unpickled go
through every loader, in Python and on the command line, and must never run. For each
bad input: the exception type, a message naming the argument or field, and — for stateful
objects — that the object is unchanged (it keeps stepping bit for bit like a deep copy
taken before the bad call). Inputs that used to crash the interpreter run in a
subprocess. The numerical-health decision (non-finite states end the episode, flagged) is
checked at the end.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

import netsense as ns
from netsense.cli import main
from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.policies import make_policy
from netsense.env.registry import build_model, load, load_file, make, with_overrides
from netsense.env.vector import AgentVectorEnv, BatchedEnv, make_sb3_vec_env

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter that imports this checkout's netsense."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=timeout)


def _same(a, b, where="") -> None:
    """``a`` and ``b`` equal bit for bit (nested dicts, tuples, arrays, numbers)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (tuple, list)) and not isinstance(a, np.ndarray):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif a is None or b is None:
        assert a is b, where
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=where)


# ============================================================== library functions
PLANT = ns.fig1_scalar()
DESIGN = ns.design_observer(PLANT)

LIBRARY = [
    # (id, call, match): every one raises ValueError
    ("design_observer-deadbeat-str", lambda: ns.design_observer(PLANT, deadbeat="false"),
     "deadbeat must be true or false"),
    ("design_observer-rho-str", lambda: ns.design_observer(PLANT, rho="0.5"), "rho must be"),
    ("design_observer-rho-out", lambda: ns.design_observer(PLANT, rho=1.5), "rho must be"),
    ("design_observer-rng-str", lambda: ns.design_observer(PLANT, rng="x"), "rng must be"),
    ("design_observer-rates-str", lambda: ns.design_observer(PLANT, rates="ab"),
     "rates must"),
    ("decompose-Cs-None", lambda: ns.decompose([[1.0]], None), "Cs must be a sequence"),
    ("decompose-A-str", lambda: ns.decompose("abc", [[[1.0]]]), "A must hold"),
    ("decompose-rtol-str", lambda: ns.decompose([[1.0]], [[[1.0]]], rtol="a"),
     "rtol must be"),
    ("is_observable-ragged", lambda: ns.is_observable([[1.0, 2], [1]], [[1.0, 0]]),
     "A must be an array"),
    ("Plant-A-str", lambda: ns.Plant(A="abc", C=([[1.0]],)), "A must be a matrix"),
    ("Plant-C-None", lambda: ns.Plant(A=[[1.0]], C=None), "C must be a sequence"),
    ("Plant-C-width", lambda: ns.Plant(A=np.eye(2), C=([[1.0, 0.0, 0.0, 1.0]],)),
     r"C\[0\] must have shape"),
    ("Plant-A-1e200", lambda: ns.Plant(A=[[1e200, 0], [0, 1]], C=(np.eye(2),)),
     "A has entries up to 1e\\+200"),
    ("fig1_scalar-str", lambda: ns.fig1_scalar("2"), "a must be a finite number"),
    ("random_structured-n-float", lambda: ns.random_structured(2.5, 3), "n must be an integer"),
    ("random_structured-radius", lambda: ns.random_structured(3, 3, spectral_radius=-1),
     "spectral_radius must be"),
    ("GaussianNoise-str", lambda: ns.GaussianNoise("a"), "GaussianNoise.std must be"),
    ("FreshnessObserver-batch-float", lambda: ns.FreshnessObserver(DESIGN, batch_size=1.5),
     "batch_size must be an integer"),
    ("observer-errors-shape", lambda: ns.FreshnessObserver(DESIGN).errors(np.zeros(5)),
     "x must have shape"),
    ("observer-step-transmit-not-a-mask", lambda: ns.FreshnessObserver(DESIGN).step(
        np.zeros((3, 1)), ns.fig1_graphs().sequence(1)[0], transmit=[0, 2, 1]),
     "transmit must be a bool mask"),
    ("graphs-sequence-negative", lambda: ns.fig1_graphs().sequence(-1), "num_steps must be"),
    ("RandomJointlyConnected-N-float", lambda: ns.RandomJointlyConnected(3.5, 2),
     "num_nodes must be an integer"),
    ("MarkovLinkFailures-p-str", lambda: ns.MarkovLinkFailures(np.ones((3, 3), bool), "a",
                                                               0.5), "p_fail must be"),
    ("Gossip-ragged", lambda: ns.Gossip([[1, 0], [1]]), "base must be an array"),
    ("PeriodicGraphs-edge-triple", lambda: ns.PeriodicGraphs.from_edges(3, [[(0, 1, 2)]]),
     r"edges must be pairs \[l, i\]"),
    ("CoreModel-design-of-another-plant",
     lambda: CoreModel(plant=ns.Plant(A=[[3.0]], C=(np.ones((1, 1)), np.zeros((0, 1)),
                                                    np.zeros((0, 1)))),
                       design=DESIGN, graphs=ns.fig1_graphs(), horizon=5),
     "design was made for another plant"),
    ("CoreModel-horizon-1e20",
     lambda: CoreModel(plant=PLANT, design=DESIGN, graphs=ns.fig1_graphs(), horizon=10**20),
     "horizon must be an integer in"),
    ("LyingAgent-claim-2^63", lambda: ns.observers.faults.LyingAgent(1, claim=2**63 - 1),
     "LyingAgent.claim must be <= 2\\^53"),
    ("StuckSensor-agents-str", lambda: ns.observers.faults.StuckSensor(["1"]),
     "StuckSensor.agents must be"),
    ("DelayLanguage-huge", lambda: ns.sensing.delays.DelayLanguage.each_delayed_at_most(
        1000, 1000), "holds ~1e3000 words"),
    ("make-unknown-scenario", lambda: make("nope-v0"), "unknown scenario 'nope-v0'"),
    ("make-nonfinite-mode", lambda: make("fig1_scalar-v0", nonfinite="ignore"),
     "nonfinite must be one of"),
    ("make-horizon-1e20", lambda: make("fig1_scalar-v0", horizon=10**20),
     "field 'horizon': must be <= 2\\^53"),
    ("make-deadbeat-str", lambda: make("fig1_scalar-v0", design={"deadbeat": "false"}),
     "field 'design.deadbeat'"),
    ("make-liar-claim", lambda: make("fault_liar-v0", faults=[
        {"kind": "liar", "agents": [1], "claim": 2**63 - 1}]), "field 'faults\\[0\\].claim'"),
    ("TrainConfig-steps-float", lambda: __import__("netsense.rl.sb3").rl.sb3.TrainConfig(
        "fig1_scalar-v0", steps=1.5), "TrainConfig.steps must be an integer"),
    ("TrainConfig-torch_threads-zero", lambda: __import__("netsense.rl.sb3").rl.sb3
     .TrainConfig("fig1_scalar-v0", torch_threads=0), "TrainConfig.torch_threads must be"),
    ("benchmark-make_jobs-seed-float", lambda: __import__("netsense.benchmark").benchmark
     .make_jobs(["fig1_scalar-v0"], ["freshness"], [1.5]), "seeds\\[\\] must be an integer"),
    ("SweepCase-N-str", lambda: __import__("netsense.studies.sweep").studies.sweep.SweepCase(
        "ring", "3"), "N must be an integer"),
    ("MaskedFlatObs-not-an-env", lambda: __import__("netsense.rl.wrappers").rl.wrappers
     .MaskedFlatObs(3), "env must be a PettingZoo ParallelEnv"),
    ("make-stale-delay", lambda: make("fig1_scalar-v0", faults=[
        {"kind": "stuck_sensor", "agents": [0], "mode": "stale", "delay": 10**12}]),
     "StuckSensor.delay = 1000000000000 exceeds the horizon"),
]


def _import_submodules():
    import netsense.observers.faults  # noqa: F401  (ns.observers.faults in the table)
    import netsense.sensing.delays  # noqa: F401


_import_submodules()


@pytest.mark.parametrize("call, match", [c[1:] for c in LIBRARY], ids=[c[0] for c in LIBRARY])
def test_library_rejects(call, match, request):
    if "TrainConfig" in request.node.callspec.id:
        pytest.importorskip("sb3_contrib", reason="netsense.rl.sb3 needs the 'rl' extra")
    with pytest.raises(ValueError, match=match):
        call()


# ============================================================== compiled kernels
#: Calls that used to crash the interpreter or read outside their arrays: each runs in a
#: subprocess (one for all), which must survive and report a ValueError naming the argument.
KERNELS = [
    ("gather_substates-src-1e9",  # the issue's example: segfaulted
     "kernels.gather_substates(np.zeros((2,3,4)), np.full((2,3,3),10**9), "
     "np.array([0,1,1,2]))", "src must hold indices"),
    ("gather_substates-block_of", "kernels.gather_substates(np.zeros((1,3,4)), "
     "np.zeros((1,3,3), int), np.array([0,1,1,7]))", "block_of must hold indices"),
    ("vecmat-shapes", "update.vecmat(np.ones((2,3)), np.ones((50,4)))",  # read outside
     r"M must have shape \(3, \*\)"),
    ("advance_indices-src", "kernels.advance_indices(np.zeros((1,3,3),np.int64), "
     "np.full((1,3,3),10**9))", "src must hold indices"),
    ("advance_indices-own", "kernels.advance_indices(np.zeros((1,3,3),np.int64), "
     "np.zeros((1,3,3),int), own=np.array([0,1,9]))", "own must hold indices"),
    ("uniform_mix-nbr", "kernels.uniform_mix(np.zeros((1,3,2)), np.full((1,3,2),10**9), "
     "np.ones((1,3,2),bool))", "nbr must hold indices"),
    ("average_indices-nbr", "kernels.average_indices(np.zeros((1,3,3),np.int64), "
     "np.full((1,3,2),-5), np.ones((1,3,2),bool))", "nbr must hold indices"),
    ("innovation_correction-C", "kernels.innovation_correction(np.zeros((1,3,2)), "
     "np.zeros((1,3,1)), None, np.zeros((1,1,2)), np.zeros((1,2,1)))",
     r"C_bar_pad must have shape \(3, \*, 2\)"),
    ("innovation_correction-rows", "kernels.innovation_correction(np.zeros((1,3,2)), "
     "np.zeros((1,3,1)), None, np.zeros((3,1,2)), np.zeros((3,2,1)), "
     "rows=np.array([[0,99]]*3))", "rows must hold indices"),
    ("slot_messages-nbr", "kernels.slot_messages(np.full((1,3,2),7), np.ones((1,3),bool))",
     "nbr must hold indices"),
    ("freshness_choice-transmit", "kernels.freshness_choice(np.zeros((1,3,3),np.int64), "
     "np.full((1,3,2),50), np.ones((1,3,2),bool), np.ones((1,3),bool))",
     "nbr must hold indices"),
    ("apply_actions-nbr", "kernels.apply_actions(np.zeros((1,3,1)), "
     "np.zeros((1,3,3),np.int64), np.zeros((1,3,4),np.int64), np.full((1,3,2),10**6), "
     "np.ones((1,3,2),bool), np.zeros(1,np.int64), np.eye(1), np.eye(1), x=np.zeros((1,1)), "
     "A_T=np.eye(1), T=np.eye(1), corr=np.zeros((1,3,1)))", "nbr must hold indices"),
    ("apply_actions-block_of", "kernels.apply_actions(np.zeros((1,3,1)), "
     "np.zeros((1,3,3),np.int64), np.zeros((1,3,4),np.int64), np.full((1,3,2),-1), "
     "np.zeros((1,3,2),bool), np.array([5]), np.eye(1), np.eye(1), x=np.zeros((1,1)), "
     "A_T=np.eye(1), T=np.eye(1), corr=np.zeros((1,3,1)))", "block_of must hold indices"),
    ("check_actions-choice-shape", "update.check_actions(np.zeros((1,3,4),np.int64), "
     "np.ones((1,3,2),bool), np.zeros((1,3,1),np.int64), np.zeros((1,3,1),bool))",
     r"act must have shape \(1, 3, 2\)"),
]

_KERNEL_SCRIPT = """
import json, sys
import numpy as np
from netsense import kernels
from netsense.kernels import update
for name, expr in json.loads(sys.argv[1]):
    try:
        eval(expr)
        out = ["returned", ""]
    except Exception as exc:
        out = [type(exc).__name__, str(exc)]
    print(json.dumps([name] + out), flush=True)
"""


@pytest.fixture(scope="module")
def kernel_results():
    cases = json.dumps([[c[0], c[1]] for c in KERNELS])
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-c", _KERNEL_SCRIPT, cases], capture_output=True,
                         text=True, cwd=ROOT, env=env, timeout=600)
    got = {}
    for line in res.stdout.splitlines():
        name, kind, msg = json.loads(line)
        got[name] = (kind, msg)
    return res.returncode, got, res.stderr


@pytest.mark.parametrize("name, match", [(c[0], c[2]) for c in KERNELS],
                         ids=[c[0] for c in KERNELS])
def test_kernels_reject_without_crashing(kernel_results, name, match):
    rc, got, stderr = kernel_results
    assert name in got, f"the subprocess died (return code {rc}) at or before {name}: " \
                        f"{stderr[-500:]}"
    kind, msg = got[name]
    assert kind == "ValueError", (kind, msg)
    assert __import__("re").search(match, msg), msg
    assert rc == 0


# ============================================================== scenario files
BASE = 'horizon = 10\n[plant]\nkind = "fig1_scalar"\n[graph]\nkind = "fig1"\n'
G = '[graph]\nkind = "fig1"\n'


def _matrices(A: str, C: str) -> str:
    return f'horizon = 10\n[plant]\nkind = "matrices"\nA = {A}\nC = {C}\n' + G


SCENARIOS = [
    # (id, file text, field named in the message)
    ("C-row-width-4",  # the issue's example: reshaped into two outputs
     _matrices("[[1.0, 0.0], [0.0, 1.0]]", "[[1.0, 0.0, 0.0, 1.0], [], []]"), "plant.C[0]"),
    ("C-ragged", _matrices("[[1.0]]", "[[[1.0, 2.0], [1.0]], [], []]"), "plant.C[0]"),
    ("C-wrong-width", _matrices("[[1.0, 0.0], [0.0, 1.0]]",
                                "[[[1.0, 0.0, 1.0]], [[1.0, 0.0]], []]"), "plant.C[0]"),
    ("A-empty", _matrices("[]", "[[], [], []]"), "plant.A"),
    ("A-strings", _matrices('[["a"]]', "[[[1.0]], [], []]"), "plant.A"),
    ("A-1e200", _matrices("[[1e200, 0.0], [0.0, 1.0]]", "[[[1.0, 0.0]], [[0.0, 1.0]], []]"),
     "plant"),
    ("edge-three-elements", 'horizon = 10\n[plant]\nkind = "fig1_scalar"\n[graph]\n'
     'kind = "static"\nnum_nodes = 3\nedges = [[0, 1, 2], [1, 2], [2, 0]]\n', "graph.edges"),
    ("offsets-non-numeric", 'horizon = 10\n[plant]\nkind = "fig1_scalar"\n[graph]\n'
     'kind = "markov"\nnum_nodes = 3\np_fail = 0.1\np_recover = 0.5\n'
     'base = {kind = "circulant", offsets = ["x"]}\n', "graph.base.offsets"),
    ("num_nodes-float", 'horizon = 10\n[plant]\nkind = "fig1_scalar"\n[graph]\n'
     'kind = "random_jsc"\nnum_nodes = 3.5\nperiod = 2\n', "graph.num_nodes"),
    ("horizon-1e20", BASE.replace("horizon = 10", "horizon = 100000000000000000000"),
     "horizon"),
    ("deadbeat-string", BASE + '[design]\ndeadbeat = "false"\n', "design.deadbeat"),
    ("rho-string", BASE + '[design]\nrho = "0.5"\n', "design.rho"),
    ("reward-bool", BASE + "[reward]\nmessage_cost = true\n", "reward.message_cost"),
    ("reward-overflow", BASE + "[reward]\nerror_weight = 1e308\n", "reward"),
    ("divergence_limit-nan", BASE.replace("horizon = 10\n", "horizon = 10\n"
                                          "divergence_limit = nan\n"), "divergence_limit"),
    ("x0_std-inf", BASE.replace("horizon = 10\n", "horizon = 10\nx0_std = inf\n"), "x0_std"),
    ("noise-not-a-table", BASE + "[noise]\nmeasurement = 3\n", "noise.measurement"),
    ("fault-agents-float", BASE + '[[faults]]\nkind = "crash"\nagents = [1.5]\n',
     "faults[0].agents"),
    ("stale-delay-huge",  # 7 TiB of memory for the stale readings before
     BASE + '[[faults]]\nkind = "stuck_sensor"\nagents = [0]\nmode = "stale"\n'
     "delay = 1000000000000\n", "faults"),
    ("kfio-Q-string", BASE + '[source_estimator]\nkind = "kfio"\nQ = "x"\nR = 1.0\n',
     "source_estimator.Q"),
    ("language-huge", _matrices("[[1.2, 0.0], [0.0, 1.1]]",
                                "[[[1.0, 0.0]], [[0.0, 1.0]], []]")
     + '[source_estimator]\nkind = "equalized"\neta_v = 0.05\n'
     'language = {kind = "each_delayed_at_most", m = 1000, T = 1000}\n',
     "source_estimator.language"),
    ("channel-empty",  # silently meant "no channel" although capacity is required
     BASE + "[channel]\n", "channel.capacity"),
    ("substate_cost-per-substate",  # 3 substates x 1e308 overflows: rewards of -inf
     BASE + '[control]\nmode = "transmit"\n[reward]\nsubstate_cost = 1e308\n', "reward"),
]


@pytest.mark.parametrize("text, field", [c[1:] for c in SCENARIOS], ids=[c[0] for c in SCENARIOS])
def test_scenario_files_name_file_and_field(tmp_path, text, field):
    path = tmp_path / "bad_v0.toml"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        build_model(load_file(path))
    msg = str(err.value)
    assert str(path) in msg and f"field '{field}'" in msg, msg


@pytest.mark.parametrize("content, match", [
    (bytes(range(256)), "not a TOML text file"),  # a binary file
    (b"horizon = 10\nhorizon = 11\n", "not valid TOML"),
    (None, "cannot read the scenario file"),  # missing
], ids=["binary", "duplicate-key", "missing"])
def test_unreadable_scenario_files_name_the_file(tmp_path, content, match):
    path = tmp_path / "bad_v0.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ValueError, match=match) as err:
        load_file(path)
    assert str(path) in str(err.value)


# ============================================================== PettingZoo env
def _env_mid_episode():
    env = make("link_failures-v0", horizon=12)
    obs, infos = env.reset(seed=3)
    pol = make_policy("freshness", env)
    for _ in range(2):
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
    return env, pol, obs, infos


def _env_future(env, pol, obs, infos) -> list:
    """Three steps, then an unseeded reset and two more: everything they return."""
    out = []
    for _ in range(3):
        res = env.step(pol.act_dict(env, obs, infos))
        obs, infos = res[0], res[4]
        out.append(res)
    obs, infos = env.reset()  # draws its seed from the env's generator
    out.append((obs, infos))
    for _ in range(2):
        res = env.step(pol.act_dict(env, obs, infos))
        obs, infos = res[0], res[4]
        out.append(res)
    return out


def _action(env, **change):
    act = {a: np.r_[np.zeros(env.core.M, np.int64), 1] for a in env.agents}
    for a, v in change.items():
        act[a] = v
    return act


ENV = [
    # (id, bad call on the env, match)
    ("reset-seed-negative", lambda e: e.reset(seed=-1), "seed must be an integer"),
    ("reset-seed-float", lambda e: e.reset(seed=1.5), "seed must be an integer"),
    ("reset-seed-str", lambda e: e.reset(seed="abc"), "seed must be an integer"),
    ("reset-seed-list", lambda e: e.reset(seed=[1, 2]), "seed must be an integer"),
    ("reset-seed-bool", lambda e: e.reset(seed=True), "seed must be an integer"),
    ("reset-options-int", lambda e: e.reset(seed=0, options=3), "options must be a dict"),
    ("step-missing-agent", lambda e: e.step({"sensor_0": [0] * 11}), "missing for agents"),
    ("step-unknown-agent", lambda e: e.step({**_action(e), "spy": [0] * 11}),
     "unknown agents"),
    ("step-not-a-dict", lambda e: e.step([0] * 11), "actions must be a dict"),
    ("step-short-action", lambda e: e.step(_action(e, sensor_0=[0, 1])),
     "every action must be a vector of 11"),
    ("step-inf-action",  # the issue's example: the message showed -2^63
     lambda e: e.step(_action(e, sensor_0=[np.inf] + [0] * 10)), "is inf"),
    ("step-fraction", lambda e: e.step(_action(e, sensor_0=[0.5] + [0] * 10)),
     "actions must be integers"),
    ("step-out-of-range", lambda e: e.step(_action(e, sensor_0=[0] * 10 + [7])),
     "for transmit is 7, outside 0..1"),
    ("step-masked-own-substate", lambda e: e.step(_action(e, sensor_0=[1] + [0] * 10)),
     "masked action: agent 0"),
    ("step-str-action", lambda e: e.step(_action(e, sensor_0="abcdefghijk")),
     "every action must be a vector"),
    ("observation_space-unknown", lambda e: e.observation_space("spy"), "unknown agent 'spy'"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in ENV], ids=[c[0] for c in ENV])
def test_env_rejects_and_keeps_stepping_like_an_untouched_copy(call, match):
    env, pol, obs, infos = _env_mid_episode()
    twin = copy.deepcopy((env, obs, infos))
    with pytest.raises(ValueError, match=match):
        call(env)
    _same(_env_future(env, pol, obs, infos), _env_future(twin[0], pol, twin[1], twin[2]))


def test_the_untouched_copy_check_can_fail():
    """The comparison above sees a changed env (here: a different unseeded reset)."""
    env, pol, obs, infos = _env_mid_episode()
    twin = copy.deepcopy((env, obs, infos))
    env._seed_rng = np.random.default_rng(1)  # what reset(seed=[1, 2]) used to do
    with pytest.raises(AssertionError):
        _same(_env_future(env, pol, obs, infos), _env_future(twin[0], pol, twin[1], twin[2]))


# ============================================================== batched core
def _model(sid="link_failures-v0", **over):
    return build_model(with_overrides(load(sid), **{"horizon": 12, **over}))


MODEL = _model()


def _core_mid_episode():
    core = BatchedCore(MODEL, 3)
    obs, mask = core.reset(5)
    pol = make_policy("freshness", core)
    for _ in range(2):
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    return core, pol, obs, mask


def _core_future(core, pol, obs, mask) -> list:
    out = []
    for _ in range(3):
        res = core.step(pol.act(obs, mask))
        obs, mask = res.obs, res.action_mask
        out.append(tuple(res) + (core.x.copy(), core.Z.copy(), core.tau.copy()))
    obs, mask = core.reset(7, members=np.array([True, False, True]))
    out.append((obs, mask))
    res = core.step(pol.act(obs, mask))
    return out + [tuple(res)]


def _acts(core, **at):
    a = np.zeros((3, core.N, core.M + 1))
    a[..., -1] = 1
    for v in at.values():
        a[v[0]] = v[1]
    return a


CORE = [
    ("reset-members-integers",  # the issue's example: read as a bool mask
     lambda c: c.reset(0, members=np.array([0, 2, 1])), "members must be a bool mask"),
    ("reset-members-shape", lambda c: c.reset(0, members=np.array([True, False])),
     r"members must be a bool mask of shape \(3,\)"),
    ("reset-seed-negative", lambda c: c.reset(-1), "seed must be an integer"),
    ("reset-seed-float", lambda c: c.reset(1.5), "seed must be an integer"),
    ("reset-seed-str", lambda c: c.reset("abc"), "seed must be an integer"),
    ("reset-seed-short", lambda c: c.reset([1, 2]), "seed must hold 3 entries"),
    ("reset-seed-entry", lambda c: c.reset([1, 2, 3.5]), r"seed\[2\] must be an integer"),
    ("step-shape", lambda c: c.step(np.zeros((3, c.N, c.M))), "actions must have shape"),
    ("step-inf", lambda c: c.step(_acts(c, x=((1, 2, 0), np.inf))), "is inf"),
    ("step-nan", lambda c: c.step(_acts(c, x=((0, 0, 3), np.nan))), "actions must be integers"),
    ("step-huge-float", lambda c: c.step(_acts(c, x=((0, 0, 3), 1e30))),
     "actions must be integers"),
    ("step-object", lambda c: c.step(np.full((3, c.N, c.M + 1), None)),
     "actions must be integers"),
    ("step-out-of-range", lambda c: c.step(_acts(c, x=((2, 1, 0), 99)).astype(int)),
     "action of agent 1 \\(batch member 2\\) for substate 0 is 99"),
    ("step-uint64-huge", lambda c: c.step(np.full((3, c.N, c.M + 1), 2**64 - 1, np.uint64)),
     "is 18446744073709551615"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in CORE], ids=[c[0] for c in CORE])
def test_core_rejects_and_keeps_stepping_like_an_untouched_copy(call, match):
    core, pol, obs, mask = _core_mid_episode()
    twin = copy.deepcopy(core)
    with pytest.raises(ValueError, match=match):
        call(core)
    _same(_core_future(core, pol, obs, mask), _core_future(twin, pol, obs, mask))


@pytest.mark.parametrize("kwargs, match", [
    ({"batch_size": 1.5}, "batch_size must be an integer"),  # the issue's examples:
    ({"batch_size": "4"}, "batch_size must be an integer"),  # converted silently
    ({"batch_size": 0}, "batch_size must be an integer >= 1"),
    ({"invalid_actions": "ignore"}, "invalid_actions must be one of"),
    ({"chunk": 0}, "chunk must be an integer >= 1"),
    ({"nonfinite": "ignore"}, "nonfinite must be one of"),
    ({"model": "link_failures-v0"}, "model must be a CoreModel"),
], ids=["B-float", "B-str", "B-zero", "invalid_actions", "chunk", "nonfinite", "model"])
def test_core_constructor_rejects(kwargs, match):
    kw = {"model": MODEL, "batch_size": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        BatchedCore(**kw)


@pytest.mark.parametrize("call", ["step", "observe", "action_mask", "state_vector"])
def test_core_before_reset_says_so(call):
    core = BatchedCore(MODEL, 2)
    args = (np.zeros((2, core.N, core.M + 1), np.int64),) if call == "step" else ()
    with pytest.raises(ValueError, match=f"reset\\(\\) must be called before {call}"):
        getattr(core, call)(*args)


# ============================================================== vector envs
def _batched_mid():
    be = BatchedEnv("link_failures-v0", 3, horizon=6)
    be.reset(seed=2)
    for _ in range(2):
        be.step(_fixed(be.core, 3))
    return be


def _fixed(core, B):
    a = np.zeros((B, core.N, core.M + 1), np.int64)
    a[..., -1] = 1
    return a


def _batched_future(be) -> list:  # crosses the horizon: an auto-reset from the generator
    return [be.step(_fixed(be.core, 3)) for _ in range(6)]


BATCHED = [
    ("reset-seed-float", lambda b: b.reset(seed=1.5), "seed must be an integer"),
    ("reset_at-float-indices", lambda b: b.reset_at([0.5]), "members must be member indices"),
    ("reset_at-mask-shape", lambda b: b.reset_at(np.array([True])), "a member mask must have"),
    ("reset_at-out-of-range", lambda b: b.reset_at([5]), "member indices must be in 0..2"),
    ("reset_at-seed-negative", lambda b: b.reset_at([0], seed=-3), "seed must be an integer"),
    ("step-shape", lambda b: b.step(np.zeros((3, b.num_agents, 2), np.int64)),
     "actions must have shape"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in BATCHED], ids=[c[0] for c in BATCHED])
def test_batched_env_rejects_and_keeps_stepping_like_an_untouched_copy(call, match):
    be = _batched_mid()
    twin = copy.deepcopy(be)
    with pytest.raises(ValueError, match=match):
        call(be)
    _same(_batched_future(be), _batched_future(twin))


def _agent_vec_mid():
    av = AgentVectorEnv("link_failures-v0", 2, horizon=6)
    av.reset(seed=4)
    for _ in range(2):
        av.step(_fixed(av.batched.core, 2).reshape(av.num_envs, -1))
    return av


AGENT_VEC = [
    ("reset_mask-integers", lambda v: v.reset(options={"reset_mask": np.array([0, 1])}),
     "reset_mask must be a bool array"),
    ("options-not-a-dict", lambda v: v.reset(options="x"), "options must be a dict"),
    ("options-unknown", lambda v: v.reset(options={"x": 1}), "unknown reset options"),
    ("step-shape", lambda v: v.step(np.zeros((5, 11), np.int64)), "actions must have shape"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in AGENT_VEC],
                         ids=[c[0] for c in AGENT_VEC])
def test_agent_vector_env_rejects_and_keeps_stepping(call, match):
    av = _agent_vec_mid()
    twin = copy.deepcopy(av)

    def future(v):
        return [v.step(_fixed(v.batched.core, 2).reshape(v.num_envs, -1)) for _ in range(5)]

    with pytest.raises(ValueError, match=match):
        call(av)
    _same(future(av), future(twin))


@pytest.mark.parametrize("call, match", [
    (lambda: BatchedEnv("fig1_scalar-v0", 2.0), "num_envs must be an integer"),
    (lambda: BatchedEnv("fig1_scalar-v0", "abc"), "num_envs must be an integer"),
    (lambda: BatchedEnv(3, 2), "scenario must be a scenario id or a CoreModel"),
    (lambda: AgentVectorEnv("fig1_scalar-v0", 2, render_mode="ansi"), "options of the"),
    (lambda: make_sb3_vec_env("fig1_scalar-v0", 2, seed="a"), "seed must be an integer"),
    (lambda: make_sb3_vec_env("fig1_scalar-v0", 0), "num_envs must be an integer >= 1"),
], ids=["num_envs-float", "num_envs-str", "scenario-int", "env-only-option", "sb3-seed",
        "sb3-batch-zero"])
def test_vector_constructors_reject(call, match):
    pytest.importorskip("stable_baselines3")
    with pytest.raises(ValueError, match=match):
        call()


# ============================================================== command line
CLI = [
    # (id, argv, text the one stderr line must contain)
    ("demo-steps-negative", ["demo", "--steps", "-5"], "argument --steps: must be >= 1"),
    ("demo-steps-text", ["demo", "--steps", "abc"], "argument --steps: invalid integer"),
    ("train-unknown-scenario", ["train", "nope-v0", "--out", "{tmp}/t"],
     "unknown scenario 'nope-v0'"),
    ("train-bad-override", ["train", "fig1_scalar-v0", "--out", "{tmp}/t", "--override",
                            "horizon=abc"], "field 'horizon'"),
    ("train-override-syntax", ["train", "fig1_scalar-v0", "--out", "{tmp}/t", "--override",
                               "noequals"], "override must look like KEY=VALUE"),
    ("benchmark-unknown-scenario", ["benchmark", "nope-v0", "--out", "{tmp}/b"],
     "unknown scenario 'nope-v0'"),
    ("benchmark-seeds-zero", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b", "--seeds",
                              "0"], "argument --seeds: must be >= 1"),
    ("benchmark-unknown-policy", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                  "--policies", "bogus"], "--policies: unknown policy"),
    ("benchmark-missing-policy-file", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                       "--policies", "learned:{tmp}/none.zip"],
     "no policy file"),
    ("benchmark-workers", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b", "--workers",
                           "2"], "needs --backend process"),
    ("equalized-A-not-json", ["equalized", "--A", "notjson", "--C", "[[1.0]]", "--language",
                              "each:1:3"], "argument --A: not valid JSON"),
    ("equalized-C-width", ["equalized", "--A", "[[2.0]]", "--C", "[[1.0, 2.0]]",
                           "--language", "each:1:3"], "--C must be a matrix with n = 1"),
    ("equalized-language", ["equalized", "--A", "[[2.0]]", "--C", "[[1.0]]", "--language",
                            "each:x:3"], "each:M:T"),
    ("sweep-family", ["sweep", "--family", "torus", "--quiet"], "--family: unknown family"),
    ("grid-load-scale-nan", ["grid", "script", "--load-scale", "nan"],
     "argument --load-scale: must be a finite number"),
    ("bench-env-N-zero", ["bench", "env", "--N", "0"], "argument --N: must be >= 1"),
    ("demo-out-unwritable", ["demo", "--steps", "3", "--out", "/proc/netsense-nope"],
     "netsense-nope"),
    ("unknown-command", ["nosuchcmd"], "invalid choice: 'nosuchcmd'"),
    # the training and communication surfaces
    ("train-typo-flag-names-the-subcommand", ["train", "fig1_scalar-v0", "--stpes", "5"],
     "netsense train: error: unrecognized arguments: --stpes 5 (did you mean: --stpes -> "
     "--steps?)"),
    ("train-scenario-suggestion", ["train", "fig1_scalr-v0"],
     "unknown scenario 'fig1_scalr-v0' (did you mean 'fig1_scalar-v0'"),
    ("train-override-invalid-json", ["train", "fig1_scalar-v0", "--override",
                                     'reward={"message_cost: 0.1}'],
     "--override reward=: not valid JSON"),  # was "must be a table"
    ("train-override-twice", ["train", "fig1_scalar-v0", "--override", "horizon=5",
                              "--override", "horizon=6"], "--override horizon= is given twice"),
    ("train-sb3-with-torchrl-option", ["train", "fig1_scalar-v0", "--backend", "sb3",
                                       "--network", "set", "--reward", "team"],
     "--network, --reward belong to --backend torchrl; the sb3 backend would ignore them"),
    ("train-rollout-zero", ["train", "fig1_scalar-v0", "--backend", "torchrl",
                            "--n-steps", "0"], "argument --rollout/--n-steps: must be >= 1"),
    ("train-torch-threads-zero", ["train", "fig1_scalar-v0", "--torch-threads", "0"],
     "argument --torch-threads: must be >= 1"),
    ("train-torchrl-device-bogus", ["train", "fig1_scalar-v0", "--backend", "torchrl",
                                    "--device", "bogus", "--out", "{tmp}/t"],
     "PPOConfig.device must be 'auto', 'cpu', 'cuda' or 'cuda:<index>'"),
    ("train-torchrl-gamma", ["train", "fig1_scalar-v0", "--backend", "torchrl", "--gamma",
                             "1.5", "--out", "{tmp}/t"], "PPOConfig.gamma must be"),
    ("train-torchrl-bc-unknown", ["train", "fig1_scalar-v0", "--backend", "torchrl", "--bc",
                                  "nope", "--out", "{tmp}/t"], "PPOConfig.bc must be"),
    ("train-torchrl-num-envs-huge", ["train", "fig1_scalar-v0", "--backend", "torchrl",
                                     "--num-envs", "10000000", "--out", "{tmp}/t"],
     "PPOConfig.num_envs must be an integer in [1, 900000]"),
    ("train-torchrl-seeds-twice", ["train", "fig1_scalar-v0", "--backend", "torchrl",
                                   "--seeds", "1", "1", "--out", "{tmp}/t"],
     "--seeds lists a seed twice"),
    ("train-torchrl-second-seed-bad", ["train", "fig1_scalar-v0", "--backend", "torchrl",
                                       "--seeds", "0", "4000", "--num-envs", "256", "--out",
                                       "{tmp}/t"], "below 900000"),  # before seed 0 runs
    ("benchmark-learned-without-frontier", ["benchmark", "fig1_scalar-v0", "--out",
                                            "{tmp}/b", "--learned", "{tmp}/p.pt"],
     "--learned needs --frontier"),  # was exit 0 with no learned row
    ("benchmark-families-without-frontier", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                             "--families", "periodic"],
     "--families needs --frontier"),
    ("benchmark-frontier-with-policies", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                          "--frontier", "--policies", "freshness"],
     "--policies does not apply to --frontier"),
    ("benchmark-frontier-with-eps", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                     "--frontier", "--eps", "0.1"],
     "--eps does not apply to --frontier"),
    ("benchmark-frontier-with-backend", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                         "--frontier", "--backend", "process"],
     "--backend process does not apply to --frontier"),
    ("benchmark-frontier-missing-learned", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                            "--frontier", "--learned", "{tmp}/none.pt"],
     "no policy file"),  # was reported after the whole scripted frontier
    ("benchmark-learned-sampled-missing", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                           "--policies", "learned_sampled:{tmp}/none.zip"],
     "no policy file"),
    ("benchmark-learned-no-path", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                   "--policies", "learned"], "a learned policy needs its file"),
    ("benchmark-address-without-ray", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                       "--address", "auto"], "--address needs --backend ray"),
    ("benchmark-bad-override", ["benchmark", "fig1_scalar-v0", "--out", "{tmp}/b",
                                "--override", "channel={}"], "field 'channel.capacity'"),
    ("policy-check-missing", ["policy", "check", "{tmp}/none.pt"], "no policy file at"),
    ("policy-check-suffix", ["policy", "check", "{tmp}/p.txt"], "ends in .pt"),
    ("policy-convert-without-trust", ["policy", "convert", "{tmp}/p.pt"],
     "convert needs --trust"),
]


@pytest.mark.parametrize("argv, text", [c[1:] for c in CLI], ids=[c[0] for c in CLI])
def test_cli_exits_2_with_one_line(tmp_path, capsys, argv, text):
    if "torchrl" in argv or argv[0] == "policy":  # (these checks run on torch's side)
        pytest.importorskip("torch")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own errors exit through the parser
        rc = exc.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1, err
    assert lines[0].startswith("netsense") and ": error: " in lines[0] and text in lines[0], err


@pytest.mark.parametrize("argv, text", [
    (["demo", "--steps", "-5"], "argument --steps"),
    (["train", "nope-v0", "--out", "/tmp/x"], "unknown scenario 'nope-v0'"),
], ids=["argparse", "command"])
def test_cli_console_entry_exits_2_without_traceback(argv, text):
    res = _python(f"import sys; from netsense.cli import main; sys.exit(main({argv!r}))")
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and text in res.stderr
    assert len([ln for ln in res.stderr.splitlines() if ln.startswith("netsense")]) == 1


# ============================================================== learned-policy files
@pytest.fixture(scope="module")
def policy_files(tmp_path_factory):
    sb3 = pytest.importorskip("sb3_contrib")
    from netsense.rl.sb3 import make_vec_env

    d = tmp_path_factory.mktemp("policies")
    venv = make_vec_env("fig1_scalar-v0", num_vec_envs=1, seed=0, overrides={"horizon": 8})
    model = sb3.MaskablePPO("MlpPolicy", venv, n_steps=8, batch_size=8, device="cpu")
    good = d / "policy.zip"
    model.save(good)
    (d / "foreign.zip").write_bytes(good.read_bytes())  # SB3's own zip: no netsense.json
    from netsense.rl.sb3_policy import sb3_metadata, write_sb3_metadata

    write_sb3_metadata(good, sb3_metadata(model, scenario="fig1_scalar-v0",
                                          overrides={"horizon": 8}, seed=0, num_vec_envs=1))
    data = good.read_bytes()
    (d / "truncated.zip").write_bytes(data[:3000])
    flipped = bytearray(data)
    for i in range(200, len(flipped), 97):
        flipped[i] ^= 0xFF
    (d / "corrupted.zip").write_bytes(bytes(flipped))
    (d / "text.zip").write_text("hello\n")
    (d / "dir.zip").mkdir()
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(d / "inner.zip", "w") as zout:
        for n in zin.namelist():  # a valid zip whose members are cut short
            b = zin.read(n)
            zout.writestr(n, b[:len(b) // 3] if n in ("data", "policy.pth") else b)
    return d


@pytest.mark.parametrize("name, match", [
    ("truncated.zip", "not a readable MaskablePPO policy file"),
    ("corrupted.zip", "not a readable MaskablePPO policy file"),
    ("text.zip", "not a readable MaskablePPO policy file"),
    ("inner.zip", "not a readable policy file"),  # policy.pth cut short
    ("dir.zip", "not a policy file"),
    ("missing.zip", "no learned policy at"),
])
def test_bad_policy_files_raise_value_error_naming_the_file(policy_files, name, match):
    from netsense.rl.sb3_policy import LearnedPolicy

    with pytest.raises(ValueError, match=match) as err:
        LearnedPolicy(policy_files / name)
    assert name in str(err.value)


def test_policy_of_another_scenario_is_refused(policy_files):
    from netsense.rl.sb3_policy import LearnedPolicy
    from netsense.rl.wrappers import MaskedFlatObs

    pol = LearnedPolicy(policy_files / "policy.zip")
    wrapped = MaskedFlatObs(make("link_failures-v0"))
    obs, _ = wrapped.reset(seed=0)
    with pytest.raises(ValueError, match="trained for observations of shape"):
        pol.act(obs, wrapped)
    ok = MaskedFlatObs(make("fig1_scalar-v0", horizon=8))  # its own scenario still works
    obs, _ = ok.reset(seed=0)
    assert set(pol.act(obs, ok)) == set(ok.possible_agents)


# ============================================================== numerical health
def _run_unstable(**kw):
    env = make("fig1_scalar-v0", horizon=3000, **kw)  # x[k+1] = 2 x[k]: inf at k = 1024
    obs, infos = env.reset(seed=0)
    pol = make_policy("freshness", env)
    steps, out = 0, None
    while env.agents:
        out = env.step(pol.act_dict(env, obs, infos))
        obs, infos = out[0], out[4]
        steps += 1
    return env, steps, out


def test_an_unstable_plant_run_long_is_flagged_and_ends_the_episode():
    with pytest.warns(ns.NumericalWarning, match="plant state x is inf or NaN at step 1024 "
                                                  r"\(batch member 0\)"):
        env, steps, (obs, rew, term, trunc, infos) = _run_unstable()
    assert steps == 1024 and all(term.values()) and not any(trunc.values())
    for a in env.possible_agents:
        assert infos[a]["nonfinite"] == {"step": 1024, "what": "state", "agent": None}
        assert np.isfinite(rew[a])


def test_nonfinite_raise_mode_raises_before_the_commit():
    env = make("fig1_scalar-v0", horizon=3000, nonfinite="raise")
    obs, infos = env.reset(seed=0)
    pol = make_policy("freshness", env)
    with pytest.raises(ns.NumericalError, match="at step 1024") as err:
        for _ in range(3000):
            obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))
    e = err.value
    assert (e.member, e.agent, e.step, e.what) == (0, None, 1024, "state")
    assert env.core.k[0] == 1023 and np.isfinite(env.core.x).all()  # not committed


def test_an_overflowing_error_is_flagged_with_its_agent():
    """Relays that never adopt keep estimate 0 while x grows as 2^k: their error's square
    overflows at k = 512 although state and estimates are finite."""
    env = make("fig1_scalar-v0", horizon=3000)
    env.reset(seed=0)
    keep = {a: np.array([0, 0, 0, 1]) for a in env.possible_agents}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ns.NumericalWarning)
        while env.agents:
            *_, infos = env.step(keep)
    assert infos["sensor_1"]["nonfinite"] == {"step": 512, "what": "error", "agent": 1}


def test_vector_envs_flag_nonfinite_members_and_auto_reset_them():
    be = BatchedEnv("fig1_scalar-v0", 2, horizon=3000)
    obs, info = be.reset(seed=0)
    pol = make_policy("freshness", be.core)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ns.NumericalWarning)
        for _ in range(1100):
            obs, rew, term, trunc, info = be.step(pol.act(obs, info["action_mask"]))
            if term.any():
                break
    flagged = [r for r in info["nonfinite"] if r is not None]
    assert flagged and all(r["what"] == "state" for r in flagged)
    assert np.isfinite(obs).all() and np.isfinite(rew).all()  # restarted members


# ============================================================== training surfaces
# The batched trainer's configuration, its environment and the control modes: every bad
# field is refused when the object is built (before any training iteration), naming it.
COMM = "comm_process_noise-v0"
COMM_SHORT = {"horizon": 12}


def _torch():
    return pytest.importorskip("torchrl", reason="the batched trainer needs the 'torchrl' extra")


PPO_CONFIG = [
    # (id, PPOConfig keywords, text the message must contain)
    ("steps-str", {"steps": "100"}, "PPOConfig.steps must be an integer"),  # the issue's
    ("num_envs-float", {"num_envs": 1.5}, "PPOConfig.num_envs must be an integer"),
    ("lr-bool", {"lr": True}, "PPOConfig.lr must be a finite number"),
    ("clip-negative", {"clip": -0.2}, "PPOConfig.clip must be a finite number in (0, 1]"),
    ("hidden-zero", {"hidden": (0,)}, "PPOConfig.hidden[0] must be an integer in [1,"),
    ("gamma-nan", {"gamma": float("nan")}, "PPOConfig.gamma must be a finite number"),
    ("entropy_coef-inf", {"entropy_coef": float("inf")}, "PPOConfig.entropy_coef"),
    ("max_grad_norm-nan", {"max_grad_norm": float("nan")}, "PPOConfig.max_grad_norm"),
    ("device-bogus", {"device": "bogus"}, "PPOConfig.device must be 'auto', 'cpu'"),
    ("clip-above-1", {"clip": 1.5}, "PPOConfig.clip must be a finite number in (0, 1]"),
    ("gamma-above-1", {"gamma": 1.5}, "PPOConfig.gamma must be a finite number in [0, 1]"),
    ("lmbda-negative", {"lmbda": -0.1}, "PPOConfig.lmbda"),
    ("critic_coef-zero", {"critic_coef": 0.0}, "PPOConfig.critic_coef"),
    ("hidden-empty", {"hidden": ()}, "PPOConfig.hidden must be a non-empty tuple"),
    ("hidden-str", {"hidden": "64"}, "PPOConfig.hidden must be a non-empty tuple"),
    ("critic_hidden-float", {"critic_hidden": (64.0,)}, "PPOConfig.critic_hidden[0] must be"),
    ("hidden-huge", {"hidden": (10**7,)}, "PPOConfig.hidden[0] must be an integer in [1, 65536]"),
    ("set_hidden-zero", {"set_hidden": 0}, "PPOConfig.set_hidden"),
    ("epochs-zero", {"epochs": 0}, "PPOConfig.epochs must be an integer"),
    ("minibatch-str", {"minibatch": "512"}, "PPOConfig.minibatch must be an integer"),
    ("eval_interval-negative", {"eval_interval": -1}, "PPOConfig.eval_interval"),
    ("eval_envs-zero", {"eval_envs": 0}, "PPOConfig.eval_envs"),
    ("critic_warmup-float", {"critic_warmup": 2.0}, "PPOConfig.critic_warmup must be"),
    ("bc_steps-bool", {"bc_steps": True}, "PPOConfig.bc_steps must be an integer"),
    ("bc_lr-inf", {"bc_lr": float("inf")}, "PPOConfig.bc_lr"),
    ("bc-unknown", {"bc": "nope"}, "PPOConfig.bc must be a scripted policy"),
    ("bc-bad-knob", {"bc": "event:x"}, "PPOConfig.bc: 'event:x'"),
    ("bc-gate-bad-base", {"bc": "acked(nope:0)"},
     "PPOConfig.bc: unknown communication policy 'nope'"),
    ("numba_threads-zero", {"numba_threads": 0}, "PPOConfig.numba_threads"),
    ("torch_threads-str", {"torch_threads": "1"}, "PPOConfig.torch_threads"),
    ("overlap-int", {"overlap": 1}, "PPOConfig.overlap"),
    ("precision-unknown", {"precision": "fp16"}, "PPOConfig.precision must be one of"),
    ("precision-case", {"precision": "BF16"}, "PPOConfig.precision must be one of"),
    ("seed-bool", {"seed": True}, "PPOConfig.seed must be an integer"),
    ("algo-case", {"algo": "MAPPO"}, "PPOConfig.algo must be one of"),
    ("reward-unknown", {"reward": "shaped"}, "PPOConfig.reward must be one of"),
    ("critic-ippo-state", {"algo": "ippo", "critic": "state"}, "ippo uses a local critic"),
    ("device-mps", {"device": "mps"}, "PPOConfig.device must be"),
    ("scenario-unknown", {"scenario": "comm_proces_noise-v0"},
     "did you mean 'comm_process_noise-v0'"),
    ("scenario-int", {"scenario": 3}, "PPOConfig.scenario must be a string"),
    ("overrides-list", {"overrides": [("horizon", 5)]}, "PPOConfig.overrides must be a dict"),
    ("overrides-bad-value", {"overrides": {"horizon": "abc"}}, "field 'horizon'"),
    ("overrides-env-option", {"overrides": {"render_mode": "ansi"}}, "field 'render_mode'"),
    ("overrides-control-not-a-table", {"overrides": {"control": "transmit"}},
     "PPOConfig.overrides['control'] must be a table"),
    ("control-unknown", {"control": "tx"}, "PPOConfig.control must be one of"),
    ("control-dict-bad-mode", {"control": {"mode": "broadcast"}}, "control.mode"),
    ("clock-period-1", {"clock": (1, 5)}, "PPOConfig.clock[0] must be an integer in [2,"),
    ("clock-repeated", {"clock": [5, 5]}, "PPOConfig.clock must not repeat a value"),
    ("clock-str", {"clock": "5"}, "PPOConfig.clock must be a tuple of integers"),
    ("clock-obs-norm", {"clock": (5,), "obs_norm": True}, "not available with obs_norm=True"),
    ("clock-set-network", {"clock": (5,), "network": "set"}, "network='set'"),
    ("clock_shift-without-clock", {"clock_shift": True}, "give the periods in PPOConfig.clock"),
    ("clock_only-without-clock", {"clock_only": True}, "give the periods in PPOConfig.clock"),
    ("comm_fields_only-str", {"comm_fields_only": "yes"},
     "PPOConfig.comm_fields_only must be one of"),
    ("comm_fields_only-set-network", {"comm_fields_only": True, "network": "set"},
     "PPOConfig.comm_fields_only keeps"),
    ("comm_fields_only-full", {"comm_fields_only": True, "control": "full"},
     "PPOConfig.comm_fields_only keeps"),
    ("ages-zero", {"ages": (0, 4)}, "PPOConfig.ages[0] must be an integer in [1,"),
    ("ages-repeated", {"ages": [4, 4]}, "PPOConfig.ages must not repeat a value"),
    ("ages-set-network", {"ages": (4,), "network": "set"}, "network='set'"),
    ("news_gate-str", {"news_gate": "yes"}, "PPOConfig.news_gate must be one of"),
    ("news_gate-full", {"news_gate": True, "control": "full"},
     "PPOConfig.news_gate gates the send choices"),
    ("news_gate-full-table", {"news_gate": True, "control": {"mode": "full"}},
     "PPOConfig.news_gate gates the send choices"),
]


@pytest.mark.parametrize("kwargs, match", [c[1:] for c in PPO_CONFIG],
                         ids=[c[0] for c in PPO_CONFIG])
def test_ppo_config_refuses_and_names_the_field(kwargs, match):
    _torch()
    from netsense.rl.config import PPOConfig

    kw = {"scenario": COMM, **kwargs}
    with pytest.raises(ValueError) as err:
        PPOConfig(**kw)
    assert match in str(err.value), str(err.value)


def test_ppo_config_takes_what_it_refused_as_a_type_in_its_own_type():
    """The refusals above are about the value, not the field: the same fields take
    correct values (and a list of widths is stored as a tuple)."""
    _torch()
    from netsense.rl.config import PPOConfig

    cfg = PPOConfig(COMM, steps=100, num_envs=2, lr=1e-3, clip=1.0, hidden=[16, 8],
                    gamma=1.0, lmbda=0.0, entropy_coef=0.0, bc="event:2", seed=0,
                    device="cpu", numba_threads=None)
    assert cfg.hidden == (16, 8) and cfg.steps == 100
    # a gate with its base rule, as the frontier writes it (acked(sources:0))
    assert PPOConfig(COMM, bc="acked(sources:0)").bc == "acked(sources:0)"


def _comm_core_mid_episode(B=3, mode="transmit"):
    from netsense.env.comm_policies import make_comm_policy
    from netsense.rl.envs import make_core

    core = make_core(COMM, B, control=mode, **COMM_SHORT)
    obs, mask = core.reset(4)
    pol = make_comm_policy("periodic:2", core)
    for _ in range(2):
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    return core, pol, obs, mask


def _comm_future(core, pol, obs, mask) -> list:
    out = []
    for _ in range(3):
        res = core.step(pol.act(obs, mask))
        obs, mask = res.obs, res.action_mask
        out.append(tuple(res) + (core.x.copy(), core.Z.copy(), core.tau.copy()))
    return out


def _bits(core, value, dtype=np.int64):
    a = np.zeros((core.B, core.N, core.nvec.size), dtype)
    a[1, 2, 0] = value
    return a


COMM_CORE = [
    # (id, bad call on a transmit-mode core mid-episode, match)
    ("transmit-2^63-uint64",  # the issue's example: reported against 0..D + 1
     lambda c: c.step(_bits(c, 2**63, np.uint64)),
     r"agent 2 \(batch member 1\) for transmit is 9223372036854775808, outside 0..1"),
    ("transmit-2", lambda c: c.step(_bits(c, 2)), "for transmit is 2, outside 0..1"),
    ("transmit-negative", lambda c: c.step(_bits(c, -1)), "for transmit is -1, outside 0..1"),
    ("transmit-half", lambda c: c.step(_bits(c, 0.5, float)), "actions must be integers"),
    ("transmit-nan", lambda c: c.step(_bits(c, np.nan, float)), "actions must be integers"),
    ("transmit-full-layout", lambda c: c.step(np.zeros((c.B, c.N, c.M + 1), np.int64)),
     r"actions must have shape \(B, N, len\(nvec\)\)"),
    ("transmit-str", lambda c: c.step(np.full((c.B, c.N, 1), "1")), "actions must be integers"),
    ("env-seed-float", lambda c: __import__("netsense.rl.envs").rl.envs.NetSenseBatchedEnv(
        c, seed=1.5), "seed must be an integer"),  # the issue's example: used seed 1
    ("env-seed-negative", lambda c: __import__("netsense.rl.envs").rl.envs
     .NetSenseBatchedEnv(c, seed=-1), "seed must be an integer"),
    ("env-seed-str", lambda c: __import__("netsense.rl.envs").rl.envs.NetSenseBatchedEnv(
        c, seed="3"), "seed must be an integer"),
    ("env-reward-unknown", lambda c: __import__("netsense.rl.envs").rl.envs
     .NetSenseBatchedEnv(c, reward="shaped"), "reward must be one of"),
    ("env-device-bogus", lambda c: __import__("netsense.rl.envs").rl.envs
     .NetSenseBatchedEnv(c, device="bogus"), "device must be 'auto', 'cpu'"),
]


@pytest.mark.parametrize("call, match", [c[1:] for c in COMM_CORE],
                         ids=[c[0] for c in COMM_CORE])
def test_comm_core_and_its_torchrl_env_reject_and_keep_stepping(call, match):
    _torch()
    core, pol, obs, mask = _comm_core_mid_episode()
    twin = copy.deepcopy(core)
    with pytest.raises(ValueError, match=match):
        call(core)
    _same(_comm_future(core, pol, obs, mask), _comm_future(twin, pol, obs, mask))


def test_substates_core_names_the_substate_of_a_huge_bit():
    _torch()
    core, *_ = _comm_core_mid_episode(mode="substates")
    with pytest.raises(ValueError, match="for substate 0 is 9223372036854775808, "
                                         "outside 0..1"):
        core.step(_bits(core, 2**63, np.uint64))


MAKE_CORE = [
    ("num_envs-float", {"num_envs": 2.5}, "num_envs must be an integer"),  # the issue's
    ("num_envs-str", {"num_envs": "2"}, "num_envs must be an integer"),  # examples: ran
    ("num_envs-bool", {"num_envs": True}, "num_envs must be an integer"),  # with B = 2, 2, 1
    ("num_envs-zero", {"num_envs": 0}, "num_envs must be an integer >= 1"),
    ("env-option", {"nonfinite": "raise"}, "options of the PettingZoo env"),
    ("substate_cost-per-substate", {"control": "substates", "reward": {"substate_cost": 1e308}},
     "substate_cost \\* M must be finite"),
    ("channel-empty", {"channel": {}}, "field 'channel.capacity': is required"),
    ("channel-capacity-float", {"channel": {"capacity": 1.5}}, "channel.capacity must be"),
    ("channel-capacity-zero", {"channel": {"capacity": 0}}, "channel.capacity must be"),
    ("channel-unknown-key", {"channel": {"capacity": 2, "slots": 3}}, "channel.slots"),
]


@pytest.mark.parametrize("kwargs, match", [c[1:] for c in MAKE_CORE],
                         ids=[c[0] for c in MAKE_CORE])
def test_make_core_refuses(kwargs, match):
    _torch()
    from netsense.rl.envs import make_core

    kw = {"num_envs": 2, **COMM_SHORT, **kwargs}
    with pytest.raises(ValueError, match=match):
        make_core(COMM, **kw)


def test_a_huge_batch_is_a_value_error_naming_num_envs():
    """Arrays that cannot be allocated: ``ValueError`` naming ``num_envs`` (was a bare
    ``MemoryError``); run in a subprocess under a 2 GiB address-space limit."""
    _torch()
    res = _python("import resource; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))\n"
                  "from netsense.env.registry import make\n"
                  "from netsense.rl.envs import make_core\n"
                  "try:\n    make_core('fig1_scalar-v0', 10**8)\n"
                  "except ValueError as e:\n    print('ValueError', e)\n")
    assert "ValueError num_envs = 100000000: the core's arrays alone take about" in \
        res.stdout, res.stdout + res.stderr


def test_the_reward_bound_counts_the_payload_cost_per_substate():
    """c_s M finite is accepted, and the rewards stay finite (the issue's example gave
    -inf: the bound counted c_s once while it is paid for each of M = 5 substates)."""
    from netsense.env.comm_policies import make_comm_policy

    env = make("comm_substates-v0", horizon=4, reward={"substate_cost": 3e307,
                                                      "message_cost": 0.0})
    assert env.model.reward_bound == pytest.approx(1.0 + 5 * 3e307)
    core = env.core
    obs, mask = core.reset(0)
    out = core.step(make_comm_policy("always", core).act(obs, mask))
    assert np.isfinite(out.reward).all() and out.reward.min() < -1e307
    with pytest.raises(ValueError, match="substate_cost \\* M must be finite"):
        make("comm_substates-v0", reward={"substate_cost": 4e307})  # 5 x 4e307 overflows


def test_the_torchrl_env_refuses_rewards_beyond_float32():
    _torch()
    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    core = make_core(COMM, 2, reward={"error_weight": 1e300}, **COMM_SHORT)
    with pytest.raises(ValueError, match="float32 reward spec"):
        NetSenseBatchedEnv(core)


@pytest.mark.parametrize("device, match", [
    ("cuda", "torch sees no CUDA device here"),  # the issue's: a 46-line AssertionError
    ("cuda:0", "torch sees no CUDA device here"),
    ("bogus", "PPOConfig.device must be 'auto', 'cpu'"),  # was torch's own message
])
def test_device_is_checked_against_what_torch_has(device, match):
    torch = pytest.importorskip("torch")
    _torch()
    from netsense.rl.config import device_of

    if device.startswith("cuda") and torch.cuda.is_available():
        assert device_of(device).type == "cuda"
        with pytest.raises(ValueError, match="torch sees"):
            device_of(f"cuda:{torch.cuda.device_count()}")
        return
    with pytest.raises(ValueError, match=match):
        device_of(device)


def test_a_control_override_is_a_valid_input():
    """``overrides={"control": ...}`` crashed make_core with a TypeError (``control`` given
    twice); it is folded into ``control`` and the run builds."""
    _torch()
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core

    cfg = PPOConfig("message_cost-v1", overrides={"control": {"mode": "transmit"},
                                                  **COMM_SHORT})
    assert cfg.control == {"mode": "transmit"} and "control" not in cfg.overrides
    core = make_core(cfg.scenario, 2, control=cfg.control, **cfg.overrides)
    assert core.control.mode == "transmit"
    both = PPOConfig("message_cost-v1", control="substates",
                     overrides={"control": {"mode": "transmit", "fusion": "tree"}})
    assert both.control == {"mode": "substates", "fusion": "tree"}  # the flag wins on mode


# ============================================================== policy files (.pt)
@pytest.fixture(scope="module")
def pt_files(tmp_path_factory):
    """A valid ``.pt`` (MLP, transmit mode) and one broken variant per way a file can be
    wrong; weights are untrained (loading, not acting well, is under test)."""
    _torch()
    import torch

    from netsense.rl.checkpoint import read_policy, save_checkpoint, write_policy
    from netsense.rl.config import PPOConfig
    from netsense.rl.envs import make_core
    from netsense.rl.policy import actor_net

    d = tmp_path_factory.mktemp("pt")
    cfg = PPOConfig(COMM, control="transmit", hidden=(8,), set_hidden=8,
                    overrides=COMM_SHORT)
    core = make_core(COMM, 1, control="transmit", **COMM_SHORT)
    net = actor_net(cfg, core)
    save_checkpoint(d / "good.pt", cfg, net, net, 1, 8, core)
    full = PPOConfig(COMM, network="set", control="full", set_hidden=8, overrides=COMM_SHORT)
    fcore = make_core(COMM, 1, control="full", **COMM_SHORT)
    fnet = actor_net(full, fcore)
    save_checkpoint(d / "set_full.pt", full, fnet, fnet, 1, 8, fcore)
    good = read_policy(d / "good.pt")

    def variant(name, change, seal=True):
        state = copy.deepcopy(good)
        change(state)
        if seal:
            write_policy(d / name, state)
        else:
            torch.save(state, d / name)

    first = next(iter(good["actor"]))
    variant("nan.pt", lambda s: s["actor"][first].fill_(float("nan")))
    variant("int_weights.pt", lambda s: s["actor"].__setitem__(
        first, s["actor"][first].long()))
    variant("unsealed.pt", lambda s: [s.pop(k) for k in ("sha256", "format",
                                                          "format_version")], seal=False)
    variant("no_hidden.pt", lambda s: s["config"].pop("hidden"))
    variant("unknown_key.pt", lambda s: s["config"].__setitem__("frobnicate", 1))
    variant("bad_lr.pt", lambda s: s["config"].__setitem__("lr", -1.0))
    variant("unknown_scenario.pt", lambda s: s["config"].__setitem__("scenario", "gone-v0"))
    variant("wrong_size.pt", lambda s: s["actor"].__setitem__(
        first, torch.zeros(s["actor"][first].shape[0] + 3, s["actor"][first].shape[1])))
    variant("future.pt", lambda s: s.__setitem__("format_version", 99), seal=False)
    variant("trained_on.pt", lambda s: s["trained_on"].__setitem__("N", "10"))
    variant("control.pt", lambda s: s.__setitem__("control", "transmit"))
    variant("edited.pt", lambda s: s["config"].__setitem__("hidden", [16]), seal=False)
    torch.save([1, 2, 3], d / "list.pt")
    (d / "text.pt").write_text("hello\n")
    (d / "truncated.pt").write_bytes((d / "good.pt").read_bytes()[:700])
    (d / "dir.pt").mkdir()
    flipped = d / "flipped.pt"  # the issue's probe: 8 bytes flipped in each tensor record
    flipped.write_bytes((d / "good.pt").read_bytes())
    _flip_tensor_records(flipped)
    return d


def _flip_tensor_records(path: Path) -> None:
    """Flip 8 bytes inside every tensor data record of a ``torch.save`` zip (the zip's
    own CRCs are not checked by torch: such a file loaded before checksums)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            if "/data/" not in info.filename or info.file_size < 16:
                continue
            off = info.header_offset
            name_len = int.from_bytes(data[off + 26:off + 28], "little")
            extra_len = int.from_bytes(data[off + 28:off + 30], "little")
            start = off + 30 + name_len + extra_len
            for i in range(start + 4, start + 12):
                data[i] ^= 0x5A
    path.write_bytes(bytes(data))


PT_FILES = [
    # (file, text the message must contain besides the path)
    ("nan.pt", "NaN or infinite; a policy with non-finite weights is refused"),  # the issue's
    ("flipped.pt", "checksum mismatch"),  # the issue's: five actor tensors changed, loaded
    ("no_hidden.pt", "the stored config lacks ['hidden']"),  # was KeyError: 'hidden'
    ("wrong_size.pt", "the actor's weights do not fit the mlp network"),  # a tensordict error
    ("set_full.pt", "trained in control mode 'full'"),  # a raw size mismatch
    ("int_weights.pt", "has dtype torch.int64"),
    ("unsealed.pt", "carries no checksum"),
    ("unknown_key.pt", "keys this netsense does not know: ['frobnicate']"),
    ("bad_lr.pt", "the stored config is refused: PPOConfig.lr"),
    ("unknown_scenario.pt", "unknown scenario 'gone-v0'"),
    ("future.pt", "version 99"),
    ("trained_on.pt", "entry 'trained_on' must hold the integers"),
    ("control.pt", "entry 'control' must be a dict"),
    ("edited.pt", "checksum mismatch"),
    ("list.pt", "not a policy file of netsense's batched trainer (a list"),
    ("text.pt", "not a readable policy file"),
    ("truncated.pt", "not a readable policy file"),
    ("dir.pt", "not a policy file (a directory?)"),
    ("missing.pt", "no policy file at"),
]


@pytest.mark.parametrize("name, match", PT_FILES, ids=[c[0] for c in PT_FILES])
def test_pt_policy_files_are_refused_naming_the_file_and_the_mismatch(pt_files, name, match):
    from netsense.rl.checkpoint import load_policy

    core, pol, obs, mask = _comm_core_mid_episode()
    twin = copy.deepcopy(core)
    with pytest.raises(ValueError) as err:
        load_policy(pt_files / name, core)
    msg = str(err.value)
    assert str(pt_files / name) in msg and match in msg, msg
    _same(_comm_future(core, pol, obs, mask), _comm_future(twin, pol, obs, mask))


def test_the_valid_pt_file_loads_and_acts(pt_files):
    from netsense.rl.checkpoint import load_policy, read_policy

    core, pol, obs, mask = _comm_core_mid_episode()
    act = load_policy(pt_files / "good.pt", core).act(obs, mask)
    assert act.shape == (core.B, core.N, 1)
    core.step(act)
    assert len(read_policy(pt_files / "good.pt")["sha256"]) == 64


# ============================================================== policy files (.zip)
@pytest.fixture(scope="module")
def zip_files(policy_files, tmp_path_factory):
    """Variants of a netsense MaskablePPO zip (``policy_files``' ``policy.zip``)."""
    import torch

    from netsense.rl.sb3_policy import write_sb3_metadata

    d = tmp_path_factory.mktemp("zips")
    good = policy_files / "policy.zip"
    meta = json.loads(zipfile.ZipFile(good).read("netsense.json"))

    def rewrite(name, members: dict, reseal_meta: dict | None = None):
        with zipfile.ZipFile(good) as zin, zipfile.ZipFile(d / name, "w") as zout:
            for n in zin.namelist():
                zout.writestr(n, members.get(n, zin.read(n)))
        if reseal_meta is not None:
            write_sb3_metadata(d / name, reseal_meta)

    def pth(change):
        import io

        w = torch.load(io.BytesIO(zipfile.ZipFile(good).read("policy.pth")),
                       weights_only=True)
        change(w)
        buf = io.BytesIO()
        torch.save(w, buf)
        return buf.getvalue()

    first = "mlp_extractor.policy_net.0.weight"
    rewrite("nan.zip", {"policy.pth": pth(lambda w: w[first].fill_(float("inf")))}, meta)
    rewrite("tampered.zip", {"netsense.json": json.dumps({**meta, "net_arch": [32]})})
    rewrite("arch.zip", {}, {**meta, "net_arch": [32]})
    rewrite("activation.zip", {}, {**meta, "activation": "sigmoid"})
    rewrite("meta_json.zip", {"netsense.json": b"{not json"})
    rewrite("flipped.zip", {"policy.pth": pth(lambda w: w[first].mul_(-1.0))})
    return d


ZIP_FILES = [
    ("foreign.zip", "refused: a Stable-Baselines3 zip without netsense's metadata"),
    ("nan.zip", "NaN or infinite"),
    ("tampered.zip", "checksum mismatch"),
    ("flipped.zip", "checksum mismatch"),
    ("arch.zip", "the weights do not fit the policy its metadata describes"),
    ("activation.zip", "'activation' must be one of ['tanh', 'relu']"),
    ("meta_json.zip", "netsense.json is not valid JSON"),
]


@pytest.mark.parametrize("name, match", ZIP_FILES, ids=[c[0] for c in ZIP_FILES])
def test_zip_policy_files_are_refused_naming_the_file_and_the_mismatch(zip_files,
                                                                       policy_files,
                                                                       name, match):
    from netsense.rl.sb3_policy import LearnedPolicy

    path = (policy_files if name == "foreign.zip" else zip_files) / name
    with pytest.raises(ValueError) as err:
        LearnedPolicy(path)
    assert str(path) in str(err.value) and match in str(err.value), str(err.value)


# ============================================================== malicious policy files
class _Payload:
    """Unpickling this object opens (creates) ``marker``: the proof that a loader ran code
    from a file. ``__reduce__`` names ``builtins.open``, as a real attack would name
    ``os.system``."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        import builtins

        return (builtins.open, (self.marker, "w"))


@pytest.fixture()
def malicious(pt_files, policy_files, tmp_path):
    """Policy files that run code when unpickled, and the marker file the code creates.

    ``.pt``: a valid sealed checkpoint with the payload hidden as an extra entry (the
    issue's probe), inside the config, and in place of a weight. ``.zip``: SB3's own zip
    with the payload in a cloudpickled ``data`` entry (no netsense.json), a netsense zip
    with the same poisoned ``data`` (netsense never reads it), and one whose
    ``policy.pth`` holds the payload.
    """
    import base64

    import cloudpickle
    import torch

    from netsense.rl.checkpoint import read_policy

    marker = tmp_path / "payload_ran"
    good = read_policy(pt_files / "good.pt")
    out = {"marker": marker}
    for name, change in (
            ("extra", lambda s: s.__setitem__("note", _Payload(marker))),
            ("config", lambda s: s["config"].__setitem__("device", _Payload(marker))),
            ("weight", lambda s: s["actor"].__setitem__(next(iter(s["actor"])),
                                                         _Payload(marker)))):
        state = copy.deepcopy(good)
        change(state)
        torch.save(state, tmp_path / f"evil_{name}.pt")
        out[f"pt_{name}"] = tmp_path / f"evil_{name}.pt"

    def poison_data(src: Path, dst: Path, pth: bytes | None = None) -> Path:
        with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
            for n in zin.namelist():
                b = zin.read(n)
                if n == "data":
                    d = json.loads(b)
                    d["probe"] = {":type:": "<class 'object'>", ":serialized:": base64.b64encode(
                        cloudpickle.dumps(_Payload(marker))).decode()}
                    b = json.dumps(d).encode()
                if n == "policy.pth" and pth is not None:
                    b = pth
                zout.writestr(n, b)
        return dst

    import io

    buf = io.BytesIO()
    torch.save({"w": _Payload(marker)}, buf)
    out["zip_foreign"] = poison_data(policy_files / "foreign.zip", tmp_path / "evil_sb3.zip")
    out["zip_data"] = poison_data(policy_files / "policy.zip", tmp_path / "evil_data.zip")
    out["zip_pth"] = poison_data(policy_files / "policy.zip", tmp_path / "evil_pth.zip",
                                 buf.getvalue())
    assert not marker.exists()
    return out


def test_the_payloads_are_live(malicious):
    """The files do run code when unpickled the usual way (so the tests below can fail)."""
    import torch
    from sb3_contrib import MaskablePPO

    m = malicious["marker"]
    for key in ("pt_extra", "pt_config", "pt_weight"):
        torch.load(malicious[key], weights_only=False)
        assert m.exists(), key
        m.unlink()
    MaskablePPO.load(malicious["zip_data"], device="cpu")
    assert m.exists()


PT_LOADERS = {
    "read_policy": lambda f: __import__("netsense.rl.checkpoint").rl.checkpoint.read_policy(f),
    "load_policy": lambda f: __import__("netsense.rl.checkpoint").rl.checkpoint.load_policy(f),
    "seal_policy": lambda f: __import__("netsense.rl.checkpoint").rl.checkpoint.seal_policy(f),
    "rollout": lambda f: ns.benchmark.rollout(COMM, f"learned:{f}", 1_000_000, COMM_SHORT),
    "protocol.evaluate": lambda f: __import__("netsense.benchmark.protocol").benchmark
    .protocol.evaluate(COMM, f"learned:{f}", [1_000_000], COMM_SHORT),
    "protocol.frontier": lambda f: __import__("netsense.benchmark.protocol").benchmark
    .protocol.frontier(COMM, episodes=1, families={}, learned=[str(f)],
                       overrides=COMM_SHORT, progress=False, settled_bases=()),
}


@pytest.mark.parametrize("where", ["extra", "config", "weight"])
@pytest.mark.parametrize("loader", list(PT_LOADERS))
def test_no_python_loader_runs_a_pt_payload(malicious, loader, where):
    import netsense.benchmark  # noqa: F401  (ns.benchmark in the table)

    path = malicious[f"pt_{where}"]
    with pytest.raises(ValueError, match="refused: the file holds Python objects") as err:
        PT_LOADERS[loader](path)
    assert str(path) in str(err.value) and "it references io.open" in str(err.value)
    assert not malicious["marker"].exists()


@pytest.mark.parametrize("key, refused", [("zip_foreign", "without netsense's metadata"),
                                          ("zip_pth", "refused: the file holds Python"),
                                          ("zip_data", None)])
def test_no_python_loader_runs_a_zip_payload(malicious, key, refused):
    """A poisoned ``data`` member is never read: a netsense zip carrying one loads and
    acts; a zip without netsense.json or with a poisoned policy.pth is refused."""
    from netsense.benchmark import rollout
    from netsense.benchmark.protocol import evaluate
    from netsense.rl.sb3_policy import LearnedPolicy

    path = malicious[key]
    calls = [lambda: LearnedPolicy(path),
             lambda: rollout("fig1_scalar-v0", f"learned:{path}", 5, {"horizon": 8}),
             lambda: evaluate("fig1_scalar-v0", f"learned:{path}", [1_000_000],
                              {"horizon": 8})]
    for call in calls:
        if refused is None:
            call()
        else:
            with pytest.raises(ValueError, match=refused):
                call()
        assert not malicious["marker"].exists()


@pytest.mark.parametrize("key", ["pt_extra", "pt_config", "zip_foreign", "zip_pth",
                                 "zip_data"])
def test_no_cli_loader_runs_a_payload(malicious, key, tmp_path, capsys):
    path = malicious[key]
    zipped = key.startswith("zip")
    sc, over = ("fig1_scalar-v0", "horizon=8") if zipped else (COMM, "horizon=12")
    runs = [["benchmark", sc, "--policies", f"learned:{path}", "--seeds", "1", "--override",
             over, "--out", str(tmp_path / "b"), "--no-progress"],
            ["policy", "check", str(path)]]
    if not zipped:  # the frontier reads .pt policies (a zip runs in the scenario's mode)
        runs += [["benchmark", sc, "--frontier", "--learned", str(path), "--seeds", "1",
                  "--families", "periodic", "--override", over, "--out",
                  str(tmp_path / "f"), "--no-progress"],
                 ["policy", "convert", str(path), "--trust", "--out", str(tmp_path / "x.pt")]]
    for argv in runs:
        rc = main(argv)
        err = capsys.readouterr().err
        if key == "zip_data":
            assert rc == 0, err  # the poisoned member is never read
        else:
            assert rc == 2 and "refused" in err and str(path) in err, (argv, err)
        assert not malicious["marker"].exists(), argv


def test_converting_a_trusted_zip_is_the_one_place_that_unpickles(malicious, tmp_path):
    """``convert --trust`` does run the file (that is what trusting it means); without
    ``--trust`` it refuses before reading anything."""
    from netsense.rl.sb3_policy import LearnedPolicy, convert_sb3_policy

    with pytest.raises(ValueError, match="pass trust=True"):
        convert_sb3_policy(malicious["zip_foreign"], tmp_path / "c.zip")
    assert not malicious["marker"].exists()
    assert main(["policy", "convert", str(malicious["zip_foreign"]), "--out",
                 str(tmp_path / "c.zip")]) == 2
    assert not malicious["marker"].exists()
    out = convert_sb3_policy(malicious["zip_foreign"], tmp_path / "c.zip", trust=True)
    assert malicious["marker"].exists()  # trusted, so unpickled: the payload ran
    malicious["marker"].unlink()
    LearnedPolicy(out)  # and the converted file reads as data from then on
    assert not malicious["marker"].exists()


# ============================================================== the CLI says what it did
def test_cli_train_on_a_machine_without_the_device_says_so_before_training(tmp_path, capsys):
    torch = pytest.importorskip("torch")
    _torch()
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    rc = main(["train", "fig1_scalar-v0", "--backend", "torchrl", "--device", "cuda",
               "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert rc == 2 and "torch sees no CUDA device here" in err and "Traceback" not in err
    assert not (tmp_path / "t").exists()  # nothing written, nothing trained


def test_cli_names_the_policies_a_scenario_skipped(tmp_path, capsys):
    rc = main(["benchmark", COMM, "--policies", "freshness", "uniform_consensus", "--seeds",
               "1", "--override", "horizon=5", "--out", str(tmp_path), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 0
    assert f"note: uniform_consensus skipped on {COMM}:" in err, err
    assert "freshness skipped" not in err


@pytest.mark.parametrize("backend", ["torchrl", "sb3"])
def test_cli_torch_threads_reaches_either_backend_config(backend):
    """``--torch-threads`` is one flag for both backends: it becomes the config field that
    each learner hands to ``torch.set_num_threads``; not given, the configs' defaults stand
    (SB3: one thread; TorchRL: ``None``, torch's own count)."""
    import argparse

    from netsense.commands.train import add_arguments, given_fields

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["fig1_scalar-v0", "--backend", backend, "--torch-threads", "3"])
    assert given_fields(args, backend) == {"torch_threads": 3}
    args = parser.parse_args(["fig1_scalar-v0", "--backend", backend])
    assert "torch_threads" not in given_fields(args, backend)
    if backend == "torchrl":
        _torch()
        from netsense.rl.config import PPOConfig as Config
    else:
        pytest.importorskip("torch", reason="the sb3 backend needs the 'rl' extra")
        from netsense.rl.sb3 import TrainConfig as Config
    assert Config("fig1_scalar-v0").torch_threads == (None if backend == "torchrl" else 1)


def test_cli_precision_choices_are_the_configs():
    """``--precision`` lists its choices literally (the parser does not import torch);
    they must stay :data:`netsense.rl.config.PRECISIONS`."""
    import argparse

    from netsense.commands.train import add_arguments

    _torch()
    from netsense.rl.config import PRECISIONS

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    action = next(a for a in parser._actions if a.dest == "precision")
    assert tuple(action.choices) == PRECISIONS


def test_cli_torchrl_training_with_a_control_override_runs(tmp_path, capsys):
    """The issue's crash (``make_core() got multiple values for keyword argument
    'control'``) is a valid input: the run trains, says the minibatch is the whole
    iteration and how many agent-steps it trained."""
    _torch()
    rc = main(["train", "message_cost-v1", "--backend", "torchrl", "--override",
               'control={"mode": "transmit"}', "--override", "horizon=4", "--steps", "30",
               "--num-envs", "2", "--rollout", "2", "--epochs", "1", "--eval-envs", "1",
               "--out", str(tmp_path), "--no-progress"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "note: --batch-size 2048 is more than one iteration's 4 env-steps" in cap.err
    assert "40 agent-steps (30 asked, whole iterations)" in cap.out
    from netsense.rl.checkpoint import policy_control, read_policy

    assert policy_control(read_policy(tmp_path / "seed_0" / "policy.pt"))["mode"] == \
        "transmit"



def test_cli_names_the_extra_of_a_missing_stack(monkeypatch, capsys):
    """Without torch, a command that needs it says which extra to install, in one line."""
    import builtins

    real = builtins.__import__

    def no_torch(name, *args, **kwargs):
        if name.split(".")[0] == "torch":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real(name, *args, **kwargs)

    from netsense.cli import _one_line

    monkeypatch.setattr(builtins, "__import__", no_torch)
    try:
        import torch  # noqa: F401
    except ModuleNotFoundError as exc:
        line = _one_line(exc)
    assert "'torch'" in line and '".[torchrl]"' in line and "pip install torch==2.13.0" in line


# ============================================== inputs that never end or nest without end
@pytest.mark.parametrize("text, match", [
    ("a = " + "[" * 1000 + "1" + "]" * 1000 + "\n", "nested too deeply to parse"),
    ("a = " + "{b = " * 400 + "1" + "}" * 400 + "\n", "nested too deeply to parse"),
    ("[" + ".".join(["t"] * 500) + "]\nx = 1\n", "tables or arrays nested 501 deep"),
    ("horizon = 5\n" + "# padding\n" * 200_000, "larger than 1048576 bytes"),
])
def test_scenario_file_nested_or_huge_is_a_value_error_naming_it(tmp_path, text, match):
    path = tmp_path / "deep_v0.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        load_file(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_scenario_path_that_never_ends_is_refused_without_reading(device):
    if not os.path.exists(device):
        pytest.skip(f"no {device} here")
    with pytest.raises(ValueError, match=f"{device}: not a regular file"):
        load_file(device)


def test_scenario_path_of_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe_v0.toml"
    os.mkfifo(fifo)  # opening it for reading would wait for a writer
    with pytest.raises(ValueError, match="not a regular file"):
        load_file(fifo)


def test_torchrl_env_reset_mask_of_the_wrong_shape_names_it():
    pytest.importorskip("torchrl")
    import torch
    from tensordict import TensorDict

    from netsense.rl.envs import NetSenseBatchedEnv, make_core

    env = NetSenseBatchedEnv(make_core("message_cost-v1", 4), seed=0)
    env.reset()
    for mask in (torch.ones(4, 2, dtype=torch.bool), torch.ones(4, 1, 1, dtype=torch.bool),
                 torch.ones(4, 1)):
        td = TensorDict({"_reset": mask}, batch_size=[4])
        with pytest.raises(ValueError, match=r"'_reset' must be a bool mask of shape \(4,\)"):
            env.reset(td)
        with pytest.raises(ValueError, match=r"'_reset' must be a bool mask"):
            env._reset(td)
    with pytest.raises(ValueError, match=r"batch size must be the env's \(4,\), got \(\)"):
        env.reset(TensorDict({"_reset": torch.ones(4, dtype=torch.bool)}, batch_size=[]))
    ok = env.reset(TensorDict({"_reset": torch.tensor([True, False, True, False])},
                              batch_size=[4]))
    assert ok.batch_size == torch.Size([4])
