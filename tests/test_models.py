"""Model-level checks against hand computations, closed forms and random inputs."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.models import (
    OVFL,
    OVM,
    Proposed,
    battery,
    equilibrium_gap,
    make_law,
    optimal_velocity,
    powertrain,
    vehicle,
)
from aev_ocp.models.energy import g_exact, g_smooth
from aev_ocp.models.leader import PaperLeader, SpeedTrace, drive_cycle, load_cycle_si
from aev_ocp.params import (
    CarFollowingParams,
    CellParams,
    EVParams,
    PackParams,
    ParameterError,
    PowertrainOptions,
    Units,
    VehicleParams,
)

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)


def test_laws_by_hand() -> None:
    h, v, vl = 1.0, 1.0, 1.5
    V = math.tanh(-1.0) + math.tanh(2.0)
    assert float(OVM().accel(h, v, vl)) == pytest.approx(2 * (V - 1))
    assert float(OVFL().accel(h, v, vl)) == pytest.approx(2 * (V - 1) + 3 * 0.5 / 1.0)
    term = -0.03 * 1.0 * 0.25 / (0.25 + 1e-6)
    assert float(Proposed().accel(h, v, vl)) == pytest.approx(2 * (V - 1) + 1.5 + term)
    assert float(Proposed().function(h, v, vl)) == pytest.approx(float(Proposed().accel(h, v, vl)))


def test_make_law_and_unknown() -> None:
    law = make_law("proposed", CarFollowingParams(kappa=0.1))
    assert isinstance(law, Proposed) and law.kappa == 0.1
    with pytest.raises(ParameterError, match="unknown car-following law 'foo'"):
        make_law("foo")


@given(st.floats(min_value=math.tanh(2) - 0.999, max_value=1 + math.tanh(2) - 1e-3))
def test_equilibrium_gap_inverts_V(v: float) -> None:
    assert float(optimal_velocity(equilibrium_gap(v))) == pytest.approx(v, abs=1e-9)


def test_equilibrium_gap_out_of_range() -> None:
    with pytest.raises(ParameterError, match="outside the range"):
        equilibrium_gap(2.5)


@pytest.mark.parametrize("vbar", [0.3, 1.0, 1.7])
def test_jacobians_equal_at_equilibrium(vbar: float) -> None:
    """Paper §6: the proposed model linearises to OVFL at (V⁻¹(v̄), v̄, v̄)."""
    x = ca.SX.sym("x", 3)
    point = [equilibrium_gap(vbar), vbar, vbar]
    J = [
        ca.Function("J", [x], [ca.jacobian(law.accel(x[0], x[1], x[2]), x)])(point).full()
        for law in (OVFL(), Proposed())
    ]
    np.testing.assert_allclose(J[0], J[1], rtol=0, atol=1e-12)
    # and both vanish: the equilibrium is one
    assert float(Proposed().accel(*point)) == pytest.approx(0.0, abs=1e-12)


def test_proposed_never_accelerates_more_than_ovfl() -> None:
    rng = np.random.default_rng(0)
    h, v, vl = rng.uniform(0.1, 10, 1000), rng.uniform(0, 2, 1000), rng.uniform(0, 2, 1000)
    a1 = np.asarray(ca.DM(Proposed().function.map(1000)(h, v, vl))).ravel()
    a2 = np.asarray(ca.DM(OVFL().function.map(1000)(h, v, vl))).ravel()
    assert np.all(a1 <= a2 + 1e-15)


def test_paper_leader_consistency() -> None:
    L = PaperLeader()
    t = np.linspace(0.01, 69.9, 400)
    dt = 1e-5
    v_fd = (L.position(t + dt) - L.position(t - dt)) / (2 * dt)
    np.testing.assert_allclose(v_fd, L.speed_np(t), atol=1e-6)
    a_fd = (L.speed_np(t + dt) - L.speed_np(t - dt)) / (2 * dt)
    a = np.array([float(L.accel(tt)) for tt in t])
    mask = np.abs(t - 20) > 1e-3
    np.testing.assert_allclose(a_fd[mask], a[mask], atol=1e-5)
    assert float(L.speed(20.0)) == pytest.approx(1.7, abs=1e-12)  # the leader returns to 1.7 at t = 20
    assert L.breakpoints == (20.0,)


def test_max_speed_is_the_closed_forms_grid_maximum_once_per_leader_and_horizon(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """LeaderProfile.max_speed against the paper leader's closed form v0 − c((1 − cos w1 t)/w1 + sin(w2 t)/w2) on the
    same grid (numpy), computed once per process for equal leaders and horizons: an equal leader built again and the
    same horizon reuse it, another horizon, amplitude or type computes its own."""
    from aev_ocp.models import leader as leader_mod
    from aev_ocp.stability.perturbation import PerturbedLeader

    monkeypatch.setattr(leader_mod, "_MAX_SPEEDS", {})
    computed: list[float] = []
    real = leader_mod.LeaderProfile._max_speed

    def counted(self, t_end, n):  # noqa: ANN001, ANN202
        computed.append(t_end)
        return real(self, t_end, n)

    monkeypatch.setattr(leader_mod.LeaderProfile, "_max_speed", counted)

    def closed_form(ld: PaperLeader, t_end: float, n: int = 20001) -> float:
        t = np.minimum(np.linspace(0.0, t_end, n), ld.t_end)
        c = ld.amplitude
        return float(np.max(ld.v0 - c * ((1 - np.cos(ld.w1 * t)) / ld.w1 + np.sin(ld.w2 * t) / ld.w2)))

    a = PaperLeader(v0=1.63, amplitude=1.17)
    assert a.max_speed(3.7) == pytest.approx(closed_form(a, 3.7), abs=1e-13) and computed == [3.7]
    assert PaperLeader(v0=1.63, amplitude=1.17).max_speed(3.7) == a.max_speed(3.7) and computed == [3.7]
    b = PaperLeader(v0=1.63, amplitude=0.83, t_end=2.9)
    assert b.max_speed(3.7) == pytest.approx(closed_form(b, 3.7), abs=1e-13) and computed == [3.7, 3.7]
    # another type, and another horizon: v* + A sin(ω t) peaks at t = π/(2ω) = 1.745, after 0.31 and before 3.7
    p = PerturbedLeader(v_star=1.63, amplitude=0.21, omega=0.9)
    assert p.max_speed(0.31) == pytest.approx(1.63 + 0.21 * math.sin(0.9 * 0.31), abs=1e-12)
    assert p.max_speed(3.7) == pytest.approx(1.63 + 0.21, abs=1e-9)
    assert p.max_speed(0.31) < p.max_speed(3.7) and computed == [3.7, 3.7, 0.31, 3.7]


def test_cycle_distance_matches_provenance() -> None:
    """aev_ocp/data/README.md: UDDS 11.99 km, HWFET 16.51 km, US06 12.89 km."""
    u = Units()
    for name, km in (("udds", 11.99), ("hwfet", 16.51), ("us06", 12.89)):
        tr = drive_cycle(name, u)
        d_m = u.length_to_si(float(tr.position(tr.times[-1])))
        assert d_m / 1000 == pytest.approx(km, abs=0.01)
        t_s, v_mps = load_cycle_si(name)
        np.testing.assert_allclose(tr.speed_np(u.time_from_si(t_s)), u.speed_from_si(v_mps), atol=1e-12)


def test_speed_trace_validation() -> None:
    with pytest.raises(ParameterError, match="negative"):
        SpeedTrace((0.0, 1.0), (1.0, -0.5))
    with pytest.raises(ParameterError, match="increase"):
        SpeedTrace((0.0, 0.0), (1.0, 1.0))


def test_road_load_by_hand() -> None:
    p = VehicleParams()
    v = 20.0
    F = 0.5 * 1.225 * 2.22 * 0.23 * 400 + 0.007 * 1752 * 9.81
    assert float(vehicle.road_load_force_N(v, p)) == pytest.approx(F)
    assert float(vehicle.wheel_power_W(v, 1.0, p)) == pytest.approx((1752 + F) * v)


@settings(max_examples=300, deadline=None)
@given(P_w=st.floats(-2e5, 2e5), V1=st.floats(-0.05, 0.05), V2=st.floats(-0.05, 0.05), S=st.floats(0.05, 0.95))
def test_current_map_round_trip(P_w: float, V1: float, V2: float, S: float) -> None:
    """I·V_T equals the cell's power demand, exactly, wherever the demand is feasible."""
    ev = EVParams()
    P_b = float(powertrain.battery_power_W(P_w, ev.vehicle))
    P_c = float(powertrain.cell_power_W(P_b, ev.pack))
    E = float(battery.ocv(S)) - V1 - V2
    I, disc = (float(x) for x in powertrain.current_from_power(P_c, E, ev.cell))
    assert disc > 0
    V_T = float(battery.terminal_voltage(S, V1, V2, I, ev.cell))
    assert I * V_T == pytest.approx(P_c, rel=1e-10, abs=1e-10)
    assert math.copysign(1, I) == math.copysign(1, P_c) or P_c == 0
    # the physical root is the small one: |I| below the current at maximum power E / (2 R_s)
    assert abs(I) <= E / (2 * ev.cell.R_s_ohm)
    # Q = I (OCV − V_T)
    assert float(battery.heat_Q(V1, V2, I, ev.cell)) == pytest.approx(I * (float(battery.ocv(S)) - V_T), abs=1e-9)


