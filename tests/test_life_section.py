"""The "battery life" report section on a reduced configuration: rows, files, the install line without BLAST-Lite."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from aev_ocp import life_section as ls


def test_life_section_reduced(tmp_path: Path) -> None:
    lines: list[str] = []
    md = ls.life_section(tmp_path, lines.append, segment_s=12.0, years=1.0, cycles=("us06",))
    data = json.loads((tmp_path / "battery_life" / "life.json").read_text())
    rows = data["rows"]
    assert {(r["ambient"], r["controller"]) for r in rows} == {
        (a, c) for a in ("hot", "cold") for c in ("mpc", "proposed", "ovfl")
    }
    for r in rows:
        assert r["status"] == "ok" and r["peak_temperature_K"] >= r["ambient_K"] - 1e-9
        assert r["mean_temperature_K"] <= r["peak_temperature_K"]
        assert "cell" not in r and "depth_of_discharge" not in r  # the default: the scenario's cell, as before
    assert "## Battery life" in md and (tmp_path / "battery_life" / "life.csv").exists()
    if ls.blast_available():
        hot = {r["controller"]: r["capacity_1y"] for r in rows if r["ambient"] == "hot"}
        cold = {r["controller"]: r["capacity_1y"] for r in rows if r["ambient"] == "cold"}
        assert all(hot[c] < cold[c] < 1.0 for c in hot)  # the hot pack ages faster
    else:
        assert ls.INSTALL_HINT in md


def test_section_without_blast_says_how_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ls, "blast_available", lambda: False)
    md = ls.life_section(tmp_path, lambda m: None, segment_s=6.0, years=1.0, cycles=("us06",))
    assert ls.INSTALL_HINT in md and "capacity_1y" not in (tmp_path / "battery_life" / "life.csv").read_text()


def test_life_claims_say_no_measurable_difference_within_the_resolution() -> None:
    rows = [
        {"cycle": "udds", "ambient": "hot", "controller": c, "capacity_10y": q}
        for c, q in (("proposed", 0.91234), ("ovfl", 0.91241), ("mpc", 0.91302))
    ] + [
        {"cycle": "us06", "ambient": "hot", "controller": c, "capacity_10y": q}
        for c, q in (("proposed", 0.905), ("mpc", 0.9081))
    ]
    lines = ls.life_claims(rows, 10.0)
    assert len(lines) == 2
    assert "UDDS, hot" in lines[0] and "no measurable difference" in lines[0]  # spread 6.8e-4 <= 1e-3
    assert "US06, hot" in lines[1] and "differ by 0.31 %" in lines[1]  # spread 3.1e-3 > 1e-3
    assert ls.life_claims(rows[:1], 10.0) == [] and ls.life_claims(rows, 5.0) == []


# ---- per-cell battery life (issue 37 item 5) ----------------------------------------------------------------------
# The two PyBaMM-identified cells of different chemistries, the BLAST-Lite model each must get (stated here by hand,
# from aev_ocp/life.py's documentation), and their packs next to the scenario's 106s70p A123 pack (2.3 Ah, OCV 3.2976 V
# at SOC 0.5): n_parallel = round(70·2.3/Q), n_series = round(106·3.2976/OCV(0.5)).
PER_CELL = {
    "lg_m50": ("NMC", "Nmc811_GrSi_LGMJ1_4Ah_Battery", round(70 * 2.3 / 5.153198326131941), 93),
    "nca_kim2011": ("NCA", "Nca_Gr_Panasonic3Ah_Battery", round(70 * 2.3 / 0.4831330397279993), 95),
}
SEG_S, T_HOT_K = 9.0, 303.65


@pytest.fixture(scope="module")
def per_cell_rows() -> list[dict]:
    return ls.life_rows(("us06",), {"warm": T_HOT_K}, segment_s=SEG_S, years=1.0, cells=tuple(PER_CELL), mpc=False)


def _law_run(cell: str):
    """The proposed law's run of the per-cell scenario, built here independently of life_rows."""
    from aev_ocp.mpc.cycles import cycle_scenario
    from aev_ocp.mpc.cycles_section import section_settings

    chem, _model, n_p, n_s = PER_CELL[cell]
    sc = cycle_scenario("us06", SEG_S).with_overrides(
        {
            "cell.name": cell,
            "pack.n_parallel": n_p,
            "pack.n_series": n_s,
            "thermal.enabled": True,
            "thermal.ambient_K": T_HOT_K,
        }
    )
    return ls._law_runs(sc, section_settings())[("proposed", None)]


