"""Training pipeline, alternative to stage *training loop*: an evolution strategy.

:func:`train_es` searches the weights of the actor a :class:`~netsense.rl.config.PPOConfig`
describes (the same network, inputs and policy file as :func:`~netsense.rl.ppo.train_ppo`)
with the separable CMA-ES of ``pycma`` (Ros & Hansen 2008: a diagonal covariance, for
thousands of weights), scoring each candidate by the return of its **greedy** policy, the
one the protocol evaluates. Where a policy gradient follows the change of one decision's
probability at a time on a stochastic policy, a candidate here is a perturbation of every
weight at once, scored on whole episodes: a search that can change several of the policy's
choices together (Salimans et al. 2017 scale the same idea to large networks).

A generation plays every candidate on the same ``episodes`` training episodes (common
random numbers: the candidates differ by their weights, not by their luck), drawn without
replacement from the run's training seeds ``seed * num_envs + b`` (``b < num_envs``,
:func:`~netsense.rl.config.training_seeds`, below the protocol's evaluation seeds). Every
``eval_interval`` generations the search's mean is evaluated greedy on the validation
episodes of :mod:`netsense.rl.evaluation` and written as a checkpoint, so a run folder of
this trainer reads like one of :func:`~netsense.rl.ppo.train_ppo` (``log.csv``,
``policy.pt``, ``summary.json``, ``config.json``).

A recurrent actor is refused (a generation would have to carry one memory per candidate).

Imports: torch, pycma, and the stages below (run_folder, config, envs, distributions,
policy, cloning, evaluation, runlog, checkpoint).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from netsense.rl.atomic import write_json
from netsense.rl.checkpoint import _fit, policy_state, read_policy, write_policy
from netsense.rl.config import PPOConfig
from netsense.rl.distributions import MaskedMultiCategorical
from netsense.rl.envs import make_core
from netsense.rl.evaluation import evaluate
from netsense.rl.policy import actor_net
from netsense.rl.run_folder import FINISHED, RUNNING, claim, mark
from netsense.rl.runlog import RunLog

__all__ = ["ESConfig", "greedy_returns", "train_es"]


@dataclass(frozen=True)
class ESConfig:
    """Settings of the evolution strategy (the network and task come from a
    :class:`PPOConfig`).

    Parameters
    ----------
    popsize : int
        Candidates per generation (>= 3).
    episodes : int
        Training episodes each candidate plays per generation, the same for all of them;
        at most the config's ``num_envs`` (the pool of training seeds).
    sigma : float
        Initial step size of the search, in units of the weights (> 0). The search
        starts from all weights zero, or (``PPOConfig.bc``) from the weights of a
        behaviour clone of a scripted policy (:func:`~netsense.rl.cloning.
        behaviour_clone`): a warm start.
    init : str or None
        A policy file of the same actor (the same network and inputs) whose weights the
        search starts from instead, ``{seed}`` replaced by the run's seed: the
        continuation of another run (a PPO run from scratch, say). Its agent-steps count
        in this run's budget and log. Not with ``PPOConfig.bc``.
    """

    popsize: int = 32
    episodes: int = 16
    sigma: float = 0.5
    init: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.popsize, int) or isinstance(self.popsize, bool) \
                or self.popsize < 3:
            raise ValueError(f"ESConfig.popsize must be an integer >= 3 (pycma mirrors the "
                             f"samples of small populations, which fails with 2), got "
                             f"{self.popsize!r}")
        if not isinstance(self.episodes, int) or isinstance(self.episodes, bool) \
                or self.episodes < 1:
            raise ValueError(f"ESConfig.episodes must be an integer >= 1, got "
                             f"{self.episodes!r}")
        if not isinstance(self.sigma, (int, float)) or isinstance(self.sigma, bool) \
                or not math.isfinite(self.sigma) or self.sigma <= 0:
            raise ValueError(f"ESConfig.sigma must be a finite number > 0, got {self.sigma!r}")
        if self.init is not None and (not isinstance(self.init, str) or not self.init):
            raise ValueError(f"ESConfig.init must be a path (a string) or None, got "
                             f"{self.init!r}")


def _init_path(config: PPOConfig, es: ESConfig) -> Path:
    """The policy file ``es.init`` names for this run's seed."""
    return Path(es.init.format(seed=config.seed))


def _check(config: PPOConfig, es: ESConfig) -> None:
    if config.memory:
        raise ValueError("train_es: a recurrent actor (PPOConfig.memory) is not supported; "
                         "the evolution strategy searches feed-forward actors")
    if es.init is not None and config.bc:
        raise ValueError("ESConfig.init and PPOConfig.bc both set the search's start; "
                         "give one")
    if es.init is not None and not _init_path(config, es).is_file():
        raise ValueError(f"ESConfig.init: no policy file at {_init_path(config, es)}")
    if es.episodes > config.num_envs:
        raise ValueError(f"ESConfig.episodes ({es.episodes}) exceeds the pool of training "
                         f"seeds, PPOConfig.num_envs ({config.num_envs})")


