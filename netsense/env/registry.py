"""Scenario registry: the TOML files in ``netsense/env/scenarios/`` are the only list of scenarios.

A file ``netsense/env/scenarios/<name>_v<k>.toml`` defines the scenario ``<name>-v<k>``
(``envs/`` at the repository root is a symlink to that folder; the files ship as
package data). :func:`make` builds a :class:`netsense.env.pettingzoo_env.NetSenseEnv`,
:func:`list_scenarios` lists the ids, :func:`load` returns the validated
:class:`Scenario` and :func:`build_model` the :class:`netsense.engine.model.CoreModel` (what
the batched core consumes).

File format (every key optional unless marked *required*; unknown keys raise)::

    description = "one line"
    horizon = 50                       # required: episode length
    x0_std = 1.0                       # x[0] ~ N(0, x0_std^2 I)
    initial_transmit = true            # transmit flags of step 0
    divergence_limit = 1e6             # terminate when a normalised error exceeds it
    substates = "all"                  # or "sources": indices/actions over the agents
                                       # with a non-empty block only (N x M, M <= n)

    [plant]                            # required
    kind = "fig1_scalar"               # a = 2.0
    # kind = "random_structured"       # n, num_agents, seed, [num_sources,
    #                                    outputs_per_source, spectral_radius]
    # kind = "oscillator_bank"         # num_agents, [agents_per_oscillator = 2,
    #                                    spectral_radius = 0.99, thetas]: N / p damped
    #                                    oscillators, agent p j measures block j
    # kind = "matrices"                # A = [[...]], C = [[[...]], [], ...] (one per agent),
    #                                    [W = [[...]]: x[k+1] = A x[k] + W w[k], n x p]

    [graph]                            # required; netsense.graphs.spec.graph_process_from_dict
    kind = "fig1"                      # or periodic / random_jsc / markov / gossip;
    # markov and gossip accept base = {kind = "circulant", offsets = [1, 3]} or
    # base = {kind = "complete"} instead of an explicit base_edges list; markov takes
    # draws = "all" (default: one uniform per node pair and step, the -v0 stream) or
    # "base" (one per base link: O(N D) draws, a different realisation);
    # base = {kind = "geometric", radius = 0.2, seed = 0}: sensors placed uniformly in
    # the unit square (one layout per seed), linked within the radius
    # (netsense.graphs.geometric)

    [design]                           # netsense.design_observer
    deadbeat = false
    rho = 0.5
    seed = 0

    [noise]                            # netsense.sensing.noise.noise_from_dict
    process = {kind = "none"}
    measurement = {kind = "gaussian", std = 0.01}

    [arrivals]                         # ArrivalModel specs (always/bernoulli/
    measurement = {kind = "always"}    # gilbert_elliott/multirate)
    message = {kind = "bernoulli", p = 0.9}   # per directed link
    # multirate: {kind = "multirate", periods = [1, 2, ...], phases = [...], jitter = 0,
    #             drop_prob = 0.0}; one period per agent (measurements: sensor i; messages:
    #             the sender l of link l -> i)

    [source_estimator]                 # the sources' local update (default eq. (7))
    kind = "luenberger"                # fixed gain L_j of the design, eq. (7)
    # kind = "kfio"                    # KFIOSource: Q, R required; W, P0 optional
    # kind = "rseio"                   # RSEIOSource: Q, R, mu required; W, P0, dA, dW, dC
    # kind = "equalized"               # EqualizedSource: language, eta_v required;
    #                                    eta_w, mu1, weights, truncate optional; language =
    #   {kind = "each_delayed_at_most", m = 1, T = 3} | {kind = "at_most_missing", m, T}
    #   | {kind = "words", words = ["210", "x00"], tau_bar = 2}

    [[faults]]                         # netsense.observers.faults.fault_from_dict, one table each
    kind = "crash"                     # agents = [1], at = 20: stop transmitting
    # kind = "stuck_sensor"            # agents, at, mode = "stuck" | "stale", delay
    # kind = "liar"                    # agents, claim = 0, at: false freshness indices

    [reward]                           # netsense.engine.model.RewardConfig
    error_weight = 1.0
    team_weight = 0.0
    message_cost = 0.0
    error_floor = 1e-3
    error_clip = 10.0
    substate_cost = 0.0                # per substate sent (control.mode = "substates")

    [control]                          # netsense.engine.control.Control
    mode = "full"                      # or "transmit" / "substates": communication only
    fusion = "freshness"               # the adoption rule then: or "uniform" / "tree"
    announce = false                   # observation field next_out: out-links in G[k+1]
    feedback = false                   # observation field acks: delivery per out-link

    [channel]                          # netsense.engine.control.Channel (default: none)
    capacity = 2                       # required in the section: at most K senders per
                                       # step, else all messages lost

A malformed file raises ``ValueError("<file>: field '<section.key>': ...")``.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
import stat
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from netsense.engine.model import CoreModel, RewardConfig
from netsense.kernels import checks

_TOP = {"description", "horizon", "x0_std", "initial_transmit", "divergence_limit",
        "plant", "graph", "design", "noise", "arrivals", "reward", "source_estimator",
        "faults", "substates", "control", "channel"}
_ENV_KWARGS = {"render_mode", "invalid_actions", "action_mask_in", "aoi_info", "nonfinite"}
#: Keywords of :func:`make` that are options of the PettingZoo env, not scenario keys.
ENV_OPTIONS = frozenset(_ENV_KWARGS)
_PLANT_FIELDS = {
    "fig1_scalar": ({"kind"}, {"a"}),
    "random_structured": ({"kind", "n", "num_agents", "seed"},
                          {"num_sources", "outputs_per_source", "spectral_radius"}),
    "matrices": ({"kind", "A", "C"}, {"W"}),
    "oscillator_bank": ({"kind", "num_agents"},
                        {"agents_per_oscillator", "spectral_radius", "thetas"}),
}
#: ``[source_estimator]`` kinds: (required, optional) fields besides ``kind``.
_SOURCE_FIELDS = {
    "luenberger": (set(), set()),
    "kfio": ({"Q", "R"}, {"W", "P0"}),
    "rseio": ({"Q", "R", "mu"}, {"W", "P0", "dA", "dW", "dC"}),
    "equalized": ({"language", "eta_v"}, {"eta_w", "mu1", "weights", "truncate"}),
}
_LANGUAGE_FIELDS = {"each_delayed_at_most": {"m", "T"}, "at_most_missing": {"m", "T"},
                    "words": {"words", "tau_bar"}}
#: Fault kinds a scenario may list (message loss is ``[arrivals] message``).
_FAULT_KINDS = ("crash", "stuck_sensor", "liar")


def _err(source: str, path: str, msg: str) -> ValueError:
    return ValueError(f"{source}: field '{path}': {msg}")


def _field(source: str, path: str, check, *args, **kwargs):
    """``check(path, *args)`` (a :mod:`netsense.kernels.checks` helper), its error naming
    ``source`` and ``path``."""
    try:
        return check(path, *args, **kwargs)
    except ValueError as exc:
        msg = str(exc)
        raise _err(source, path, msg[len(path) + 1:] if msg.startswith(path) else msg) \
            from None


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario file (sections kept as plain dicts, see the module docstring).

    Attributes
    ----------
    id : str
        ``name-vK``.
    horizon : int
        Episode length.
    plant, graph : dict
        Plant and graph-process specs.
    description : str
    x0_std : float
    initial_transmit : bool
    divergence_limit : float or None
    design, noise, arrivals : dict
        Gain design, noise and arrival specs.
    reward : RewardConfig
    source_estimator : dict
        ``[source_estimator]`` spec (empty: the fixed gain of eq. (7)).
    faults : tuple of dict
        ``[[faults]]`` specs (:func:`netsense.observers.faults.fault_from_dict` form).
    substates : {"all", "sources"}
        Substates the indices, actions and observations cover (see
        :class:`netsense.engine.model.CoreModel`).
    control : dict
        ``[control]`` (``mode``, ``fusion``; empty: full control).
    channel : dict
        ``[channel]`` (``capacity``; empty: no shared channel).
    source : str
        Where the scenario came from (file path), for error messages.
    """

    id: str
    horizon: int
    plant: dict
    graph: dict
    description: str = ""
    x0_std: float = 1.0
    initial_transmit: bool = True
    divergence_limit: float | None = None
    design: dict = field(default_factory=dict)
    noise: dict = field(default_factory=dict)
    arrivals: dict = field(default_factory=dict)
    reward: RewardConfig = field(default_factory=RewardConfig)
    source_estimator: dict = field(default_factory=dict)
    faults: tuple = ()
    substates: str = "all"
    control: dict = field(default_factory=dict)
    channel: dict = field(default_factory=dict)
    source: str = "<memory>"

    @classmethod
    def from_dict(cls, id: str, raw: dict, source: str = "<memory>") -> Scenario:
        """Validate a parsed TOML mapping; errors name ``source`` and the field."""
        if not isinstance(raw, dict):
            raise _err(source, "<root>", "must be a table")
        unknown = sorted(set(raw) - _TOP)
        if unknown:
            raise _err(source, unknown[0], f"unknown key; allowed: {sorted(_TOP)}")
        for req in ("horizon", "plant", "graph"):
            if req not in raw:
                raise _err(source, req, "is required")
        horizon = raw["horizon"]
        if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
            raise _err(source, "horizon", f"must be an integer >= 1, got {horizon!r}")
        if horizon > checks.MAX_STEPS:
            raise _err(source, "horizon", f"must be <= 2^53, got {horizon!r}")
        for sec in ("plant", "graph", "design", "noise", "arrivals", "reward",
                    "source_estimator", "control", "channel"):
            if sec in raw and not isinstance(raw[sec], dict):
                raise _err(source, sec, "must be a table")
        plant = dict(raw["plant"])
        kind = plant.get("kind")
        if kind not in _PLANT_FIELDS:
            raise _err(source, "plant.kind", f"must be one of {sorted(_PLANT_FIELDS)}, "
                                             f"got {kind!r}")
        req, opt = _PLANT_FIELDS[kind]
        for k in sorted(req - set(plant)):
            raise _err(source, f"plant.{k}", "is required")
        for k in sorted(set(plant) - req - opt):
            raise _err(source, f"plant.{k}", f"unknown key for plant kind {kind!r}")
        design = dict(raw.get("design", {}))
        for k in sorted(set(design) - {"deadbeat", "rho", "seed"}):
            raise _err(source, f"design.{k}", "unknown key; allowed: deadbeat, rho, seed")
        if "deadbeat" in design:
            _field(source, "design.deadbeat", checks.boolean, design["deadbeat"])
        if "rho" in design:
            _field(source, "design.rho", checks.number, design["rho"], 0, 1, lo_open=True,
                   hi_open=True)
        if "seed" in design:
            _field(source, "design.seed", checks.seed_value, design["seed"])
        noise = dict(raw.get("noise", {}))
        for k in sorted(set(noise) - {"process", "measurement"}):
            raise _err(source, f"noise.{k}", "unknown key; allowed: process, measurement")
        arrivals = dict(raw.get("arrivals", {}))
        for k in sorted(set(arrivals) - {"measurement", "message"}):
            raise _err(source, f"arrivals.{k}", "unknown key; allowed: measurement, message")
        rw = dict(raw.get("reward", {}))
        names = {f.name for f in dataclasses.fields(RewardConfig)}
        for k in sorted(set(rw) - names):
            raise _err(source, f"reward.{k}", f"unknown key; allowed: {sorted(names)}")
        for k, v in rw.items():
            _field(source, f"reward.{k}", checks.number, v)
        try:
            reward = RewardConfig(**{k: float(v) for k, v in rw.items()})
        except (TypeError, ValueError) as exc:
            raise _err(source, "reward", str(exc)) from exc
        lim = raw.get("divergence_limit")
        if lim is not None:
            _field(source, "divergence_limit", checks.number, lim, 0, lo_open=True)
        x0 = raw.get("x0_std", 1.0)
        _field(source, "x0_std", checks.number, x0, 0)
        it = raw.get("initial_transmit", True)
        if not isinstance(it, bool):
            raise _err(source, "initial_transmit", f"must be true or false, got {it!r}")
        desc = raw.get("description", "")
        if not isinstance(desc, str):
            raise _err(source, "description", "must be a string")
        est = _check_source_estimator(dict(raw.get("source_estimator", {})), source)
        faults = _check_faults(raw.get("faults", []), source)
        substates = raw.get("substates", "all")
        if substates not in ("all", "sources"):
            raise _err(source, "substates", f"must be 'all' or 'sources', got {substates!r}")
        control = dict(raw.get("control", {}))
        channel = dict(raw.get("channel", {}))
        if "channel" in raw and not channel:  # an empty table is a mistake, not "none"
            raise _err(source, "channel.capacity", "is required in a [channel] section "
                       "(leave the section out for no shared channel)")
        _build_control(control, channel, source)  # checks the fields
        if kind == "oscillator_bank":
            _oscillator_fields(plant, source)  # a bad N fails before anything is built
        base = raw["graph"].get("base")
        if isinstance(base, dict) and base.get("kind") == "geometric":
            _geometric_base(base, source)  # so does a bad radius
        N = _declared_agents(plant)
        if channel and N is not None and channel["capacity"] > N:
            raise _err(source, "channel.capacity", f"must be <= the number of agents N = "
                       f"{N}, got {channel['capacity']}")
        sc = cls(id=id, horizon=horizon, plant=plant, graph=dict(raw["graph"]),
                 description=desc, x0_std=float(x0), initial_transmit=it,
                 divergence_limit=None if lim is None else float(lim), design=design,
                 noise=noise, arrivals=arrivals, reward=reward, source_estimator=est,
                 faults=faults, substates=substates, control=control, channel=channel,
                 source=source)
        return sc

    def to_dict(self) -> dict:
        """The mapping :meth:`from_dict` accepts (round-trips)."""
        out = {"description": self.description, "horizon": self.horizon,
               "x0_std": self.x0_std, "initial_transmit": self.initial_transmit,
               "plant": copy.deepcopy(self.plant), "graph": copy.deepcopy(self.graph),
               "design": copy.deepcopy(self.design), "noise": copy.deepcopy(self.noise),
               "arrivals": copy.deepcopy(self.arrivals),
               "reward": dataclasses.asdict(self.reward)}
        if self.divergence_limit is not None:
            out["divergence_limit"] = self.divergence_limit
        if self.source_estimator:
            out["source_estimator"] = copy.deepcopy(self.source_estimator)
        if self.faults:
            out["faults"] = copy.deepcopy(list(self.faults))
        if self.substates != "all":
            out["substates"] = self.substates
        if self.control:
            out["control"] = dict(self.control)
        if self.channel:
            out["channel"] = dict(self.channel)
        return out

    @property
    def num_agents(self) -> int:
        """``N`` (read from the plant section)."""
        return build_plant(self).num_agents


