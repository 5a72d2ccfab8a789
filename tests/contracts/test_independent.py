"""Exact, independent checks at distinct, non-special values (GitHub issue 15).

Every check here recomputes the physics WITHOUT the package (NumPy/SciPy, closed forms, a second
formula), with its coefficients taken from the same parameter objects the code under test gets, and
at values where a swapped or dropped coefficient shows: weights (2, 0.5, 3, 0.7), η = 0.73,
v ≠ 1, R1 ≠ R2 ≠ R_s, C1 ≠ C2, S ≠ 1/2, P_aux ≠ 0, L = 12 m, U = 4 m/s (T = L/U = 3 s ≠ U/L).
Tolerances are round-off tolerances; every place that runs the same formula (the plant, the
compiled cascade, the OCP transcription, the MPC) is called. ``benchmarks/mutation.py`` plants bugs
in the package and runs this file first; keep it fast (about 10–20 s).
"""

from __future__ import annotations

import csv
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline
from scipy.linalg import expm
from scipy.optimize import brentq

from aev_ocp.models import OVFL, OVM, ConstantSpeed, PaperLeader, Proposed, battery, powertrain
from aev_ocp.models.carfollowing import CarFollowingLaw
from aev_ocp.models.ego import battery_side, following_ode
from aev_ocp.models.energy import g_exact, g_smooth
from aev_ocp.numerics import rk4
from aev_ocp.ocp.following import FollowingWeights, following_problem, weight_vector
from aev_ocp.ocp.formulation import s9_formulation
from aev_ocp.ocp.oracle import OracleScenario, OracleSolver, oracle_problem, stage_cost_of_trajectory
from aev_ocp.ocp.problem import ProblemBuilder
from aev_ocp.ocp.transcription import TranscriptionOptions, interval_function
from aev_ocp.params import UNLIMITED, CellParams, EVParams, PackParams, PowertrainOptions, Units, VehicleParams
from aev_ocp.plant import EVENT_RULES, PLAN_TOLERANCE
from aev_ocp.simulate import simulate_platoon

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)

ETA = 0.73
UNITS = Units(length_m=12.0, speed_mps=4.0)  # T = 3 s, U/L = 1/3 s⁻¹
VEH = VehicleParams(mass_kg=1610.0, efficiency=ETA, aux_power_W=420.0, grade_rad=0.013)
CELL = CellParams(capacity_Ah=2.6, R_s_ohm=0.012, R1_ohm=0.0071, C1_F=530.0, R2_ohm=0.019, C2_F=7300.0)
PACK = PackParams(n_series=97, n_parallel=61)
EV = EVParams(units=UNITS, vehicle=VEH, cell=CELL, pack=PACK)
W = FollowingWeights(w_Q=2.0, w_V=0.5, w_r=3.0, w_a=0.7)
SMOOTH = PowertrainOptions(230.0)

# (v, a, V1, V2, S) in model units / V / -: traction, braking, coasting-ish, with S ≠ 1/2
POINTS = np.array(
    [
        [1.45, 0.62, 0.013, -0.021, 0.83],
        [0.55, -1.3, -0.008, 0.027, 0.37],
        [1.9, 0.004, 0.031, 0.011, 0.61],
        [0.83, 1.7, -0.017, -0.005, 0.22],
    ]
)

with (Path(__file__).resolve().parents[2] / "aev_ocp" / "data" / "a123_ocv_25C.csv").open() as _fh:
    _rows = list(csv.DictReader(_fh))
_OCV = make_interp_spline([float(r["soc"]) for r in _rows], [float(r["ocv_V"]) for r in _rows], k=3)


def np_ocv(S):
    """OCV from the shipped table by SciPy's not-a-knot cubic spline (independent of CasADi)."""
    return _OCV(np.asarray(S, float))


