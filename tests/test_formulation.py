"""One formulation object (issue 20 items 1-2) and runs cut at a time or distance (issue 21 item 5)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from aev_ocp.metrics import vehicle_metrics, violation_bounds
from aev_ocp.models import PaperLeader, Proposed
from aev_ocp.mpc import MPCSettings, MPCVehicle, run_closed_loop
from aev_ocp.mpc.policy import MPCPolicy
from aev_ocp.ocp.following import FollowingBounds, FollowingWeights, following_problem
from aev_ocp.ocp.formulation import (
    Formulation,
    formulation_from_dict,
    problem_formulation,
    s9_formulation,
    traffic_formulation,
)
from aev_ocp.ocp.traffic import TrafficParams
from aev_ocp.params import UNLIMITED, EVParams, ParameterError, Units
from aev_ocp.simulate import simulate_platoon
from aev_ocp.truncation import equal_views, time_at_distance, truncate_at_distance, truncate_at_time

EV = EVParams(units=Units(12.0, 7.0))  # not the default units: model and SI differ


def _headway(f9: Formulation):
    pb = following_problem(EV, f9.bounds, f9.smooth, f9.objective, name="s9_headway")
    pb.subject_to(pb.x["h"] - 1.3 * pb.x["v"], lb=f9.bounds.h_min, soft=40.0, name="headway")
    return pb


def test_a_user_problem_is_its_own_formulation_every_derived_item_follows() -> None:
    """A §9 problem (+ headway) given as problem=: its bounds (violations, plots), the fallback's a bounds, its
    name, its cold start, its cost key and its OCP-D problem all follow it, never the traffic formulation (the
    default of MPCVehicle(settings) alone). The mismatch the issue found (§9 under traffic-derived items) fails."""
    f9 = s9_formulation(bounds=FollowingBounds(h_min=0.23, v_max=1.7, a_min=-2.6, a_max=1.45))
    s = MPCSettings(N=6, solver="ipopt", codegen=False, predictor="oracle")
    pol = MPCPolicy(s, EV, Proposed(), "constant-velocity", problem=_headway(f9))
    f = pol.formulation
    assert (f.kind, f.family, f.name, f.cost_key) == ("problem", "s9", "s9_headway", "cost_problem")
    assert pol.name == "mpc(s9_headway)" and not pol.controller.rti_cold_start  # §9's cold IPOPT start
    bm = pol.describe()["bounds_model"]
    assert (bm["h_min"], bm["v_max"], bm["a_min"], bm["a_max"]) == (0.23, 1.7, -2.6, 1.45)
    acc = 7.0**2 / 12.0  # the acceleration unit [m/s²]
    # the fallback's a bounds: the formulation's, within the vehicle's limits (-8, 4 m/s²) when it has them ...
    assert (pol._fallback.a_min, pol._fallback.a_max) == pytest.approx((max(-2.6, -8.0 / acc), min(1.45, 4.0 / acc)))
    # ... and exactly the formulation's when the vehicle has none
    free = MPCPolicy(s, replace(EV, limits=UNLIMITED), Proposed(), "constant-velocity", problem=_headway(f9))
    assert (free._fallback.a_min, free._fallback.a_max) == pytest.approx((-2.6, 1.45), rel=1e-14)
    assert f.oracle_problem(EV, 0.1).control_names == ["a", "slack_headway"]
    # the default is the traffic formulation: different everything (its bounds from its SI parameters)
    t = MPCPolicy(s, EV, Proposed(), "constant-velocity")
    tb = t.describe()["bounds_model"]
    assert t.name == "mpc(traffic)" and t.controller.rti_cold_start and t.formulation.cost_key == "cost_traffic"
    assert tb["h_min"] == pytest.approx(2.0 / 12.0) and tb["v_max"] == pytest.approx(45.0 / 7.0)
    lim = EV.limits
    assert (t._fallback.a_min, t._fallback.a_max) == pytest.approx((lim.a_min_mps2 / acc, lim.a_max_mps2 / acc))
    with pytest.raises(ParameterError, match="not both"):
        MPCVehicle(s, problem=_headway(f9), formulation=f9)


def test_violations_are_counted_against_the_running_formulations_bounds() -> None:
    """A §9 MPC's run: speed_violations count against §9's v_max (here 1.2, below the leader's 1.7), not the traffic
    formulation's 45 m/s (6.4 model); recounted by hand."""
    f9 = s9_formulation(bounds=FollowingBounds(v_max=1.2))
    s = MPCSettings(N=5, solver="ipopt", codegen=False, predictor="oracle")
    r = run_closed_loop(PaperLeader(), [MPCVehicle(s, formulation=f9)], [0.9], [1.15], 1.0, ev=EV)
    assert violation_bounds(r, 0) == (0.2, 1.2)
    m = vehicle_metrics(r, 0)
    assert m["speed_violations"] == int(np.sum(r.speed[1:, 0] > 1.2 + 1e-9))
    assert r.controllers == ["mpc(w_Q=1)"]


def test_mpc_table_keys_route_into_the_formulation() -> None:
    f = formulation_from_dict(
        {"formulation": "s9", "w_Q": 2.5, "h_min": 0.31, "objective": "omega", "smoothing_width_W": 170.0}
    )
    assert (f.kind, f.weights.w_Q, f.bounds.h_min, f.objective, f.smooth.smoothing_width_W) == (
        "s9",
        2.5,
        0.31,
        "omega",
        170.0,
    )
    assert formulation_from_dict({"time_headway_s": 1.3}).traffic == TrafficParams(time_headway_s=1.3)
    with pytest.raises(ParameterError, match="w_Q applies to the §9 formulation only"):
        formulation_from_dict({"w_Q": 2.0})
    with pytest.raises(ParameterError, match="time_headway_s applies to the traffic formulation only"):
        formulation_from_dict({"formulation": "s9", "time_headway_s": 1.3})
    with pytest.raises(ParameterError, match="not a solver option"):
        MPCSettings().with_(weights=FollowingWeights())
    assert problem_formulation(traffic_formulation()) == traffic_formulation()


def test_bound_role_is_checked_against_every_run() -> None:
    from aev_ocp.ocp.oracle import bound_role as _bound_role

    ms = {"mpc": [{"cost_traffic": 874.69}], "proposed": [{"cost_traffic": 1201.3}]}
    assert _bound_role(874.6, ms, "cost_traffic") == ("bound", "")
    role, why = _bound_role(1545.8, ms, "cost_traffic")  # the 'bound' above the run it bounds
    assert role == "reference" and "mpc" in why and "1545.8" in why
    assert _bound_role(874.69 * (1 + 5e-5), ms, "cost_traffic")[0] == "bound"  # within BOUND_RTOL (plant mismatch)


# ----------------------------------------------------------------------------- truncation
T_CUT = 4.1372  # model time, not a sample of the dt_out = 0.05 grid


@pytest.fixture(scope="module")
def law_runs():
    law = Proposed()
    long = simulate_platoon(PaperLeader(), [law, law], [0.7, 0.55], [1.62, 1.48], 7.3, ev=EV, dt_out=0.05)
    short = simulate_platoon(PaperLeader(), [law, law], [0.7, 0.55], [1.62, 1.48], T_CUT, ev=EV, dt_out=0.05)
    return long, short


#: measured: ≤ 5e-5 relative (ω of follower 1, whose a crosses 0 near the cut: the η switch's kink inside the
#: interval); taking the nearest sample instead is off by ~4e-3
RTOL_CUT = 1e-4
KEYS = (
    "omega_model",
    "heat_pack_J",
    "heat_irr_pack_J",
    "delta_soc",
    "distance_m",
    "duration_s",
    "min_gap_model",
    "rms_ovm_error_model",
    "rms_rel_speed_model",
    "heat_pack_J_per_km",
)


def test_truncation_at_a_time_equals_a_run_that_stops_there(law_runs) -> None:
    """The long run cut at T_CUT has the metrics of the run that stops at T_CUT (the state interpolated inside
    the sample interval, not the nearest sample: that would be off by ~1e-2 relative here)."""
    long, short = law_runs
    cut = truncate_at_time(long, T_CUT)
    assert cut.t[-1] == T_CUT and short.t[-1] == pytest.approx(T_CUT)
    for i in (0, 1):
        a, b = vehicle_metrics(cut, i), vehicle_metrics(short, i)
        for k in KEYS:
            assert a[k] == pytest.approx(b[k], rel=RTOL_CUT, abs=1e-12), (i, k, a[k], b[k])
    assert np.allclose(cut.gap[-1], short.gap[-1], rtol=1e-6) and np.allclose(cut.speed[-1], short.speed[-1], rtol=1e-6)
    with pytest.raises(ParameterError, match="t_cut"):
        truncate_at_time(long, 7.31)


def test_truncation_at_a_distance(law_runs) -> None:
    """Cut where follower 2 has travelled 41.7 m: its distance is 41.7 m, and the metrics equal a run stopped
    at that time."""
    long, _ = law_runs
    cut = truncate_at_distance(long, 1, 41.7)
    assert vehicle_metrics(cut, 1)["distance_m"] == pytest.approx(41.7, rel=1e-9)
    t_d = time_at_distance(long, 1, EV.units.length_from_si(41.7))
    assert cut.t[-1] == t_d and long.t[0] < t_d < long.t[-1]
    short = simulate_platoon(PaperLeader(), [Proposed()] * 2, [0.7, 0.55], [1.62, 1.48], t_d, ev=EV, dt_out=0.05)
    a, b = vehicle_metrics(cut, 1), vehicle_metrics(short, 1)
    for k in KEYS:
        assert a[k] == pytest.approx(b[k], rel=RTOL_CUT, abs=1e-12), (k, a[k], b[k])


def test_equal_views_cut_every_run_at_the_shortest_distance_and_common_time(law_runs) -> None:
    long, short = law_runs
    v = equal_views({"long": long, "short": short}, vehicle=0)
    d_short = vehicle_metrics(short, 0)["distance_m"]
    assert v["distance"]["cut_m"] == pytest.approx(d_short, rel=1e-12)
    assert v["time"]["cut_s"] == pytest.approx(EV.units.time_to_si(short.t[-1]))
    for view in ("distance", "time"):
        runs = v[view]["runs"]
        assert runs["long"]["heat_pack_J"] == pytest.approx(runs["short"]["heat_pack_J"], rel=RTOL_CUT)  # the same run
        assert sorted(r["rank"] for r in runs.values()) == [1, 2]
    assert math.isclose(v["distance"]["runs"]["long"]["distance_m"], d_short, rel_tol=1e-9)