def _build_control(control: dict, channel: dict, source: str):
    """``[control]`` and ``[channel]`` as :class:`netsense.engine.control.Control` and
    :class:`~netsense.engine.control.Channel` (or None); errors name the field."""
    from netsense.engine.control import Channel, Control

    for sec, tab, allowed in (("control", control, {"mode", "fusion", "announce",
                                                     "feedback"}),
                              ("channel", channel, {"capacity"})):
        for k in sorted(set(tab) - allowed):
            raise _err(source, f"{sec}.{k}", f"unknown key; allowed: {sorted(allowed)}")
    try:
        ctl = Control(**control)
    except ValueError as exc:
        head = str(exc).split("must")[0].split(" adds")[0]
        name = next((k for k in ("fusion", "announce", "feedback") if f"control.{k}" in head),
                    "mode")
        raise _err(source, f"control.{name}", str(exc)) from exc
    if not channel:
        return ctl, None
    if "capacity" not in channel:
        raise _err(source, "channel.capacity", "is required")
    try:
        return ctl, Channel(channel["capacity"])
    except ValueError as exc:
        raise _err(source, "channel.capacity", str(exc)) from exc


def _check_source_estimator(est: dict, source: str) -> dict:
    """Field names and kinds of ``[source_estimator]`` (values are checked when built)."""
    if not est:
        return est
    kind = est.get("kind", "luenberger")
    if kind not in _SOURCE_FIELDS:
        raise _err(source, "source_estimator.kind", f"must be one of "
                   f"{sorted(_SOURCE_FIELDS)}, got {kind!r}")
    req, opt = _SOURCE_FIELDS[kind]
    for k in sorted(req - set(est)):
        raise _err(source, f"source_estimator.{k}", f"is required for kind {kind!r}")
    for k in sorted(set(est) - req - opt - {"kind"}):
        raise _err(source, f"source_estimator.{k}", f"unknown key for kind {kind!r}; "
                   f"allowed: {sorted(req | opt)}")
    if kind == "equalized":
        lang = est["language"]
        if not isinstance(lang, dict) or lang.get("kind") not in _LANGUAGE_FIELDS:
            raise _err(source, "source_estimator.language.kind", "must be a table with kind "
                       f"one of {sorted(_LANGUAGE_FIELDS)}, got {lang!r}")
        allowed = _LANGUAGE_FIELDS[lang["kind"]]
        for k in sorted(set(lang) - allowed - {"kind"}):
            raise _err(source, f"source_estimator.language.{k}",
                       f"unknown key; allowed: {sorted(allowed)}")
        for k in sorted(allowed - set(lang) - {"tau_bar"}):
            raise _err(source, f"source_estimator.language.{k}", "is required")
    return est


