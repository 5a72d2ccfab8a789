"""OCP-D on drive cycles (issue 8 item 5): the mapped (MX) NLP gives the expanded (SX) one's optimum,
the grid rule, progress lines while IPOPT iterates, and a clear status at the time limit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aev_ocp.ocp.run import run_oracle
from aev_ocp.ocp.cli import cli_ocp
from aev_ocp.ocp.oracle import (
    COARSE_GRID_S,
    ORACLE_MAX_INTERVALS,
    OracleSolver,
    canonical_scenario,
    drive_cycle_scenario,
    oracle_grid_dt,
)
from aev_ocp.params import ParameterError, Units


@pytest.fixture(scope="module")
def short_scn():
    """The canonical scenario cut to t ∈ [0, 6.5] (65 intervals)."""
    return dataclasses.replace(canonical_scenario(), t_end=6.5)


def test_mapped_nlp_has_the_expanded_optimum_on_a_cycle_segment() -> None:
    # first 40 s of UDDS on the 1 s grid: the MX map (default) and the SX expansion are two builds of one NLP
    scn = drive_cycle_scenario("udds", duration_s=40.0, speed_unit_mps=17.0, h0=0.8)
    a = OracleSolver(scn).solve()
    b = OracleSolver(scn, mx_map=False).solve()
    assert a.success and b.success
    assert a.objective == pytest.approx(b.objective, rel=1e-7)
    assert np.max(np.abs(a.controls["a"] - b.controls["a"])) < 1e-4


def test_no_crawl_on_a_cycle_segment() -> None:
    # first 90 s of UDDS: with IPOPT's second-order corrections the iterates crawl (167 iterations, the
    # dual infeasibility stuck at 0.4); without them (the OCP-D setting) the same optimum in ~23
    scn = drive_cycle_scenario("udds", duration_s=90.0, speed_unit_mps=17.0, h0=0.8)
    res = OracleSolver(scn).solve()
    assert res.status == "optimal" and res.iterations < 60
    assert res.objective == pytest.approx(1.5780617509, rel=1e-8)  # the optimum both settings reach


def test_progress_reports_every_iteration(short_scn) -> None:
    lines: list[str] = []
    s = OracleSolver(short_scn, progress=lines.append, progress_every_s=0.0)
    res = s.solve()
    rec = s.progress_lines
    assert res.success and res.iterations > 3
    # IPOPT calls back at the initial point and after each iteration: 0 … iter_count
    assert [r["iteration"] for r in rec] == list(range(res.iterations + 1))
    assert rec[-1]["objective"] == pytest.approx(res.objective, rel=1e-12)
    assert rec[-1]["infeasibility"] <= 1e-6 < rec[0]["infeasibility"]  # the guess is not feasible, the optimum is
    assert all(b["elapsed_s"] >= a["elapsed_s"] for a, b in zip(rec, rec[1:]))
    it_lines = [ln for ln in lines if ln.startswith("OCP-D: iteration ")]
    assert len(it_lines) == res.iterations + 1 and f"/ {s.solver.options.max_iter}" in it_lines[-1]
    assert lines[-1].startswith(f"OCP-D: optimal after {res.iterations} iterations")
    # a second solve restarts the count
    s.solve()
    assert s.progress_lines[0]["iteration"] == 0


def test_progress_is_throttled(short_scn) -> None:
    lines: list[str] = []
    res = OracleSolver(short_scn, progress=lines.append, progress_every_s=1e3).solve()
    assert res.success and sum(ln.startswith("OCP-D: iteration") for ln in lines) == 1  # iteration 0 only


def test_time_limit_stops_with_a_clear_status(short_scn) -> None:
    res = OracleSolver(short_scn, time_limit_s=1e-4).solve()
    assert res.status == "time_limit" and not res.success
    assert res.message == (
        f"OCP-D stopped at the time limit of 0.0001 s after {res.iterations} iterations; "
        "the last iterate is not optimal"
    )
    assert res.message in res.warnings and "cost_terms" not in res.meta
    with pytest.raises(ParameterError, match="time limit"):
        OracleSolver(short_scn, time_limit_s=-2.0)


def test_run_oracle_at_the_time_limit_reports_no_bound() -> None:
    rep = run_oracle(time_limit_s=1e-4)
    assert not rep["ok"] and rep["result"].status == "time_limit"
    assert "no lower bound: OCP-D stopped at the time limit of 0.0001 s" in rep["table"]
    assert "lower bound Σℓ·dt =" not in rep["table"]


def test_cli_time_limit(capsys) -> None:
    assert cli_ocp(["oracle", "--time-limit", "-3"]) == 2
    assert "--time-limit" in capsys.readouterr().err
    assert cli_ocp(["prop31", "--time-limit", "30"]) == 2
    assert "applies to current-profile, eco-trip and oracle" in capsys.readouterr().err


def test_grid_rule() -> None:
    u = Units(15.0, 17.0)
    assert oracle_grid_dt(70.0, 0.1, u) == pytest.approx(0.1)  # N = 700: the caller's grid
    t_end = 1551.533333  # whole UDDS: 15 515 intervals of 0.1 -> the 1 s grid
    dt = oracle_grid_dt(t_end, 0.1, u)
    n = t_end / dt
    assert abs(n - round(n)) < 1e-9 and round(n) == 1369
    assert dt * u.time_s == pytest.approx(COARSE_GRID_S, rel=1e-3)
    assert round(1e6 / oracle_grid_dt(1e6, 0.1, u)) == ORACLE_MAX_INTERVALS  # even 1 s is too fine
    with pytest.raises(ParameterError, match="t_end"):
        oracle_grid_dt(-1.0, 0.1, u)


def test_docs_quote_the_ocpd_grid_threshold() -> None:
    # the guides said OCP-D inside `aev-ocp mpc` switches to the 1 s grid above 2000 intervals; the code's threshold
    # is ORACLE_BOUND_MAX_INTERVALS: every guide that names a threshold quotes that one, and no other
    import re
    from pathlib import Path

    from aev_ocp.ocp.oracle import ORACLE_BOUND_MAX_INTERVALS

    quoted = f"{ORACLE_BOUND_MAX_INTERVALS:,}".replace(",", " ")  # 20 000: the guides' thousands separator
    guides = Path(__file__).resolve().parents[1] / "docs" / "guide"
    for name in ("mpc.md", "ocp.md", "extending.md"):
        text = " ".join((guides / name).read_text().split())
        assert f"{quoted} intervals (`ORACLE_BOUND_MAX_INTERVALS`" in text, name
        for m in re.finditer(r"more than ([\d ]+?) intervals", text):
            assert m.group(1).strip() == quoted, (name, m.group(0))