def np_battery(v, a, V1, V2, S, ev=EV, width=None):
    """The battery side of a motion, model guide §5–§7, written out in NumPy; width=None: exact η switch.
    The current is the SMALL root of R_s I² − E I + P_c = 0 by the other quadratic formula."""
    u, veh, c = ev.units, ev.vehicle, ev.cell
    vs, as_ = v * u.speed_mps, a * u.speed_mps**2 / u.length_m
    F = (
        0.5 * veh.air_density_kgpm3 * veh.frontal_area_m2 * veh.drag_coefficient * vs**2
        + veh.rolling_coefficient * veh.mass_kg * veh.gravity_mps2
        + veh.mass_kg * veh.gravity_mps2 * math.sin(veh.grade_rad)
    )
    Pw = (veh.mass_kg * as_ + F) * vs
    eta = veh.efficiency
    if width is None:
        Pb = np.where(Pw > 0, Pw / eta, Pw * eta)
    else:
        sig = 0.5 * (1 + np.tanh(Pw / width))
        Pb = sig * Pw / eta + (1 - sig) * Pw * eta
    Pb = Pb + veh.aux_power_W
    Pc = Pb / (ev.pack.n_series * ev.pack.n_parallel)
    ocv = np_ocv(S)
    E = ocv - V1 - V2
    disc = E * E - 4 * c.R_s_ohm * Pc
    I = (E - np.sqrt(disc)) / (2 * c.R_s_ohm)
    VT = ocv - V1 - V2 - c.R_s_ohm * I
    n = ev.pack.n_series * ev.pack.n_parallel
    Q = I * (ocv - VT)
    return {
        "P_w": Pw,
        "P_b": Pb,
        "P_c": Pc,
        "E": E,
        "disc": disc,
        "I": I,
        "dV1": (I - V1 / c.R1_ohm) / c.C1_F,
        "dV2": (I - V2 / c.R2_ohm) / c.C2_F,
        "dS": -I / (c.capacity_Ah * 3600.0),
        "Q": Q,
        "Q_pack": n * Q,
        "Q_irr_pack": n * (c.R_s_ohm * I**2 + V1**2 / c.R1_ohm + V2**2 / c.R2_ohm),
    }


def np_stage(h, v, V1, V2, S, a, vl_hat, weights=W, ev=EV, width=SMOOTH.smoothing_width_W, objective="heat"):
    """ℓ of model guide §9 with the given weights (nothing hard-coded)."""
    if objective == "heat":
        e = np_battery(v, a, V1, V2, S, ev, width)["Q_pack"] / 1000.0
    else:  # the exact g (the problem states v g(a) exactly, by an epigraph)
        eta = ev.vehicle.efficiency
        e = v * np.where(a >= 0, a / eta, eta * a)
    Vh = np.tanh(h - 2.0) + np.tanh(2.0)
    return weights.w_Q * e + weights.w_V * (Vh - v) ** 2 + weights.w_r * (vl_hat - v) ** 2 + weights.w_a * a**2


def np_following_rhs(z, a, vl, ev=EV, width=None):
    b = np_battery(z[1], a, z[2], z[3], z[4], ev, width)
    T = ev.units.length_m / ev.units.speed_mps
    return np.array([vl - z[1], a, T * b["dV1"], T * b["dV2"], T * b["dS"]])


def np_rk4(f, x, h, n):
    """Classical RK4, written out again (Butcher tableau 0, ½, ½, 1; weights 1/6, 1/3, 1/3, 1/6)."""
    d = h / n
    for _ in range(n):
        s1 = f(x)
        s2 = f(x + 0.5 * d * s1)
        s3 = f(x + 0.5 * d * s2)
        s4 = f(x + d * s3)
        x = x + d * (s1 / 6 + s2 / 3 + s3 / 3 + s4 / 6)
    return x


def dm(x):
    return np.asarray(ca.DM(x)).ravel()


# ----------------------------------------------------------------------------- powertrain and cell
def test_eta_switch_by_hand() -> None:
    """Exact switch: P_w/η + P_aux when driving, η P_w + P_aux when braking (η = 0.73, P_aux = 420 W)."""
    assert float(powertrain.battery_power_W(10_000.0, VEH)) == pytest.approx(10_000.0 / 0.73 + 420.0, rel=1e-14)
    assert float(powertrain.battery_power_W(-10_000.0, VEH)) == pytest.approx(-7300.0 + 420.0, rel=1e-14)
    # smoothed switch: σ/η on the driving side, σ = ½(1 + tanh(P_w/w)); at P_w = w: σ = ½(1 + tanh 1)
    w = SMOOTH.smoothing_width_W
    sig = 0.5 * (1 + math.tanh(1.0))
    for P in (w, -w):
        s = sig if P > 0 else 1 - sig
        want = P * (s / 0.73 + (1 - s) * 0.73) + 420.0
        assert float(powertrain.battery_power_smooth_W(P, VEH, SMOOTH)) == pytest.approx(want, rel=1e-14)


