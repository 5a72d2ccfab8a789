"""Ring roads (issue 22): the compiled ring against CVODES and an independent SciPy integration, the ring's linear
stability against the full Jacobian and against simulation, Stern's laws from their equations, the experiments'
targets, events and bad input."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pytest
from cli_helpers import run_cli
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.control import Command, Observation
from aev_ocp.models.carfollowing import OVM, Proposed
from aev_ocp.params import UNLIMITED, EVParams, ParameterError, VehicleLimits
from aev_ocp.ring.run import fleet_metrics, human_ring, make_aev, run_ring
from aev_ocp.ring.laws import FollowerStopper, PISaturation, follower_stopper_speed, idm_si
from aev_ocp.ring.simulate import (
    RingInitial,
    RingOptions,
    RingRoad,
    RingSimulator,
    gaps_from_positions,
    uniform_flow,
    uniform_speed_mps,
)
from aev_ocp.stability.ring import measured_growth, ring_jacobian, ring_stability

EV = EVParams()


def _match(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance of an optimal one-to-one matching of two eigenvalue sets."""
    from scipy.optimize import linear_sum_assignment

    c = np.abs(a[:, None] - b[None, :])
    r, k = linear_sum_assignment(c)
    return float(c[r, k].max())


# ------------------------------------------------------------------------------------------- stability
@pytest.mark.parametrize(
    "law, n, length_m, ev",
    [
        (idm_si(EV.units), 22, 230.0, EV),  # unstable (Sugiyama)
        (idm_si(EV.units, T_s=1.3), 17, 263.0, EV),  # another IDM, another ring
        (OVM(alpha=1.3), 31, 470.0, EV),  # OVM
        (Proposed(alpha=1.7, beta=2.3, kappa=0.04), 9, 170.0, EV),
        (idm_si(EV.units), 13, 187.0, EVParams(limits=VehicleLimits(lag_s=0.35))),  # actuator lag: cubic modes
    ],
)
def test_ring_eigenvalues_equal_the_full_jacobian(law, n, length_m, ev):
    rs = ring_stability(law, n, length_m, ev=ev)
    lam = np.array([complex(*p) for m in rs.modes for p in m])
    mu = np.linalg.eigvals(ring_jacobian(law, n, length_m, ev=ev))
    assert lam.size == mu.size
    assert _match(lam, mu) < 1e-8
    # the growth rate is the largest real part over the modes k >= 1 (k = 0 holds λ = 0 and λ = f_v)
    assert rs.growth_rate_per_s == pytest.approx(max(p[0] for m in rs.modes[1:] for p in m), abs=1e-15)


@settings(max_examples=12, deadline=None)
@given(spacing=st.floats(8.2, 60.0), t_h=st.floats(0.6, 2.2))
def test_limit_growth_agrees_with_head_to_tail_criterion(spacing, t_h):
    law = idm_si(EV.units, T_s=t_h)
    try:
        rs = ring_stability(law, 40, 40 * spacing, ev=EV)
    except ParameterError:  # no moving uniform flow at this spacing
        return
    if abs(rs.criterion_per_s2) < 1e-9:
        return
    assert (rs.limit_growth_rate_per_s > 1e-12) == (rs.criterion_per_s2 < 0)
    # a finite ring's modes are among the limit's θ: its growth never exceeds the limit
    assert rs.growth_rate_per_s <= rs.limit_growth_rate_per_s + 1e-12
    # the limit is the sup of the modes of ever larger rings (stable: the longest wave's decay ∝ 1/n² → 0); a ring
    # large enough that its mode spacing 2π/n resolves the limit's wavenumber θ* to a tenth (a narrow unstable band
    # near θ = 0 needs thousands of cars: n = 1500 missed the sup by 6 % at θ* = 0.0145)
    theta = float(rs.limit_theta) if rs.criterion_per_s2 < 0 else 1.0
    n_big = min(20_000, max(1500, math.ceil(20 * math.pi / theta)))
    big = ring_stability(law, n_big, n_big * spacing, ev=EV).growth_rate_per_s
    if rs.criterion_per_s2 < 0:
        assert 0.98 * rs.limit_growth_rate_per_s <= big <= rs.limit_growth_rate_per_s + 1e-12
    else:
        assert rs.growth_rate_per_s < big <= 0