def _check_faults(faults: Any, source: str) -> tuple:
    """``[[faults]]``: a list of tables whose kinds the environment supports."""
    if not isinstance(faults, list) or not all(isinstance(f, dict) for f in faults):
        raise _err(source, "faults", "must be an array of tables ([[faults]])")
    for i, f in enumerate(faults):
        if f.get("kind") == "link_drops":
            raise _err(source, f"faults[{i}].kind", "message loss on links is the "
                       "scenario's [arrivals] message model; use that section")
        if f.get("kind") not in _FAULT_KINDS:
            raise _err(source, f"faults[{i}].kind", f"must be one of {list(_FAULT_KINDS)}, "
                       f"got {f.get('kind')!r}")
    return tuple(dict(f) for f in faults)


# ----------------------------------------------------------------------------- files
def _envs_dir():
    return resources.files("netsense.env") / "scenarios"


def _id_of(filename: str) -> str | None:
    if not filename.endswith(".toml"):
        return None
    stem = filename[: -len(".toml")]
    name, sep, ver = stem.rpartition("_v")
    if not sep or not name or not ver.isdigit():
        return None
    return f"{name}-v{ver}"


def _files() -> dict[str, Any]:
    out = {}
    for entry in _envs_dir().iterdir():
        sid = _id_of(entry.name)
        if sid is not None:
            out[sid] = entry
    return out


