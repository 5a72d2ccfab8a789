"""The wave-damping MPC's SUMO integration: a sampled controller runs at the period it plans with (a whole number of
SUMO steps, whatever [units]), the named ``wave-mpc`` plans at the ring's 0.2 s, SUMO's IDM ring drives the
toolkit's IDM (its uniform flow to the digit, its stop-and-go wave against the toolkit's own ring simulation), and
FollowerStopper in SUMO is Stern et al.'s law with the scenario's desired speed."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from aev_ocp.control import Command
from aev_ocp.sumo import SumoError, sumo_available
from aev_ocp.sumo.run import controller_steps, make_controller_factory, run_sumo
from aev_ocp.sumo.scenario import load_sumo_scenario, parse_sumo_scenario

needs_sumo = pytest.mark.skipif(not sumo_available(), reason="SUMO is not installed (pip install 'aev_ocp[sumo]')")
SCENARIOS = Path(__file__).resolve().parents[1] / "aev_ocp" / "sumo" / "scenarios"
IDM = {"a": 1.0, "b": 1.5, "v0": 30.0, "s0": 2.0, "T": 1.0}  # Treiber et al. 2000, the toolkit's IDM_SI
GAP_M = 230.0 / 22 - 5.0  # the IDM ring's equal bumper-to-bumper gap


def _idm_uniform_speed(gap_m: float) -> float:
    """The IDM's equilibrium speed at gap_m [m]: s*(v, v) / sqrt(1 − (v/v0)^4) = gap (written out here)."""
    p = IDM
    return brentq(lambda v: (p["s0"] + v * p["T"]) / math.sqrt(1 - (v / p["v0"]) ** 4) - gap_m, 0.0, p["v0"] - 1e-9)


def _idm_doc(t_end_s: float, **ring: float) -> dict:
    doc = copy.deepcopy(load_sumo_scenario(SCENARIOS / "sumo_ring_idm.toml").document)
    doc["sumo"].update(t_end_s=t_end_s, share=0.0)
    doc["sumo"]["ring"].update(ring)
    return doc


def _speeds(run) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """(t [s], speeds [m/s] K × n) of every ring car."""
    rs = [run.vehicles[f"ring.{i}"] for i in range(len(run.vehicles))]
    u = rs[0].units
    return np.asarray(u.time_to_si(rs[0].t)), np.array([u.speed_to_si(r.speed[:, 0]) for r in rs]).T


# ----------------------------------------------------------------------------- the controller's period
class _Hold:
    """A sampled controller that commands +0.3 m/s² and −0.3 m/s² by turns, every dt [model time]."""

    name = "hold"

    def __init__(self, dt: float) -> None:
        self.dt, self.k = dt, 0

    def reset(self) -> None:
        self.k = 0

    def command(self, obs) -> Command:  # noqa: ANN001
        self.k += 1
        return Command(0.3 / 2.5 if self.k % 2 else -0.3 / 2.5)  # model accel at 5 m/s per 2 s: 2.5 m/s²

    def describe(self) -> dict:
        return {"controller": self.name}


class _Push(_Hold):
    """+0.3 m/s² at every step."""

    def command(self, obs) -> Command:  # noqa: ANN001
        return Command(0.3 / 2.5)


def push(ev):  # noqa: ANN001, ANN201
    return _Push(0.1 / ev.units.time_s)


def hold_fine(ev):  # noqa: ANN001, ANN201 - 'module:function' factories of the tests below
    return _Hold(0.05 / ev.units.time_s)  # 0.05 s: half a SUMO step


def hold_two_steps(ev):  # noqa: ANN001, ANN201
    return _Hold(0.2 / ev.units.time_s)  # 0.2 s: two SUMO steps


