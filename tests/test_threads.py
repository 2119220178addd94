"""Threads of the compiled drivers (docs/threads.md): who runs threaded, the thread-count
knob, fork-based workers and a package that cannot write numba's cache."""

from __future__ import annotations

import gc
import os
import warnings

import numpy as np
import pytest

# every module that builds drivers, imported before the drivers are collected
import netsense.engine.observation  # noqa: F401
import netsense.engine.rewards  # noqa: F401
import netsense.graphs.processes  # noqa: F401
import netsense.kernels.drivers  # noqa: F401
import netsense.sensing.noise  # noqa: F401
from netsense.env.policies import make_policy
from netsense.env.registry import list_scenarios, make
from netsense.kernels import jit as compiled


def _count_threaded_builds(monkeypatch) -> dict[str, int]:
    """Replace the threaded build of every driver of the package by a counting wrapper;
    returns the counts (by driver name), filled as drivers run threaded."""
    counts: dict[str, int] = {}
    drivers = [o for o in gc.get_objects() if type(o) is compiled.Driver]  # (no proxies)
    assert len(drivers) > 10  # the package's drivers were found

    for d in drivers:
        def counted(*args, _build=d.parallel, _name=d.parallel.py_func.__name__):
            counts[_name] = counts.get(_name, 0) + 1
            return _build(*args)
        monkeypatch.setattr(d, "parallel", counted)
    return counts


def _episode(sid: str) -> None:
    env = make(sid, horizon=4 if sid.startswith("large") else 12)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=3)
    while env.agents:
        obs, _, _, _, infos = env.step(pol.act_dict(env, obs, infos))


@pytest.mark.parametrize("sid", list_scenarios())
def test_the_single_env_never_runs_a_threaded_driver(sid, monkeypatch):
    # every work threshold at zero: only the member count may keep B = 1 serial
    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    counts = _count_threaded_builds(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _episode(sid)
    assert counts == {}


@pytest.mark.parametrize("sid", ["large_n20_N100-v0", "large_n20_N100-v2"])
def test_the_single_large_env_stays_serial_at_the_default_thresholds(sid, monkeypatch):
    # N = 100: the observation pass and the policy touch more than PARALLEL_WORK elements
    counts = _count_threaded_builds(monkeypatch)
    _episode(sid)
    assert counts == {}


def test_a_threaded_build_is_counted(monkeypatch):
    # the counter itself sees a threaded call (a batch of many members)
    from netsense.kernels import update as kernels

    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    counts = _count_threaded_builds(monkeypatch)
    tau = np.zeros((64, 4, 4), dtype=np.int64)
    kernels.advance_indices(tau, np.zeros_like(tau))
    assert counts == {f"advance_all_parallel_{compiled.inlined_digest()}": 1}


# ----------------------------------------------------------------------------- read-only
_READ_ONLY_CHILD = """
import warnings
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import numpy as np
    import netsense
    from netsense.kernels.jit import CacheWarning
    from netsense.env.policies import make_policy
    env = netsense.make("message_cost-v0", horizon=3)
    pol = make_policy("freshness", env)
    obs, infos = env.reset(seed=0)
    while env.agents:
        obs, rew, *_, infos = env.step(pol.act_dict(env, obs, infos))
    assert np.isfinite(list(rew.values())).all()
print("FILE", netsense.__file__)
print("CACHE_WARNINGS", sum(issubclass(w.category, CacheWarning) for w in caught))
for w in caught:
    if issubclass(w.category, CacheWarning):
        print("MESSAGE", w.message)
"""


def _without_dac_override():
    """preexec_fn: as root, drop the capabilities that let root write read-only files
    (from the bounding set, so the child's python never regains them on exec): root then
    obeys file modes like any user. Other users obey them anyway."""
    import ctypes

    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2, 3):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, CAP_FOWNER
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def _can_drop_dac_override() -> bool:
    import subprocess
    import sys

    try:
        out = subprocess.run([sys.executable, "-c", "pass"], preexec_fn=_without_dac_override,
                             capture_output=True, timeout=60, check=False)
    except (OSError, subprocess.SubprocessError):
        return False
    return out.returncode == 0