def list_scenarios() -> list[str]:
    """Every registered scenario id (one per file in ``netsense/env/scenarios/``), sorted."""
    return sorted(_files())


def unknown_scenario(scenario_id: Any) -> ValueError:
    """The error for an id that is not registered: ``unknown scenario '<id>'``, the closest
    registered ids when there are some (``difflib``), and where the list is."""
    import difflib

    ids = list_scenarios()
    close = (difflib.get_close_matches(scenario_id, ids, n=3, cutoff=0.6)
             if isinstance(scenario_id, str) else [])
    hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
    return ValueError(f"unknown scenario {scenario_id!r}{hint}; `netsense list` shows the "
                      f"{len(ids)} registered ids")


def load(scenario_id: str) -> Scenario:
    """Parse and validate the scenario file of ``scenario_id``."""
    files = _files()
    if not isinstance(scenario_id, str) or scenario_id not in files:
        raise unknown_scenario(scenario_id)
    entry = files[scenario_id]
    return load_file(entry, scenario_id)


#: Largest scenario file read (bytes); the shipped ones are a few kilobytes.
MAX_SCENARIO_BYTES = 1 << 20
#: Deepest nesting of tables and arrays in a scenario file (the shipped ones: 4).
MAX_SCENARIO_DEPTH = 16


def _read_bytes(path) -> bytes:
    """At most :data:`MAX_SCENARIO_BYTES` + 1 bytes of a regular file (a device, pipe or
    folder is refused before it is opened: ``/dev/zero`` never ends, a FIFO blocks)."""
    if not isinstance(path, (str, os.PathLike)):  # a packaged file (importlib.resources)
        return path.read_bytes()
    p = Path(path)
    mode = p.stat().st_mode
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a device, pipe or socket"
        raise ValueError(f"{path}: not a regular file ({kind}); a scenario is a TOML file")
    with p.open("rb") as fh:
        return fh.read(MAX_SCENARIO_BYTES + 1)


