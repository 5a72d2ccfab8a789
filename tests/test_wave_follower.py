"""The wave MPC's follower term (leading cruise control; aev_ocp.mpc.wave, WaveParams.follower_*) against independent
results: the ring's rear-radar observation is the simulator's stored state of the vehicle behind; the linearised human
law's equilibrium gap solves the IDM's a = 0 and its slopes are the IDM's finite differences; the MPC's prediction of the
follower is a direct simulation (SciPy) of the linearised law under the car's own plan, and close to one of the IDM
itself; the term pulls a slow follower (the car accelerates) and brakes a fast one; without a measured follower the
term is off (the command of the weight-0 controller); with its weights 0 the problem is today's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp.loop import Command, Observation
from aev_ocp.models.carfollowing import IDM, OVM, Proposed
from aev_ocp.mpc.controller import MPCController
from aev_ocp.mpc.settings import MPCSettings
from aev_ocp.mpc.wave import FOLLOWER_STATES, WaveMPC, WaveParams, follower_linearisation, wave_problem
from aev_ocp.ocp.formulation import problem_formulation
from aev_ocp.params import EVParams, Units

EV = EVParams()
U = EV.units
S = MPCSettings(codegen=False)  # interpreted: no C compiled for the tests' parameter sets
LAW = WaveParams().follower_law  # the calibrated ring population's median IDM
W_F = 40.0
OFF = WaveParams(follower_speed_weight=0.0)  # the term off (the wave MPC as before it)


class Radar:
    """A sampled controller that records (t [model], its follower observation) and commands 0.1 m/s²."""

    name = "radar"

    def __init__(self, units: Units, dt_s: float = 0.2) -> None:
        self.units, self.dt = units, float(units.time_from_si(dt_s))
        self.seen: list[tuple[float, np.ndarray | None]] = []

    def reset(self) -> None:
        self.seen = []

    def command(self, obs: Observation) -> Command:
        self.seen.append((obs.t, None if obs.follower is None else obs.follower.copy()))
        return Command(float(self.units.accel_from_si(0.1)))

    def describe(self) -> dict:
        return {"controller": self.name}


def test_the_ring_observes_the_vehicle_behind_as_the_simulator_stores_it():
    """Vehicle 1 of 4 (followed by vehicle 2; vehicle 0 by the last one, around the ring): at every control instant its
    observed follower is vehicle 2's gap and speed in the ring's stored output at that instant."""
    from aev_ocp.ring.simulate import RingOptions, RingRoad, RingSimulator, uniform_flow

    radar = Radar(U)
    ring = RingRoad(160.0, (OVM(), radar, IDM(), OVM()), ev=EV)
    res = RingSimulator(ring, RingOptions(dt_out_s=0.2)).run(uniform_flow(ring, speed_mps=7.0, shift_m=3.0), 6.0)
    assert len(radar.seen) == 30
    t_out = np.asarray(res.t_s)
    moving = 0.0
    for t, fol in radar.seen:
        assert fol is not None
        k = int(np.argmin(abs(t_out - float(U.time_to_si(t)))))
        assert abs(t_out[k] - float(U.time_to_si(t))) < 1e-9
        assert float(U.length_to_si(fol[0])) == pytest.approx(res.gap_m[k, 2], rel=1e-9, abs=1e-9)
        assert float(U.speed_to_si(fol[1])) == pytest.approx(res.speed_mps[k, 2], rel=1e-9, abs=1e-9)
        moving = max(moving, abs(res.speed_mps[k, 2] - 7.0))
    assert moving > 0.05  # the follower's state changes over the run: the match is not of constants


@pytest.mark.parametrize("v_star", [2.3, 6.1, 11.7])
def test_the_linearisation_is_the_idms_equilibrium_and_slopes(v_star):
    idm = IDM(LAW.a_mps2, LAW.b_mps2, LAW.v0_mps, LAW.s0_m, LAW.T_s)
    h, a_h, a_v, a_l = (float(x) for x in follower_linearisation(LAW, v_star))
    assert idm.accel(h, v_star, v_star) == pytest.approx(0.0, abs=1e-12)
    assert h > LAW.s0_m + v_star * LAW.T_s  # (s0 + vT)/√(1 − (v/v0)^4) > s0 + vT
    e = 1e-6
    fd = [
        (idm.accel(h + e, v_star, v_star) - idm.accel(h - e, v_star, v_star)) / (2 * e),
        (idm.accel(h, v_star + e, v_star) - idm.accel(h, v_star - e, v_star)) / (2 * e),
        (idm.accel(h, v_star, v_star + e) - idm.accel(h, v_star, v_star - e)) / (2 * e),
    ]
    np.testing.assert_allclose([a_h, a_v, a_l], fd, rtol=1e-6)
    assert a_h > 0 and a_v < 0 and a_l > 0  # more gap: faster; own speed and closing speed: slower


def _plan(wp: WaveParams, h_m: float, v_mps: float, vref_mps: float, hf_m: float, vf_mps: float) -> np.ndarray:
    """The converged plan X (SI rows h, v, h_f, v_f) of the wave problem (IPOPT), the predecessor at v_mps."""
    s = S.with_(solver="ipopt", tol=1e-10)
    pb = wave_problem(EV, wp, s.dt)
    ctl = MPCController(s, EV, formulation=problem_formulation(pb))
    z0 = np.array([float(U.length_from_si(h_m)), float(U.speed_from_si(v_mps)), 0.0, 0.0, EV.cell.soc0])
    vl = np.full(s.N, float(U.speed_from_si(v_mps)))
    own = {
        "a_prev": 0.0,
        "v_ref": float(U.speed_from_si(vref_mps)),
        "h_f": float(U.length_from_si(hf_m)),
        "v_f": float(U.speed_from_si(vf_mps)),
        "follower_on": 1.0,
    }
    sol = ctl.solve(z0, vl, vl, own=own)
    assert sol.success, sol.status
    names = list(ctl.problem.state_names)
    X = sol.X
    return np.array(
        [
            U.length_to_si(X[names.index("h")]),
            U.speed_to_si(X[names.index("v")]),
            U.length_to_si(X[names.index("h_f")]),
            U.speed_to_si(X[names.index("v_f")]),
        ]
    )


def test_the_predicted_follower_is_a_simulation_of_the_human_law_under_the_cars_plan():
    """A follower 0.6 m/s slower than v_ref = 5 m/s, 0.8 m beyond its equilibrium gap: the plan's h_f, v_f are the
    linearised law integrated by SciPy under the plan's own speed (linear between nodes), to 2e-3 m/s, and within
    20 % of the speed deviation of the nonlinear IDM integrated the same way."""
    v_ref, dt_s = 5.0, float(U.time_to_si(S.dt))
    h_star, a_h, a_v, a_l = (float(x) for x in follower_linearisation(LAW, v_ref))
    hf0, vf0 = h_star + 0.8, v_ref - 0.6
    X = _plan(WaveParams(follower_speed_weight=W_F), 15.0, v_ref, v_ref, hf0, vf0)
    t = dt_s * np.arange(X.shape[1])
    v_car = lambda tt: np.interp(tt, t, X[1])  # noqa: E731

    def linear(tt, y):
        return [v_car(tt) - y[1], a_h * (y[0] - h_star) + a_v * (y[1] - v_ref) + a_l * (v_car(tt) - v_ref)]

    idm = IDM(LAW.a_mps2, LAW.b_mps2, LAW.v0_mps, LAW.s0_m, LAW.T_s)

    def nonlinear(tt, y):
        return [v_car(tt) - y[1], idm.accel(y[0], y[1], v_car(tt))]

    lin = solve_ivp(linear, (0, t[-1]), [hf0, vf0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt_s / 4)
    nl = solve_ivp(nonlinear, (0, t[-1]), [hf0, vf0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt_s / 4)
    assert np.max(abs(X[3] - lin.y[1])) < 2e-3 and np.max(abs(X[2] - lin.y[0])) < 2e-3
    dev = nl.y[1] - v_ref
    assert np.max(abs(X[3] - nl.y[1])) < 0.2 * np.max(abs(dev))
    assert X[3, -1] - X[3, 0] > 0.1  # the follower speeds up over the horizon: the comparison is not of a constant


def _first_move(wp: WaveParams, follower: np.ndarray | None) -> float:
    c = WaveMPC(EV, Proposed(), wp, S)
    v = float(U.speed_from_si(5.0))
    c.average.update(v)
    z = np.array([float(U.length_from_si(18.0)), v, 0.0, 0.0, EV.cell.soc0])
    ob = Observation(0.0, S.dt, 0, z, np.array([0.0]), np.array([v]), None, 0.0, follower=follower)
    cmd = c.command(ob)
    assert cmd.ok, cmd.status
    return float(U.accel_to_si(cmd.a))


def _follower(dv_mps: float) -> np.ndarray:
    h_star = float(follower_linearisation(LAW, 5.0)[0])
    return np.array([float(U.length_from_si(h_star)), float(U.speed_from_si(5.0 + dv_mps))])


def test_the_term_pulls_a_slow_follower_and_holds_back_a_fast_one():
    """The car at v_ref = 5 m/s, its gap inside the band: a follower at equilibrium leaves its move where the weight-0
    car's is; a follower 1 m/s slower makes it accelerate (it opens the gap the follower speeds up into), one 1 m/s
    faster makes it brake."""
    base = _first_move(replace(OFF, catch_gain_per_s=0.0), None)
    wp = WaveParams(catch_gain_per_s=0.0, follower_speed_weight=W_F)
    at_eq, slow, fast = (_first_move(wp, _follower(dv)) for dv in (0.0, -1.0, 1.0))
    assert abs(at_eq - base) < 0.02
    assert slow > base + 0.05 and fast < base - 0.05


def test_without_a_measured_follower_the_term_is_off():
    """No follower observed (the platoon's last car, a simulator without a rear radar): over five warm-started steps
    the weighted controller's commands are the weight-0 controller's, bit for bit (such steps are its follower-less
    twin's)."""
    for h, v in ((18.0, 5.0), (9.0, 6.5), (30.0, 3.0)):
        moves = []
        for wp in (OFF, WaveParams(follower_speed_weight=W_F, follower_terminal_speed_weight=3.0)):
            c = WaveMPC(EV, Proposed(), wp, S)
            c.average.update(float(U.speed_from_si(4.0)))
            z = np.array([float(U.length_from_si(h)), float(U.speed_from_si(v)), 0.0, 0.0, EV.cell.soc0])
            vl = float(U.speed_from_si(4.5))
            seen = [Observation(0.1 * k, S.dt, 0, z, np.array([0.0]), np.array([vl]), None, 0.0) for k in range(5)]
            moves.append([(c.command(o).a, c.v_ref) for o in seen])
        assert moves[1] == moves[0]
        assert np.ptp([a for a, _ in moves[0]]) > 1e-3  # the steps differ: warm starts, not one solve repeated


def _move_at(wp: WaveParams, v_mps: float, follower: np.ndarray | None) -> tuple[float, bool]:
    """The first move [m/s²] of a wave MPC at own speed v_mps = v_ref (k = 0), 18 m behind a leader at the same speed,
    and whether it was solved."""
    c = WaveMPC(EV, Proposed(), replace(wp, catch_gain_per_s=0.0), S)
    v = float(U.speed_from_si(v_mps))
    z = np.array([float(U.length_from_si(18.0 + 1.2 * v_mps)), v, 0.0, 0.0, EV.cell.soc0])
    cmd = c.command(Observation(0.0, S.dt, 0, z, np.array([0.0]), np.array([v]), None, 0.0, follower=follower))
    return float(U.accel_to_si(cmd.a)), cmd.ok


@pytest.mark.parametrize(
    "v_mps, gap_m, vf_mps, used",
    [
        (5.0, 58.7, 5.4, True),  # within the radar's range (60 m): the far, fast follower moves the car
        (5.0, 61.3, 5.4, False),  # beyond it: no follower
        (14.2, 31.0, 13.1, True),  # v_ref below 0.9 v0 = 14.7 m/s of the calibrated law: its equilibrium exists
        (15.3, 31.0, 13.1, False),  # above: the law has no equilibrium near v_ref (NaN at v0 = 16.35 m/s): none
    ],
)
def test_a_follower_out_of_range_or_where_the_law_has_no_equilibrium_is_none(v_mps, gap_m, vf_mps, used):
    """A measured follower the term cannot use (farther than ``follower_range_m``, or v_ref above FOLLOWER_V0_SHARE of
    the law's v0, where SUMO's merge put NaN into the problem) leaves the command the weight-0 controller's, bit for
    bit, and solved; one it can use changes it."""
    fol = np.array([float(U.length_from_si(gap_m)), float(U.speed_from_si(vf_mps))])
    on = WaveParams(follower_speed_weight=W_F)
    assert on.follower_range_m == 60.0 and 0.9 * LAW.v0_mps == pytest.approx(14.715)
    a_on, ok_on = _move_at(on, v_mps, fol)
    a_off, ok_off = _move_at(OFF, v_mps, fol)
    assert ok_on and ok_off
    if used:
        assert abs(a_on - a_off) > 1e-3
    else:
        assert a_on == a_off


def test_a_follower_that_comes_and_goes_keeps_one_reference():
    """A follower measured, then not, then again: v_ref stays the mean of every own speed measured (one window,
    shared by the controller and its follower-less twin) and each step is solved (no fallback)."""
    c = WaveMPC(EV, Proposed(), WaveParams(window_s=1.0, catch_gain_per_s=0.0, follower_speed_weight=W_F), S)
    speeds = [4.1, 4.9, 3.7, 5.3, 4.4, 3.9, 5.1, 4.6]
    fol = _follower(-0.5)
    for k, v in enumerate(speeds):
        z = np.array([float(U.length_from_si(15.0)), float(U.speed_from_si(v)), 0.0, 0.0, EV.cell.soc0])
        ob = Observation(0.1 * k, S.dt, 0, z, np.array([0.0]), np.array([U.speed_from_si(4.5)]), None, 0.0)
        ob.follower = None if k in (2, 3, 6) else fol
        cmd = c.command(ob)
        assert cmd.ok, (k, cmd.status)
        want = np.mean(speeds[max(0, k - 4) : k + 1])  # 5 samples of 0.2 s
        assert float(U.speed_to_si(c.v_ref)) == pytest.approx(want, rel=1e-12), k


def test_with_weights_zero_the_problem_is_todays_and_ignores_the_follower():
    """The follower weights 0 (the defaults) build the problem without the follower states, and then a measured
    follower changes nothing (bit-identical commands with and without it)."""
    assert not set(FOLLOWER_STATES) & set(wave_problem(EV, OFF).x)
    assert set(FOLLOWER_STATES) <= set(wave_problem(EV, replace(OFF, follower_terminal_speed_weight=1.0)).x)
    assert WaveParams() == OFF  # the default: the term off (the calibrated ring's [ring.wave] sets it)
    moves = [_first_move(OFF, f) for f in (None, _follower(-1.0))]
    assert moves[0] == moves[1]


class SumoRadar(Radar):
    """:class:`Radar` in a SUMO run, also recording the vehicle behind as SUMO's state gives it without
    ``getFollower``: the vehicle whose leader (``getLeader``) is this one, its gap (plus its minGap) and speed [SI]."""

    def __init__(self, units: Units, vid: str) -> None:
        super().__init__(units, 0.2)
        self.vid, self.truth = vid, []

    def command(self, obs: Observation) -> Command:
        import libsumo

        V = libsumo.vehicle
        behind = [
            (V.getLeader(o, 100.0)[1] + libsumo.vehicletype.getMinGap(V.getTypeID(o)), V.getSpeed(o))
            for o in V.getIDList()
            if o != self.vid and V.getLeader(o, 100.0) and V.getLeader(o, 100.0)[0] == self.vid
        ]
        self.truth.append(min(behind) if behind else None)
        return super().command(obs)


SUMO_RADARS: list[SumoRadar] = []


def sumo_radar(ev: EVParams) -> SumoRadar:
    """The SUMO 'module:function' form of SumoRadar (on the ring's vehicle ring.3)."""
    SUMO_RADARS.append(SumoRadar(ev.units, "ring.3"))
    return SUMO_RADARS[-1]


@pytest.mark.parametrize("human, lookahead_m", [("krauss", 250.0), ("idm", 250.0), ("krauss", 4.7)])
def test_sumo_observes_the_vehicle_behind_as_its_own_leader_gap_gives_it(human, lookahead_m):
    """In the SUMO ring (Krauss drivers: no minGap; IDM drivers: minGap s0 = 2 m) the controlled car's follower
    observation is the gap (plus minGap) and speed of the vehicle whose leader it is, read from SUMO independently of
    getFollower, at every control instant; with a radar range (the lookahead) shorter than some of those gaps, a
    vehicle farther behind is no follower (None; SUMO's getFollower may return it)."""
    from aev_ocp.sumo import sumo_available

    if not sumo_available():
        pytest.skip("SUMO is not installed (pip install 'aev_ocp[sumo]')")
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    doc = {
        "sumo": {
            "network": "ring",
            "t_end_s": 8.0,
            "step_s": 0.1,
            "controller": f"{__name__}:sumo_radar",
            "share": 0.0,
            "ids": ["ring.3"],
            "ring": {"human": human},
            "lookahead_m": lookahead_m,
        }
    }
    SUMO_RADARS.clear()
    run_sumo(parse_sumo_scenario(doc))
    r = SUMO_RADARS[-1]
    seen = [(fol, tr) for (_, fol), tr in zip(r.seen, r.truth) if tr is not None and tr[0] <= lookahead_m]
    beyond = [fol for (_, fol), tr in zip(r.seen, r.truth) if tr is not None and tr[0] > lookahead_m]
    assert len(seen) >= 20 and (lookahead_m > 100 or len(beyond) >= 5)
    assert all(fol is None for fol in beyond)
    for fol, (gap_m, v_mps) in seen:
        assert fol is not None
        assert float(r.units.length_to_si(fol[0])) == pytest.approx(gap_m, abs=1e-6)
        assert float(r.units.speed_to_si(fol[1])) == pytest.approx(v_mps, abs=1e-9)
    assert np.ptp([tr[0] for _, tr in seen]) > 0.05  # the gap changes over the run


def test_the_guide_quotes_the_follower_terms_evaluation_on_fresh_seeds():
    """The guide's paragraph on the follower term's one evaluation (fresh seeds 120–139, the term off against on,
    paired) quotes the run recorded in tests/data: both speed-std ratios and their paired difference as means and 95 %
    t intervals (recomputed here with SciPy from the per-seed values), the seeds above 0.20, and every seed's pair."""
    import json
    from pathlib import Path

    from scipy import stats

    root = Path(__file__).parents[1]
    doc = json.loads((root / "tests/data/bench_wave_mpc_ring_wave_follower_seeds120-139.json").read_text("utf-8"))
    assert doc["seeds"] == list(range(120, 140))
    assert "follower_speed_weight=0.0" in doc["wave_params"]
    assert "follower_speed_weight=300," in doc["variant_params"]  # (given as the integer 300)
    ps = doc["per_seed"]
    ratio = {
        c: np.array([ps[str(k)][c]["speed_std_mps"] / ps[str(k)]["human"]["speed_std_mps"] for k in doc["seeds"]])
        for c in ("wave-mpc", "wave-mpc-variant")
    }

    def cell(x: np.ndarray, sign: str = "") -> str:
        half = stats.t.ppf(0.975, x.size - 1) * np.std(x, ddof=1) / np.sqrt(x.size)
        return f"{x.mean():{sign}.3f} [{x.mean() - half:{sign}.3f}, {x.mean() + half:{sign}.3f}]"

    text = (root / "docs" / "guide" / "studies.md").read_text(encoding="utf-8")
    start = text.index("**The follower term on the fresh seeds 120–139")
    para = " ".join(text[start : text.index("\n\n", start)].split()).replace("−", "-")
    for c in ratio:
        assert cell(ratio[c]) in para, c
        assert f"{int(np.sum(ratio[c] > 0.20))} of 20 above 0.20" in para, c
        iv = doc["variant"][c]["speed_std_ratio_to_human"]
        assert iv["mean"] == pytest.approx(ratio[c].mean(), rel=1e-12)
    assert cell(ratio["wave-mpc-variant"] - ratio["wave-mpc"], "+") in para
    pairs = ", ".join(f"{a:.3f}/{b:.3f}" for a, b in zip(ratio["wave-mpc"], ratio["wave-mpc-variant"]))
    assert pairs in para


def test_the_calibrated_ring_sets_the_follower_term_and_feeds_it():
    """scenarios/ring_wave.toml's [ring.wave] turns the term on (w_f = 300, its evaluated value) for its wave-MPC car,
    whose ring gives it the vehicle behind at every step (the term's states in the problem it solves)."""
    from pathlib import Path

    from aev_ocp.ring.scenario import build_ring, load_ring_scenario

    sc = load_ring_scenario(Path(__file__).parents[1] / "scenarios" / "ring_wave.toml")
    ring, _ = build_ring(sc, "wave-mpc")
    car = ring.vehicles[0]
    assert isinstance(car, WaveMPC) and car.params.follower_speed_weight == 300.0 and car.with_follower
    assert set(FOLLOWER_STATES) <= set(car.controller.problem.state_names)