@pytest.mark.skipif(not hasattr(os, "geteuid"), reason="POSIX file modes")
def test_a_read_only_installed_wheel_imports_and_steps(tmp_path):
    """The wheel installed read-only, used by someone without a writable home and without
    NUMBA_CACHE_DIR: numba finds no place for its cache (``cannot cache function
    'bit_generator': no locator available`` before the fallback). netsense must import,
    step, and say so in one CacheWarning."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    if not _can_drop_dac_override():
        pytest.skip("root here cannot drop CAP_DAC_OVERRIDE, so cannot see read-only files")
    root = Path(__file__).resolve().parents[1]
    src = tmp_path / "src"  # a copy: building writes build/ and *.egg-info next to it
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(root / name, src / name)
    shutil.copytree(root / "netsense", src / "netsense",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "-q", "-w", str(wheels), str(src)], check=True, capture_output=True,
                   timeout=600)
    (wheel,) = wheels.glob("netsense-*.whl")
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(site), str(wheel)], check=True, capture_output=True, timeout=600)
    ro = tmp_path / "ro"  # a home that cannot be created, a read-only working directory
    ro.mkdir()
    subprocess.run(["chmod", "-R", "a-w", str(site), str(ro)], check=True)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "PYTHON"))}
    tmp = tmp_path / "tmp"  # the fallback's temporary directory (not the shared /tmp)
    tmp.mkdir()
    env.update(PYTHONPATH=str(site), HOME=str(ro / "nonexistent"), TMPDIR=str(tmp))
    try:
        out = subprocess.run([sys.executable, "-c", _READ_ONLY_CHILD], env=env, cwd=ro,
                             preexec_fn=_without_dac_override, capture_output=True,
                             text=True, timeout=900, check=False)
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(site), str(ro)], check=True)
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"FILE {site}" in out.stdout  # the installed copy, not the source tree
    assert "CACHE_WARNINGS 1" in out.stdout, out.stdout
    assert "NUMBA_CACHE_DIR" in out.stdout and f"cached in {tmp}" in out.stdout, out.stdout
    assert not any(site.rglob("*.nbi"))  # nothing written into the install
    assert any((tmp / f"netsense-numba-{os.getuid()}").rglob("*.nbi"))  # cached there


def test_functions_numba_cannot_cache_compile_anyway_with_one_warning(tmp_path, monkeypatch):
    # functions without a source file have no cache place at all: numba raises "no
    # locator available" at decoration; the fallback compiles them uncached, one warning
    import tempfile

    monkeypatch.setattr(compiled, "_FALLBACK", {})
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    ns: dict = {}
    exec(compile("def f(x):\n    return x + 1\n\ndef g(x):\n    return 2 * x\n",
                 "<no file>", "exec"), ns)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = compiled.njit_cached()(ns["f"])
        g = compiled.njit_cached(inline="always")(ns["g"])
    assert f(1) == 2 and g(2) == 4
    assert [w.category for w in caught] == [compiled.CacheWarning]
    assert compiled._FALLBACK["dir"] == str(tmp_path / f"netsense-numba-{os.getuid()}")


# ----------------------------------------------------------------------------- the knob
def _batch_step(B: int = 64):
    from netsense.engine.core import BatchedCore
    from netsense.env.policies import FreshnessPolicy
    from netsense.speed import bench_model

    core = BatchedCore(bench_model(6, 4, horizon=20), B)
    pol = FreshnessPolicy(core.layout)
    obs, mask = core.reset(0)
    for _ in range(3):
        out = core.step(pol.act(obs, mask))
        obs, mask = out.obs, out.action_mask
    return obs, core.errors.copy()


def test_set_num_threads_one_keeps_every_batch_serial(monkeypatch):
    import numba

    monkeypatch.setattr(compiled, "PARALLEL_WORK", 0)
    counts = _count_threaded_builds(monkeypatch)
    before = compiled._num_threads
    numba_before = numba.get_num_threads()  # other code in this process may have set it
    try:
        compiled.set_num_threads(1)
        assert compiled.get_num_threads() == 1
        serial = _batch_step()
        assert counts == {}
        compiled.set_num_threads(2)
        threaded = _batch_step()
        assert sum(counts.values()) > 0
        assert numba.get_num_threads() == numba_before  # restored after each call
        compiled.set_num_threads(10**6)  # more than the pool: the pool
        assert compiled.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    finally:
        compiled.set_num_threads(before)
    for a, b in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("bad", [-1, 1.5, "two", True])
def test_set_num_threads_rejects_what_is_no_thread_count(bad):
    with pytest.raises(ValueError, match="integer >= 0"):
        compiled.set_num_threads(bad)


def test_the_environment_variable_sets_the_knob():
    import subprocess
    import sys
    from pathlib import Path

    code = ("import netsense, netsense.kernels.jit as c; print(netsense.get_num_threads(), "
            "c.get_num_threads())")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "NETSENSE_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=root, text=True,
                         capture_output=True, timeout=600, check=True)
    assert out.stdout.split() == ["1", "1"]
    env["NETSENSE_NUM_THREADS"] = "many"
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=root, text=True,
                         capture_output=True, timeout=600, check=False)
    assert out.returncode != 0 and "NETSENSE_NUM_THREADS must be an integer" in out.stderr


# ----------------------------------------------------------------------------- fork
_FORK_CHILD = """
import multiprocessing as mp, os, sys
import numba
from netsense.kernels import jit as compiled
import tests.test_threads as t
compiled.PARALLEL_WORK = 0  # every batched call threaded in the parent
expect = t._batch_step()
print("LAYER", numba.threading_layer(), flush=True)