def _depth(value) -> int:
    """Nesting depth of tables and arrays (iterative: no recursion on deep input)."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            stack += [(x, d + 1) for x in v.values()]
        elif isinstance(v, list):
            stack += [(x, d + 1) for x in v]
        else:
            continue
        deepest = max(deepest, d + 1)
    return deepest


def load_file(path, scenario_id: str | None = None) -> Scenario:
    """Parse and validate a scenario TOML file (any path, e.g. a user's own file).

    Raises
    ------
    ValueError
        Naming the file: missing or unreadable, not a regular file (a device such as
        ``/dev/zero``, a pipe, a folder), larger than :data:`MAX_SCENARIO_BYTES`, not
        UTF-8, not valid TOML, nested deeper than :data:`MAX_SCENARIO_DEPTH` tables or
        arrays, or a scenario that does not validate.
    """
    name = getattr(path, "name", str(path))
    sid = scenario_id or _id_of(Path(name).name) or Path(name).stem
    try:
        data = _read_bytes(path)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the scenario file: "
                         f"{exc.strerror or exc}") from None
    if len(data) > MAX_SCENARIO_BYTES:
        raise ValueError(f"{path}: larger than {MAX_SCENARIO_BYTES} bytes; a scenario "
                         "file is a few kilobytes of TOML")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a TOML text file (not UTF-8: {exc.reason} at byte "
                         f"{exc.start})") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from exc
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise ValueError(f"{path}: tables or arrays nested too deeply to parse (a scenario "
                         f"nests at most {MAX_SCENARIO_DEPTH})") from None
    depth = _depth(raw)
    if depth > MAX_SCENARIO_DEPTH:
        raise ValueError(f"{path}: tables or arrays nested {depth} deep; a scenario nests "
                         f"at most {MAX_SCENARIO_DEPTH}")
    return Scenario.from_dict(sid, raw, source=str(path))


# ----------------------------------------------------------------------------- builders
def build_plant(sc: Scenario):
    """The :class:`netsense.systems.plants.Plant` of a scenario (with its noise models)."""
    from netsense.sensing.noise import noise_from_dict
    from netsense.systems.plants import Plant, fig1_scalar, oscillator_bank, random_structured

    p = dict(sc.plant)
    kind = p.pop("kind")
    src = sc.source
    try:
        if kind == "fig1_scalar":
            plant = fig1_scalar(_field(src, "plant.a", checks.number, p.get("a", 2.0)))
        elif kind == "random_structured":
            n = _field(src, "plant.n", checks.integer, p.pop("n"), 1)
            N = _field(src, "plant.num_agents", checks.integer, p.pop("num_agents"), 1)
            seed = _field(src, "plant.seed", checks.seed_value, p.pop("seed"))
            for k in ("num_sources", "outputs_per_source"):
                if k in p:
                    p[k] = _field(src, f"plant.{k}", checks.integer, p[k], 1)
            if "spectral_radius" in p:
                p["spectral_radius"] = _field(src, "plant.spectral_radius", checks.number,
                                              p["spectral_radius"], 0, lo_open=True)
            plant = random_structured(n, N, rng=seed, **p)
        elif kind == "oscillator_bank":
            plant = oscillator_bank(**_oscillator_fields(p, src))
        else:
            A, Cs = _matrices(p["A"], p["C"], src)
            W = None
            if "W" in p:
                W = p["W"]
                if (not isinstance(W, list) or not W or not all(isinstance(r, list) for r in W)
                        or len(W) != len(A) or len({len(r) for r in W}) != 1
                        or not all(_numbers(v) for r in W for v in r)):
                    raise _err(src, "plant.W", f"must be a table of n = {len(A)} rows of "
                               f"numbers, all of one length (the noise inputs), got {W!r:.80}")
                W = np.array(W, dtype=float)
            plant = Plant(A=A, C=Cs, W=W, name=sc.id)
    except MemoryError:
        raise _err(src, "plant", "too large: building it needs more memory than is "
                   "available") from None
    except (ValueError, TypeError) as exc:
        if isinstance(exc, ValueError) and str(exc).startswith(f"{src}: field"):
            raise
        raise _err(sc.source, "plant", str(exc)) from exc
    noise = {}
    for key in ("process", "measurement"):
        if key in sc.noise:
            try:
                noise[f"{key}_noise"] = noise_from_dict(sc.noise[key])
            except (ValueError, TypeError) as exc:
                raise _err(sc.source, f"noise.{key}", str(exc)) from exc
    return dataclasses.replace(plant, **noise) if noise else plant


def _declared_agents(plant: dict) -> int | None:
    """``N`` as a ``[plant]`` table states it, without building the plant (None when it
    cannot be read cheaply)."""
    kind = plant.get("kind")
    if kind == "fig1_scalar":
        return 3
    if kind == "matrices":
        C = plant.get("C")
        return len(C) if isinstance(C, list) else None
    N = plant.get("num_agents")
    return N if isinstance(N, int) and not isinstance(N, bool) else None


def _oscillator_fields(p: dict, source: str) -> dict:
    """The keywords of :func:`netsense.systems.plants.oscillator_bank` from a ``[plant]``
    table of kind ``oscillator_bank`` (without ``kind``); errors name the field."""
    out = {"num_agents": _field(source, "plant.num_agents", checks.integer,
                                p["num_agents"], 1)}
    if "agents_per_oscillator" in p:
        out["agents_per_oscillator"] = _field(source, "plant.agents_per_oscillator",
                                              checks.integer, p["agents_per_oscillator"], 1)
    if "spectral_radius" in p:
        out["spectral_radius"] = _field(source, "plant.spectral_radius", checks.number,
                                        p["spectral_radius"], 0, lo_open=True)
    if "thetas" in p:
        th = p["thetas"]
        if not isinstance(th, list) or not th or not all(_numbers(v) for v in th):
            raise _err(source, "plant.thetas", f"must be a non-empty list of numbers, "
                       f"got {th!r:.60}")
        out["thetas"] = tuple(float(v) for v in th)
    if out["num_agents"] % out.get("agents_per_oscillator", 2):
        raise _err(source, "plant.num_agents", f"must be a multiple of "
                   f"agents_per_oscillator = {out.get('agents_per_oscillator', 2)}, got "
                   f"{out['num_agents']}")
    return out


def _numbers(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _matrices(A: Any, C: Any, source: str) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """``plant.A`` (a non-empty square table of numbers) and ``plant.C`` (one entry per
    agent: ``[]``, a list of rows of length ``n``, or one row of length ``n``)."""
    if (not isinstance(A, list) or not A or not all(isinstance(r, list) for r in A)
            or any(len(r) != len(A) for r in A)):
        raise _err(source, "plant.A", f"must be a non-empty square matrix (a list of n rows "
                   f"of n numbers), got {A!r:.80}")
    if not all(_numbers(v) for r in A for v in r):
        raise _err(source, "plant.A", "must hold numbers only")
    n = len(A)
    if not isinstance(C, list) or not C:
        raise _err(source, "plant.C", "must be a list with one output matrix per agent")
    Cs = []
    for i, Ci in enumerate(C):
        if not isinstance(Ci, list):
            raise _err(source, f"plant.C[{i}]", f"must be a list of rows, got {Ci!r:.40}")
        rows = [Ci] if Ci and not isinstance(Ci[0], list) else Ci  # one row may be flat
        if any(not isinstance(r, list) or len(r) != n for r in rows):
            raise _err(source, f"plant.C[{i}]", f"every row must hold n = {n} numbers (the "
                       f"width of A), got {Ci!r:.80}")
        if not all(_numbers(v) for r in rows for v in r):
            raise _err(source, f"plant.C[{i}]", "must hold numbers only")
        Cs.append(np.array(rows, dtype=float).reshape(len(rows), n))
    return np.array(A, dtype=float), tuple(Cs)


def _base_edges(spec: dict, N: int, source: str) -> list[list[int]]:
    kind = spec.get("kind")
    if kind == "circulant":
        offs = spec.get("offsets")
        if set(spec) != {"kind", "offsets"} or not isinstance(offs, list) or not offs:
            raise _err(source, "graph.base", "circulant needs exactly 'offsets' (a list)")
        for o in offs:
            _field(source, "graph.base.offsets", checks.integer, o)
        return [[l, (l + int(o)) % N] for o in offs for l in range(N) if int(o) % N]
    if kind == "complete":
        if set(spec) != {"kind"}:
            raise _err(source, "graph.base", "complete takes no other field")
        return [[l, i] for l in range(N) for i in range(N) if l != i]
    if kind == "geometric":
        from netsense.graphs.geometric import geometric_edges

        r, seed = _geometric_base(spec, source)
        return geometric_edges(N, r, seed)
    raise _err(source, "graph.base.kind", f"must be 'circulant', 'complete' or 'geometric', "
               f"got {kind!r}")


def _geometric_base(spec: dict, source: str) -> tuple[float, int]:
    """``radius`` and ``seed`` of ``graph.base = {kind = "geometric", ...}``, checked."""
    from netsense.graphs.geometric import check_geometric_spec

    try:
        return check_geometric_spec(spec)
    except ValueError as exc:
        name = str(exc).split(":")[0].split(" ")[0]
        raise _err(source, f"graph.base.{name}", str(exc)) from None


def build_graphs(sc: Scenario):
    """The :class:`netsense.graphs.processes.GraphProcess` of a scenario."""
    from netsense.graphs.processes import fig1_graphs
    from netsense.graphs.spec import graph_process_from_dict

    g = dict(sc.graph)
    if g.get("kind") == "fig1":
        if set(g) != {"kind"}:
            raise _err(sc.source, "graph", "kind 'fig1' takes no other field")
        return fig1_graphs()
    if "base" in g:
        base = g.pop("base")
        if not isinstance(base, dict):
            raise _err(sc.source, "graph.base", "must be a table")
        N = _field(sc.source, "graph.num_nodes", checks.integer, g.get("num_nodes"), 1)
        g["base_edges"] = _base_edges(base, N, sc.source)
    try:
        return graph_process_from_dict(g)
    except (ValueError, TypeError, KeyError) as exc:
        name = _field_of(str(exc), set(g) - {"kind"})
        raise _err(sc.source, f"graph.{name}" if name else "graph", str(exc)) from exc


def _arrival(spec: dict, path: str, source: str):
    from netsense.sensing.drops import arrival_from_dict

    try:
        return arrival_from_dict(spec)  # also dispatches kind = "multirate"
    except (ValueError, TypeError) as exc:
        raise _err(source, path, str(exc)) from exc


def _field_of(msg: str, fields: set[str]) -> str:
    """The first field name of ``fields`` that an estimator's error message mentions."""
    for word in msg.replace("[", " ").replace("(", " ").replace(".", " ").split():
        if word.strip("'\",.:;])") in fields:
            return word.strip("'\",.:;])")
    return ""


def _number_or_array(v: Any, path: str = "value", source: str = "<memory>"
                     ) -> float | np.ndarray:
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        return float(v)
    if not isinstance(v, (list, tuple, np.ndarray)):
        raise _err(source, path, f"must be a number or an array of numbers, got {v!r:.60}")
    try:
        return np.asarray(v, dtype=float)
    except (ValueError, TypeError):
        raise _err(source, path, "must be a number or a (rectangular) array of numbers, got "
                   f"{v!r:.60}") from None


def build_language(spec: dict, source: str = "<memory>"):
    """The :class:`netsense.sensing.delays.DelayLanguage` of a ``language`` table."""
    from netsense.sensing.delays import DelayLanguage

    spec = dict(spec)
    kind = spec.pop("kind")
    for k in ("m", "T", "tau_bar"):
        v = spec.get(k)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int)):
            raise _err(source, f"source_estimator.language.{k}", f"must be an integer, "
                       f"got {v!r}")
    try:
        if kind == "words":
            words = spec["words"]
            if not isinstance(words, list) or not words:
                raise ValueError(f"words must be a non-empty list, got {words!r}")
            return DelayLanguage.from_words(words, tau_bar=spec.get("tau_bar"))
        if kind == "each_delayed_at_most":
            return DelayLanguage.each_delayed_at_most(spec["m"], spec["T"])
        return DelayLanguage.at_most_missing(spec["m"], spec["T"])
    except (ValueError, TypeError) as exc:
        raise _err(source, "source_estimator.language", str(exc)) from exc