@pytest.mark.parametrize(
    "law, length_m, ev",
    [
        (idm_si(EV.units), 230.0, EV),  # growing
        (idm_si(EV.units), 600.0, EV),  # decaying
        (idm_si(EV.units), 230.0, EVParams(limits=VehicleLimits(lag_s=0.4))),
    ],
)
def test_measured_growth_within_5_percent(law, length_m, ev):
    m = measured_growth(law, 22, length_m, ev=ev)
    assert m["status"] == "ok"
    assert m["relative_error"] < 0.05


# ------------------------------------------------------------------------------------------- simulation
def _small_ring(ev: EVParams = EV, noise: float = 0.0) -> RingRoad:
    laws = [idm_si(ev.units, T_s=1.0 + 0.07 * i) for i in range(5)] + [FollowerStopper.from_si(ev.units, 5.3)]
    return RingRoad(130.0, tuple(laws), ev=ev, noise_mps2=noise, seed=3)


def test_compiled_ring_equals_cvodes():
    ring = _small_ring()
    init = uniform_flow(ring, speed_mps=6.1, shift_m=2.5, vehicle=2, speed_dip_mps=0.7)
    a = RingSimulator(ring, RingOptions(rtol=1e-10, atol=1e-10, dt_out_s=1.0, method="compiled")).run(init, 30.0)
    b = RingSimulator(ring, RingOptions(rtol=1e-10, atol=1e-10, dt_out_s=1.0, method="cvodes")).run(init, 30.0)
    assert a.status == b.status == "ok"
    assert a.stats["method"] == "compiled" and b.stats["method"] == "cvodes"
    np.testing.assert_allclose(a.speed_mps, b.speed_mps, atol=1e-6)
    np.testing.assert_allclose(a.gap_m, b.gap_m, atol=1e-6)
    np.testing.assert_allclose(a.sim.S, b.sim.S, atol=1e-9)
    np.testing.assert_allclose(a.sim.heat_J[-1], b.sim.heat_J[-1], rtol=1e-5)
    np.testing.assert_allclose(a.energy_J[-1], b.energy_J[-1], rtol=1e-5)


def _scipy_ring(ring: RingRoad, init: RingInitial, t_end_s: float) -> dict[str, np.ndarray]:
    """The ring written again in NumPy (SI), IDM from Treiber et al. 2000 and FollowerStopper from Stern et al.
    2018, with aev_ocp.reference's cell model, integrated with solve_ivp (DOP853)."""
    from scipy.integrate import solve_ivp

    from aev_ocp.reference import make_ocv_numpy

    ev, n = ring.ev, ring.n
    veh, cell, pack = ev.vehicle, ev.cell, ev.pack
    ocv = make_ocv_numpy()
    T_h = np.array([1.0 + 0.07 * i for i in range(5)])
    ncell = pack.n_series * pack.n_parallel

    def accel(h, v, vl):
        a = np.empty(n)
        s_star = 2.0 + v[:5] * T_h + v[:5] * (v[:5] - vl[:5]) / (2 * math.sqrt(1.0 * 1.5))
        a[:5] = 1.0 * (1 - (v[:5] / 30.0) ** 4 - (s_star / h[:5]) ** 2)
        dvm = min(vl[5] - v[5], 0.0)
        x1, x2, x3 = (x0 + dvm**2 / (2 * d) for x0, d in ((4.5, 1.5), (5.25, 1.0), (6.0, 0.5)))
        vb = min(max(vl[5], 0.0), 5.3)
        g = h[5]
        vc = (
            0.0
            if g <= x1
            else vb * (g - x1) / (x2 - x1)
            if g <= x2
            else vb + (5.3 - vb) * (g - x2) / (x3 - x2)
            if g <= x3
            else 5.3
        )
        a[5] = (vc - v[5]) / 0.6
        return np.clip(a, -8.0, 4.0)

    def rhs(t, y):
        h, v, V1, V2, S = (y[k * n : (k + 1) * n] for k in range(5))
        vl = np.roll(v, 1)
        a = accel(h, v, vl)
        Fres = (
            0.5 * veh.air_density_kgpm3 * veh.frontal_area_m2 * veh.drag_coefficient * v**2
            + veh.rolling_coefficient * veh.mass_kg * veh.gravity_mps2
        )
        Pw = (veh.mass_kg * a + Fres) * v
        Pb = np.where(Pw > 0, Pw / veh.efficiency, veh.efficiency * Pw)
        Pc = Pb / ncell
        E = ocv(S) - V1 - V2
        I = 2 * Pc / (E + np.sqrt(np.maximum(E**2 - 4 * cell.R_s_ohm * Pc, 0.0)))
        Q = I * (V1 + V2) + cell.R_s_ohm * I**2
        return np.concatenate(
            [
                vl - v,
                a,
                -V1 / (cell.R1_ohm * cell.C1_F) + I / cell.C1_F,
                -V2 / (cell.R2_ohm * cell.C2_F) + I / cell.C2_F,
                -I / (3600 * cell.capacity_Ah),
                ncell * Q,
                Pb,
                v,
            ]
        )

    y0 = np.concatenate(
        [
            gaps_from_positions(ring, init.positions_m),
            init.speeds_mps,
            np.zeros(2 * n),
            np.full(n, cell.soc0),
            np.zeros(3 * n),
        ]
    )
    sol = solve_ivp(rhs, (0, t_end_s), y0, method="DOP853", rtol=1e-11, atol=1e-11)
    y = sol.y[:, -1]
    return {
        "gap": y[:n],
        "speed": y[n : 2 * n],
        "S": y[4 * n : 5 * n],
        "heat": y[5 * n : 6 * n],
        "energy": y[6 * n : 7 * n],
        "distance": y[7 * n :],
    }


