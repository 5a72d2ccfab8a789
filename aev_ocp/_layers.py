"""The package's layers: which module may import which (docs/guide/layers.md; kept true by tests/contracts/test_layers.py).

A module imports only from its own layer or from layers below it; function-local and ``TYPE_CHECKING``
imports count, and so does a package ``__init__``'s lazy export table (``_EXPORTS``). Within a layer the
imports form no cycle. A package ``__init__`` has a layer of its own (the highest of the names it
re-exports) and never imports its sub-package's CLI, report or other code above that layer.

This module is data only: it imports nothing.
"""

from __future__ import annotations

#: The layers from the bottom up: (name, modules). Every module of ``aev_ocp`` is in exactly one.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "foundation",
        (
            "aev_ocp._layers",
            "aev_ocp._version",
            "aev_ocp.lazy",
            "aev_ocp.errors",
            "aev_ocp.params",
            "aev_ocp.numerics",
            "aev_ocp.fastcall",
            "aev_ocp.compiled",
            "aev_ocp.cells",
            "aev_ocp.limits",
            "aev_ocp.progress",
            "aev_ocp.provenance",
            "aev_ocp.interrupts",
        ),
    ),
    (
        "physics",
        (
            "aev_ocp.models",
            "aev_ocp.models.actuator",
            "aev_ocp.models.battery",
            "aev_ocp.models.carfollowing",
            "aev_ocp.models.ego",
            "aev_ocp.models.energy",
            "aev_ocp.models.leader",
            "aev_ocp.models.powertrain",
            "aev_ocp.models.vehicle",
            "aev_ocp.models.thermal",
            "aev_ocp.reference",
            "aev_ocp.models.braking",
            "aev_ocp.models.safety_bound",
            "aev_ocp.models.battery_step",
        ),
    ),
    (
        "results",
        (
            "aev_ocp.results",
            "aev_ocp.intervals",
            "aev_ocp.calibration",
            "aev_ocp.metrics",
            "aev_ocp.truncation",
            "aev_ocp.ocp_result",
            "aev_ocp.life",
        ),
    ),
    (
        "plant and closed loop",
        (
            "aev_ocp.estimation",
            "aev_ocp.estimation.sensors",
            "aev_ocp.estimation.mismatch",
            "aev_ocp.estimation.base",
            "aev_ocp.estimation.kalman",
            "aev_ocp.estimation.mhe",
            "aev_ocp.plant",
            "aev_ocp.loop",
            "aev_ocp.control",
            "aev_ocp.simulate",
            "aev_ocp.ring.simulate",
            "aev_ocp.trace_replay",
        ),
    ),
    (
        "problem description",
        (
            "aev_ocp.ocp.problem",
            "aev_ocp.ocp.following",
            "aev_ocp.ocp.formulation",
            "aev_ocp.ocp.traffic",
            "aev_ocp.ocp.traffic_cost",
            "aev_ocp.ocp.transcription",
            "aev_ocp.ocp.cell",
            "aev_ocp.ocp.checks",
        ),
    ),
    (
        "solvers and controllers",
        (
            "aev_ocp.ocp",
            "aev_ocp.ocp.oracle",
            "aev_ocp.ocp.prop31",
            "aev_ocp.ocp.current_profile",
            "aev_ocp.ocp.eco_trip",
            "aev_ocp.mpc.settings",
            "aev_ocp.mpc.controller",
            "aev_ocp.mpc.ocpqp",
            "aev_ocp.mpc.policy",
            "aev_ocp.mpc.predictors",
            "aev_ocp.mpc.nlp",
            "aev_ocp.mpc.rti",
            "aev_ocp.mpc.fallback",
            "aev_ocp.mpc.solution",
            "aev_ocp.mpc.cstep",
            "aev_ocp.mpc.wave",
            "aev_ocp.safety",
            "aev_ocp.mpc.safe_fallback",
            "aev_ocp.stability",
            "aev_ocp.stability.linear",
            "aev_ocp.stability.mixed",
            "aev_ocp.stability.perturbation",
            "aev_ocp.stability.measure",
            "aev_ocp.ring",
            "aev_ocp.ring.laws",
            "aev_ocp.ring.humans",
            "aev_ocp.stability.ring",
        ),
    ),
    (
        "configuration",
        (
            "aev_ocp.scenarios",
            "aev_ocp.scenarios.tables",
            "aev_ocp.scenarios.sections",
            "aev_ocp.scenarios.providers",
            "aev_ocp.scenarios.size",
            "aev_ocp.scenarios.vehicle",
            "aev_ocp.scenarios.leader",
            "aev_ocp.scenarios.followers",
            "aev_ocp.scenarios.platoon",
            "aev_ocp.scenarios.shipped",
            "aev_ocp.scenarios.files",
            "aev_ocp.overrides",
            "aev_ocp.mpc.scenario",
            "aev_ocp.safety.cases",
            "aev_ocp.study.spec",
            "aev_ocp.study.model",
            "aev_ocp.study.tasks",
            "aev_ocp.study.points",
            "aev_ocp.study.tables",
            "aev_ocp.sumo",
            "aev_ocp.sumo.networks",
            "aev_ocp.sumo.scenario",
            "aev_ocp.ring.scenario",
            "aev_ocp.estimation.scenario",
        ),
    ),
    (
        "outputs",
        (
            "aev_ocp.plots",
            "aev_ocp.ocp.plots",
            "aev_ocp.mpc.plots",
            "aev_ocp.stability.plots",
            "aev_ocp.report",
            "aev_ocp.report_html",
            "aev_ocp.saved",
            "aev_ocp.study.table",
            "aev_ocp.study.seeds",
            "aev_ocp.ring.plots",
            "aev_ocp.safety.plots",
            "aev_ocp.sumo.plots",
        ),
    ),
    (
        "applications",
        (
            "aev_ocp.report_sections",
            "aev_ocp.paper_sections",
            "aev_ocp.claims",
            "aev_ocp.table1_hypotheses",
            "aev_ocp.ocp.run",
            "aev_ocp.ocp.section",
            "aev_ocp.mpc",
            "aev_ocp.mpc.run",
            "aev_ocp.mpc.report",
            "aev_ocp.mpc.cycles",
            "aev_ocp.mpc.cycles_section",
            "aev_ocp.stability.run",
            "aev_ocp.stability.section",
            "aev_ocp.safety.run",
            "aev_ocp.safety.report",
            "aev_ocp.safety.section",
            "aev_ocp.life_section",
            "aev_ocp.study",
            "aev_ocp.study.run",
            "aev_ocp.ring.field",
            "aev_ocp.study.traffic",
            "aev_ocp.study.runner",
            "aev_ocp.study.traffic_study",
            "aev_ocp.study.cluster",
            "aev_ocp.study.report",
            "aev_ocp.ring.run",
            "aev_ocp.ring_section",
            "aev_ocp.sumo.run",
            "aev_ocp.sumo.outputs",
            "aev_ocp.ring.outputs",
            "aev_ocp.safety.outputs",
            "aev_ocp.stability.outputs",
            "aev_ocp.robustness",
            "aev_ocp.validation",
        ),
    ),
    (
        "entry points",
        (
            "aev_ocp",
            "aev_ocp.loading",
            "aev_ocp.console",
            "aev_ocp.reproduce_pool",
            "aev_ocp.reproduce",
            "aev_ocp.cli",
            "aev_ocp.ocp.cli",
            "aev_ocp.mpc.cli",
            "aev_ocp.mpc.export",
            "aev_ocp.stability.cli",
            "aev_ocp.safety.cli",
            "aev_ocp.study.cli",
            "aev_ocp.ring.cli",
            "aev_ocp.sumo.cli",
            "aev_ocp.tuning.core",
            "aev_ocp.tuning.write",
            "aev_ocp.tuning.cycles",
            "aev_ocp.tuning.ring",
            "aev_ocp.tuning.safety",
            "aev_ocp.tuning.cli",
            "aev_ocp.tuning",
        ),
    ),
)


