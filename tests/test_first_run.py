"""The first run: a light ``import netsense``, a one-line compile notice, ``netsense warmup``.

Each check runs in a fresh interpreter (and, where compilation matters, with a fresh
``NUMBA_CACHE_DIR``), asserting on what was imported or compiled, never on a time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTICE = "netsense: compiling numba kernels"

#: Prints the netsense functions numba compiles (not loads from its cache) after this point.
COUNT_COMPILES = """
import atexit, json
from numba.core import event
compiled = []
class L(event.Listener):
    def on_start(self, ev):
        fn = ev.data["dispatcher"].py_func
        if fn.__module__.startswith("netsense."):
            compiled.append(fn.__name__)
    def on_end(self, ev):
        pass
event.register("numba:compile", L())
atexit.register(lambda: print("COMPILED=" + json.dumps(compiled)))
"""


def _python(code: str, cache: Path | None = None, **env) -> subprocess.CompletedProcess:
    full = dict(os.environ, **env)
    if cache is not None:
        full["NUMBA_CACHE_DIR"] = str(cache)
    # run from the checkout, so that this tree's netsense is the one imported
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=full, cwd=ROOT, check=True, timeout=900)


def _compiled(res: subprocess.CompletedProcess) -> list[str]:
    line = next(s for s in res.stdout.splitlines() if s.startswith("COMPILED="))
    return json.loads(line.partition("=")[2])


def test_import_netsense_is_light():
    res = _python("import sys, netsense\n"
                  "heavy = ['numpy', 'scipy', 'numba', 'networkx', 'matplotlib', 'torch', "
                  "'gymnasium', 'pettingzoo', 'tqdm', 'netsense.kernels.drivers']\n"
                  "print([m for m in heavy if m in sys.modules])")
    assert res.stdout.strip() == "[]"


def test_make_path_imports_no_optional_or_slow_module_and_compiles_nothing():
    """``netsense.make`` loads the environment's modules, but neither scipy's signal,
    optimize or sparse packages, networkx, matplotlib, tqdm nor torch, and compiles no
    driver until a scenario steps."""
    res = _python("import sys, netsense\nnetsense.make\n"
                  "from netsense.env.warmup import compiled_drivers\n"
                  "heavy = ['scipy.signal', 'scipy.optimize', 'scipy.sparse', 'scipy.stats', "
                  "'networkx', 'matplotlib', 'tqdm', 'torch']\n"
                  "print([m for m in heavy if m in sys.modules])\n"
                  "print(len(compiled_drivers()), "
                  "sum(len(d.signatures) for _, drv in compiled_drivers() "
                  "for d in (drv.serial, drv.parallel)))")
    imported, counts = res.stdout.strip().splitlines()
    assert imported == "[]"
    drivers, signatures = (int(v) for v in counts.split())
    assert drivers >= 10 and signatures == 0


def test_compile_notice_once_per_process_and_only_when_cold(tmp_path):
    code = ("import numpy as np\n"
            "from netsense.kernels import advance_indices, gather_substates\n"
            "tau = np.zeros((1, 3, 3), np.int64)\n"
            "src = np.zeros((1, 3, 3), np.int64)\n"
            "advance_indices(tau, src)\n"
            "gather_substates(np.zeros((1, 3, 3)), src, np.arange(3))\n")
    cold = _python(code, tmp_path)
    assert cold.stderr.count(NOTICE) == 1, cold.stderr
    assert "netsense warmup" in cold.stderr and str(tmp_path) in cold.stderr
    warm = _python(code, tmp_path)
    assert NOTICE not in warm.stderr


def test_after_warmup_a_new_process_compiles_nothing(tmp_path):
    warm = subprocess.run([sys.executable, "-m", "netsense.cli", "warmup", "fig1_scalar-v0",
                           "--serial-only", "--quiet"], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path)),
                          check=True, timeout=900)
    assert warm.stdout == "" and NOTICE not in warm.stderr  # --quiet: nothing printed
    res = _python(COUNT_COMPILES + (
        "import netsense as ns\n"
        "from netsense.env.policies import make_policy\n"
        "env = ns.make('fig1_scalar-v0')\n"
        "for name in ('freshness', 'uniform', 'open_loop'):\n"
        "    policy = make_policy(name, env)\n"
        "    obs, infos = env.reset(seed=1)\n"
        "    while env.agents:\n"
        "        obs, r, te, tr, infos = env.step(policy.act_dict(env, obs, infos))\n"),
        tmp_path)
    assert _compiled(res) == [], res.stdout
    assert NOTICE not in res.stderr


def test_bench_first_run_smoke(tmp_path):
    sys.path.insert(0, str(ROOT / "tests"))
    from experiment_loader import load_experiment

    mod = load_experiment("bench/first_run")
    assert mod.main(["--smoke", "--out", str(tmp_path), "--no-progress"]) == 0
    rows = (tmp_path / "bench_first_run_smoke.csv").read_text().splitlines()
    assert rows[0].startswith("case,scenario,cache") and len(rows) == 5
    cold, warm = rows[3].split(","), rows[4].split(",")
    assert cold[2] == "cold" and int(cold[-1]) > 0  # a fresh cache compiles
    assert warm[2] == "warm" and int(warm[-1]) == 0  # the second process loads it all


def test_each_driver_build_compiles_for_one_signature():
    """Single envs and batches whose members drift apart (restarts mid-episode) call every
    driver with one set of argument types per build: an array that arrives sometimes
    C-contiguous and sometimes strided would compile a build twice (seconds each)."""
    res = _python(
        "import json\n"
        "from netsense.env.policies import make_policy\n"
        "from netsense.env.registry import make\n"
        "from netsense.env.vector import BatchedEnv\n"
        "from netsense.env.warmup import compiled_drivers\n"
        "for sid in ('fig1_scalar-v0', 'link_failures-v0', 'fault_sensor_outage-v0',\n"
        "            'large_n20_N100-v2'):\n"
        "    env = make(sid)\n"
        "    policy = make_policy('freshness', env)\n"
        "    obs, infos = env.reset(seed=0)\n"
        "    for _ in range(3):\n"
        "        obs, r, te, tr, infos = env.step(policy.act_dict(env, obs, infos))\n"
        "    env = BatchedEnv(sid, num_envs=64)\n"
        "    policy = make_policy('freshness', env.core)\n"
        "    obs, info = env.reset(seed=0)\n"
        "    for k in range(6):\n"
        "        if k == 3:\n"
        "            obs, info = env.reset_at(list(range(32)))\n"
        "        obs, r, te, tr, info = env.step(policy.act(obs, info['action_mask']))\n"
        "print(json.dumps({name: [len(drv.serial.signatures), len(drv.parallel.signatures)]\n"
        "                  for name, drv in compiled_drivers()}))\n")
    counts = json.loads(res.stdout.strip().splitlines()[-1])
    assert counts and all(max(c) <= 1 for c in counts.values()), counts


def test_warmup_has_policies_every_scenario_accepts():
    """`netsense warmup` steps every scenario with two policies; a communication-only
    scenario refuses an adoption rule of its own, so it must get ones it accepts."""
    from netsense.env.policies import make_policy
    from netsense.env.registry import list_scenarios, make
    from netsense.env.warmup import _policies

    for sid in list_scenarios():
        env = make(sid)
        for name in _policies(env.model):
            make_policy(name, env)  # raises on a policy the scenario refuses