def test_compiled_ring_equals_an_independent_scipy_integration():
    ring = _small_ring()
    init = uniform_flow(ring, speed_mps=6.1, shift_m=2.5, vehicle=2, speed_dip_mps=0.7)
    a = RingSimulator(ring, RingOptions(rtol=1e-10, atol=1e-10, dt_out_s=5.0)).run(init, 40.0)
    ref = _scipy_ring(ring, init, 40.0)
    assert a.status == "ok"
    np.testing.assert_allclose(a.gap_m[-1], ref["gap"], atol=2e-6)
    np.testing.assert_allclose(a.speed_mps[-1], ref["speed"], atol=2e-6)
    np.testing.assert_allclose(a.distance[-1] * EV.units.length_m, ref["distance"], rtol=1e-8)
    np.testing.assert_allclose(a.sim.S[-1], ref["S"], atol=1e-8)
    np.testing.assert_allclose(a.energy_J[-1], ref["energy"], rtol=1e-5)
    np.testing.assert_allclose(a.sim.heat_J[-1], ref["heat"], rtol=1e-3)  # OCV: B-spline vs not-a-knot spline
    # the per-vehicle metrics name it battery energy, per km of the SciPy run's own distance
    m = a.metrics()
    per_km = ref["energy"] / (ref["distance"] / 1000.0)
    np.testing.assert_allclose([x["battery_energy_J_per_km"] for x in m], per_km, rtol=1e-5)
    np.testing.assert_allclose([x["battery_energy_kWh_per_100km"] for x in m], per_km * 100 / 3.6e6, rtol=1e-5)
    assert not any("energy_J" in x for x in m)


def test_gap_sum_is_conserved_and_positions_close_the_ring():
    ring = human_ring(230.0, noise_mps2=0.15, seed=5)
    res = RingSimulator(ring, RingOptions(dt_out_s=2.0)).run(uniform_flow(ring, shift_m=3.0), 200.0)
    assert res.status == "ok"
    total = ring.length_m - ring.n * ring.vehicle_length_m
    np.testing.assert_allclose(res.gap_m.sum(axis=1), total, atol=1e-8)
    # the positions from the integrated distances give back the integrated gaps
    np.testing.assert_allclose(gaps_from_positions(ring, res.positions_m()[-1]), res.gap_m[-1], atol=1e-6)


