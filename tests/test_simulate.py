"""Simulation checks: an independent SciPy integration, conservation laws, tolerance convergence, events."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aev_ocp.metrics import _hermite_min, min_gap_continuous
from aev_ocp.models import OVFL, OVM, ConstantSpeed, PaperLeader, Proposed
from aev_ocp.models.battery import stored_energy_J
from aev_ocp.models.carfollowing import CarFollowingLaw
from aev_ocp.params import UNLIMITED, CellParams, EVParams, PackParams, ParameterError
from aev_ocp.plant import PLAN_TOLERANCE
from aev_ocp.reference import simulate_reference
from aev_ocp.simulate import PlatoonSimulator, SimOptions, simulate_platoon

GAPS = np.array([0.3, 3.5, 3.5, 3.5, 3.5])
PAPER = EVParams(limits=UNLIMITED)  # the paper's laws as printed (no vehicle limits), as the references integrate them
SPEEDS = np.full(5, 1.1 * 1.7)


METHODS = ["cascade", "cvodes"]


def _has_compiler() -> bool:
    import shutil

    return shutil.which("gcc") is not None or shutil.which("cc") is not None


if not _has_compiler():  # the compiled cascade needs gcc/cc; CVODES is then the only integrator
    METHODS = ["cvodes"]


@pytest.fixture(scope="module", params=METHODS)
def table1(request: pytest.FixtureRequest) -> dict[str, Any]:
    """Table 1 runs with each integrator (the compiled cascade and CVODES)."""
    L = PaperLeader()
    return {
        law.name: simulate_platoon(
            L, [law] * 5, GAPS, SPEEDS, 70.0, rtol=1e-10, atol=1e-10, method=request.param, ev=PAPER
        )
        for law in (Proposed(), OVFL())
    }


@pytest.fixture(scope="module")
def references() -> dict[str, dict[str, Any]]:
    """The independent SciPy runs of Table 1 (aev_ocp.reference), each computed once for both integrators' checks
    (issue 40: it was computed again for each)."""
    return {kind: simulate_reference(kind, GAPS, SPEEDS, 70.0, rtol=1e-10, atol=1e-10) for kind in ("proposed", "ovfl")}


@pytest.mark.parametrize("kind", ["proposed", "ovfl"])
def test_omega_and_heat_match_independent_scipy(
    table1: dict[str, Any], references: dict[str, dict[str, Any]], kind: str
) -> None:
    ref = references[kind]
    r = table1[kind]
    assert r.status == "ok"
    assert r.meta["integrator"].split("-")[0] in METHODS
    np.testing.assert_allclose(r.omega[-1], ref["omega"], atol=1e-6)
    np.testing.assert_allclose(r.gap[-1], ref["gap"], atol=1e-6)
    np.testing.assert_allclose(r.heat_J[-1], ref["heat_J"], rtol=1e-6)
    np.testing.assert_allclose(r.S[-1], ref["S"], atol=1e-7)


def test_energy_balance_of_the_cell(table1: dict[str, Any]) -> None:
    """Q = Q_irr + d/dt(½C1V1² + ½C2V2²): the pack integrals must differ by the stored RC energy."""
    r = table1["proposed"]
    ev = r.ev
    stored = stored_energy_J(r.V1, r.V2, ev.cell) * ev.pack.n_cells
    np.testing.assert_allclose(r.heat_J[-1] - r.heat_irr_J[-1], stored[-1] - stored[0], rtol=1e-5, atol=1e-6)
    assert np.all(np.diff(r.heat_irr_J, axis=0) >= -1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_charge_balance(method: str) -> None:
    """ΔS = −∫I dt/(3600 C_n): a trapezoid on the sampled current converges (second order in the
    sample spacing) to the integrated S."""
    errs = []
    for dt in (0.01, 0.002):
        r = simulate_platoon(
            PaperLeader(), [OVFL()] * 5, GAPS, SPEEDS, 70.0, dt_out=dt, rtol=1e-9, atol=1e-9, method=method, ev=PAPER
        )  # (saturation kinks the current: no second order)
        charge = np.trapezoid(r.current_A, r.t * r.units.time_s, axis=0)
        dS = -charge / (3600 * r.ev.cell.capacity_Ah)
        errs.append(np.abs((r.S[-1] - r.S[0] - dS) / dS).max())
    assert errs[1] < 1e-4
    assert errs[1] < errs[0] / 15  # (0.01/0.002)² = 25 for a second-order rule


@pytest.mark.quick
def test_table1_converged_across_tolerances(table1: dict[str, Any]) -> None:
    r = table1["proposed"]
    loose = simulate_platoon(
        PaperLeader(), [Proposed()] * 5, GAPS, SPEEDS, 70.0, rtol=1e-8, atol=1e-8, dt_out=0.02, ev=PAPER
    )
    np.testing.assert_allclose(loose.omega[-1], r.omega[-1], atol=5e-6)


@pytest.mark.parametrize("method", METHODS)
def test_steady_state_follower_uses_cruise_power(method: str) -> None:
    """At equilibrium behind a constant leader, P_w = F_res(v) v and ω = 0 (no acceleration)."""
    from aev_ocp.models import equilibrium_gap
    from aev_ocp.models.vehicle import road_load_force_N

    ev = EVParams()
    v = 1.5
    r = simulate_platoon(ConstantSpeed(v), [Proposed()], [equilibrium_gap(v)], [v], 10.0, ev=ev, method=method)
    assert np.max(np.abs(r.accel)) < 1e-9 and abs(r.omega[-1, 0]) < 1e-9
    vs = ev.units.speed_to_si(v)
    P_c = float(road_load_force_N(vs, ev.vehicle)) * vs / ev.vehicle.efficiency / ev.pack.n_cells
    # at t = 0: S = 0.8 (a knot of the OCV table, 3.3352 V) and no polarisation; P_c = I (E − R_s I)
    E, R = 3.3352, ev.cell.R_s_ohm
    I = (E - np.sqrt(E**2 - 4 * R * P_c)) / (2 * R)
    assert r.current_A[0, 0] == pytest.approx(I, rel=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_collision_detected_with_time_and_vehicle(method: str) -> None:
    """OVM has no follow-the-leader term: a fast follower hits a stopped leader. Compare the time
    with SciPy's event location on the same ODE."""
    from scipy.integrate import solve_ivp

    r = simulate_platoon(ConstantSpeed(0.0), [OVM()], [0.5], [2.0], 10.0, battery=False, method=method, ev=PAPER)
    assert r.status == "collision"
    ev = r.events[0]
    assert ev.vehicle == 0

    def f(t: float, y: np.ndarray) -> list[float]:
        return [-y[1], 2.0 * (np.tanh(y[0] - 2) + np.tanh(2) - y[1])]

    hit = lambda t, y: y[0]  # noqa: E731
    hit.terminal = True
    sol = solve_ivp(f, (0, 10), [0.5, 2.0], events=hit, rtol=1e-10, atol=1e-12)
    assert ev.time == pytest.approx(sol.t_events[0][0], abs=1e-8)  # located on the integrator, not a sample
    # the trajectory ends at the contact: gap <= 0 there, so the run's min gap says so; impact speed in m/s
    assert r.t[-1] == ev.time and r.gap[-1, 0] <= 0 and np.all(r.gap[:-1] > 0)
    assert r.metrics()[0]["min_gap_m"] <= 0
    assert ev.impact_speed_mps == pytest.approx(r.units.speed_to_si(sol.y_events[0][0][1]), rel=1e-6)


