"""``substates = "sources"``: indices, actions and observations over the sources only.

An empty substate has nothing to estimate, so restricting the bookkeeping to the agents
with a non-empty block must leave every estimate and reward unchanged, and the indices
must equal the source columns of the full ``N x N`` table.
"""

from __future__ import annotations

import numpy as np
import pytest

from netsense.engine.core import BatchedCore, CoreModel
from netsense.env.policies import make_policy
from netsense.env.registry import Scenario, build_model, load, make, with_overrides
from netsense.observers.faults import LyingAgent


@pytest.mark.parametrize("policy", ["freshness", "uniform"])
def test_sources_only_changes_nothing_but_the_bookkeeping(policy):
    full = BatchedCore(build_model(load("large_n20_N100-v1")), 3)
    lean = BatchedCore(build_model(load("large_n20_N100-v2")), 3)
    assert full.M == 100 and lean.M == 20 and list(lean.layout.sources) == list(lean.sources)
    assert lean.layout.size < full.layout.size / 4
    o_f, m_f = full.reset(5)
    o_l, m_l = lean.reset(5)
    p_f, p_l = make_policy(policy, full), make_policy(policy, lean)
    for _ in range(40):
        r_f = full.step(p_f.act(o_f, m_f))
        r_l = lean.step(p_l.act(o_l, m_l))
        np.testing.assert_array_equal(lean.Z, full.Z)
        np.testing.assert_array_equal(r_l.reward, r_f.reward)
        np.testing.assert_array_equal(lean.tau, full.tau[:, :, lean.sources])
        o_f, m_f, o_l, m_l = r_f.obs, r_f.action_mask, r_l.obs, r_l.action_mask
    assert np.isfinite(lean.errors).all()


def test_masks_and_validation_use_the_own_column():
    core = BatchedCore(build_model(load("large_n20_N100-v2")), 2)
    obs, mask = core.reset(0)
    D, M = core.D, core.M
    blocks = mask[..., :M * (D + 2)].reshape(2, core.N, M, D + 2)
    for i in range(core.N):
        o = core.own[i]
        if o >= 0:  # a source: only keep on its own column
            assert (blocks[:, i, o, 1:] == 0).all() and (blocks[:, i, o, 0] == 1).all()
        assert (blocks[:, i, [m for m in range(M) if m != o], D + 1] == 1).all()
    src = int(core.sources[0])
    act = np.zeros((2, core.N, M + 1), dtype=np.int64)
    act[1, src, 0] = D + 1  # average on the own substate: masked
    Z0 = core.Z.copy()
    with pytest.raises(ValueError, match=rf"agent {src} \(batch member 1\), substate 0.*eq. \(7\)"):
        core.step(act)
    np.testing.assert_array_equal(core.Z, Z0)
    with pytest.raises(ValueError, match=r"\(B, N, M \+ 1\)"):
        core.step(np.zeros((2, core.N, core.N + 1), dtype=np.int64))
    env = make("large_n20_N100-v2")
    assert len(env.action_space("sensor_0").nvec) == M + 1


def test_bad_substates_and_liars_are_refused():
    raw = load("large_n20_N100-v2").to_dict()
    raw["substates"] = "some"
    with pytest.raises(ValueError, match="substates"):
        Scenario.from_dict("x-v0", raw)
    model = build_model(load("large_n20_N100-v2"))
    with pytest.raises(ValueError, match="LyingAgent"):
        CoreModel(plant=model.plant, design=model.design, graphs=model.graphs,
                  horizon=5, faults=(LyingAgent(agents=(3,), claim=0),),
                  substates="sources")
    sc = with_overrides(load("link_failures-v0"), substates="sources")
    core = BatchedCore(build_model(sc), 1)
    blocks = np.unique(core.block_of)
    assert core.M == blocks.size < sc.num_agents and list(core.sources) == list(blocks)