def test_noise_is_seeded_and_only_on_humans():
    ring = human_ring(230.0, aevs={0: FollowerStopper.from_si(EV.units, 3.1)}, noise_mps2=0.3, seed=11)
    opt = RingOptions(dt_out_s=1.0)
    a = RingSimulator(ring, opt).run(uniform_flow(ring), 20.0)
    b = RingSimulator(ring, opt).run(uniform_flow(ring), 20.0)
    np.testing.assert_array_equal(a.speed_mps, b.speed_mps)
    c = RingSimulator(
        human_ring(230.0, aevs={0: FollowerStopper.from_si(EV.units, 3.1)}, noise_mps2=0.3, seed=12), opt
    ).run(uniform_flow(ring), 20.0)
    assert np.max(np.abs(c.speed_mps - a.speed_mps)) > 1e-3
    assert not ring.is_human(0) and ring.is_human(1)


class _Rammer:
    """A sampled controller that accelerates at a fixed 2.7 m/s² whatever happens ahead."""

    name = "rammer"
    dt = 0.05

    def reset(self) -> None:
        pass

    def command(self, obs: Observation) -> Command:
        return Command(2.7 / EV.units.accel_mps2)

    def describe(self) -> dict:
        return {"controller": self.name}


def test_collision_is_located_with_its_impact_speed():
    ring = RingRoad(120.0, (_Rammer(),) + tuple([idm_si(EV.units)] * 5), ev=EV)
    res = RingSimulator(ring, RingOptions(dt_out_s=0.5)).run(uniform_flow(ring), 60.0)
    assert res.status == "collision"
    e = res.sim.events[0]
    assert e.vehicle == 0 and e.impact_speed_mps is not None and e.impact_speed_mps > 0
    assert abs(res.gap_m[-1, 0]) < 1e-6  # the run ends at contact
    assert res.t_s[-1] == pytest.approx(e.time_s, rel=1e-12)


def test_unbounded_laws_report_negative_speed():
    ev = EVParams(limits=UNLIMITED)
    ring = RingRoad(6 * 6.5, tuple([idm_si(ev.units)] * 6), ev=ev)  # gaps 1.5 m < s0 = 2 m: the IDM backs off
    res = RingSimulator(ring, RingOptions(dt_out_s=0.5)).run(uniform_flow(ring, speed_mps=0.4), 30.0)
    assert res.status == "negative_speed"
    assert res.speed_mps[-1].min() == pytest.approx(-1e-6 * EV.units.speed_mps, rel=1e-6)  # located on the rule
    # with the vehicle limits the brakes hold the stopped cars instead
    held = RingSimulator(RingRoad(6 * 6.5, tuple([idm_si(EV.units)] * 6), ev=EV), RingOptions(dt_out_s=0.5)).run(
        uniform_flow(ring, speed_mps=0.4), 30.0
    )
    assert held.status == "ok" and held.speed_mps.min() >= -1e-9


# ------------------------------------------------------------------------------------------- Stern's laws
@pytest.mark.parametrize(
    "gap, v, vl",
    [(4.1, 3.3, 2.9), (4.9, 3.3, 3.6), (5.6, 2.2, 2.5), (5.6, 4.4, 3.1), (9.3, 3.7, 1.9), (12.7, 3.7, 4.2)],
)
def test_follower_stopper_equations(gap, v, vl):
    r = 4.6
    dvm = min(vl - v, 0.0)
    x = [x0 + dvm**2 / (2 * d) for x0, d in ((4.5, 1.5), (5.25, 1.0), (6.0, 0.5))]
    vb = min(max(vl, 0), r)
    want = (
        0.0
        if gap <= x[0]
        else vb * (gap - x[0]) / (x[1] - x[0])
        if gap <= x[1]
        else vb + (r - vb) * (gap - x[1]) / (x[2] - x[1])
        if gap <= x[2]
        else r
    )
    got = float(follower_stopper_speed(gap, v, vl, r, (4.5, 5.25, 6.0), (1.5, 1.0, 0.5)))
    assert got == pytest.approx(want, abs=1e-12)
    law = FollowerStopper.from_si(EV.units, r, tau_s=0.8)
    u = EV.units
    a_si = float(law.accel(u.length_from_si(gap), u.speed_from_si(v), u.speed_from_si(vl))) * u.accel_mps2
    assert a_si == pytest.approx((want - v) / 0.8, abs=1e-9)