@dataclass(frozen=True)
class Brake(CarFollowingLaw):
    """A user-defined law: constant braking (tests that laws are pluggable)."""

    decel: float = 1.3
    name = "brake"

    def accel(self, h, v, v_l):  # type: ignore[no-untyped-def]
        return -self.decel + 0 * h


@pytest.mark.parametrize("method", METHODS)
def test_negative_speed_detected(method: str) -> None:
    """v = 0.65 − 1.3 t crosses the plant's threshold −PLAN_TOLERANCE (the table's rule) at 0.5 + tol/1.3."""
    r = simulate_platoon(ConstantSpeed(1.0), [Brake()], [5.0], [0.65], 3.0, battery=False, method=method, ev=PAPER)
    assert r.status == "negative_speed"  # (with vehicle limits the brakes hold a stopped car: no reversing)
    assert r.events[0].time == pytest.approx(0.5 + PLAN_TOLERANCE / 1.3, abs=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_infeasible_current_detected(method: str) -> None:
    """One cell cannot drive a car: the current map reports the infeasible demand with its time."""
    ev = EVParams(pack=PackParams(1, 1))
    r = simulate_platoon(ConstantSpeed(1.7), [Proposed()], [3.5], [1.7], 5.0, ev=ev, method=method)
    assert r.status == "infeasible_current"
    assert r.events[0].time == 0.0 and r.events[0].vehicle == 0


@pytest.mark.quick
@pytest.mark.parametrize("method", METHODS)
def test_soc_out_of_range_detected(method: str) -> None:
    ev = EVParams(cell=CellParams(capacity_Ah=1e-4, soc0=0.01), pack=PackParams(106, 700))
    r = simulate_platoon(ConstantSpeed(1.7), [Proposed()], [3.5], [1.7], 50.0, ev=ev, method=method)
    assert r.status == "soc_out_of_range"
    assert 0 < r.events[0].time < 50


@pytest.mark.quick
def test_mixed_platoon_and_reuse() -> None:
    sim = PlatoonSimulator(PaperLeader(), [Proposed(), OVFL(), OVM(alpha=1.5)], options=SimOptions(dt_out=0.05))
    a = sim.run([0.3, 3.5, 3.5], [1.87] * 3, 30.0)
    b = sim.run([0.3, 3.5, 3.5], [1.87] * 3, 30.0)
    assert a.controllers == ["proposed", "ovfl", "ovm"]
    np.testing.assert_array_equal(a.omega, b.omega)


@pytest.mark.parametrize(
    "gaps,speeds,match",
    [
        ([0.0], [1.0], "initial gap of vehicle 1"),
        ([-1.0], [1.0], "initial gap"),
        ([1.0], [-0.1], "initial speed of vehicle 1"),
        ([1.0, 1.0], [1.0], "one per follower"),
    ],
)
def test_bad_initial_conditions(gaps: list[float], speeds: list[float], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        simulate_platoon(ConstantSpeed(1.0), [Proposed()], gaps, speeds, 1.0)


def test_hermite_min() -> None:
    # h(t) = (t − 0.3)² + 0.1 on [0, 1]: exact cubic, minimum 0.1 between samples
    assert _hermite_min(0.0, 1.0, 0.19, 0.59, -0.6, 1.4) == pytest.approx(0.1, abs=1e-12)
    t = np.array([0.0, 1.0, 2.0])
    h = (t - 1.3) ** 2 + 0.1
    assert min_gap_continuous(t, h, 2 * (t - 1.3)) == pytest.approx(0.1, abs=1e-12)


def test_min_gap_continuous_below_samples(table1: dict[str, Any]) -> None:
    r = table1["proposed"]
    m = r.metrics()
    assert all(mm["min_gap_model"] <= r.gap[:, i].min() + 1e-15 for i, mm in enumerate(m))
    assert all(mm["collisions"] == 0 for mm in m)


@pytest.mark.quick
def test_cascade_and_cvodes_agree_on_a_mixed_platoon() -> None:
    """The two integrators share no stepping code: their trajectories and integrals must agree."""
    laws = [Proposed(), OVFL(), OVM(alpha=1.5), Proposed(kappa=0.1)]
    res = {
        m: simulate_platoon(
            PaperLeader(),
            laws,
            [0.3, 3.5, 3.5, 3.5],
            [1.87] * 4,
            40.0,
            dt_out=0.05,
            rtol=1e-10,
            atol=1e-10,
            method=m,
            ev=PAPER,
        )
        for m in METHODS
    }
    a, b = res["cascade"], res["cvodes"]
    np.testing.assert_allclose(a.t, b.t, atol=1e-12)
    for name in ("gap", "speed", "S", "omega", "heat_J", "heat_irr_J", "int_ovm_err2", "int_rel_speed2"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-6, atol=1e-6, err_msg=name)
    # the cascade takes the predecessor's jerk from the derivative of its dense output (one order less)
    np.testing.assert_allclose(a.int_jerk2, b.int_jerk2, rtol=1e-5, atol=1e-6)


@pytest.mark.quick
def test_event_time_is_located_between_samples() -> None:
    """A 106s1p pack cannot follow the paper leader: both integrators place the infeasible-current event
    at the same time, well inside a sample interval (dt_out = 0.01)."""
    ev = EVParams(pack=PackParams(106, 1))
    times = {
        m: simulate_platoon(PaperLeader(), [Proposed()] * 5, GAPS, SPEEDS, 70.0, ev=ev, method=m).events[0]
        for m in METHODS
    }
    for e in times.values():
        assert e.kind == "infeasible_current" and e.vehicle == 0
    t = [e.time for e in times.values()]
    assert max(t) - min(t) < 1e-4


def test_no_compiler_auto_falls_back_to_cvodes_and_cascade_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    import aev_ocp.compiled as B
    import aev_ocp.simulate as S

    monkeypatch.setattr(B.shutil, "which", lambda name: None)
    monkeypatch.setattr(S, "_FALLBACK_WARNED", set())
    with pytest.warns(RuntimeWarning, match="compiled cascade is unavailable.*CVODES"):
        sim = PlatoonSimulator(ConstantSpeed(1.0), [Proposed(kappa=0.0123)], options=SimOptions(dt_out=0.1))
    assert sim.method == "cvodes"
    with pytest.raises(ParameterError, match="no C compiler found"):
        PlatoonSimulator(ConstantSpeed(1.0), [Proposed(kappa=0.0123)], options=SimOptions(method="cascade"))


def test_cascade_driver_compiles_cleanly_with_all_warnings(tmp_path: Path) -> None:
    """The shipped driver (aev_ocp/c/cascade.c) with its generated prologue compiles with -Wall -Werror."""
    import shutil
    import subprocess

    import aev_ocp.simulate as S

    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    sources: list[str] = []
    orig = S._compile_shared
    S._compile_shared = lambda src: (sources.append(src), orig(src))[1]  # type: ignore[assignment]
    try:
        PlatoonSimulator(PaperLeader(), [Proposed(kappa=0.0421), OVFL(beta=2.7)], options=SimOptions(method="cascade"))
    finally:
        S._compile_shared = orig  # type: ignore[assignment]
    c = tmp_path / "cascade_full.c"
    c.write_text(sources[0])
    res = subprocess.run(
        [cc, "-Wall", "-Werror", "-O1", "-fPIC", "-shared", "-o", str(tmp_path / "x.so"), str(c)],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr[-2000:]


def test_first_vehicle_stopped_at_t0_does_not_crash_the_cascade() -> None:
    """A pack of one cell cannot drive the second follower at all (the first one brakes, regenerating):
    it stops at t = 0 before its first step. The third then has no trajectory to follow; the cascade read that empty trajectory
    and crashed the interpreter (as rtol = atol = 1e-30 did, now refused by SimOptions). Subprocess: a
    crash fails the test instead of killing the suite."""
    import subprocess
    import sys

    code = (
        "from aev_ocp.simulate import simulate_platoon; from aev_ocp.models import PaperLeader, Proposed; "
        "from aev_ocp.params import EVParams, PackParams; "
        "r = simulate_platoon(PaperLeader(), [Proposed()] * 3, [0.3, 3.5, 3.5], [1.87] * 3, 9.0, "
        "ev=EVParams(pack=PackParams(1, 1)), method='cascade'); "
        "print(r.status, r.events[0].vehicle, r.t.size, r.speed[0].tolist())"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parents[1])
    assert res.returncode == 0, res.stderr[-1500:]
    assert res.stdout.split()[:3] == ["infeasible_current", "1", "1"]
    with pytest.raises(ParameterError, match="rtol"):
        SimOptions(rtol=1e-30, atol=1e-30)


def test_law_coefficients_are_runtime_parameters_of_the_cascade() -> None:
    """A κ (or α, β, …) sweep generates ONE C source (compiled once), and each run still uses its own
    coefficients: the cascade agrees with CVODES, which builds the law's coefficients in."""
    import aev_ocp.simulate as S

    sources: list[str] = []
    orig = S._compile_shared
    S._compile_shared = lambda src: (sources.append(src), orig(src))[1]  # type: ignore[assignment]
    try:
        runs = {
            k: simulate_platoon(
                PaperLeader(),
                [Proposed(kappa=k, alpha=1.9), OVFL(beta=2.6)],
                [0.3, 3.1],
                [1.87, 1.8],
                25.0,
                method="cascade",
            )
            for k in (0.0217, 0.0731)
        }
    finally:
        S._compile_shared = orig  # type: ignore[assignment]
    assert len(sources) == 2 and sources[0] == sources[1]
    assert abs(runs[0.0217].omega[-1, 0] - runs[0.0731].omega[-1, 0]) > 1e-3
    for k, r in runs.items():
        ref = simulate_platoon(
            PaperLeader(),
            [Proposed(kappa=k, alpha=1.9), OVFL(beta=2.6)],
            [0.3, 3.1],
            [1.87, 1.8],
            25.0,
            method="cvodes",
        )
        np.testing.assert_allclose(r.omega[-1], ref.omega[-1], rtol=1e-6, atol=1e-7)


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
def test_cascade_step_limit_grows_with_the_horizon(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fixed total of max_num_steps per vehicle cut long trips short with an unactionable 'raise max_num_steps'
    (e.g. a US06 leader held past its end, 5000 s: integration_failed at 4660 s). The limit is now per
    STEP_LIMIT_SPAN of model time. Scaled down here (span 20, 1000 steps) so that Table 1's 70 time units need
    4 spans: the run completes and equals the run with an unlimited budget to the last bit; with the horizon's
    single span it stops, and the message names the limit and the keys a user can change."""
    import aev_ocp.simulate as sim
    from aev_ocp.models.carfollowing import Proposed
    from aev_ocp.models.leader import PaperLeader
    from aev_ocp.params import SimOptions

    def run(max_steps: int):  # noqa: ANN202
        opts = SimOptions(dt_out=0.05, max_num_steps=max_steps, method="cascade")
        return sim.PlatoonSimulator(PaperLeader(), [Proposed()] * 2, None, opts).run([0.3, 3.5], [1.87, 1.87], 70.0)

    assert sim.cascade_step_limit(1000, 70.0) == 1000 and sim.cascade_step_limit(1000, 2500.0) == 3000
    monkeypatch.setattr(sim, "STEP_LIMIT_SPAN", 20.0)
    ref, got = run(10**9), run(1000)
    if "cascade" not in str(ref.meta):
        pytest.skip("no C compiler: the cascade did not run")
    assert max(s["nsteps"] + s["nrejected"] for s in ref.solver_stats) > 1000  # the old fixed total was too small
    assert got.status == "ok" and np.array_equal(got.omega, ref.omega) and np.array_equal(got.speed, ref.speed)
    monkeypatch.setattr(sim, "STEP_LIMIT_SPAN", 1000.0)
    cut = run(1000)
    assert cut.status == "integration_failed"
    assert "more than 1000 steps for this vehicle: loosen simulation.rtol/atol" in cut.events[0].message