def test_per_cell_rows_use_their_own_chemistry_and_pack(per_cell_rows: list[dict]) -> None:
    assert {(r["cell"], r["controller"]) for r in per_cell_rows} == {(c, k) for c in PER_CELL for k in ls.LAWS}
    for r in per_cell_rows:
        chem, model, n_p, n_s = PER_CELL[r["cell"]]
        assert r["status"] == "ok" and r["chemistry"] == chem
        assert (r["n_parallel"], r["n_series"]) == (n_p, n_s)
        if ls.blast_available():
            assert r["model"] == model  # each cell through its own chemistry's BLAST-Lite model
            assert 0.8 < r["capacity_1y"] < 1.0
    if ls.blast_available():  # NMC and NCA age differently on the same drive
        by = {(r["cell"], r["controller"]): r["capacity_1y"] for r in per_cell_rows}
        assert abs(by[("lg_m50", "proposed")] - by[("nca_kim2011", "proposed")]) > 1e-4
    assert ls.real_cells() == ("a123_prada2013", "lg_m50", "nca_kim2011")


def test_per_cell_throughput_and_depth_of_discharge_by_hand(per_cell_rows: list[dict]) -> None:
    from scipy.integrate import trapezoid

    from aev_ocp.life import DailySchedule

    for cell in PER_CELL:
        r = _law_run(cell)
        row = next(x for x in per_cell_rows if x["cell"] == cell and x["controller"] == "proposed")
        t_s = np.asarray(r.t, float) * r.units.time_s
        I_A, S = np.asarray(r.current_A[:, 0], float), np.asarray(r.S[:, 0], float)
        n_p, Q = PER_CELL[cell][2], r.ev.cell.capacity_Ah
        hand_Ah = trapezoid(np.abs(I_A), t_s) * n_p / 3600.0
        assert row["charge_throughput_Ah"] == pytest.approx(hand_Ah, rel=1e-9)
        # coulomb counting: the net charge drawn equals the SOC drop × capacity (pack); 1 %: the trapezoid of the
        # sampled current against the integrated SOC (0.35 % apart on these 9 s from rest)
        assert trapezoid(I_A, t_s) * n_p / 3600.0 == pytest.approx((S[0] - S[-1]) * Q * n_p, rel=1e-2)
        assert hand_Ah >= (S[0] - S[-1]) * Q * n_p * (1 - 1e-2) > 0
        # depth of discharge of the default day (2 trips): (n − 1)·d + S_max − S_min, up to the 1 s resampling
        n_trips, d = len(DailySchedule().trip_start_h), S[0] - S[-1]
        hand_dod = (n_trips - 1) * d + S.max() - S.min()
        slope = np.max(np.abs(np.diff(S) / np.diff(t_s)))  # [1/s]
        assert row["depth_of_discharge"] == pytest.approx(hand_dod, abs=2 * slope * 1.0)
        assert row["depth_of_discharge"] > 0


class _Run:
    """A stand-in for a SimulationResult with the fields depth_of_discharge reads (time in seconds)."""

    def __init__(self, t_s: np.ndarray, soc: np.ndarray) -> None:
        from types import SimpleNamespace

        self.t, self.S = t_s, soc[:, None]
        self.ev = SimpleNamespace(
            units=SimpleNamespace(time_to_si=lambda t: t), thermal=SimpleNamespace(ambient_K=297.4)
        )


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.floats(-4e-4, 6e-4), min_size=3, max_size=400),
    s0=st.floats(0.35, 0.93),
    trips=st.sampled_from([(8.0,), (7.5, 17.25), (6.0, 12.5, 18.75)]),
)
def test_depth_of_discharge_is_the_days_swing(steps: list[float], s0: float, trips: tuple[float, ...]) -> None:
    """On a 1 s grid (no resampling error) the day's SOC swing is exactly (n − 1)·d + S_max − S_min."""
    from aev_ocp.life import DailySchedule

    soc = s0 - np.concatenate([[0.0], np.cumsum(steps)])
    assume(soc[-1] <= soc[0])  # a drive that uses charge (d >= 0), as the schedule's charging needs
    t_s = np.arange(soc.size, dtype=float)
    dod = ls.depth_of_discharge(_Run(t_s, soc), 0, DailySchedule(trip_start_h=trips, sample_s=1.0))
    hand = (len(trips) - 1) * (soc[0] - soc[-1]) + soc.max() - soc.min()
    assert dod == pytest.approx(hand, abs=1e-12)