@pytest.mark.parametrize("smooth", [None, SMOOTH], ids=["exact", "smooth"])
def test_battery_side_matches_independent_numpy(smooth) -> None:
    """The whole chain motion → P_w → P_b → P_c → I → cell rates, Q, Q_irr against NumPy, to round-off."""
    ref = np_battery(*POINTS.T, width=None if smooth is None else smooth.smoothing_width_W)
    assert np.all(ref["disc"] > 0) and np.ptp(np.sign(ref["P_w"])) == 2  # both branches of the switch
    for k, (v, a, V1, V2, S) in enumerate(POINTS):
        b = battery_side(v, a, V1, V2, S, EV, smooth)
        for key in ("P_b", "disc", "I", "dV1", "dV2", "dS", "Q", "Q_pack", "Q_irr_pack"):
            assert float(b[key]) == pytest.approx(ref[key][k], rel=1e-10, abs=1e-14), key


def test_current_root_against_scipy() -> None:
    """I = 2 P_c/(E + sqrt(E² − 4 R_s P_c)) is the root of I (E − R_s I) = P_c below E/(2 R_s) (brentq)."""
    for P_c, E in ((7.3, 3.21), (-11.9, 3.37), (181.0, 3.05), (0.37, 3.3), (-0.02, 3.29)):
        I, disc = (float(x) for x in powertrain.current_from_power(P_c, E, CELL))
        Imax = E / (2 * CELL.R_s_ohm)
        ref = brentq(lambda i: i * (E - CELL.R_s_ohm * i) - P_c, -10 * Imax, Imax, xtol=1e-15, rtol=1e-15)
        assert I == pytest.approx(ref, rel=1e-12, abs=1e-15)
        assert disc == pytest.approx(E**2 - 4 * CELL.R_s_ohm * P_c, rel=1e-14)


def test_cell_rates_by_hand_and_energy_identity() -> None:
    """Cell ODE, Q and Q_irr by hand; and the second formula Q = Q_irr + d/dt(½C1V1² + ½C2V2²) exactly."""
    V1, V2, I = 0.023, -0.011, 17.3
    c = CELL
    d1, d2, dS = (float(x) for x in battery.cell_derivatives(V1, V2, I, c))
    assert d1 == pytest.approx(-V1 / (0.0071 * 530.0) + I / 530.0, rel=1e-14)
    assert d2 == pytest.approx(-V2 / (0.019 * 7300.0) + I / 7300.0, rel=1e-14)
    assert dS == pytest.approx(-I / (3600.0 * 2.6), rel=1e-14)
    Q = float(battery.heat_Q(V1, V2, I, c))
    Qi = float(battery.heat_irreversible(V1, V2, I, c))
    assert Q == pytest.approx(I * (V1 + V2) + 0.012 * I**2, rel=1e-14)
    assert Qi == pytest.approx(0.012 * I**2 + V1**2 / 0.0071 + V2**2 / 0.019, rel=1e-14)
    assert Q - Qi == pytest.approx(530.0 * V1 * d1 + 7300.0 * V2 * d2, rel=1e-12)
    # the terminal voltage closes Q = I (OCV − V_T)
    S = 0.71
    VT = float(battery.terminal_voltage(S, V1, V2, I, c))
    assert Q == pytest.approx(I * (float(np_ocv(S)) - VT), rel=1e-12)


def test_following_ode_is_the_cell_ode_in_seconds_times_T() -> None:
    """ż = (v_l − v, a, T·cell ODE) with T = L/U = 3 s, to 1e-12 relative (exact and smoothed switch)."""
    vl = 1.37
    for smooth, width in ((None, None), (SMOOTH, SMOOTH.smoothing_width_W)):
        for v, a, V1, V2, S in POINTS:
            z = np.array([1.9, v, V1, V2, S])
            got = dm(following_ode(z, a, vl, EV, smooth))
            b = np_battery(v, a, V1, V2, S, EV, width)
            want = np.array([vl - v, a, 3.0 * b["dV1"], 3.0 * b["dV2"], 3.0 * b["dS"]])
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-18)


# ----------------------------------------------------------------------------- laws and g
LAW_POINTS = [(1.3, 1.45, 0.9), (2.6, 0.55, 0.95), (0.8, 1.9, 1.2), (3.4, 0.37, 0.37)]
AL, BE, KA, EP = 1.3, 2.7, 0.07, 1e-3


def _hand(h, v, vl):
    V = math.tanh(h - 2.0) + math.tanh(2.0)
    ovm = AL * (V - v)
    ovfl = ovm + BE * (vl - v) / h**2
    dv2 = (vl - v) ** 2
    return ovm, ovfl, ovfl - KA * v * v * dv2 / (dv2 + EP)