def test_current_map_infeasible_signal() -> None:
    cell = CellParams()
    E = 3.3
    P_max = E**2 / (4 * cell.R_s_ohm)
    I, disc = powertrain.current_from_power(1.01 * P_max, E, cell)
    assert float(disc) < 0
    I, disc = powertrain.current_from_power(0.99 * P_max, E, cell)
    assert float(disc) > 0


# sup_x x/(1 + e^{2x}): the largest relative smoothing error; model guide §7 prints it rounded down as 0.139
_X = np.linspace(0.0, 3.0, 300001)
SMOOTHING_SUP = float(np.max(_X / (1 + np.exp(2 * _X))))


@settings(max_examples=200, deadline=None)
@given(P_w=st.floats(-5e4, 5e4), width=st.floats(10.0, 2000.0))
def test_smoothing_error_bound(P_w: float, width: float) -> None:
    """model guide §7: |P_b,smooth − P_b| ≤ c (1/η − η) × width with c = sup x/(1+e^{2x}) ≈ 0.13923."""
    p = VehicleParams()
    exact = float(powertrain.battery_power_W(P_w, p))
    smooth = float(powertrain.battery_power_smooth_W(P_w, p, PowertrainOptions(width)))
    assert abs(smooth - exact) <= SMOOTHING_SUP * (1 / p.efficiency - p.efficiency) * width * (1 + 1e-9)