def build_source_estimator(sc: Scenario, design):
    """The ``[source_estimator]`` of a scenario as a picklable factory, or None (eq. (7)).

    The estimator is built and validated once (for ``equalized`` this solves the design
    LPs of every source); the factory returns independent copies, one per core.
    """
    from netsense.observers.source_estimators import KFIOSource, RSEIOSource
    from netsense.observers.source_estimators_equalized import EqualizedSource

    spec = dict(sc.source_estimator)
    kind = spec.pop("kind", "luenberger")
    if kind == "luenberger":
        return None
    src = sc.source
    fields = set(_SOURCE_FIELDS[kind][0] | _SOURCE_FIELDS[kind][1])
    for k in ("eta_v", "eta_w", "mu1", "mu"):
        v = spec.get(k)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise _err(src, f"source_estimator.{k}", f"must be a number, got {v!r}")
    try:
        if kind in ("kfio", "rseio"):
            arrays = {k: _number_or_array(v, f"source_estimator.{k}", src)
                      for k, v in spec.items() if k != "mu"}
            for k in ("R", "dC"):  # per-agent lists (R may also be one number)
                if isinstance(spec.get(k), list):
                    arrays[k] = [np.zeros((0, 0)) if isinstance(v, list) and not v
                                 else np.atleast_2d(np.asarray(v, dtype=float))
                                 for v in spec[k]]
            est = (KFIOSource(**arrays) if kind == "kfio"
                   else RSEIOSource(mu=spec["mu"], **arrays))
            copy.deepcopy(est).reset(design, 1)  # validates shapes and PD covariances
        else:
            lang = build_language(spec.pop("language"), src)
            weights = spec.pop("weights", None)
            truncate = spec.pop("truncate", True)
            if not isinstance(truncate, bool):
                raise ValueError(f"truncate must be true or false, got {truncate!r}")
            from netsense.sensing.delays import DelayChannel

            channel = DelayChannel(lang, None if weights is None else tuple(weights),
                                   truncate)
            est = EqualizedSource(lang, channel=channel, **spec)
            est.designs(design)  # solves the LPs once; copies reuse them
    except (ValueError, TypeError, RuntimeError) as exc:
        if isinstance(exc, ValueError) and str(exc).startswith(src):
            raise
        name = _field_of(str(exc), fields)
        raise _err(src, f"source_estimator.{name}" if name else "source_estimator",
                   str(exc)) from exc
    return functools.partial(copy.deepcopy, est)