@pytest.mark.parametrize("h, v, vl", LAW_POINTS)
def test_laws_by_hand_at_distinct_values(h: float, v: float, vl: float) -> None:
    ovm, ovfl, prop = _hand(h, v, vl)
    for law, want in ((OVM(AL), ovm), (OVFL(AL, BE), ovfl), (Proposed(AL, BE, KA, EP), prop)):
        assert float(law.accel(h, v, vl)) == pytest.approx(want, rel=1e-13, abs=1e-15)
        assert float(law.function(h, v, vl)) == pytest.approx(want, rel=1e-13, abs=1e-15)


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_simulators_apply_the_law(method: str) -> None:
    """The acceleration each simulator reports at t = 0 is the hand-computed law (both integrators)."""
    h, v, vl = LAW_POINTS[0]
    law = Proposed(AL, BE, KA, EP)
    r = simulate_platoon(ConstantSpeed(vl), [law], [h], [v], 0.05, ev=EV, dt_out=0.05, battery=False, method=method)
    assert r.accel[0, 0] == pytest.approx(_hand(h, v, vl)[2], rel=1e-12)


def test_g_by_hand() -> None:
    assert float(g_exact(0.61, ETA)) == pytest.approx(0.61 / 0.73, rel=1e-15)
    assert float(g_exact(-0.61, ETA)) == pytest.approx(-0.61 * 0.73, rel=1e-15)
    sig = 0.5 * (1 + math.tanh(0.61 / 0.2))
    assert float(g_smooth(0.61, ETA, 0.2)) == pytest.approx(0.61 * (sig / 0.73 + (1 - sig) * 0.73), rel=1e-14)


@dataclass(frozen=True)
class LinearLaw(CarFollowingLaw):
    """v̇ = k_h (h − h*) + k_v (v_l − v): behind a constant-speed leader the platoon ODE is linear."""

    k_h: float = 0.8
    k_v: float = 1.9
    h_star: float = 1.4
    name = "linear_test"

    def accel(self, h, v, v_l):  # type: ignore[no-untyped-def]
        return self.k_h * (h - self.h_star) + self.k_v * (v_l - v)


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_simulators_integrate_a_linear_law_exactly(method: str) -> None:
    """Both integrators against the closed form y(t) = expm(M t) y0, y = (h − h*, v − v_l), to 1e-8."""
    law, vl, h0, v0 = LinearLaw(), 1.1, 0.9, 1.6
    r = simulate_platoon(ConstantSpeed(vl), [law], [h0], [v0], 4.0, ev=EV, dt_out=0.05, battery=False, method=method)
    assert r.status == "ok"
    M = np.array([[0.0, -1.0], [law.k_h, -law.k_v]])
    y = np.array([expm(M * t) @ [h0 - law.h_star, v0 - vl] for t in r.t])
    np.testing.assert_allclose(r.gap[:, 0], y[:, 0] + law.h_star, rtol=0, atol=1e-8)
    np.testing.assert_allclose(r.speed[:, 0], y[:, 1] + vl, rtol=0, atol=1e-8)