def test_smoothing_error_bound_is_attained() -> None:
    assert SMOOTHING_SUP == pytest.approx(0.13923, abs=1e-5)
    p, w = VehicleParams(), 300.0
    x = _X[np.argmax(_X / (1 + np.exp(2 * _X)))]
    err = float(
        powertrain.battery_power_W(x * w, p) - powertrain.battery_power_smooth_W(x * w, p, PowertrainOptions(w))
    )
    assert abs(err) == pytest.approx(SMOOTHING_SUP * (1 / p.efficiency - p.efficiency) * w, rel=1e-9)


def test_g_functions() -> None:
    assert float(g_exact(1.0, 0.8)) == pytest.approx(1.25)
    assert float(g_exact(-1.0, 0.8)) == pytest.approx(-0.8)
    assert float(g_smooth(1.0, 0.8, 0.01)) == pytest.approx(1.25, rel=1e-6)


def test_cell_constant_current_closed_form() -> None:
    """The cell ODE under constant current against its closed-form solution, heat integral included."""
    p = CellParams()
    I0, tf = 12.0, 120.0
    x, I = ca.SX.sym("x", 4), ca.SX.sym("I")
    dV1, dV2, dS = battery.cell_derivatives(x[0], x[1], I, p)
    dae = {"x": x, "p": I, "ode": ca.vertcat(dV1, dV2, dS, battery.heat_Q(x[0], x[1], I, p))}
    F = ca.integrator("F", "cvodes", dae, 0.0, [tf], {"abstol": 1e-12, "reltol": 1e-12})
    xf = F(x0=[0, 0, 0.8, 0], p=I0)["xf"].full().ravel()
    t1, t2 = p.tau1_s, p.tau2_s
    V1 = I0 * p.R1_ohm * (1 - math.exp(-tf / t1))
    V2 = I0 * p.R2_ohm * (1 - math.exp(-tf / t2))
    S = 0.8 - I0 * tf / (3600 * p.capacity_Ah)
    heat = (
        p.R_s_ohm * I0**2 * tf
        + I0**2 * p.R1_ohm * (tf - t1 * (1 - math.exp(-tf / t1)))
        + I0**2 * p.R2_ohm * (tf - t2 * (1 - math.exp(-tf / t2)))
    )
    np.testing.assert_allclose(xf, [V1, V2, S, heat], rtol=1e-9)