def test_pi_saturation_equations():
    c = PISaturation(units=EV.units, dt_s=0.1, window_s=0.3)
    u = EV.units
    obs = lambda gap, v, vl: Observation(  # noqa: E731
        0.0,
        c.dt,
        0,
        np.array([u.length_from_si(gap), u.speed_from_si(v), 0, 0, 0.8]),
        np.array([0.0]),
        np.array([u.speed_from_si(vl)]),
    )
    vs, v_cmd = [], None
    for gap, v, vl in ((11.5, 3.2, 3.9), (6.1, 3.6, 2.4), (25.0, 2.9, 3.1), (40.0, 4.3, 3.5)):
        cmd = c.command(obs(gap, v, vl))
        vs.append(v)
        U = float(np.mean(vs[-3:]))
        v_target = U + 1.0 * min(max((gap - 7.0) / 23.0, 0), 1)
        alpha = min(max((gap - max(2 * (vl - v), 4.0)) / 2.0, 0), 1)
        beta = 1 - alpha / 2
        v_cmd = beta * (alpha * v_target + (1 - alpha) * vl) + (1 - beta) * (v if v_cmd is None else v_cmd)
        assert cmd.a * u.accel_mps2 == pytest.approx((v_cmd - v) / c.tau_s, rel=1e-12)


# ------------------------------------------------------------------------------------------- experiments
def test_sugiyama_jams_at_230_m_and_not_at_600_m():
    jam = run_ring(human_ring(230.0, seed=2), 400.0).fleet
    calm = run_ring(human_ring(600.0, seed=2), 400.0).fleet
    assert jam["status"] == calm["status"] == "ok"
    assert jam["speed_std_mps"] > 1.0 and jam["vehicles_stopped"] >= 5
    assert -8.0 < jam["wave_speed_mps"] < -2.0  # the jam travels backwards
    assert calm["speed_std_mps"] < 0.3 and calm["vehicles_stopped"] == 0
    assert ring_stability(idm_si(EV.units), 22, 230.0).growth_rate_per_s > 0
    assert ring_stability(idm_si(EV.units), 22, 600.0).growth_rate_per_s < 0


@pytest.mark.parametrize("aev", ["followerstopper", "pi-saturation"])
def test_one_aev_dissolves_the_jam(aev):
    base = human_ring(230.0, seed=4)
    human = run_ring(base, 400.0).fleet
    ring = human_ring(230.0, aevs={0: make_aev(aev, EV, 0.85 * uniform_speed_mps(base))}, seed=4)
    mixed = run_ring(ring, 400.0).fleet
    assert mixed["status"] == "ok" and mixed["collisions"] == 0
    assert mixed["speed_std_mps"] <= 0.5 * human["speed_std_mps"]
    assert mixed["battery_energy_J_per_km"] < human["battery_energy_J_per_km"]
    assert mixed["heat_pack_J_per_km"] < human["heat_pack_J_per_km"]
    assert mixed["braking_events"] < human["braking_events"]


def test_fleet_metrics_totals():
    res = RingSimulator(human_ring(300.0, noise_mps2=0.0), RingOptions(dt_out_s=1.0)).run(
        uniform_flow(human_ring(300.0)), 50.0
    )
    f = fleet_metrics(res, t_from_s=0.0)
    m = res.metrics()
    assert f["distance_km"] == pytest.approx(sum(x["distance_m"] for x in m) / 1000, rel=1e-9)
    assert f["heat_pack_J_per_km"] == pytest.approx(sum(x["heat_pack_J"] for x in m) / f["distance_km"], rel=1e-9)
    # uniform flow at 6.63 m/s: every vehicle drives 50 s × v*
    assert f["distance_km"] == pytest.approx(22 * 50 * uniform_speed_mps(human_ring(300.0)) / 1000, rel=1e-6)


# ------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: RingRoad(100.0, tuple([OVM()] * 22)), "do not fit"),
        (lambda: RingRoad(-5.0, (OVM(), OVM())), "length_m"),
        (lambda: RingRoad(100.0, (OVM(), "idm")), "vehicle 2"),
        (lambda: RingOptions(threads=0), "threads"),
        (
            lambda: RingSimulator(RingRoad(100.0, (OVM(), OVM()))).run(RingInitial((0.0, 2.0), (1.0, 1.0)), 10.0),
            "overlap",
        ),
        (lambda: human_ring(230.0, heterogeneity=1.5), "heterogeneity"),
        (lambda: ring_stability(idm_si(EV.units), 22, 22 * 6.5), "no moving uniform flow"),
    ],
)
def test_bad_input_is_one_clear_line(make, match):
    with pytest.raises(ParameterError, match=match):
        make()


