"""The map powertrain (aev_ocp.models.powertrain): FASTSim's table at its grid points, linear between them, the
smooth map within its stated tolerance, the regenerative limit on, inside and outside it, the auxiliary load's sign,
the energy balance of the flows, and the paper's η switch untouched."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.models import powertrain as pt
from aev_ocp.params import ParameterError, PowertrainOptions, VehicleParams
from powertrain_oracle import EFFICIENCY, FRACTION, battery_power

MAP = VehicleParams.model3()
P_fn = ca.SX.sym("P")


def _fn(expr_of: object, p: VehicleParams) -> ca.Function:
    return ca.Function("f", [P_fn], [expr_of(P_fn, p)])  # type: ignore[operator]


EXACT = _fn(pt.battery_power_W, MAP)
SMOOTH = _fn(lambda P, p: pt.battery_power_smooth_W(P, p, PowertrainOptions()), MAP)


def test_map_at_fastsim_grid_points_and_linear_between() -> None:
    x = ca.SX.sym("x")
    eta = ca.Function("eta", [x], [pt.motor_efficiency(x)])
    got = np.array([float(eta(xi)) for xi in FRACTION])
    np.testing.assert_allclose(got, EFFICIENCY, rtol=0, atol=1e-12)
    mid = 0.5 * (FRACTION[1:] + FRACTION[:-1])
    np.testing.assert_allclose([float(eta(m)) for m in mid], np.interp(mid, FRACTION, EFFICIENCY), atol=1e-12)
    assert float(eta(1.37)) == pytest.approx(EFFICIENCY[-1], abs=1e-12)  # held beyond the table


@settings(max_examples=60, deadline=None)
@given(x=st.floats(0.0, 1.3))
def test_smooth_map_within_its_stated_tolerance(x: float) -> None:
    w = 300.0 / MAP.motor_power_max_W
    exact = float(pt.motor_efficiency(ca.DM(x)))
    smooth = float(pt.motor_efficiency(ca.DM(x), w))
    assert abs(smooth - exact) <= pt.SMOOTH_MAP_TOLERANCE * w + 1e-15
    assert pt.SMOOTH_MAP_TOLERANCE == pytest.approx(0.55)


@settings(max_examples=80, deadline=None)
@given(P=st.floats(-4.0e5, 4.0e5).filter(lambda v: abs(v) > 6000.0))
def test_smooth_battery_power_near_exact_away_from_the_switch(P: float) -> None:
    # away from P_w = 0 (|P_w| > 20 w) the smooth power differs by the map's smoothing (≤ 0.55 w/P_max in η,
    # i.e. ≤ 1e-3 relative) and the smooth regenerative minimum (≤ w/2)
    e, s = float(EXACT(P)), float(SMOOTH(P))
    assert abs(s - e) <= 1e-3 * abs(e - MAP.aux_power_W) + 150.0


@settings(max_examples=100, deadline=None)
@given(P=st.floats(-5.0e5, 5.0e5))
def test_exact_power_equals_the_numpy_oracle(P: float) -> None:
    for p in (MAP, VehicleParams(), dataclasses.replace(MAP, regen_efficiency=None, regen_power_max_W=4.7e4)):
        assert float(_fn(pt.battery_power_W, p)(P)) == pytest.approx(float(battery_power(P, p)), rel=1e-12, abs=1e-9)


@pytest.mark.parametrize(
    "p", [MAP, VehicleParams(), dataclasses.replace(MAP, regen_power_max_W=3.3e4, regen_efficiency=None)]
)
def test_flows_balance_battery_energy(p: VehicleParams) -> None:
    P = np.linspace(-3.1e5, 2.7e5, 2001)
    f = {k: np.asarray(ca.Function("fl", [P_fn], [v])(P)).ravel() for k, v in pt.powertrain_flows(P_fn, p).items()}
    scale = np.abs(P) + 1.0
    np.testing.assert_allclose((f["P_b"] - (f["traction"] + f["loss"] + f["aux"] - f["regen"])) / scale, 0, atol=1e-12)
    np.testing.assert_allclose((np.maximum(-P, 0) - f["regen"] - f["friction"]) / scale, 0, atol=1e-12)
    assert np.all(f["loss"] >= 0) and np.all(f["friction"] >= 0) and np.all(f["regen"] >= 0)


def test_regenerative_limit_on_inside_outside() -> None:
    lim, et, er = 4.1e4, MAP.transmission_efficiency, MAP.regen_efficiency
    p = dataclasses.replace(MAP, regen_power_max_W=lim)
    f = _fn(pt.battery_power_W, p)
    assert er is not None
    inside = -0.6 * lim / et
    on = -lim / et
    outside = -2.7 * lim / et
    assert float(f(inside)) == pytest.approx(-er * 0.6 * lim + p.aux_power_W, rel=1e-12)
    assert float(f(on)) == pytest.approx(-er * lim + p.aux_power_W, rel=1e-12)
    assert float(f(outside)) == pytest.approx(-er * lim + p.aux_power_W, rel=1e-12)  # the brakes take the rest
    fl = {k: float(ca.Function("fl", [P_fn], [v])(outside)) for k, v in pt.powertrain_flows(P_fn, p).items()}
    assert fl["friction"] == pytest.approx(2.7 * lim / et - lim / et, rel=1e-12)
    assert fl["regen"] == pytest.approx(lim / et, rel=1e-12)


def test_aux_load_discharges() -> None:
    for p in (MAP, dataclasses.replace(VehicleParams(), aux_power_W=317.0)):
        assert float(_fn(pt.battery_power_W, p)(0.0)) == pytest.approx(p.aux_power_W)
        assert float(_fn(pt.battery_power_W, p)(-1234.5)) > -1234.5 + p.aux_power_W  # regen returns less than braking
    assert float(SMOOTH(0.0)) == pytest.approx(MAP.aux_power_W, abs=1.0)


def test_constant_powertrain_is_the_papers_switch() -> None:
    p = VehicleParams()
    assert p.powertrain == "constant"
    f = _fn(pt.battery_power_W, p)
    assert float(f(2345.0)) == 2345.0 / 0.8 and float(f(-2345.0)) == -2345.0 * 0.8
    s = pt.battery_power_smooth_W(P_fn, p)
    ref = P_fn * (0.5 * (1 + ca.tanh(P_fn / 300.0)) / 0.8 + (1 - 0.5 * (1 + ca.tanh(P_fn / 300.0))) * 0.8)
    g = ca.Function("g", [P_fn], [s - ref])
    assert max(abs(float(g(P))) for P in (-5e4, -37.0, 0.0, 41.0, 6e4)) == 0.0


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("powertrain", "fastsim"),
        ("regen_efficiency", 0.0),
        ("regen_power_max_W", -1.0),
        ("rotating_mass_kg", -2.0),
        ("transmission_efficiency", 1.2),
    ],
)
def test_bad_powertrain_fields_named(field: str, value: object) -> None:
    with pytest.raises(ParameterError, match=field):
        VehicleParams(**{field: value})  # type: ignore[arg-type]


def test_smooth_map_is_smooth_for_optimisers() -> None:
    # its derivative exists everywhere (no kink at P_w = 0, at the map's grid points or at the regenerative limit)
    # and equals central finite differences of the smooth power
    dP = ca.Function("dP", [P_fn], [ca.jacobian(pt.battery_power_smooth_W(P_fn, MAP), P_fn)])
    lim_wheel = -MAP.regen_power_max_W / MAP.transmission_efficiency
    pts = [0.0, 37.0, -41.0, 0.04 * MAP.motor_power_max_W * MAP.transmission_efficiency, lim_wheel, 1.9e5, -7.3e4]
    for P in pts:
        h = 1e-3
        fd = (float(SMOOTH(P + h)) - float(SMOOTH(P - h))) / (2 * h)
        d = float(dP(P))
        assert np.isfinite(d) and d == pytest.approx(fd, rel=1e-5, abs=1e-6)
    # while the exact map has a kink at x = 0.06 (its slope goes from 1.0 to 0.5): one-sided slopes of P_b differ
    x6 = 0.06 * MAP.motor_power_max_W * MAP.transmission_efficiency
    left = (float(EXACT(x6)) - float(EXACT(x6 - 10.0))) / 10.0
    right = (float(EXACT(x6 + 10.0)) - float(EXACT(x6))) / 10.0
    assert abs(left - right) > 1e-3
