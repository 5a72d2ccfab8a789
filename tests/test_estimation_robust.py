"""Issue 25's estimator target under model mismatch: SOC error below 1 % after 60 s from a 10 % initial error, for
seeded random draws of the declared mismatch set (±10 % mass, ±20 % R0, R1, R2, C1, C2 and capacity, a small OCV
offset), on UDDS, US06 and HWFET segments, with production sensor noise and 0.1 s delays, the thermal plant on in
one case.

Checked against the plant's true SOC (the CVODES plant, independent of the filter), the OCV curve's slope (a
closed form for what an OCV offset does), and the declared errors (the learnt scales).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from aev_ocp.control import ClosedLoop
from aev_ocp.estimation import EKF, MHE, Mismatch, Sensors
from aev_ocp.models import battery
from aev_ocp.mpc.cycles import cycle_scenario
from aev_ocp.params import EVParams, ParameterError, ThermalParams

SEGMENT_S = 90.0  # the SOC error is checked over 60-90 s
CELL_ERRORS = ("R0_rel", "R1_rel", "R2_rel", "C1_rel", "C2_rel", "capacity_rel")
CELL_BOUND, MASS_BOUND = 0.2, 0.1  # the declared mismatch: ±20 % on the cell's parameters, ±10 % on the mass
#: the OCV offset of the draws [V per cell]: at S = 0.8 the shipped LFP cell's OCV rises 0.49 mV per % SOC, so an
#: offset δ costs δ/OCV'(S) ≈ 2 % SOC per mV; with the other errors' ≲ 0.6 % the target holds for |δ| ≲ 0.2 mV
OCV_BOUND_V = 1e-4
N_DRAWS = 4  # per cycle


def draws(n: int, seed: int) -> list[dict[str, float]]:
    """``n`` mismatches (Mismatch keyword arguments) with every parameter drawn in both directions: for each one
    half the draws are positive, half negative (a seeded permutation), the magnitude uniform in [0.3, 1] × its
    bound (no draw near zero, none exactly at the bound)."""
    rng = np.random.default_rng(seed)
    bounds = {**{k: CELL_BOUND for k in CELL_ERRORS}, "mass_rel": MASS_BOUND, "ocv_offset_V": OCV_BOUND_V}
    signs = {k: rng.permutation([1.0] * (n // 2) + [-1.0] * (n - n // 2)) for k in bounds}
    return [{k: float(signs[k][i] * rng.uniform(0.3, 1.0) * b) for k, b in bounds.items()} for i in range(n)]


def _run(
    cycle: str,
    mm: Mismatch | None,
    soc_guess: float,
    seed: int,
    law: str = "proposed",
    ev: EVParams | None = None,
    estimator: type = EKF,
    segment_s: float = SEGMENT_S,
) -> tuple[Any, list[Any]]:
    sc = cycle_scenario(cycle, segment_s)
    made: list[Any] = []

    def factory(model_ev: EVParams, s: Sensors, off: float, i: int) -> Any:
        made.append(estimator(model_ev, s, soc0=soc_guess, ocv_offset_V=off))
        return made[-1]

    r = ClosedLoop(
        sc.leader, [sc.law(law)], ev or sc.ev, sensors=Sensors(seed=seed), mismatch=mm, estimator=factory, law_dt=0.2
    ).run(sc.gaps0, sc.speeds0, sc.t_end)
    return r, made


def test_draws_cover_both_directions_within_the_bounds() -> None:
    ds = draws(N_DRAWS, 5)
    for k in (*CELL_ERRORS, "mass_rel", "ocv_offset_V"):
        v = np.array([d[k] for d in ds])
        b = {"mass_rel": MASS_BOUND, "ocv_offset_V": OCV_BOUND_V}.get(k, CELL_BOUND)
        assert (v > 0).sum() == (v < 0).sum() == N_DRAWS // 2
        assert np.all(np.abs(v) >= 0.3 * b) and np.all(np.abs(v) < b)


@pytest.mark.parametrize("cycle, seed", [("udds", 11), ("us06", 12), ("hwfet", 13)])
def test_soc_error_below_one_percent_after_60_s_for_drawn_mismatches(cycle: str, seed: int) -> None:
    """Every draw: the estimator starts 10 % off (alternately above and below the true 0.8), the laws drive
    (alternately the proposed law and OVFL, sampled on the noisy, late measurements), and from 60 s on the EKF's
    SOC is within 1 % of the plant's, and its R0 and R1 scales are the plant's ratios. HWFET's first draw runs the thermal plant with temperature-dependent
    resistances (E_a = 24 kJ/mol: −3 %/K at 25 °C; a warm pack at 27 °C, so the plant's resistances are a further
    ~6 % below the model's and drift as it cools)."""
    for i, d in enumerate(draws(N_DRAWS, seed)):
        guess = 0.7 if i % 2 else 0.9
        sc = cycle_scenario(cycle, SEGMENT_S)
        ev = sc.ev
        if cycle == "hwfet" and i == 0:
            ev = dataclasses.replace(
                ev,
                thermal=ThermalParams(enabled=True, T0_K=300.15),
                cell=dataclasses.replace(ev.cell, activation_energy_Jpmol=2.4e4),
            )
        r, made = _run(cycle, Mismatch(**d), guess, 100 + i, "proposed" if i % 3 else "ovfl", ev)
        est = r.solver_stats[0]["estimation"]
        assert r.status == "ok"
        assert r.meta["estimators"][0]["soc0"] == guess and abs(r.S[0, 0] - guess) == pytest.approx(0.1)
        if ev.thermal.enabled:
            assert np.ptp(r.temperature_K[:, 0]) > 0.0
        assert est["soc_err_max_after_60s_pct"] < 1.0, (cycle, i, d, est)
        x = made[0].x
        assert np.all(x[7:] > 0.5) and np.all(x[7:] < 2.0)  # the scales stay physical
        # R0 and R1 are observable within the run: the scales reach the plant's ratios (at its final temperature)
        f = battery.arrhenius_factor(float(r.temperature_K[-1, 0]), ev.cell) if ev.thermal.enabled else 1.0
        assert x[7] == pytest.approx(f / (1 + d["R0_rel"]), abs=0.03), (cycle, i, d)
        assert x[8] == pytest.approx(f / (1 + d["R1_rel"]), abs=0.08), (cycle, i, d)


@pytest.mark.parametrize("true_soc", [0.35, 0.55])
def test_soc_error_below_one_percent_elsewhere_on_the_plateau(true_soc: float) -> None:
    """The same target away from the test's S = 0.8: at 0.55 (the flattest part of the LFP plateau, 2.9 % SOC per
    mV) and 0.35, four fresh draws on US06, the estimator starting 10 % above or below."""
    for i, d in enumerate(draws(N_DRAWS, 31)):
        sc = cycle_scenario("us06", SEGMENT_S)
        ev = dataclasses.replace(sc.ev, cell=dataclasses.replace(sc.ev.cell, soc0=true_soc))
        guess = true_soc - 0.1 if i % 2 else true_soc + 0.1
        r, _ = _run("us06", Mismatch(**d), guess, 300 + i, "proposed", ev)
        assert r.status == "ok" and r.S[0, 0] == pytest.approx(true_soc)
        assert r.solver_stats[0]["estimation"]["soc_err_max_after_60s_pct"] < 1.0, (true_soc, i, d)


def test_the_ekf_learns_the_plants_resistances() -> None:
    """Fixed errors R0 −13 %, R1 +17 % (model against plant): on 90 s of US06 the EKF's scales converge to the
    plant's ratios 1/0.87 and 1/1.17, and the SOC stays within 1 %."""
    r, made = _run("us06", Mismatch(R0_rel=-0.13, R1_rel=0.17), 0.7, 4, "ovfl")
    x = made[0].x
    assert x[7] == pytest.approx(1 / 0.87, abs=0.02)
    assert x[8] == pytest.approx(1 / 1.17, abs=0.03)
    assert r.solver_stats[0]["estimation"]["soc_err_max_after_60s_pct"] < 1.0


def test_an_ocv_offset_becomes_an_soc_error_of_offset_over_slope() -> None:
    """On the flat plateau an OCV offset δ of the model is not observable: the SOC estimate moves by −δ/OCV'(S)
    (the model reads OCV(Ŝ) + δ = OCV(S)), with OCV'(S) from the cell's spline at the true SOC. Checked for
    δ = +0.37 mV and −0.29 mV against the same run without an offset (same noise)."""
    r0, _ = _run("udds", None, 0.9, 3, segment_s=60.0)
    e0 = r0.solver_stats[0]["estimation"]["soc_err_final_pct"]
    s_true = float(r0.S[-1, 0])
    ocv = battery.ocv_function(r0.ev.cell)
    slope_V = (float(ocv(s_true + 1e-3)) - float(ocv(s_true - 1e-3))) / 2e-3  # [V per unit SOC]
    for delta_V in (3.7e-4, -2.9e-4):
        r, _ = _run("udds", Mismatch(ocv_offset_V=delta_V), 0.9, 3, segment_s=60.0)
        shift_pct = r.solver_stats[0]["estimation"]["soc_err_final_pct"] - e0
        assert shift_pct == pytest.approx(-100 * delta_V / slope_V, rel=0.15)


def test_mhe_with_mismatch_holds_the_soc_and_solves_every_window() -> None:
    """The MHE (the EKF's learnt scales held over its window) under R1 +18 % and C2 −16 %: every window solves and
    the SOC is within 1 % from 60 s on."""
    r, made = _run("hwfet", Mismatch(R1_rel=0.18, C2_rel=-0.16), 0.7, 2, "ovfl", estimator=MHE, segment_s=66.0)
    assert made[0].fails == 0 and r.meta["estimators"][0]["parameters"].startswith("the EKF's scales")
    assert r.solver_stats[0]["estimation"]["soc_err_max_after_60s_pct"] < 1.0


class _NaNAfter:
    """A wrapped EKF whose estimate turns NaN in ``field`` from its ``k``-th update on (or returns None)."""

    def __init__(self, inner: Any, field: str, k: int) -> None:
        self.inner, self.field, self.k, self.n = inner, field, k, 0
        self.name = "nan_after"

    def reset(self, first: Any) -> Any:
        return self.inner.reset(first)

    def update(self, y: Any) -> Any:
        self.n += 1
        e = self.inner.update(y)
        if self.n < self.k:
            return e
        return None if self.field == "none" else dataclasses.replace(e, **{self.field: float("nan")})

    def describe(self) -> dict[str, Any]:
        return {"name": self.name}


@pytest.mark.parametrize("field", ["gap_m", "lead_speed_mps"])
def test_a_nan_estimate_stops_the_run_with_an_event_not_full_braking(field: str) -> None:
    """A NaN gap estimate used to become a NaN law command and that full braking (status ok); now the run stops at
    the first NaN with an 'estimation_failed' event naming the vehicle and the field."""
    sc = cycle_scenario("udds", 30.0)
    law = sc.law("proposed")

    def factory(model_ev: EVParams, s: Sensors, off: float, i: int) -> Any:
        return _NaNAfter(EKF(model_ev, s, soc0=0.7, ocv_offset_V=off), field, 37)

    r = ClosedLoop(sc.leader, [law], sc.ev, sensors=Sensors(seed=3), estimator=factory, law_dt=0.2).run(
        sc.gaps0, sc.speeds0, sc.t_end
    )
    assert r.status == "estimation_failed"
    ev = r.events[0]
    assert ev.vehicle == 0 and f"Estimate.{field}" in ev.message and "nan_after" in ev.message
    assert ev.time == pytest.approx(37 * 0.2, abs=1e-9)  # the 37th update, law_dt = 0.2 [model]
    # nothing acted on the NaN: the applied accelerations stay finite and well above full braking until then
    assert np.all(np.isfinite(r.accel)) and r.t[-1] <= ev.time + 1e-9


def test_an_estimator_returning_none_is_refused_by_name() -> None:
    sc = cycle_scenario("udds", 30.0)

    def factory(model_ev: EVParams, s: Sensors, off: float, i: int) -> Any:
        return _NaNAfter(EKF(model_ev, s, soc0=0.7, ocv_offset_V=off), "none", 5)

    loop = ClosedLoop(sc.leader, [sc.law("ovfl")], sc.ev, sensors=Sensors(seed=3), estimator=factory, law_dt=0.2)
    with pytest.raises(ParameterError, match="estimator 'nan_after' of vehicle 1 returned NoneType"):
        loop.run(sc.gaps0, sc.speeds0, sc.t_end)