@pytest.fixture(scope="module")
def runs():
    """A Proposed-law follower behind the paper leader (η = 0.73, P_aux, L = 12 m, U = 4 m/s), both integrators."""
    law = Proposed(AL, BE, KA, EP)
    return {
        m: simulate_platoon(PaperLeader(), [law], [0.9], [1.6], 4.0, ev=EV, dt_out=0.002, method=m)
        for m in ("cascade", "cvodes")
    }


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_simulated_omega_is_the_exact_split(runs, method: str) -> None:
    """ω = A Δ(v²/2) + B TV(v²/2), A = (1/η + η)/2, B = (1/η − η)/2 (g = A u + B |u|, v ≥ 0),
    from the samples."""
    r = runs[method]
    assert r.status == "ok"
    w = 0.5 * r.speed[:, 0] ** 2
    A, B = 0.5 * (1 / ETA + ETA), 0.5 * (1 / ETA - ETA)
    want = A * (w[-1] - w[0]) + B * np.sum(np.abs(np.diff(w)))
    assert r.omega[-1, 0] == pytest.approx(want, rel=2e-6)
    assert abs(np.sum(np.abs(np.diff(w)))) > 2 * abs(w[-1] - w[0])  # B matters here


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_simulated_current_and_cell_rates_are_the_independent_map(runs, method: str) -> None:
    """The current each simulator reports is the NumPy current map (exact switch) of its own states,
    and its cell states move at the NumPy rates times T (finite differences of the samples)."""
    r = runs[method]
    ref = np_battery(r.speed[:, 0], r.accel[:, 0], r.V1[:, 0], r.V2[:, 0], r.S[:, 0], EV, None)
    np.testing.assert_allclose(r.current_A[:, 0], ref["I"], rtol=1e-9, atol=1e-9)
    T, dt = 3.0, np.diff(r.t)
    for nm, key in (("V1", "dV1"), ("V2", "dV2"), ("S", "dS")):
        x = getattr(r, nm)[:, 0]
        mid = 0.5 * (ref[key][1:] + ref[key][:-1]) * T
        np.testing.assert_allclose(np.diff(x) / dt, mid, rtol=1e-3, atol=1e-3 * np.max(np.abs(mid)))
    # pack heat: ∫ T Q_pack dt by the trapezoid on the samples
    heat = np.sum(0.5 * (ref["Q_pack"][1:] + ref["Q_pack"][:-1]) * dt) * T
    assert r.heat_J[-1, 0] == pytest.approx(heat, rel=1e-4)
    heat_irr = np.sum(0.5 * (ref["Q_irr_pack"][1:] + ref["Q_irr_pack"][:-1]) * dt) * T
    assert r.heat_irr_J[-1, 0] == pytest.approx(heat_irr, rel=1e-4)


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_simulated_tracking_and_jerk_integrals_from_samples(runs, method: str) -> None:
    """∫(V(h) − v)², ∫(v_l − v)² (trapezoid) and ∫ jerk² (finite differences of the sampled a) against
    each simulator's quadratures, and the §10 RMS metrics built from them."""
    from aev_ocp.metrics import vehicle_metrics

    r = runs[method]
    t, h, v, vl, a = r.t, r.gap[:, 0], r.speed[:, 0], r.leader_speed, r.accel[:, 0]
    dt = np.diff(t)
    trap = lambda y: float(np.sum(0.5 * (y[1:] + y[:-1]) * dt))  # noqa: E731
    e_ovm, e_rel = (np.tanh(h - 2) + np.tanh(2) - v) ** 2, (vl - v) ** 2
    assert r.int_ovm_err2[-1, 0] == pytest.approx(trap(e_ovm), rel=1e-5)
    assert r.int_rel_speed2[-1, 0] == pytest.approx(trap(e_rel), rel=1e-5)
    jerk2 = float(np.sum(np.diff(a) ** 2 / dt))
    assert r.int_jerk2[-1, 0] == pytest.approx(jerk2, rel=1e-3)
    m = vehicle_metrics(r, 0)
    assert m["rms_rel_speed_model"] == pytest.approx(math.sqrt(trap(e_rel) / (t[-1] - t[0])), rel=1e-5)
    assert m["rms_jerk_model"] == pytest.approx(math.sqrt(jerk2 / (t[-1] - t[0])), rel=1e-3)


# ----------------------------------------------------------------------------- RK4 (numerics, OCP, MPC)
A_LIN = np.array([[-0.7, 1.3, 0.0], [-0.4, -0.2, 0.9], [0.25, 0.0, -1.1]])
C_LIN = np.array([0.3, -1.7, 0.45])


def _taylor(h: float, x0: np.ndarray) -> tuple[np.ndarray, float]:
    """One RK4 step of ẋ = A x is the 4th-order Taylor polynomial of exp(hA); its quadrature of c·x is
    c·(h + h²A/2 + h³A²/6 + h⁴A³/24) x0 — both exact to round-off."""
    I3, A = np.eye(3), A_LIN
    A2, A3, A4 = A @ A, A @ A @ A, A @ A @ A @ A
    x = (I3 + h * A + h**2 / 2 * A2 + h**3 / 6 * A3 + h**4 / 24 * A4) @ x0
    q = C_LIN @ (h * I3 + h**2 / 2 * A + h**3 / 6 * A2 + h**4 / 24 * A3) @ x0
    return x, float(q)


def test_rk4_one_step_is_the_taylor_polynomial() -> None:
    x0, h = np.array([0.8, -1.1, 0.35]), 0.37
    x, q = rk4(lambda y: A_LIN @ y, x0, h, 1, lambda y: C_LIN @ y)
    xt, qt = _taylor(h, x0)
    np.testing.assert_allclose(x, xt, rtol=1e-14, atol=1e-15)
    assert q == pytest.approx(qt, rel=1e-13)
    # three sub-steps = three Taylor steps
    x3, q3 = rk4(lambda y: A_LIN @ y, x0, 3 * h, 3, lambda y: C_LIN @ y)
    y, qs = x0, 0.0
    for _ in range(3):
        y, dq = _taylor(h, y)
        qs += dq
    np.testing.assert_allclose(x3, y, rtol=1e-13, atol=1e-15)
    assert q3 == pytest.approx(qs, rel=1e-13)