def build_faults(sc: Scenario, num_agents: int) -> tuple:
    """The ``[[faults]]`` of a scenario as :class:`netsense.observers.faults.Fault` objects."""
    from netsense.observers.faults import LyingAgent, fault_from_dict

    out = []
    for i, spec in enumerate(sc.faults):
        try:
            f = fault_from_dict(spec)
            f.check(num_agents)
        except (ValueError, TypeError) as exc:
            name = _field_of(str(exc), {"agents", "at", "mode", "delay", "claim"})
            raise _err(sc.source, f"faults[{i}].{name}" if name else f"faults[{i}]",
                       str(exc)) from exc
        out.append(f)
    if sum(isinstance(f, LyingAgent) for f in out) > 1:
        raise _err(sc.source, "faults", "at most one liar table (list every liar in its "
                   "agents)")
    return tuple(out)


def _scale_hint(plant) -> str:
    """A hint for a plant whose entries span many orders of magnitude (the rank decisions
    of Lemma 1 are relative to the largest norm, so small outputs look like zero)."""
    vals = np.abs(np.concatenate([plant.A.ravel(), *[c.ravel() for c in plant.C]]))
    vals = vals[vals > 0]
    if vals.size and vals.max() / vals.min() > 1e8:
        return (f" (the plant is badly scaled: its entries range from {vals.min():.3g} to "
                f"{vals.max():.3g}; rescale the state or the outputs)")
    return ""


