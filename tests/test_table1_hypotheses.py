"""The Table 1 hypotheses (issue 10 item 6) against independent evaluations: the CVODES quadratures against
SciPy's DOP853 on a hand-written NumPy platoon, the baseline against the simulator, the forward-Euler
mapaccum against a NumPy loop, the Riemann sums against the simulator's samples, and the fitted
regeneration efficiency by substituting it back."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import PaperLeader
from aev_ocp.params import UNLIMITED, EVParams, ParameterError, VehicleParams
from aev_ocp.simulate import simulate_platoon
from aev_ocp import table1_hypotheses as th

AL, BE, KA, EP = 1.7, 2.6, 0.045, 1e-3  # distinct, non-special coefficients
ETA = 0.77
GAPS, SPEEDS = (0.45, 2.9), (1.83, 1.76)


def _law(h: float, v: float, vl: float, kappa: float) -> float:
    V = math.tanh(h - 2.0) + math.tanh(2.0)
    dv = vl - v
    return AL * (V - v) + BE * dv / h**2 - kappa * v * v * dv * dv / (dv * dv + EP)


def _leader_accel(t: float, L: PaperLeader) -> float:
    return -L.amplitude * (math.sin(L.w1 * t) + math.cos(L.w2 * t)) if t < L.t_end else 0.0


def _np_rhs(t: float, y: np.ndarray, kappa: float, L: PaperLeader, gs: list) -> np.ndarray:
    n = len(GAPS)
    xl, vl, pos, vel = y[0], y[1], y[2 : 2 + n], y[2 + n : 2 + 2 * n]
    ax, av = np.r_[xl, pos[:-1]], np.r_[vl, vel[:-1]]
    a = np.array([_law(ax[i] - pos[i], vel[i], av[i], kappa) for i in range(n)])
    q = [vel[i] * g(a[i]) for g in gs for i in range(n)]
    return np.r_[vl, _leader_accel(t, L), vel, a, q]


NP_G = {
    "exact": lambda a: a / ETA if a >= 0 else ETA * a,
    "smoothed": lambda a: (
        a * (0.5 * (1 + math.tanh(a / th.SMOOTH_WIDTH)) / ETA + (1 - 0.5 * (1 + math.tanh(a / th.SMOOTH_WIDTH))) * ETA)
    ),
    "regen_eta2": lambda a: a / ETA if a >= 0 else ETA**2 * a,
    "regen_full": lambda a: a / ETA if a >= 0 else a,
    "no_regen": lambda a: a / ETA if a >= 0 else 0.0,
}


def _setup(kappa: float = KA) -> th.PlatoonSetup:
    L = PaperLeader()
    law = Proposed(AL, BE, kappa, EP) if kappa else OVFL(AL, BE)
    return th.PlatoonSetup(L, (law, law), GAPS, SPEEDS, ETA, (L.t_end,))


def _scipy_omegas(t_end: float, kappa: float) -> dict[str, np.ndarray]:
    L = PaperLeader()
    gs = list(NP_G.values())
    n = len(GAPS)
    y0 = np.r_[0.0, L.v0, -np.cumsum(GAPS), SPEEDS, np.zeros(n * len(gs))]
    y = y0
    for lo, hi in ((0.0, L.t_end), (L.t_end, t_end)):  # restart at the leader's switch, as the module does
        sol = solve_ivp(_np_rhs, (lo, hi), y, method="DOP853", rtol=1e-11, atol=1e-11, args=(kappa, L, gs))
        y = sol.y[:, -1]
    q = y[2 + 2 * n :]
    return {name: q[j * n : (j + 1) * n] for j, name in enumerate(NP_G)}


@pytest.fixture(scope="module")
def traj() -> th.Trajectory:
    return th.integrate(_setup(), 26.0, dt_grid=0.1)


def test_every_g_variant_matches_scipy(traj: th.Trajectory) -> None:
    want = _scipy_omegas(26.0, KA)
    for name, w in want.items():
        np.testing.assert_allclose(traj.window(name, 0.0, 26.0), w, rtol=2e-6, atol=2e-6, err_msg=name)


def test_baseline_is_the_simulators_omega(traj: th.Trajectory) -> None:
    s = _setup()
    ev = EVParams(vehicle=VehicleParams(efficiency=ETA), limits=UNLIMITED)  # Table 1's laws: no vehicle limits
    r = simulate_platoon(
        s.leader, list(s.laws), list(GAPS), list(SPEEDS), 26.0, ev=ev, dt_out=0.1, rtol=1e-10, atol=1e-10
    )
    np.testing.assert_allclose(traj.omega["exact"][-1], r.omega[-1], rtol=1e-6, atol=1e-7)
    k = int(np.argmin(np.abs(r.t - 13.0)))  # an intermediate window end, on both grids
    assert r.t[k] == pytest.approx(13.0, abs=1e-12)
    np.testing.assert_allclose(traj.window("exact", 0.0, 13.0), r.omega[k], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(traj.window("exact", 13.0, 26.0), r.omega[-1] - r.omega[k], rtol=1e-6, atol=1e-7)
    # the Riemann sum at Δ = 0.5 over [0, 20) from the simulator's samples (another integrator)
    ks = [int(np.argmin(np.abs(r.t - tk))) for tk in np.arange(0.0, 20.0 - 1e-9, 0.5)]
    np.testing.assert_allclose(r.t[ks], np.arange(0.0, 20.0 - 1e-9, 0.5), atol=1e-12)
    a, v = r.accel[ks], r.speed[ks]
    hand = np.sum(v * np.where(a >= 0, a / ETA, ETA * a), axis=0) * 0.5
    np.testing.assert_allclose(th.riemann_omega(traj, ETA, 0.5, 20.0), hand, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("kappa", [KA, 0.0])
def test_forward_euler_matches_a_numpy_loop(kappa: float) -> None:
    h, t_end = 0.05, 12.0
    L = PaperLeader()
    n = len(GAPS)
    pos, vel = -np.cumsum(GAPS), np.array(SPEEDS, float)
    xl, vl, om = 0.0, L.v0, np.zeros(n)
    for k in range(int(round(t_end / h))):
        t = k * h
        ax, av = np.r_[xl, pos[:-1]], np.r_[vl, vel[:-1]]
        a = np.array([_law(ax[i] - pos[i], vel[i], av[i], kappa) for i in range(n)])
        om += h * vel * np.where(a >= 0, a / ETA, ETA * a)
        pos, vel, xl, vl = pos + h * vel, vel + h * a, xl + h * vl, vl + h * _leader_accel(t, L)
    np.testing.assert_allclose(th.euler_omega(_setup(kappa), t_end, h), om, rtol=1e-10, atol=1e-12)


def test_a_diverging_euler_run_is_nan_and_bad_steps_are_refused() -> None:
    s = _setup()
    assert np.all(np.isnan(th.euler_omega(s, 40.0, 0.8)))  # far beyond the stiff braking term's stability limit
    with pytest.raises(ParameterError, match="multiple"):
        th.euler_omega(s, 10.0, 0.3)


def test_fitted_regeneration_reproduces_the_target(traj: th.Trajectory) -> None:
    target = traj.window("exact", 0.0, 26.0) * np.array([1.043, 1.087])
    c = th.fitted_regeneration(traj, target, 26.0)
    for i, ci in enumerate(c):
        tr = th.integrate(
            _setup(), 26.0, dt_grid=0.1, variants={"c": lambda a, ci=ci: ca.if_else(a >= 0, a / ETA, ci * a)}
        )
        assert tr.window("c", 0.0, 26.0)[i] == pytest.approx(target[i], rel=1e-7)


def test_window_off_the_grid_is_refused(traj: th.Trajectory) -> None:
    with pytest.raises(ParameterError, match="grid"):
        traj.window("exact", 0.0, 13.03)


def test_setup_is_validated() -> None:
    with pytest.raises(ParameterError, match="eta"):
        th.PlatoonSetup(PaperLeader(), (OVFL(),), (1.0,), (1.0,), 1.3)
    with pytest.raises(ParameterError, match="one entry per follower"):
        th.PlatoonSetup(PaperLeader(), (OVFL(),), (1.0, 2.0), (1.0,), 0.8)


def test_table1_hypotheses_reproduce_our_table1() -> None:
    from aev_ocp.report import PAPER_TABLE1
    from aev_ocp.scenarios import load_scenario

    setups = th.table1_setups()
    hyps, extra = th.run_hypotheses(
        setups["proposed"],
        PAPER_TABLE1["proposed"],
        euler_steps=(0.05,),
        sample_steps=(0.5,),
        ends=(60.0,),
        starts=(1.0,),
    )
    s = load_scenario("table1")
    r = simulate_platoon(s.leader, [s.law("proposed")] * s.n_followers, **s.simulate_kwargs())
    base = next(h for h in hyps if h.key == "baseline")
    np.testing.assert_allclose(base.omega, r.omega[-1], rtol=1e-6)
    np.testing.assert_allclose(
        base.deviation_pct, 100 * (r.omega[-1] / np.array(PAPER_TABLE1["proposed"]) - 1), rtol=1e-5
    )
    assert not base.fits  # the gap this module exists to explain
    md = th.hypotheses_markdown({"proposed": (hyps, extra)})
    assert "printed (paper)" in md and "1.827" in md and "regeneration efficiency c" in md