def test_transcription_interval_is_rk4_with_its_quadrature() -> None:
    """The transcription's interval function (used by OCP-D and the MPC) on ẋ = A x with ∫c·x dt."""
    pb = ProblemBuilder("lin", time_unit="s")
    x = ca.vertcat(*[pb.state(f"x{i}") for i in range(3)])
    u = pb.control("u")
    rhs = ca.mtimes(ca.DM(A_LIN), x)
    for i in range(3):
        pb.set_der(pb.x[f"x{i}"], rhs[i] + 0 * u)
    pb.add_integral_cost(ca.dot(ca.DM(C_LIN), x), "q")
    pr = pb.build()
    F = interval_function(pr, TranscriptionOptions(method="ms", N=1, rk4_substeps=1))
    x0, h = np.array([0.8, -1.1, 0.35]), 0.37
    out = F(xk=x0, uk=0.0, xc=ca.DM(0, 1), xn=np.zeros(3), w=ca.DM(0, 1), p=ca.DM(0, 1), h=h)
    xt, qt = _taylor(h, x0)
    np.testing.assert_allclose(dm(out["eq"]), xt, rtol=1e-14, atol=1e-15)
    assert float(out["J"]) == pytest.approx(qt, rel=1e-13)


@pytest.mark.parametrize("scheme", ["radau", "legendre"])
def test_collocation_interval_is_exact_on_a_polynomial(scheme: str) -> None:
    """Collocation (degree 3) on ẋ = u with ∫ x² dt: the exact states x0 + u t at the collocation points
    solve its equations, and its quadrature of x² is exact: J = ((x0 + u h)³ − x0³)/(3u)."""
    from aev_ocp.ocp.transcription import collocation_coefficients

    pb = ProblemBuilder("poly", time_unit="s")
    x = pb.state("x")
    u = pb.control("u")
    pb.set_der(x, u)
    pb.add_integral_cost(x**2, "x2")
    pr = pb.build()
    F = interval_function(pr, TranscriptionOptions(method="collocation", N=1, degree=3, scheme=scheme))
    x0, u0, h = 0.7, -1.3, 0.37
    tau = collocation_coefficients(3, scheme)[0][1:]
    out = F(xk=x0, uk=u0, xc=x0 + u0 * h * tau, xn=x0 + u0 * h, w=ca.DM(0, 1), p=ca.DM(0, 1), h=h)
    np.testing.assert_allclose(dm(out["eq"]), 0.0, atol=1e-14)
    assert float(out["J"]) == pytest.approx(((x0 + u0 * h) ** 3 - x0**3) / (3 * u0), rel=1e-13)


@pytest.fixture(scope="module")
def mpc():
    from aev_ocp.mpc import MPCController, MPCSettings
    from aev_ocp.ocp.formulation import s9_formulation

    return MPCController(
        MPCSettings(N=4, dt=0.1, solver="ipopt", codegen=False),
        ev=EV,
        formulation=s9_formulation(weights=W, smooth=SMOOTH),
    )


def test_following_step_of_ocp_and_mpc_is_rk4_of_the_independent_ode(mpc) -> None:
    """One interval of the §9 model (smoothed switch) in the OCP transcription and in the MPC
    (its interval function and its guess rollout step) against NumPy RK4 of the NumPy ODE."""
    z0 = np.array([1.1, 1.45, 0.013, -0.021, 0.83])
    a, vm, vh, dt = 0.62, 1.52, 1.48, 0.1
    f = lambda z: np_following_rhs(z, a, vm, EV, SMOOTH.smoothing_width_W)  # noqa: E731
    xs = np.array([1, 1, 0.01, 0.01, 1])
    pr = following_problem(EV, smooth=SMOOTH).build()
    for F, n in ((interval_function(pr, TranscriptionOptions(method="ms", N=1, rk4_substeps=2)), 2), (mpc.F, 1)):
        out = F(xk=z0 / xs, uk=a, xc=ca.DM(0, 1), xn=np.zeros(5), w=[vm, vh], p=weight_vector(W), h=dt)
        np.testing.assert_allclose(dm(out["eq"]) * xs, np_rk4(f, z0, dt, n), rtol=1e-11, atol=1e-15)
        # and the interval cost is ℓ(z_k, a_k)·dt with the given weights
        assert float(out["J"]) == pytest.approx(float(np_stage(*z0, a, vh)) * dt, rel=1e-11)
    np.testing.assert_allclose(dm(mpc.step(z0, a, [vm, vh], weight_vector(W))), np_rk4(f, z0, dt, 1), rtol=1e-11)


