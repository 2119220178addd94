"""Training pipeline, stage *warm start*: behaviour cloning (an optional warm start).

:func:`behaviour_clone` minimises the cross-entropy of the masked policy on a scripted
policy's actions collected through the batched core (:mod:`netsense.rl.scripted`).

Imports: torch and the stages below.
"""

from __future__ import annotations

import torch
from tqdm.auto import tqdm

from netsense.rl.config import BC_HELDOUT_SEED, PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import make_core
from netsense.rl.scripted import collect_scripted

__all__ = ["behaviour_clone"]


def behaviour_clone(net: torch.nn.Module, config: PPOConfig, scripted: str, *,
                    steps: int | None = None, epochs: int | None = None,
                    lr: float | None = None,
                    seed: int | None = None, device=None, progress: bool = False) -> dict:
    """Warm start: minimise the cross-entropy of the masked policy on scripted actions.

    Data: about ``steps`` env-steps (default ``config.bc_steps``) of ``config.num_envs``
    members driven by ``scripted`` (members seeded from ``seed``, default the training
    seeds ``config.seed * num_envs + b``; a quarter as many held-out steps from members
    seeded from :data:`BC_HELDOUT_SEED`). ``progress``: tqdm bars over the data
    collection and the gradient steps (the phase takes minutes at the defaults).

    Returns
    -------
    dict
        ``ce_before``, ``ce_after`` (held-out cross-entropy per agent-step, nats),
        ``accuracy`` (held-out share of action entries where the most likely allowed
        choice equals the scripted one), ``chance`` (the same for a uniform choice among
        the allowed ones), ``samples``.
    """
    steps = int(steps or config.bc_steps)
    epochs = int(epochs or config.bc_epochs)
    lr = float(lr or config.bc_lr)
    device = device or next(net.parameters()).device
    seed = config.seed * config.num_envs if seed is None else int(seed)
    obs, mask, act = (t.to(device) for t in collect_scripted(
        config, scripted, steps, seed, progress=progress))
    h_obs, h_mask, h_act = (t.to(device) for t in collect_scripted(
        config, scripted, max(steps // 4, 1), BC_HELDOUT_SEED, progress=progress))
    core_nvec = make_core(config.scenario, 1, control=config.control,
                          **config.overrides).nvec

    def dist(o, m):
        return MaskedMultiCategorical(net(o), m, core_nvec)

    def held_out() -> tuple[float, float]:
        with torch.no_grad():
            d = dist(h_obs, h_mask)
            ce = float(-d.log_prob(h_act).mean())
            acc = float((d.deterministic_sample == h_act).float().mean())
        return ce, acc

    ce_before, _ = held_out()
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    rows = obs.shape[0]
    mb = max(1, min(rows, config.bc_minibatch))
    bar = tqdm(total=epochs * -(-rows // mb), desc=f"cloning {scripted}", unit="step",
               disable=not progress)
    for _ in range(epochs):
        perm = torch.randperm(rows, generator=gen).to(device)
        for s in range(0, rows, mb):
            bar.update(1)
            idx = perm[s:s + mb]
            loss = -dist(obs[idx], mask[idx]).log_prob(act[idx]).mean()
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), config.max_grad_norm)
            opt.step()
    bar.close()
    ce_after, acc = held_out()
    allowed = MaskedMultiCategorical(torch.zeros(h_mask.shape, device=device), h_mask,
                                     core_nvec).base_dist.mask.sum(-1).float()
    return {"ce_before": ce_before, "ce_after": ce_after, "accuracy": acc,
            "chance": float((1.0 / allowed).mean()), "samples": rows * act.shape[1]}