class _Ran(NamedTuple):
    """What a command gave (the fields of subprocess.CompletedProcess these tests read)."""

    returncode: int
    stdout: str
    stderr: str


def test_cli_ring_stability_and_errors(tmp_path, capsys):
    # in this process (issue 40: an interpreter's start-up and imports per command; exit code, stdout and stderr are
    # the command's all the same, and an exception would fail the test, not only print a traceback)
    run = lambda *a: _Ran(*run_cli(list(a), capsys))  # noqa: E731
    p = run(
        "stability",
        "--law",
        "ovm",
        "--set",
        "carfollowing.ovm.alpha=1.3",
        "--ring",
        "22",
        "--density-per-km",
        "47",
        "--out",
        str(tmp_path),
    )
    assert p.returncode == 0, p.stderr
    assert "growth rate" in p.stdout and "measured growth" in p.stdout and (tmp_path / "ring_stability.json").exists()
    p = run("stability", "--law", "ovm", "--ring", "22", "--out", str(tmp_path))
    assert p.returncode == 2 and "--spacing-m" in p.stderr and "Traceback" not in p.stderr
    p = run("ring", "sweep", "--penetration", "30", "--out", str(tmp_path / "sweep"))
    assert p.returncode == 2 and "--penetration 30" in p.stderr and "Traceback" not in p.stderr


# ------------------------------------------------------------------------------------------- the MPC as a ring AEV
class _Recorder:
    """A Controller that records what the wrapped one observed (time, own z, last measured predecessor speed)."""

    def __init__(self, inner):
        self.inner, self.name, self.dt, self.seen = inner, inner.name, inner.dt, []

    def reset(self):
        self.inner.reset()
        self.seen = []

    def command(self, obs):
        self.seen.append((obs.t, obs.z.copy(), float(obs.meas_v[-1]), obs.meas_v.size))
        return self.inner.command(obs)

    def describe(self):
        return self.inner.describe()


def test_mpc_ring_aev_measures_its_predecessor_and_stays_safe():
    from aev_ocp.ring.laws import ring_mpc

    base = human_ring(240.0, seed=3)
    pol = ring_mpc(EV)
    assert pol.describe()["predictor"] != "oracle" and pol.formulation.kind == "traffic"
    rec = _Recorder(pol)
    ring = human_ring(240.0, aevs={5: rec}, seed=3)
    res = RingSimulator(ring, RingOptions(dt_out_s=0.2)).run(uniform_flow(base, shift_m=1.5), 40.0)
    f = fleet_metrics(res, t_from_s=0.0)
    assert res.status == "ok" and f["collisions"] == 0
    st_ = res.sim.solver_stats[5]
    assert st_["steps"] == len(rec.seen) == 200 and st_["fallbacks"] == 0
    # the observation: the predecessor's (vehicle 5, index 4) measured speed and the AEV's own state at t_k
    t = res.t_s
    for tk, z, v_meas, k in rec.seen[::17]:
        j = int(np.argmin(np.abs(t - tk * EV.units.time_s)))
        assert abs(t[j] - tk * EV.units.time_s) < 1e-9
        assert v_meas * EV.units.speed_mps == pytest.approx(res.speed_mps[j, 4], abs=1e-9)
        assert z[1] * EV.units.speed_mps == pytest.approx(res.speed_mps[j, 5], abs=1e-9)
        assert z[0] * EV.units.length_m == pytest.approx(res.gap_m[j, 5], abs=1e-9)
        assert k == int(round(tk / pol.dt)) + 1  # every sample so far
    # the MPC's own gap keeps above its formulation's floor (2 m) with the safety filter
    assert res.gap_m[:, 5].min() > 2.0


def test_mpc_ring_refuses_the_oracle():
    from aev_ocp.ring.laws import ring_mpc

    with pytest.raises(ParameterError, match="predictor"):
        ring_mpc(EV, predictor="oracle")


# ------------------------------------------------------------------------------------------- the [ring] scenario form
def _ring_doc(**ring):
    base = {"length_m": 247.0, "vehicles": 19, "t_end_s": 30.0, "noise_mps2": 0.13, "seed": 5}
    base.update(ring)
    return {"name": "r", "ring": base}