# ----------------------------------------------------------------------------- the §9 stage cost
@pytest.mark.parametrize("objective", ["heat", "omega"])
def test_stage_cost_weights_reach_every_user(objective: str) -> None:
    """ℓ with weights (2, 0.5, 3, 0.7) and η = 0.73 in the problem (OCP-D's), in OCP-D's solver path and
    in stage_cost_of_trajectory, against NumPy; each weight moves only its own term."""
    scn = OracleScenario(
        ev=EV, formulation=s9_formulation(weights=W, smooth=SMOOTH, objective=objective), t_end=0.4, dt=0.1
    )
    pr = oracle_problem(scn)
    Z = np.vstack([[1.3, 2.1, 0.7, 2.9], POINTS[:, 0], POINTS[:, 2], POINTS[:, 3], POINTS[:, 4]])  # h, v, V1, V2, S
    A = POINTS[:, 1].copy()
    vh = np.array([1.2, 0.9, 1.7, 1.05])
    want = np_stage(*Z, A, vh, objective=objective)
    eta = EV.vehicle.efficiency
    for k in range(4):
        # objective 'omega': the epigraph control at its optimum, e = v g(a)
        u = A[k] if objective == "heat" else [A[k], Z[1, k] * (A[k] / eta if A[k] >= 0 else eta * A[k])]
        got = float(pr.stage(Z[:, k], u, [1.0, vh[k]], weight_vector(W)))
        assert got == pytest.approx(want[k], rel=1e-11)
    t = np.arange(5) * 0.1
    c = stage_cost_of_trajectory(t, *np.hstack([Z, Z[:, -1:]]), A, vh, W, EV, SMOOTH, objective)
    assert c["total"] == pytest.approx(float(np.sum(want) * 0.1), rel=1e-11)
    # term by term: each weight scales its own term only
    one = FollowingWeights(1.0, 1.0, 1.0, 1.0)
    c1 = stage_cost_of_trajectory(t, *np.hstack([Z, Z[:, -1:]]), A, vh, one, EV, SMOOTH, objective)
    for nm, wk in zip((objective, "ovm", "relative", "accel"), weight_vector(W)):
        assert c[nm] == pytest.approx(wk * c1[nm], rel=1e-12)


def test_ocp_d_objective_is_the_numpy_cost_with_distinct_weights() -> None:
    """A short OCP-D solve with weights (2, 0.5, 3, 0.7): its optimum's cost recomputed in NumPy."""
    scn = OracleScenario(
        ev=EV, formulation=s9_formulation(weights=W, smooth=SMOOTH), t_end=1.0, dt=0.1, h0=0.9, v0=1.6, S0=0.83
    )
    r = OracleSolver(scn).solve()
    assert r.success
    st = r.states
    vh = r.meta["leader_speed_hat"]
    ell = np_stage(st["h"][:-1], st["v"][:-1], st["V1"][:-1], st["V2"][:-1], st["S"][:-1], r.controls["a"], vh)
    assert float(np.sum(ell) * scn.dt) == pytest.approx(r.objective, rel=1e-9)


def test_mpc_objective_is_the_numpy_cost_with_distinct_weights(mpc) -> None:
    z0 = np.array([0.9, 1.6, 0.004, -0.002, 0.83])
    vm, vh = np.array([1.62, 1.6, 1.58, 1.57]), np.array([1.63, 1.61, 1.59, 1.575])
    sol = mpc.solve(z0, vm, vh)
    assert sol.success
    X, a = sol.X, sol.a
    ell = np_stage(X[0, :-1], X[1, :-1], X[2, :-1], X[3, :-1], X[4, :-1], a, vh)
    assert float(np.sum(ell) * 0.1) == pytest.approx(sol.cost, rel=1e-9)
    # per-solve weights (no rebuild) reach the NLP too
    W2 = FollowingWeights(w_Q=0.3, w_V=1.7, w_r=0.6, w_a=2.2)
    sol2 = mpc.solve(z0, vm, vh, weights=W2)
    assert sol2.success
    X, a = sol2.X, sol2.a
    ell2 = np_stage(X[0, :-1], X[1, :-1], X[2, :-1], X[3, :-1], X[4, :-1], a, vh, weights=W2)
    assert float(np.sum(ell2) * 0.1) == pytest.approx(sol2.cost, rel=1e-9)


