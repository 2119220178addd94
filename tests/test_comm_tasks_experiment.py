"""Smoke run of experiments/rl/comm_tasks.py, and its privileged rules against the core."""

from __future__ import annotations

import csv

import numpy as np
from experiment_loader import load_experiment

from netsense.benchmark.protocol import evaluate


def test_smoke_run_writes_the_frontier_and_the_summary(tmp_path):
    exp = load_experiment("rl/comm_tasks")
    summary = exp.main(["--scenarios", "comm_fading-v0", "comm_channel_k2-v0",
                        "--episodes", "2", "--horizon", "12", "--out", str(tmp_path),
                        "--no-progress"])
    for f in ("frontier.csv", "frontier.md", "summary.csv", "summary.md",
              "frontier_comm_fading-v0.png"):
        assert (tmp_path / f).is_file(), f
    whats = {(r["scenario"], r["what"]) for r in summary}
    assert ("comm_fading-v0", "informed: acked") in whats
    assert ("comm_fading-v0", "privileged: oracle_channel") in whats
    assert ("comm_channel_k2-v0", "best centralised") in whats
    assert not any(w.startswith(("informed", "privileged")) for s, w in whats
                   if s == "comm_channel_k2-v0")
    rows = list(csv.DictReader((tmp_path / "summary.csv").open()))
    assert len(rows) == len(summary)


def test_oracle_gates_on_exactly_the_messages_that_arrive():
    """The privileged rule on ``always`` transmits iff the next message reaches an
    out-neighbour: every message it sends arrives somewhere, and its error equals
    ``always``'s (a message that reaches no one changes nothing)."""
    exp = load_experiment("rl/comm_tasks")
    sid, seeds = "comm_fading-v0", [3, 4]
    over = exp.rule_overrides(sid, "oracle", {"horizon": 70})
    sent = []

    def actor(core, s):
        rule = exp.rule_actor("oracle", "always")(core, s)

        def act(obs, mask):
            if core.k[0] > 0:  # the messages of this step, sent on the oracle's bits
                sent.append((core.transmit.copy(), core.msg.copy(), core.nbr.copy()))
            return rule(obs, mask)
        return act

    gated = evaluate(sid, "oracle(always)", seeds, over, actor=actor)
    always = evaluate(sid, "always", seeds, over)
    np.testing.assert_allclose(gated["mean_rel_error"], always["mean_rel_error"])
    assert gated["msgs_per_agent_step"].mean() < 0.5 * always["msgs_per_agent_step"].mean()
    for transmit, msg, nbr in sent:
        for b, l in zip(*np.nonzero(transmit), strict=True):
            assert msg[b][nbr[b] == l].any()  # someone got it