def test_ring_scenario_builds_the_ring_of_the_experiments():
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario, parse_ring_scenario

    sc = load_ring_scenario("ring_stern")
    assert sc.spec.controllers == ("followerstopper", "pi-saturation", "proposed", "ovfl", "mpc")
    assert sc.spec.aev_vehicles == (0,) and sc.spec.length_m == 230.0 and sc.spec.vehicles == 22
    ring, init = build_ring(sc, None)
    ref = human_ring(230.0, seed=0)
    assert ring.vehicles == ref.vehicles and ring.noise_mps2 == ref.noise_mps2 and ring.seed == ref.seed
    assert init == uniform_flow(ref, shift_m=2.0)
    ring, _ = build_ring(sc, "followerstopper")
    r_mps = 0.85 * uniform_speed_mps(ref)
    assert ring.vehicles[0] == make_aev("followerstopper", EV, r_mps) and ring.vehicles[1:] == ref.vehicles[1:]
    assert not ring.is_human(0) and ring.is_human(1)
    # density_per_km is the same ring as its length; an OVM ring with α in 1/s; given positions and speeds
    a = parse_ring_scenario(_ring_doc(), "a.toml")
    dens = {k: v for k, v in _ring_doc(density_per_km=1000 * 19 / 247.0)["ring"].items() if k != "length_m"}
    b = parse_ring_scenario({"ring": dens}, "b.toml")
    assert b.spec.length_m == pytest.approx(a.spec.length_m, rel=1e-14)
    o = parse_ring_scenario(_ring_doc(human="ovm", ovm={"alpha_per_s": 0.65}), "o.toml")
    assert build_ring(o, None)[0].vehicles[3] == OVM(alpha=0.65 * EV.units.time_s)
    pos = [(-i * 13.0) % 247.0 for i in range(19)]
    g = parse_ring_scenario(_ring_doc(initial={"positions_m": pos, "speeds_mps": [2.5] * 19}), "g.toml")
    assert build_ring(g, None)[1].positions_m == tuple(pos)


@pytest.mark.parametrize(
    "ring, match",
    [
        ({"aev": {"vehicles": [30], "controllers": ["mpc"]}}, r"g.toml: ring.aev.vehicles = \[30\]"),
        ({"aev": {"vehicles": [2], "controllers": ["warp"]}}, "g.toml: ring.aev.controllers"),
        ({"density_per_km": 40.0}, "give exactly one"),
        ({"length_m": 90.0}, "g.toml: ring.length_m = 90.0 is not allowed: 19 vehicles of 5 m do not fit"),
        ({"idm": {"T_s": -1.0}}, "g.toml: ring.idm.T_s"),
        ({"ovm": {"alpha_per_s": 1.0}}, "g.toml: ring.ovm"),
        ({"perturbation": {"shift_m": 9.0}}, "g.toml: ring.perturbation.shift_m"),
        ({"perturbation": {"vehicle": 20}}, "g.toml: ring.perturbation.vehicle"),
        (
            {"initial": {"positions_m": [0.0] * 19, "speeds_mps": [1.0] * 19}},
            "g.toml: ring.initial.positions_m.*overlaps",
        ),
        ({"t_end_s": 0}, "g.toml: ring.t_end_s"),
        ({"speed": 3}, "g.toml: unknown key 'ring.speed'"),
    ],
)
def test_ring_scenario_errors_name_file_and_key(ring, match):
    from aev_ocp.ring.scenario import parse_ring_scenario
    from aev_ocp.scenarios import ScenarioError

    with pytest.raises(ScenarioError, match=match):
        parse_ring_scenario(_ring_doc(**ring), "g.toml")


def test_ring_scenario_mpc_table_and_the_platoon_loader():
    from aev_ocp.ring.scenario import parse_ring_scenario
    from aev_ocp.scenarios import ScenarioError, parse_scenario, shipped_scenarios

    doc = _ring_doc(aev={"vehicles": [3], "controllers": ["mpc"]}) | {"mpc": {"N": 17}}
    sc = parse_ring_scenario(doc, "m.toml")
    assert sc.mpc.settings.N == 17
    with pytest.raises(ScenarioError, match="m.toml: mpc.predictor = 'oracle' is not allowed on a ring"):
        parse_ring_scenario(doc | {"mpc": {"predictor": "oracle"}}, "m.toml")
    with pytest.raises(ScenarioError, match="m.toml: a ring scenario .*aev-ocp ring m.toml"):
        parse_scenario(doc, "m.toml")
    assert {"ring_stern", "ring_sugiyama"} <= set(shipped_scenarios("ring"))
    assert not {"ring_stern", "ring_sugiyama"} & set(shipped_scenarios())