def work(_):
    return compiled.get_num_threads(), t._batch_step()

with mp.get_context("fork").Pool(2) as pool:  # (a killed worker would hang map())
    got = pool.map_async(work, range(2)).get(timeout=300)
for threads, arrays in got:
    for a, b in zip(arrays, expect):
        assert (a == b).all()
    print("CHILD_THREADS", threads, flush=True)
print("OK")
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork() only")
@pytest.mark.parametrize("layer", ["omp", "workqueue"])
def test_fork_workers_after_threaded_calls_complete(layer):
    # GNU OpenMP in a fork()ed child: numba terminates the child at its first threaded
    # call ("fork() called from a process already using GNU OpenMP"). netsense's drivers
    # run serially there instead (same bits); workqueue is fork-safe and keeps threads.
    import subprocess
    import sys
    from pathlib import Path

    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one thread: nothing runs threaded")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_THREADING_LAYER": layer}
    env.pop("NETSENSE_NUM_THREADS", None)
    out = subprocess.run([sys.executable, "-c", _FORK_CHILD], env=env, cwd=root, text=True,
                         capture_output=True, timeout=900, check=False)
    assert out.returncode == 0 and "OK" in out.stdout, out.stdout + out.stderr[-3000:]
    assert f"LAYER {layer}" in out.stdout
    threads = {line.split()[1] for line in out.stdout.splitlines()
               if line.startswith("CHILD_THREADS")}
    assert threads == ({"1"} if layer == "omp" else {str(numba.config.NUMBA_NUM_THREADS)})


# ----------------------------------------------------------------------------- benchmark
def test_busy_core_benchmark_smoke(tmp_path):
    # the plumbing only (processes, busy loops, files); the timing is not asserted
    import csv

    from tests.experiment_loader import load_experiment

    mod = load_experiment("bench/busy_cores")
    assert mod.main(["--smoke", "--out", str(tmp_path)]) == 0
    with (tmp_path / "bench_busy_cores.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and list(rows[0]) == list(mod.COLUMNS)
    assert {r["condition"] for r in rows} == {"idle", "busy"}
    assert (tmp_path / "bench_busy_cores.png").stat().st_size > 0
    assert "busy / idle" in (tmp_path / "bench_busy_cores.txt").read_text()


@pytest.mark.parametrize("given", [None, "active"])
def test_the_openmp_wait_policy_is_set_when_the_package_loads(given):
    """``import netsense`` alone (its ``__init__`` imports no module that loads torch or
    numba's pool) sets ``OMP_WAIT_POLICY=passive``, so libgomp reads it whenever the
    training stack loads it later; a policy the user set is kept."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY",
                                                            "GOMP_SPINCOUNT")}
    if given:
        env["OMP_WAIT_POLICY"] = given
    code = ("import os, sys; import netsense; "
            "print(os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules, "
            "'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == [given or "passive", "False", "False"]