class _Population:
    """``P`` copies of one actor; candidate ``p``'s weights are row ``p`` of a flat matrix
    in the order of ``net.parameters()``. (TorchRL's multi-agent MLP keeps its weights in a
    ``TensorDictParams``, which :func:`torch.func.functional_call` does not swap, so each
    candidate has its own copy of the network.)"""

    def __init__(self, net: torch.nn.Module, size: int) -> None:
        import copy

        self.net = net
        self.copies = [copy.deepcopy(net) for _ in range(size)]
        self.dim = int(sum(p.numel() for p in net.parameters()))

    @staticmethod
    def _set(net: torch.nn.Module, vector) -> torch.nn.Module:
        torch.nn.utils.vector_to_parameters(
            torch.as_tensor(np.asarray(vector), dtype=torch.float32), net.parameters())
        return net

    def load(self, vector: np.ndarray) -> torch.nn.Module:
        """The actor with the weights ``vector`` (one candidate)."""
        return self._set(self.net, vector)

    def set(self, weights: np.ndarray) -> None:
        """Load ``weights (P, dim)`` into the first ``P`` copies."""
        if len(weights) > len(self.copies):
            raise ValueError(f"{len(weights)} candidates, {len(self.copies)} copies")
        for net, w in zip(self.copies, weights, strict=False):
            self._set(net, w)

    def logits(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs (P, E, N, O)`` -> logits ``(P, E, N, K)`` of the loaded candidates."""
        return torch.stack([net(o) for net, o in zip(self.copies, obs, strict=False)])


def greedy_returns(population: _Population, core, weights: np.ndarray,
                   seeds: np.ndarray) -> tuple[np.ndarray, float]:
    """Return of every candidate's greedy policy on the same episodes.

    ``weights (P, dim)``, ``seeds (E,)``; ``core`` holds ``P * E`` members (member
    ``p * E + e`` plays candidate ``p`` on episode ``seeds[e]``). The return of an episode
    is the sum over its steps of the agents' mean reward, as the protocol scores it
    (:func:`netsense.benchmark.protocol.evaluate`; a member that ends early is scored over
    its own steps). Actions are the most likely allowed ones
    (:class:`~netsense.rl.distributions.MaskedMultiCategorical`, as the protocol's greedy
    learned policy acts). Returns the ``(P,)`` mean returns and the share of agent-steps
    that transmitted.
    """
    P, E = weights.shape[0], len(seeds)
    if core.B != P * E:
        raise ValueError(f"greedy_returns: the core holds {core.B} members, {P} candidates "
                         f"x {E} episodes need {P * E}")
    population.set(weights)
    obs, mask = core.reset([int(s) for s in np.tile(seeds, P)])
    ret = np.zeros(core.B)
    live = np.ones(core.B, dtype=bool)
    sent = steps = 0.0
    nvec = tuple(int(v) for v in core.nvec)
    with torch.no_grad():
        while live.any():
            o = torch.as_tensor(obs).reshape(P, E, *obs.shape[1:])
            lg = population.logits(o).reshape(core.B, core.N, -1)
            d = MaskedMultiCategorical(lg, torch.as_tensor(np.asarray(mask).astype(bool)),
                                       nvec)
            out = core.step(d.deterministic_sample.numpy())
            obs, mask = out.obs, out.action_mask
            ret[live] += out.reward.mean(1)[live]
            sent += float(core.transmit[live].sum())
            steps += float(live.sum()) * core.N
            live &= ~(out.terminated | out.truncated)
    return ret.reshape(P, E).mean(1), sent / max(steps, 1.0)


def train_es(config: PPOConfig, es: ESConfig, folder: str | Path, *,
             progress: bool = True, overwrite: bool = False) -> dict:
    """Search the actor's weights with separable CMA-ES for ``config.steps`` agent-steps
    (after those of ``es.init``'s run, when it continues one: the log and summary count
    both).

    Writes into ``folder``: ``config.json`` (the ``PPOConfig``), ``log.csv`` (one row per
    generation: ``iteration``, ``agent_steps``, ``wall_s``, the population's mean and best
    training return, its share of transmitting agent-steps, the step size, and every
    ``config.eval_interval`` generations ``eval_return`` / ``eval_error`` /
    ``eval_messages`` of the search's mean on the validation episodes),
    ``checkpoint_<generation + 1>.pt`` at those generations, ``policy.pt`` (the final mean)
    and ``summary.json`` (with the ``ESConfig`` under ``es``). Policy files hold the actor
    only (no critic). ``run.json`` says
    ``running`` until the last file is written, then ``finished``
    (:mod:`netsense.rl.run_folder`): a folder that holds a run is refused unless
    ``overwrite``.

    Returns the summary.
    """
    import cma

    _check(config, es)
    folder = Path(folder)
    claim(folder, overwrite=overwrite)  # (checks only; nothing is written yet)
    torch.set_num_threads(int(config.torch_threads or 1))
    torch.manual_seed(config.seed)
    core = make_core(config.scenario, es.popsize * es.episodes, control=config.control,
                     **config.overrides)
    population = _Population(actor_net(config, core, torch.device("cpu")), es.popsize)
    per_gen = es.popsize * es.episodes * core.N * core.horizon
    generations = max(1, math.ceil(config.steps / per_gen))
    bc, start_steps = None, 0
    if es.init is not None:  # continue another run from its final weights
        path = _init_path(config, es)
        state = read_policy(path)
        _fit(population.net, state["actor"], path, "the actor of this run's config "
             "(ESConfig.init names another actor)")
        start_steps = int(state.get("agent_steps", 0))
    folder.mkdir(parents=True, exist_ok=True)
    mark(folder, RUNNING, backend="es", seed=config.seed)
    # config.json holds the actor's PPOConfig, as a PPO run's does (what reads a run
    # folder rebuilds the network from it); the search's settings go to summary.json
    write_json(folder / "config.json", asdict(config), default=list)
    if config.bc:  # warm start: the search starts from a clone of the scripted policy
        from netsense.rl.cloning import behaviour_clone

        bc = behaviour_clone(population.net, config, config.bc, device=torch.device("cpu"),
                             progress=progress)
    x0 = (torch.nn.utils.parameters_to_vector(population.net.parameters()).detach()
          .numpy().astype(float) if es.init is not None or config.bc
          else np.zeros(population.dim))
    search = cma.CMAEvolutionStrategy(x0, es.sigma, {
        "popsize": es.popsize, "CMA_diagonal": True, "seed": config.seed + 1,
        "verbose": -9, "tolfun": 0, "tolflatfitness": 10**9, "tolstagnation": 10**9})
    rng = np.random.default_rng(config.seed)
    base = config.seed * config.num_envs
    trainer = {"algorithm": "sep-cma-es", **asdict(es)}

    def save(path: Path, vector: np.ndarray, it: int, steps: int) -> None:
        write_policy(path, dict(policy_state(config, population.load(vector), it, steps,
                                             core), trainer=trainer))

    log, t0, steps = RunLog(folder), time.perf_counter(), start_steps
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=generations, desc=f"{config.scenario} es seed {config.seed}",
                   unit="gen")
    for g in range(generations):
        seeds = base + rng.choice(config.num_envs, es.episodes, replace=False)
        cand = search.ask()
        returns, sends = greedy_returns(population, core, np.asarray(cand), seeds)
        search.tell(cand, list(-returns))
        steps += per_gen
        row = {"iteration": g, "agent_steps": steps,
               "wall_s": round(time.perf_counter() - t0, 3),
               "train_return": float(returns.mean()), "train_best": float(returns.max()),
               "train_messages": sends, "sigma": float(search.sigma),
               "eval_return": "", "eval_error": "", "eval_messages": ""}
        if (g + 1) % config.eval_interval == 0 or g == generations - 1:
            m = evaluate(population.load(search.mean), config)
            row.update(eval_return=m["return"], eval_error=m["error"],
                       eval_messages=m["messages"])
            save(folder / f"checkpoint_{g + 1:05d}.pt", search.mean, g, steps)
        log.add(row)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(ret=f"{row['train_return']:.1f}", sigma=f"{search.sigma:.3f}")
    log.close()
    if bar is not None:
        bar.close()
    save(folder / "policy.pt", search.mean, generations - 1, steps)
    wall = time.perf_counter() - t0
    summary = {"wall_s": round(wall, 2), "agent_steps": steps,
               "agent_steps_per_s": round((steps - start_steps) / wall, 1), "device": "cpu",
               "init_agent_steps": start_steps,
               "algorithm": "sep-cma-es", "es": asdict(es), "generations": generations,
               "weights": population.dim, "torch_threads": int(config.torch_threads or 1),
               "bc": None if bc is None else json.loads(json.dumps(bc, default=float))}
    write_json(folder / "summary.json", summary)
    mark(folder, FINISHED, backend="es", seed=config.seed)  # the last write
    return summary

