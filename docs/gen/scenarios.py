"""Build ``scenarios.md`` from the scenario registry (mkdocs-gen-files, at build time).

One row per registered scenario (``netsense.list_scenarios()``, one TOML file each in
``netsense/env/scenarios/``): its size as the built model has it and the description the
file carries, so the page cannot drift from the registry.
"""

from __future__ import annotations

import mkdocs_gen_files

from netsense.env.registry import build_model, list_scenarios, load


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _control(sc) -> str:
    mode = (sc.control or {}).get("mode", "full")
    cap = (sc.channel or {}).get("capacity")
    return f"{mode}, channel capacity {cap}" if cap else mode


rows = []
for sid in list_scenarios():
    sc = load(sid)
    model = build_model(sc)
    rows.append(f"| `{sid}` | {model.plant.num_agents} | {model.plant.n} | "
                f"{model.graphs.max_in_degree} | {model.horizon} | {_control(sc)} | "
                f"{_cell(sc.description)} |")

with mkdocs_gen_files.open("scenarios.md", "w") as fh:
    fh.write(f"""# Scenarios

`netsense.make("<id>", **overrides)` returns a PettingZoo `ParallelEnv`; `netsense list`
prints the same registry in a terminal. Each scenario is a TOML file in
`netsense/env/scenarios/` (`envs/` at the repository root points there); the file format,
the overrides and how to add a scenario are in [the environment page](env.md). This table is
generated from the registry when the site is built ({len(rows)} scenarios).

N: agents; n: state dimension; D: the largest in-degree of the graph process (message
slots per agent); horizon: steps per episode; control: what the agents decide (`full`:
fusion and transmit bit per substate; `transmit` / `substates`: communication only, the
freshness rule fuses; see [learning to communicate](communication.md)).

| id | N | n | D | horizon | control | description |
|---|---|---|---|---|---|---|
""")
    fh.write("\n".join(rows) + "\n")
