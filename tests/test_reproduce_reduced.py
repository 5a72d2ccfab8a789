"""reproduce runs its extended studies reduced by default and at full size with --full (issue 40): each section's
workload follows ReproduceConfig.extended, the report's table names both, and --full is one flag away."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import aev_ocp.life_section as life
import aev_ocp.mpc.cycles_section as cyc
import aev_ocp.robustness as rob
import aev_ocp.safety.section as safety
from aev_ocp import cli
from aev_ocp import reproduce as rp
from aev_ocp.report_sections import ReproduceConfig, SectionContext

DEFAULT, FULL, QUICK = ReproduceConfig(), ReproduceConfig.full(), ReproduceConfig.quick()


def _ctx(config: ReproduceConfig, lines: list[str]) -> SectionContext:
    return SectionContext(lines.append, config, [])


def test_full_is_a_full_reproduction_and_quick_is_not() -> None:
    assert DEFAULT.is_full and FULL.is_full and not QUICK.is_full
    assert FULL.extended and not DEFAULT.extended and FULL != DEFAULT


@pytest.mark.parametrize(("argv", "extended"), [([], False), (["--full"], True)])
def test_cli_full_flag_sets_extended(monkeypatch, tmp_path: Path, capsys, argv: list[str], extended: bool) -> None:  # noqa: ANN001
    seen: list[ReproduceConfig] = []

    def fake(out: Any, config: ReproduceConfig, workers: int = 1) -> Path:
        seen.append(config)
        return Path(out) / "report.md"

    monkeypatch.setattr(rp, "reproduce", fake)
    assert cli.main(["reproduce", "--out", str(tmp_path / "r"), *argv]) == 0
    assert seen == [ReproduceConfig(extended=extended)]
    capsys.readouterr()


def test_cli_quick_and_full_exclude_each_other(tmp_path: Path, capsys) -> None:  # noqa: ANN001
    assert cli.main(["reproduce", "--quick", "--full", "--out", str(tmp_path)]) == 2
    assert "--full: not allowed with argument --quick" in capsys.readouterr().err


def test_mpc_cycles_runs_one_forecast_by_default_and_every_one_with_full(monkeypatch, tmp_path: Path) -> None:  # noqa: ANN001
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(cyc, "cycles_section", lambda out, progress, **kw: calls.append(kw) or "md")
    for config in (DEFAULT, FULL, QUICK):
        cyc._reproduce_section(tmp_path, _ctx(config, []))
    default, full, quick = calls
    assert default == {"predictors": ("decaying-acceleration",)} and len(cyc.PREDICTORS) == 2
    assert full == {"predictors": cyc.PREDICTORS}
    # a reduced configuration: UDDS alone beside the platoon, one progress line per line of a cycle left out
    assert quick == {
        "predictors": ("decaying-acceleration",),
        "t_end_max": QUICK.scenario_t_end_max,
        "cycles": ("udds",),
    }
    lines: list[str] = []
    cyc._reproduce_section(tmp_path, _ctx(QUICK, lines))
    assert len(lines) == 3 * 6 == len(cyc.CYCLE_SCENARIOS) * 6 - 6  # hwfet, us06, paper: 6 lines each


def test_battery_life_drops_hwfet_by_default_and_keeps_the_progress_count(monkeypatch, tmp_path: Path) -> None:  # noqa: ANN001
    calls: list[dict[str, Any]] = []
    monkeypatch.setattr(life, "life_section", lambda out, progress, **kw: calls.append(kw) or "md")
    lines: list[str] = []
    life._reproduce_section(tmp_path, _ctx(DEFAULT, lines))
    life._reproduce_section(tmp_path, _ctx(FULL, []))
    assert calls == [{"cycles": ("udds", "us06")}, {}] and life.CYCLES == ("udds", "hwfet", "us06")
    assert len(lines) == len(life.AMBIENTS_K)  # one progress line per left-out run: the counter does not jump


def test_robustness_drops_hwfet_by_default(monkeypatch, tmp_path: Path) -> None:  # noqa: ANN001
    calls: list[tuple[Any, ...]] = []
    kws: list[dict[str, Any]] = []
    monkeypatch.setattr(rob, "run_seeded", lambda out, *a, **kw: calls.append(a) or kws.append(kw) or {})
    monkeypatch.setattr(rob, "seeded_markdown", lambda res: "")
    for config in (DEFAULT, FULL, QUICK):
        rob.robustness_section(tmp_path, _ctx(config, []))
    (c_def, *_), (c_full, *_), (c_quick, *_) = calls
    assert c_def == ("udds", "us06") and c_full == ("udds", "hwfet", "us06") and c_quick == ("udds",)
    assert [c[2] for c in calls] == [(0, 1, 2), (0, 1, 2), (0, 1)]  # seeds
    # the cut [s]: to the leader's next stop after 120 s, at most 150 s; a reduced configuration's smoke run 30 s
    assert [(c[1], c[4]) for c in calls] == [(120.0, 150.0), (120.0, 150.0), (30.0, 30.0)]
    # in the section's own process (reproduce's pool runs the sections side by side): no second pool of workers
    assert kws == [{"executor": "inprocess"}] * 3


def test_the_report_table_names_each_reduced_study_and_its_full_size() -> None:
    default, full = rp.reduced_table(False), rp.reduced_table(True)
    for head, small, big in rp.REDUCED_BY_DEFAULT:
        assert f"| {head} | {small} | {big} |" in default and f"| {head} | {small} | {big} |" in full
    assert "this run: the default column" in default and "this run: `aev-ocp reproduce --full`" in full
    assert "HWFET" not in rp.REDUCED_BY_DEFAULT[1][1] and "HWFET" in rp.REDUCED_BY_DEFAULT[1][2]


def test_safety_quick_subset_runs_the_declared_actuator_alone(monkeypatch, tmp_path: Path) -> None:  # noqa: ANN001
    calls: list[tuple[Any, dict[str, Any]]] = []
    monkeypatch.setattr(safety, "run_suite", lambda cases, **kw: calls.append((cases, kw)) or SimpleNamespace(cases=[]))
    monkeypatch.setattr(safety, "write_outputs", lambda res, out: [])
    monkeypatch.setattr(safety, "markdown", lambda res: "## Safety suite\n")
    for config in (DEFAULT, FULL, QUICK):
        safety.safety_section(tmp_path, _ctx(config, []))
    (c_def, k_def), (c_full, k_full), (c_quick, k_quick) = calls
    assert c_def == c_full == safety.reproduce_cases()
    # a reduced configuration: the first case of each family of the suite's quick subset (3 s long)
    quick = safety.suite_cases(quick=True)
    assert [c.name for c in c_quick] == [
        "CCRs_50kmh",
        "CCRm_80kmh",
        "CCRb_50kmh_12m_-6mps2",
        "laneend_100kmh_60m",
        "cutin_100kmh_lead100kmh_15m_-6mps2",
    ]
    assert all(c in quick for c in c_quick) and {c.family for c in c_quick} == set(safety.FAMILIES)
    assert k_def["actuators"] == k_full["actuators"] == ("ideal", "declared")  # both actuators
    assert k_quick == {"quick": True, "workers": 1, "actuators": ("declared",)} and k_def["quick"] is False


def test_the_ocp_sections_solve_on_fewer_intervals_in_a_reduced_configuration_only() -> None:
    from aev_ocp.ocp import section as ocp

    assert [ocp._intervals(_ctx(c, [])) for c in (DEFAULT, FULL, QUICK)] == [200, 200, 25]