def test_ocv_interpolant_matches_table_and_is_monotone() -> None:
    soc, ocv = battery.ocv_table()
    np.testing.assert_allclose([float(battery.ocv(s)) for s in soc], ocv, atol=1e-9)
    fine = np.linspace(0, 1, 2001)
    vals = np.asarray(battery.ocv_function().map(fine.size)(fine.reshape(1, -1))).ravel()
    assert vals.min() > 2.3 and vals.max() < 3.6
    assert np.all(np.diff(vals) > 0)  # the table is increasing and the spline keeps it so


@pytest.mark.parametrize(
    "cls,field,value",
    [
        (VehicleParams, "mass_kg", -1.0),
        (VehicleParams, "efficiency", 1.5),
        (CellParams, "R_s_ohm", 0.0),
        (CellParams, "soc0", 1.2),
        (PackParams, "n_series", 0),
        (CarFollowingParams, "kappa", -0.1),
        (Units, "speed_mps", float("nan")),
        (Proposed, "eps", 0.0),
        (OVFL, "beta", -3.0),
        (OVM, "alpha", float("inf")),
    ],
)
def test_parameter_validation_names_field(cls, field: str, value: float) -> None:
    with pytest.raises(ParameterError, match=rf"{cls.__name__}\.{field} = "):
        cls(**{field: value})


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
@pytest.mark.parametrize(
    "name, factory, says",
    [
        ("mine_probe", 42, "factory = 42 is not allowed"),
        (42, object, "name = 42 is not allowed"),
        ("", object, "name = '' is not allowed"),
        ("../x", object, "name = '../x' is not allowed"),
        ("a b", object, "name = 'a b' is not allowed"),
    ],
)
def test_register_law_refuses_what_make_law_could_never_build(name: object, factory: object, says: str) -> None:
    from aev_ocp.models.carfollowing import LAW_REGISTRY, register_law

    before = dict(LAW_REGISTRY)
    with pytest.raises(ParameterError, match=says.replace("(", r"\(")):
        register_law(name, factory)  # type: ignore[arg-type]
    assert LAW_REGISTRY == before


def test_registered_law_builds_by_name_and_make_law_of_a_non_string_is_named() -> None:
    """A law registered under a valid name builds with its coefficient: OVM with alpha = 1.7 at h = 2.3, v = 1.1
    gives alpha (V(h) - v) = 1.7 (tanh(0.3) + tanh(2) - 1.1) (paper eq. OVM, closed form)."""
    from aev_ocp.models.carfollowing import LAW_REGISTRY, OVM, make_law, register_law

    register_law("ovm-probe_3", OVM)
    try:
        law = make_law("OVM-probe_3", alpha=1.7)
        got = float(law.function(2.3, 1.1, 1.2))
        assert got == pytest.approx(1.7 * (math.tanh(0.3) + math.tanh(2.0) - 1.1), rel=1e-12)
    finally:
        LAW_REGISTRY.pop("ovm-probe_3", None)
    for bad in (42, None):
        with pytest.raises(ParameterError, match=f"unknown car-following law {bad!r}"):
            make_law(bad)  # type: ignore[arg-type]