def build_model(sc: Scenario) -> CoreModel:
    """Everything the batched core needs: plant, gains, graphs, arrivals, rewards."""
    from netsense.sensing.arrivals import AlwaysArrive
    from netsense.systems.design import design_observer

    plant = build_plant(sc)
    graphs = build_graphs(sc)
    if graphs.num_nodes != plant.num_agents:
        raise _err(sc.source, "graph.num_nodes", f"the graph has {graphs.num_nodes} nodes but "
                   f"the plant has {plant.num_agents} agents")
    d = sc.design
    try:
        design = design_observer(plant, rho=float(d.get("rho", 0.5)),
                                 deadbeat=d.get("deadbeat", False),
                                 rng=int(d.get("seed", 0)))
    except (ValueError, TypeError) as exc:
        raise _err(sc.source, "design", str(exc) + _scale_hint(plant)) from exc
    arr = {k: _arrival(v, f"arrivals.{k}", sc.source) for k, v in sc.arrivals.items()}
    for k, model in arr.items():
        S = getattr(model, "num_sensors", plant.num_agents)  # multirate: one per agent
        if S != plant.num_agents:
            raise _err(sc.source, f"arrivals.{k}", f"multirate needs one period per agent "
                       f"({plant.num_agents}), got {S}")
    source_estimator = build_source_estimator(sc, design)
    faults = build_faults(sc, plant.num_agents)
    control, channel = _build_control(sc.control, sc.channel, sc.source)
    try:
        return CoreModel(plant=plant, design=design, graphs=graphs, horizon=sc.horizon,
                         measurement_arrivals=arr.get("measurement", AlwaysArrive()),
                         message_arrivals=arr.get("message", AlwaysArrive()),
                         reward=sc.reward, x0_std=sc.x0_std,
                         initial_transmit=sc.initial_transmit,
                         divergence_limit=sc.divergence_limit,
                         source_estimator=source_estimator, faults=faults,
                         substates=sc.substates, control=control, channel=channel)
    except ValueError as exc:
        name = _field_of(str(exc), {"faults", "horizon", "x0_std", "initial_transmit",
                                    "divergence_limit", "design", "substates", "reward"})
        raise _err(sc.source, name or "<scenario>", str(exc)) from exc


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and \
                v.get("kind", out[k].get("kind")) == out[k].get("kind"):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def with_overrides(sc: Scenario, **overrides) -> Scenario:
    """A copy of ``sc`` with top-level keys replaced and sections merged.

    A section override (``reward={"message_cost": 0.1}``) is merged key by key into the
    file's section; one that changes ``kind`` replaces the section. Unknown keys raise.
    """
    if not overrides:
        return sc
    raw = _merge(sc.to_dict(), overrides)
    return Scenario.from_dict(sc.id, raw, source=f"{sc.source} (with overrides "
                                                  f"{sorted(overrides)})")


def control_overrides(scenario: str, control: str | dict | None, overrides: dict) -> dict:
    """``overrides`` with the scenario's ``[control]`` section updated by ``control``: a
    mode name (the section's other keys, e.g. the fusion rule, kept) or a dict of keys
    (``{"mode": "transmit", "fusion": "tree"}``); unchanged for ``control=None``."""
    from netsense.engine.control import MODES

    if control is None:
        return dict(overrides)
    if isinstance(control, str):
        if control not in MODES:
            raise ValueError(f"control must be one of {MODES} or a dict, got {control!r}")
        control = {"mode": control}
    if not isinstance(control, dict):
        raise ValueError(f"control must be a mode name, a dict or None, got "
                         f"{type(control).__name__}")
    sc = with_overrides(load(scenario), **overrides)
    return {**overrides, "control": {**sc.control, **control}}


def make(scenario_id: str, **overrides):
    """Build the PettingZoo environment of a registered scenario.

    Parameters
    ----------
    scenario_id : str
        An id from :func:`list_scenarios` (e.g. ``"fig1_scalar-v0"``).
    **overrides
        Environment arguments (``render_mode``, ``invalid_actions``, ``action_mask_in``,
        ``aoi_info``) and scenario keys (``horizon=10``, ``reward={"message_cost": 0.05}``, ...).

    Returns
    -------
    netsense.env.pettingzoo_env.NetSenseEnv
    """
    from netsense.env.pettingzoo_env import NetSenseEnv

    env_kw = {k: overrides.pop(k) for k in list(overrides) if k in _ENV_KWARGS}
    sc = with_overrides(load(scenario_id), **overrides)
    model = build_model(sc) if overrides else _cached_model(scenario_id)
    return NetSenseEnv(model, scenario_id=scenario_id, **env_kw)


_MODEL_CACHE: dict[str, CoreModel] = {}


def _cached_model(scenario_id: str) -> CoreModel:
    """Models of unmodified scenarios are immutable and reused (the gain design of a large
    plant is the expensive part of ``make``)."""
    if scenario_id not in _MODEL_CACHE:
        _MODEL_CACHE[scenario_id] = build_model(load(scenario_id))
    return _MODEL_CACHE[scenario_id]
