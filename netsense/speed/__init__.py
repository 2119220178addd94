"""Measured speed and memory of the batched core.

What is measured, in one process and interleaved (so a noisy, shared machine slows every
contender alike; compare the *ratios*):

``core``
    :meth:`netsense.engine.core.BatchedCore.step` on ``B`` members of :func:`bench_model`
    (``N`` agents, plant dimension ``n``, Markov link failures on a circulant graph with
    in-degree ``D = 3``, measurement noise), replaying ``steps`` freshness-policy actions
    recorded on a twin core from the same seed. Only ``step`` is timed (graphs/noise
    refills, validation, update, rewards and the full observations and masks included),
    in a loop of its own work like the kernel; the policy's time is reported apart.
``core_live``
    The same core with the freshness policy computed between the steps (only ``step``
    timed): the policy's numpy passes (17 ms per step at ``B = 1024, N = 30``) evict the
    core's arrays from the caches and its threads fall asleep, so this figure is lower
    and noisier; it is reported for transparency, the ratios use ``core``.
``kernel``
    The bare numpy update on the same arrays — the roofline: gather of the
    chosen agents' estimates (one flat ``np.take``) and the batched block-triangular
    multiply (two BLAS products), nothing else; written in plain numpy
    (:mod:`netsense.speed.runners`).
``vmas``
    VMAS ``simple_spread`` on CPU with ``B`` environments and ``N`` agents (zero
    continuous actions), when ``vmas`` is installed; it runs in a spawned process of its
    own, driven block by block between the other contenders, so torch's thread pool
    never shares a process with the core.

Rates are agent-steps/s ``= B N / (time of one step)``; each figure is the best of
``repeats`` blocks of ``steps`` steps. Targets: core >= 10x VMAS at
``B = 1024, N = 10`` and core >= 0.5x the kernel at every shape.

Modules: :mod:`~netsense.speed.runners` (the benchmark model and the timed contenders),
:mod:`~netsense.speed.measure` (timings, scaling, profile, observation cost),
:mod:`~netsense.speed.memory` (state size and allocation growth) and
:mod:`~netsense.speed.report` (table, verdicts, CSV and the command); every public name is
re-exported here.

Run ``python -m netsense.speed`` or :func:`main`; ``netsense bench batched`` is this
package's :data:`HELP`, :func:`add_arguments` and :func:`run` (the :mod:`netsense.cli`
contract), and ``experiments/bench/batched.py`` adds the profile, the scaling figure, the
memory figures and the CSV files.

Tool layer. May import every layer up to :mod:`netsense.env`, and the tools ``grid``,
``rl``, ``benchmark``, ``studies``.
"""

from netsense.speed.measure import (
    SHAPES,
    loglog_slope,
    measure,
    measure_shape,
    observation_cost,
    profile_core,
    scaling,
)
from netsense.speed.memory import allocation_growth, core_state_bytes, memory_footprint
from netsense.speed.report import (
    HELP,
    TARGET_VS_KERNEL,
    TARGET_VS_VMAS,
    add_arguments,
    format_table,
    main,
    run,
    source_revision,
    verdicts,
    write_csv,
)
from netsense.speed.runners import bench_model, vmas_available

__all__ = ["HELP", "SHAPES", "TARGET_VS_KERNEL", "TARGET_VS_VMAS", "add_arguments",
           "allocation_growth", "bench_model", "core_state_bytes", "format_table",
           "loglog_slope", "main", "measure", "measure_shape", "memory_footprint",
           "observation_cost", "profile_core", "run", "scaling", "source_revision",
           "verdicts",
           "vmas_available", "write_csv"]
