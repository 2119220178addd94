"""The memory diagnostic of experiments/rl/learners.py: the informed rule's gate, computed
from the observations of whichever policy acts, reproduces the rule's own decisions."""

import pytest
from experiment_loader import load_experiment

pytest.importorskip("torch")  # the learned policies' loader, and training's scripted actors

SEEDS = [1_000_000, 1_000_001]


@pytest.fixture(scope="module")
def learners():
    return load_experiment("rl/learners")


@pytest.mark.parametrize("task", ["comm_fading-v0", "comm_schedule-v0"])
def test_the_rule_never_sends_through_its_own_closed_gate(learners, task):
    """On the rule's own trajectory the probe's gate is the rule's: it sends only where the
    gate is open, while the base rule it wraps sends through closed gates."""
    rule, generic = learners.MEMORY_TASKS[task]
    own = learners.memory_use(task, rule, rule, SEEDS)
    assert own["closed_share"] > 0.05
    assert own["send_closed_view"] == 0 and own["send_closed_memory"] == 0
    base = rule.split("(", 1)[1].rstrip(")")
    other = learners.memory_use(task, rule, base, SEEDS)
    assert other["send_closed_view"] + other["send_closed_memory"] > 0.1
    assert own["return"] > other["return"]  # the gate is what the rule gains by


def test_hybrids_rebuild_the_rule_from_silence(learners):
    """``hybrid_use``: with nothing imposed a policy scores its own return; imposing every
    part of the rule's reaction (and silence on the other agents) on ``never`` gives
    ``acked(sources:0)``'s return exactly; the probe alone makes ``never`` send."""
    from netsense.benchmark.protocol import evaluate

    task = "comm_fading-v0"
    out = learners.hybrid_use(task, "never", SEEDS)
    never = evaluate(task, "never", SEEDS)["reward"].mean()
    rule = evaluate(task, "acked(sources:0)", SEEDS)["reward"].mean()
    assert out["return_own"] == pytest.approx(never, abs=1e-9)
    assert out["return_quiet"] == pytest.approx(never, abs=1e-9)  # never is quiet already
    assert out["return_quiet_probe_no_link_twin"] == pytest.approx(rule, abs=1e-9)
    assert out["return_probe"] != pytest.approx(never)
    assert out["return_others_silent"] == pytest.approx(never, abs=1e-9)
    assert len(out) == 2 ** len(learners.HYBRID_PARTS) + 2