# ----------------------------------------------------------------------------- soft constraints, events
def test_soft_constraint_adds_a_positive_l1_penalty() -> None:
    """subject_to(..., soft=ρ) adds +ρ σ + q σ² to the stage cost (σ ≥ 0 the slack) and shifts the
    bound by σ."""
    pb = ProblemBuilder("soft", time_unit="s")
    x = pb.state("x")
    u = pb.control("u")
    pb.set_der(x, u)
    pb.add_stage_cost((u - 2.3) ** 2, "track")
    pb.subject_to(u, ub=1.1, soft=5.7, soft_quadratic=0.004, name="cap")
    pr = pb.build()
    assert list(pr.control_names) == ["u", "slack_cap"]
    u0, s0 = 1.6, 0.45
    assert float(pr.stage(0.2, [u0, s0], ca.DM(0, 1), ca.DM(0, 1))) == pytest.approx(
        (u0 - 2.3) ** 2 + 5.7 * s0 + 0.004 * s0**2, rel=1e-14
    )
    assert float(pr.path(0.2, [u0, s0], ca.DM(0, 1), ca.DM(0, 1))) == pytest.approx(u0 - s0, rel=1e-14)


def test_event_rules_fire_on_the_right_side_of_their_thresholds() -> None:
    """Each rule of the one event table, just inside and just outside its threshold."""
    rule = {(r.kind, r.sign): r for r in EVENT_RULES}
    col, neg = rule[("collision", 1.0)], rule[("negative_speed", 1.0)]
    disc = rule[("infeasible_current", 1.0)]
    slo, shi = rule[("soc_out_of_range", 1.0)], rule[("soc_out_of_range", -1.0)]
    assert col.violated(0.0) and not col.violated(1e-12)
    tol = PLAN_TOLERANCE
    assert not neg.violated(0.0) and not neg.violated(-0.5 * tol) and neg.violated(-1.5 * tol)
    assert disc.violated(-1e-12) and not disc.violated(0.0)
    assert slo.violated(-1e-12) and not slo.violated(0.0) and not slo.violated(0.37)
    assert shi.violated(1 + 1e-12) and not shi.violated(1.0) and not shi.violated(0.37)


# ----------------------------------------------------------------------------- leader, plant stop
def test_paper_leader_against_its_equation() -> None:
    """v_l(t) = 1.7 + ∫₀ᵗ a_l, a_l = −(1.65/1.37)(sin(0.5πt) + cos(3.2πt)) on [0, 20] (paper eq. acc5),
    by SciPy quadrature of the printed equation; position by quadrature of that speed."""
    from scipy.integrate import quad

    L = PaperLeader()

    def a_l(t: float) -> float:
        return -(1.65 / 1.37) * (math.sin(0.5 * math.pi * t) + math.cos(3.2 * math.pi * t)) if t <= 20 else 0.0

    def v_l(t: float) -> float:
        return 1.7 + quad(a_l, 0.0, min(t, 20.0), limit=400, epsabs=1e-12, epsrel=1e-12)[0]  # a_l = 0 after 20

    for t in (0.37, 3.1, 11.9, 23.0):
        assert float(L.accel(t)) == pytest.approx(a_l(t), abs=1e-12)
        assert float(L.speed(t)) == pytest.approx(v_l(t), abs=1e-10)
    x = quad(v_l, 0.0, 3.1, limit=200, epsabs=1e-11)[0]
    assert float(L.position(3.1)) == pytest.approx(x, abs=1e-9)


@pytest.mark.parametrize("method", ["cascade", "cvodes"])
def test_plant_stops_where_the_speed_crosses_the_tolerance(method: str) -> None:
    """Braking at 1.7 from v = 0.85: the run stops at t = 0.5 + PLAN_TOLERANCE/1.7 with a negative-speed
    event (exact kinematics), in the CVODES plant and in the compiled cascade."""

    @dataclass(frozen=True)
    class Brake(CarFollowingLaw):
        name = "brake17"

        def accel(self, h, v, v_l):  # type: ignore[no-untyped-def]
            return -1.7 + 0 * h

    r = simulate_platoon(
        ConstantSpeed(1.1),
        [Brake()],
        [4.3],
        [0.85],
        2.0,
        ev=dataclasses.replace(EV, limits=UNLIMITED),
        battery=False,
        method=method,
    )  # (with vehicle limits the brakes hold a stopped car)
    assert r.status == "negative_speed" and r.events[0].vehicle == 0
    assert r.events[0].time == pytest.approx(0.5 + PLAN_TOLERANCE / 1.7, abs=1e-9)