def test_a_controller_period_is_a_whole_number_of_sumo_steps() -> None:
    """Below, on and between whole numbers of steps (the quotient's round-off of 0.3 / 0.1 accepted)."""
    assert controller_steps(0.2, 0.1, "c") == 2
    assert controller_steps(0.3, 0.1, "c") == 3
    assert controller_steps(0.1, 0.1, "c") == 1
    for bad in (0.05, 0.15, 0.0):
        with pytest.raises(SumoError, match=r"sumo.controller = 'c': its controller's dt = .* s is not allowed"):
            controller_steps(bad, 0.1, "c")


def _hold_doc(factory: str, **sumo: object) -> dict:
    return {
        "units": {"length_m": 10.0, "speed_mps": 5.0},
        "limits": {"enabled": False},
        "sumo": {
            "network": "ring",
            "t_end_s": 2.0,
            "ids": ["ring.3"],
            "controller": f"{__name__}:{factory}",
            "ring": {"speed0_mps": 4.0},
            **sumo,
        },
    }


@needs_sumo
def test_a_sampled_controller_holds_its_command_for_its_own_period_in_sumo() -> None:
    """dt = 0.2 s: SUMO's realised acceleration is +0.3, −0.3 m/s² by turns, each held two 0.1 s steps (the
    controller's own period); dt = 0.05 s (half a step, which SUMO cannot sample) is refused by name."""
    run = run_sumo(parse_sumo_scenario(_hold_doc("hold_two_steps")))
    r = run.vehicles["ring.3"]
    v = np.asarray(r.units.speed_to_si(r.speed[:, 0]))
    a = np.diff(v) / 0.1  # SUMO's own steps
    k = np.arange(a.size)
    want = np.where((k // 2) % 2 == 0, 0.3, -0.3)
    assert np.allclose(a[: 2 * (a.size // 2)], want[: 2 * (a.size // 2)], atol=1e-9), a
    with pytest.raises(SumoError, match=r"dt = 0.05 s is not allowed: must be a whole number of SUMO steps"):
        run_sumo(parse_sumo_scenario(_hold_doc("hold_fine")))


@pytest.mark.parametrize("name", ["sumo_ring", "sumo_ring_idm", "sumo_merge"])
def test_the_wave_mpc_in_sumo_plans_at_the_rings_interval_whatever_the_units(name: str) -> None:
    """The shipped scenarios' units differ (a 0.5 s, 2 s, 0.67 s time unit); the named wave MPC plans at 0.2 s
    with a 38 s own-speed window (190 samples) in every one, as on the toolkit's ring (default units, dt 0.1)."""
    pytest.importorskip("libsumo")
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.mpc.wave import WaveParams

    doc = copy.deepcopy(load_sumo_scenario(SCENARIOS / f"{name}.toml").document)
    doc["sumo"]["controller"] = "wave-mpc"
    sc = parse_sumo_scenario(doc, name)
    _, factory = make_controller_factory(sc)
    assert factory is not None
    c = factory()
    ring_dt_s = MPCSettings().dt * 2.0  # the toolkit's ring: default units, T = 10 m / 5 m/s
    assert c.dt * sc.ev.units.time_s == pytest.approx(ring_dt_s, rel=1e-12)
    assert c.average.n == round(WaveParams().window_s / ring_dt_s) == 190


# ----------------------------------------------------------------------------- SUMO's IDM ring
@needs_sumo
def test_sumos_idm_ring_holds_the_idm_uniform_flow() -> None:
    """Started at the IDM's equilibrium speed at the equal gap (computed here), unperturbed, every car keeps it
    to 1e-3 m/s for 20 s: SUMO's IDM has the toolkit's s0 (minGap), T (tau), a, b, δ and v0. One car is the
    toolkit's FollowerStopper with r = that speed (at a 5.45 m gap it commands r): the gap it measures is the
    ring's geometry, 230/22 − 5 m bumper to bumper, although SUMO's leader distance leaves out the 2 m minGap."""
    v_eq = _idm_uniform_speed(GAP_M)
    assert v_eq == pytest.approx(3.454, abs=1e-3)
    doc = _idm_doc(20.0, speed0_mps=v_eq, perturbation_m=0.0)
    doc["sumo"].update(share=0.05, controller="followerstopper", desired_speed_mps=v_eq)
    run = run_sumo(parse_sumo_scenario(doc))
    _, v = _speeds(run)
    assert np.max(np.abs(v - v_eq)) < 1e-3, np.max(np.abs(v - v_eq))
    (vid,) = [k for k, c in run.controlled.items() if c]
    r = run.vehicles[vid]
    assert np.max(np.abs(np.asarray(r.units.length_to_si(r.gap[:, 0])) - GAP_M)) < 1e-3


@pytest.mark.slow  # about 7 s of one core (two SUMO runs of 300 s and the toolkit's ring)
@needs_sumo
def test_sumos_idm_ring_jams_as_the_toolkits_ring_and_its_krauss_ring_does_not() -> None:
    """The same ring (22 IDM cars of 5 m on 230 m, uniform flow, one car 2 m back, no noise) in SUMO and in the
    toolkit's own ODE simulation: over 200–300 s both have a stop-and-go wave of the same size (fleet speed std
    within 5 %, above 2 m/s) and mean speed (within 5 %); SUMO's shipped Krauss ring has none (std < 0.3 m/s)."""
    from aev_ocp.params import EVParams
    from aev_ocp.ring.laws import idm_si
    from aev_ocp.ring.simulate import RingOptions, RingRoad, RingSimulator, uniform_flow

    run = run_sumo(parse_sumo_scenario(_idm_doc(300.0)))
    t, v = _speeds(run)
    sumo_std, sumo_mean = float(np.std(v[t >= 200])), float(np.mean(v[t >= 200]))
    ring = RingRoad(230.0, tuple(idm_si(EVParams().units, **_si()) for _ in range(22)))
    res = RingSimulator(ring, RingOptions(dt_out_s=0.1)).run(uniform_flow(ring, shift_m=2.0), 300.0)
    vt = res.speed_mps[res.t_s >= 200]
    print("speed std, mean [m/s] over 200-300 s: SUMO", sumo_std, sumo_mean, "toolkit", vt.std(), vt.mean())
    assert sumo_std > 2.0 and vt.std() > 2.0
    assert sumo_std == pytest.approx(float(vt.std()), rel=0.05)  # measured 2.964 against 2.950 m/s
    assert sumo_mean == pytest.approx(float(vt.mean()), rel=0.05)  # 2.325 against 2.371 m/s
    krauss = copy.deepcopy(load_sumo_scenario(SCENARIOS / "sumo_ring.toml").document)
    krauss["sumo"].update(share=0.0, t_end_s=300.0)
    t, v = _speeds(run_sumo(parse_sumo_scenario(krauss)))
    assert float(np.std(v[t >= 200])) < 0.3


def _si() -> dict[str, float]:
    return {"a_mps2": IDM["a"], "b_mps2": IDM["b"], "v0_mps": IDM["v0"], "s0_m": IDM["s0"], "T_s": IDM["T"]}


# ----------------------------------------------------------------------------- FollowerStopper
def _fs_speed(h: np.ndarray, v: np.ndarray, vl: np.ndarray, r: float) -> np.ndarray:
    """Stern et al. 2018, eq. (FollowerStopper), written out in SI: the commanded speed."""
    dv = np.minimum(vl - v, 0.0)
    x1 = 4.5 + dv**2 / (2 * 1.5)
    x2 = 5.25 + dv**2 / (2 * 1.0)
    x3 = 6.0 + dv**2 / (2 * 0.5)
    vv = np.minimum(np.maximum(vl, 0.0), r)
    return np.where(
        h <= x1,
        0.0,
        np.where(h <= x2, vv * (h - x1) / (x2 - x1), np.where(h <= x3, vv + (r - vv) * (h - x2) / (x3 - x2), r)),
    )


@needs_sumo
def test_followerstopper_in_sumo_is_stern_et_als_law_with_the_scenarios_desired_speed() -> None:
    """Each SUMO step of the FollowerStopper car realises (v_cmd − v)/τ (τ 0.6 s) of its own sample; v_cmd written out
    from Stern et al. with r = desired_speed_mps; a scenario without desired_speed_mps is refused by name."""
    doc = _idm_doc(30.0)
    doc["sumo"].update(share=0.05, controller="followerstopper", desired_speed_mps=2.7)
    doc["limits"] = {"enabled": False}
    run = run_sumo(parse_sumo_scenario(doc))
    (vid,) = [k for k, c in run.controlled.items() if c]
    r = run.vehicles[vid]
    u = r.units
    v = np.asarray(u.speed_to_si(r.speed[:, 0]))
    h = np.asarray(u.length_to_si(r.gap[:, 0]))
    vl = np.asarray(u.speed_to_si(r.leader_speed))
    a = np.diff(v) / 0.1
    want = np.maximum((_fs_speed(h, v, vl, 2.7) - v) / 0.6, -v / 0.1)[:-1]
    assert np.max(np.abs(a - want)) < 1e-6, np.max(np.abs(a - want))
    assert np.ptp(want) > 0.5  # the car brakes and accelerates in those 30 s: the comparison is not trivial
    del doc["sumo"]["desired_speed_mps"]
    with pytest.raises(Exception, match=r"sumo.desired_speed_mps = .* is required with controller \"followerstopper\""):
        parse_sumo_scenario(doc)


@needs_sumo
def test_speed_limits_cap_the_toolkits_speed_at_the_lanes_limit() -> None:
    """A car pushed at +0.3 m/s² from 2.9 m/s on a ring whose lanes allow 3.2 m/s: with speed_limits it climbs at
    0.3 m/s² to 3.2 m/s and stays there (the network's limit); without, it passes it (speed mode 24 lifts it)."""
    for on in (True, False):
        doc = _hold_doc("push", speed_limits=on)
        doc["sumo"]["ring"] = {"speed0_mps": 2.9, "lane_speed_mps": 3.2}
        r = run_sumo(parse_sumo_scenario(doc)).vehicles["ring.3"]
        v = np.asarray(r.units.speed_to_si(r.speed[:, 0]))
        if on:
            want = np.minimum(2.9 + 0.3 * 0.1 * np.arange(v.size), 3.2)
            assert np.max(np.abs(v - want)) < 1e-9, v
        else:
            assert v[-1] > 3.2 + 0.2


def test_the_guide_quotes_every_recorded_sumo_wave_table_and_its_event_counts() -> None:
    """Every scenario of tests/data/bench_sumo_wave.json (written by ``bench_sumo.py --wave --record``) is quoted
    between its markers in docs/guide/studies.md, on seeds >= 100; each run's event counts are the sums of its
    per-seed counts, and a run's 'failed' is its number of seeds with a status other than 'ok'."""
    import json

    root = Path(__file__).resolve().parents[1]
    doc = json.loads((root / "tests" / "data" / "bench_sumo_wave.json").read_text(encoding="utf-8"))
    text = (root / "docs" / "guide" / "studies.md").read_text(encoding="utf-8")
    names = [k for k, v in doc.items() if isinstance(v, dict) and "rows" in v]
    assert set(names) == {"sumo_ring", "sumo_ring_idm", "sumo_merge"}
    assert doc["controller"] == "wave-mpc"
    for name in names:
        d = doc[name]
        assert len(d["seeds"]) >= 10 and min(d["seeds"]) >= 100
        start = text.index(f"<!-- bench_sumo_wave {name} -->")
        assert d["markdown"].strip() in text[start : text.index("<!-- end -->", start)]
        for row in d["rows"]:
            runs = [p for p in d["per_seed"] if f"{p['share']} {p['controller']}" == row["run"]]
            assert len(runs) == row["seeds"] == len(d["seeds"])
            assert row["failed"] == sum(p["status"] != "ok" for p in runs)
            for k, n in d["events"][row["run"]].items():
                assert n == sum(int(p[k] or 0) for p in runs)
