"""Reinforcement learning on netsense: adapters to maintained RL libraries and the batched
training pipeline.

Importing :mod:`netsense.rl` imports none of the submodules (nor torch). Two groups:

**Adapters** of the PettingZoo environment, each with its own optional extra:

==============================  ======================================================  ==========
module                          what                                                    extra
==============================  ======================================================  ==========
``netsense.rl.wrappers``        flat observations with the action mask appended         (core)
``netsense.rl.credit``          team / per-agent / counterfactual sender rewards        (core)
``netsense.rl.policy_files``    policy files are data: safe loading, checksums          ``rl``
``netsense.rl.sb3_policy``      ``LearnedPolicy``: a ``policy.zip`` read as data        ``rl``
``netsense.rl.sb3``             SuperSuit + MaskablePPO, ``train``                      ``rl``
``netsense.rl.rllib``           RLlib multi-agent PPO, one shared masked policy         ``rllib``
``netsense.rl.torchrl``         TorchRL ``PettingZooWrapper`` (the BenchMARL path)      ``torchrl``
==============================  ======================================================  ==========

**The batched training pipeline** (``torchrl`` extra), one module per stage, in the order
a run goes through them; a stage imports only the stages above it in this table
(``tests/test_layers.py`` checks it):

================================  ==================================================================
stage (module)                    what
================================  ==================================================================
environment (``envs``)            ``make_core``, TorchRL ``EnvBase`` over ``BatchedCore``
distribution (``distributions``)  masked multi-categorical over the core's flat action layout
networks (``networks``,           MLP actor and critics; the permutation-invariant set actor;
``set_network``, ``memory``)      recurrent actors (GRU over the agent's own history)
configuration (``config``)        ``PPOConfig`` (frozen, checked), training seeds
modules (``policy``)              actor and critic modules built from a config
collection (``rollout``)          ``T`` steps of ``B`` environments, lean (no TensorDict per step)
advantage (``advantage``)         critic values, TorchRL's GAE, value normalisation, loss batch
scripted data (``scripted``)      scripted policies in the core's layout, data collection
warm start (``cloning``)          behaviour cloning of a scripted policy
evaluation (``evaluation``)       periodic evaluation during training
logging (``runlog``)              ``log.csv`` and TensorBoard
checkpoints (``checkpoint``)      save / read / check policy files, ``BatchedPolicy``
resume (``resume``)               ``resume.pt``: what a killed run continues from, read as data
training loop (``ppo``)           ``train_ppo``: TorchRL's MAPPO / IPPO losses, schedules, logs
evolution strategy (``es``)       ``train_es``: separable CMA-ES (pycma) over the actor's weights,
                                  scored by the greedy return; the same files as ``ppo``
many runs (``launch``)            ``launch``: seeds x configurations in this process, in worker
                                  processes or as Ray tasks, the same files either way
================================  ==================================================================

Beneath every stage, standard library only: ``atomic`` (files written whole or not at all)
and ``run_folder`` (is a run's folder finished; may a new run write into it).

``netsense.rl.mappo``, ``netsense.rl.models`` and ``netsense.rl.torchrl_batched`` are the
former homes of these names and re-export them (see the CHANGELOG).

Tool layer. May import every layer up to :mod:`netsense.env`, and :mod:`netsense.grid`.
"""

__all__ = ["advantage", "atomic", "checkpoint", "cloning", "config", "credit",
           "distributions", "envs", "es", "evaluation", "launch", "mappo", "memory", "models",
           "networks", "policy", "policy_files", "ppo", "resume", "rllib", "rollout",
           "run_folder", "runlog", "sb3", "sb3_policy", "scripted", "set_network", "torchrl",
           "torchrl_batched", "wrappers"]