def test_per_cell_claims_on_inside_and_outside_the_resolution() -> None:
    res = ls.CAPACITY_RESOLUTION
    assert res == 1e-3
    q = 0.9137
    cases = {  # cell → capacity of the two controllers
        "lg_m50": (q, q + 0.37 * res),  # inside
        "a123_prada2013": (q, math.nextafter(q + res, 0.0)),  # on: spread 1e-3 (to the float below)
        "nca_kim2011": (q, q + res),  # just outside: q + 1e-3 − q is 1e-3 plus one rounding step
    }
    rows = [
        {
            "cell": cell,
            "chemistry": {"lg_m50": "NMC", "a123_prada2013": "LFP", "nca_kim2011": "NCA"}[cell],
            "cycle": "us06",
            "ambient": "hot",
            "controller": ctrl,
            "capacity_10y": cap,
            "charge_throughput_Ah": thr,
            "depth_of_discharge": dod,
        }
        for cell, caps in cases.items()
        for ctrl, cap, thr, dod in zip(("proposed", "ovfl"), caps, (1.234, 1.567), (0.0123, 0.0145))
    ]
    lines = ls.life_claims(rows, 10.0)
    assert len(lines) == 3
    # exactly on: near capacity 0.91 no two floats are 1e-3 apart, so the rule's boundary is checked where they are
    exact = [dict(rows[0], controller=c, capacity_10y=v) for c, v in (("proposed", 2**-12), ("ovfl", 2**-12 + res))]
    assert exact[1]["capacity_10y"] - exact[0]["capacity_10y"] == res
    assert "no measurable difference" in ls.life_claims(exact, 10.0)[0]
    assert lines[0].startswith("- lg_m50 (NMC), US06, hot:") and "no measurable difference" in lines[0]
    assert lines[1].startswith("- a123_prada2013 (LFP), US06, hot:") and "no measurable difference" in lines[1]
    assert lines[2].startswith("- nca_kim2011 (NCA), US06, hot:") and "differ by 0.1 %" in lines[2]
    for line in lines:
        assert "proposed: 1.234 Ah, DoD 0.0123" in line and "ovfl: 1.567 Ah, DoD 0.0145" in line


def test_cells_argument_checks() -> None:
    from aev_ocp.params import ParameterError

    with pytest.raises(ParameterError, match="no_such_cell"):
        ls.life_rows(("us06",), segment_s=3.0, cells=("no_such_cell",), mpc=False)
    with pytest.raises(ParameterError, match="cells = \\[\\]"):
        ls.life_rows(("us06",), segment_s=3.0, cells=(), mpc=False)


def test_life_claims_use_the_intervals_of_the_capacity_difference() -> None:
    """aev_ocp.intervals decides: one capacity per controller is known to ± resolution/2, so a − b ± resolution;
    capacities over seeds give the paired t interval of a − b widened by the resolution. Overlapping intervals:
    'no measurable difference'; apart: the spread."""
    res = ls.CAPACITY_RESOLUTION
    d = ls.capacity_difference([0.9123], [0.9141])
    assert (d.mean, d.n, d.method) == (pytest.approx(-0.0018), 1, "resolution")
    assert (d.lo, d.hi) == (pytest.approx(-0.0018 - res), pytest.approx(-0.0018 + res)) and d.excludes_zero()
    assert not ls.capacity_difference([0.9123], [0.9128]).excludes_zero()
    # over 4 seeds: b is a shifted by 0.0007 (inside the resolution) or 0.0031 (outside), with a seed-to-seed scatter
    a = [0.9101, 0.9113, 0.9096, 0.9108]
    near = [x + 0.0007 + e for x, e in zip(a, (1e-5, -2e-5, 3e-5, 0.0))]
    far = [x + 0.0031 + e for x, e in zip(a, (1e-5, -2e-5, 3e-5, 0.0))]
    dn, df = ls.capacity_difference(a, near), ls.capacity_difference(a, far)
    assert dn.n == 4 and dn.method == "t+resolution" and dn.lo < -0.0007 - res < dn.hi - 2 * res
    assert not dn.excludes_zero() and df.excludes_zero()
    rows = [
        {"cycle": "hwfet", "ambient": "cold", "controller": c, "capacity_10y": q, "seed": k}
        for c, vals in (("proposed", a), ("mpc", near))
        for k, q in enumerate(vals)
    ]
    assert "no measurable difference" in ls.life_claims(rows, 10.0)[0]
    rows_far = [dict(r, capacity_10y=far[r["seed"]]) if r["controller"] == "mpc" else r for r in rows]
    assert "differ by 0.31 %" in ls.life_claims(rows_far, 10.0)[0]
    with pytest.raises(ls.ParameterError, match="one capacity per controller"):
        ls.capacity_difference([0.91, 0.92], [0.93])


def test_life_claims_need_every_two_controllers_to_overlap() -> None:
    """Three controllers: a chain whose neighbours overlap but whose ends do not is a measurable difference; one
    pair apart is enough."""

    def rows(caps):
        return [{"cycle": "us06", "ambient": "cold", "controller": c, "capacity_10y": q} for c, q in caps.items()]

    chain = {"proposed": 0.9100, "ovfl": 0.9108, "mpc": 0.9116}  # 8e-4 apart each, 1.6e-3 end to end
    assert "differ by 0.16 %" in ls.life_claims(rows(chain), 10.0)[0]
    one_apart = {"proposed": 0.9100, "ovfl": 0.9105, "mpc": 0.9125}
    assert "differ by 0.25 %" in ls.life_claims(rows(one_apart), 10.0)[0]
    close = {"proposed": 0.9100, "ovfl": 0.9105, "mpc": 0.9103}
    assert "no measurable difference" in ls.life_claims(rows(close), 10.0)[0]