#: Late edges: (importer, imported) -> why. A result's ``.plot()`` imports the module that draws it inside the method,
#: when it is called: the object needs nothing of that module to exist, load or save, so the edge may go up the table
#: (and close a circle with the figure module, which imports the result's type). Only a function-local import may
#: be late; tests/contracts/test_layers.py refuses one at module level, and one that no longer exists.
LATE_EDGES: dict[tuple[str, str], str] = {
    ("aev_ocp.results", "aev_ocp.plots"): "SimulationResult.plot() draws with plot_trajectories",
    ("aev_ocp.ocp_result", "aev_ocp.ocp.plots"): "OCPResult.plot() draws with plot_result",
}


def layer_of(module: str) -> int:
    """Index of ``module``'s layer in :data:`LAYERS` (0 = foundation); KeyError if it is in none."""
    for i, (_name, modules) in enumerate(LAYERS):
        if module in modules:
            return i
    raise KeyError(f"{module} is in no layer of aev_ocp._layers.LAYERS; add it to one")


def markdown_rows() -> list[str]:
    """The table's rows as docs/guide/layers.md writes them (``| # | layer | modules |``)."""
    return [f"| {i} | {name} | " + ", ".join(f"`{m}`" for m in mods) + " |" for i, (name, mods) in enumerate(LAYERS)]


if __name__ == "__main__":  # python -m aev_ocp._layers: the rows to paste into docs/guide/layers.md
    print("\n".join(markdown_rows()))