def test_cli_ring_scenario(tmp_path, capsys, monkeypatch):
    f = tmp_path / "small.toml"
    f.write_text(
        "[ring]\nlength_m = 263.0\nvehicles = 21\nt_end_s = 24.0\n[ring.aev]\nvehicles = [4]\n"
        'controllers = ["pi-saturation"]\n',
        encoding="utf-8",
    )
    monkeypatch.chdir(tmp_path)
    run = lambda *a: _Ran(*run_cli(["ring", *a], capsys))  # noqa: E731 (in this process, as above)
    p = run(str(f), "--no-plots", "--out", str(tmp_path / "o"))
    assert p.returncode == 0, p.stderr
    assert "all human" in p.stdout and "pi-saturation" in p.stdout
    import json

    doc = json.loads((tmp_path / "o" / "ring.json").read_text())
    assert [r["label"] for r in doc["runs"]] == ["all human", "pi-saturation"] and doc["runs"][1]["aevs"] == 1
    f.write_text("[ring]\nlength_m = 263.0\nvehicles = 21\nt_end_s = 24.0\nseed = -1\n", encoding="utf-8")
    p = run(str(f))
    assert p.returncode == 2 and "small.toml: ring.seed = -1" in p.stderr and "Traceback" not in p.stderr
    p = run("no_such_ring")
    assert p.returncode == 2 and "ring_stern" in p.stderr


def test_ring_scenario_sweep_penetration_by_density():
    from aev_ocp.ring.run import relative_to, run_ring_scenario
    from aev_ocp.ring.scenario import load_ring_scenario, parse_ring_scenario, scenario_runs, spread
    from aev_ocp.scenarios import ScenarioError

    shipped = load_ring_scenario("ring_penetration")
    runs = scenario_runs(shipped)
    assert len(runs) == 4 * (1 + 5 * 2)  # per density: all human once, then 1-5 AEVs × 2 controllers
    assert sorted({r.length_m for r in runs}) == pytest.approx(sorted(22000 / d for d in (95.65, 84.6, 73.3, 62.9)))
    assert spread(3, 22) == (0, 7, 15) and spread(0, 22) == () and spread(5, 22) == (0, 4, 9, 13, 18)
    doc = _ring_doc(t_end_s=20.0, sweep={"aevs": [0, 2], "length_m": [247.0, 301.0], "controllers": ["pi-saturation"]})
    sc = parse_ring_scenario(doc, "s.toml")
    out = run_ring_scenario(sc)
    assert [(e.fleet["length_m"], e.fleet["aevs"]) for e in out] == [(247.0, 0), (247.0, 2), (301.0, 0), (301.0, 2)]
    assert [i for i in range(19) if not out[1].result.ring.is_human(i)] == [0, 10]  # round(j 19 / 2)
    assert out[3].fleet["change_heat_pack_J_per_km"] == relative_to(out[2].fleet, out[3].fleet)["heat_pack_J_per_km"]
    assert out[3].result.ring.length_m == 301.0 and out[3].result.ring.vehicles[10].name == "pi-saturation"
    for bad, match in (
        (dict(sweep={"aevs": [0, 25]}), "s.toml: ring.sweep.aevs"),
        (dict(sweep={"aevs": [1], "density_per_km": [300.0]}), "s.toml: ring.sweep.density_per_km"),
        (dict(sweep={"aevs": [1]}, aev={"vehicles": [1], "controllers": ["mpc"]}), "not both"),
    ):
        with pytest.raises(ScenarioError, match=match):
            parse_ring_scenario(_ring_doc(**bad), "s.toml")


def test_compiled_ring_is_built_for_a_named_cpu():
    from aev_ocp.compiled import native_arch

    arch = native_arch()  # the resolved name goes into the compile flags and so into the library's cache key
    assert arch == "" or ("native" not in arch and arch.replace("-", "").isalnum())
