"""What a controlled SUMO car knows of the road (aev_ocp.loop.Observation.speed_limit, .lane_end, .merge_speed)
against SUMO's own state read independently in the controller: its lane's legal limit (and the merge network's
stated limits), whether the obstacle it measures is the end of its lane (the merge's acceleration lane), with the gap
then the distance to that end, and there the speed SUMO's driver model would drive (the merge advice)."""

from __future__ import annotations

import numpy as np
import pytest

from aev_ocp.control import Command
from aev_ocp.loop import Observation
from aev_ocp.params import EVParams, Units

VID = "ramp.1"  # (the ramp's second car: the first, a SUMO driver, is its leader on the ramp)


class MapReader:
    """A sampled controller recording (lane, lane_end, speed_limit [m/s], gap [m]) with SUMO's truth (its lane's
    limit, the distance from its front to its lane's end, its leader's gap); it never changes lanes and holds about 19.5 m/s while its obstacle
    is over 60 m ahead and brakes at 2 m/s² nearer (it may reach the acceleration lane's end)."""

    name = "map-reader"

    def __init__(self, units: Units) -> None:
        self.units, self.dt = units, float(units.time_from_si(0.2))
        self.seen: list[dict] = []

    def reset(self) -> None:
        self.seen = []

    def command(self, obs: Observation) -> Command:
        import libsumo

        u, V = self.units, libsumo.vehicle
        V.setLaneChangeMode(VID, 0)  # no lane change: it drives on to the acceleration lane's end
        lane = V.getLaneID(VID)
        lead = V.getLeader(VID, 1000.0)
        self.seen.append(
            {
                "lane": lane,
                "lane_end": obs.lane_end,
                "limit": None if obs.speed_limit is None else float(u.speed_to_si(obs.speed_limit)),
                "limit_true": libsumo.lane.getMaxSpeed(lane),
                "left_true": libsumo.lane.getLength(lane) - V.getLanePosition(VID),
                "lead_gap": lead[1] if lead and lead[0] else np.inf,
                "gap": float(u.length_to_si(obs.z[0])),
                "merge": None if obs.merge_speed is None else float(u.speed_to_si(obs.merge_speed)),
                "merge_true": V.getSpeedWithoutTraCI(VID),
            }
        )
        v, h = float(u.speed_to_si(obs.z[1])), float(u.length_to_si(obs.z[0]))
        return Command(float(u.accel_from_si(0.4 * (19.5 - v) if h > 60.0 else -2.0)))

    def describe(self) -> dict:
        return {"controller": self.name}


READERS: list[MapReader] = []


def map_reader(ev: EVParams) -> MapReader:
    """The SUMO 'module:function' form of MapReader."""
    READERS.append(MapReader(ev.units))
    return READERS[-1]


def test_a_controlled_car_knows_its_lanes_limit_and_when_its_obstacle_is_its_lanes_end():
    from aev_ocp.sumo import sumo_available

    if not sumo_available():
        pytest.skip("SUMO is not installed (pip install 'aev_ocp[sumo]')")
    from aev_ocp.sumo.networks import MergeNetwork
    from aev_ocp.sumo.run import run_sumo
    from aev_ocp.sumo.scenario import parse_sumo_scenario

    lookahead_m = 230.0
    doc = {
        "sumo": {
            "network": "merge",
            "t_end_s": 45.0,
            "step_s": 0.1,
            "controller": f"{__name__}:map_reader",
            "share": 0.0,
            "ids": [VID],
            "lookahead_m": lookahead_m,
            "merge": {"main_flow_vph": 1300.0, "ramp_flow_vph": 700.0},
        }
    }
    READERS.clear()
    run_sumo(parse_sumo_scenario(doc))
    seen = READERS[-1].seen
    net = MergeNetwork()
    on_accel = [s for s in seen if s["lane"] == "accel_0"]
    assert len(on_accel) >= 5 and any(s["lane"].startswith("ramp") for s in seen)
    for s in seen:
        assert s["limit"] == pytest.approx(s["limit_true"], rel=1e-12)
        if not s["lane"].startswith(":"):  # (a junction's internal lane has its own speed)
            stated = net.ramp_speed_mps if s["lane"].startswith("ramp") else net.main_speed_mps
            assert s["limit"] == pytest.approx(stated, rel=1e-12)
    for s in on_accel:  # the acceleration lane ends: its end is the obstacle unless a vehicle is nearer
        end_ahead = s["left_true"] < lookahead_m and not s["lead_gap"] <= s["left_true"]
        assert s["lane_end"] == end_ahead
        if end_ahead:
            assert s["gap"] == pytest.approx(s["left_true"], abs=1e-6)
    assert any(s["lane_end"] for s in on_accel)
    for s in seen:  # a merge assistant's advice only at the lane's end: the speed SUMO's own driver model asks
        if s["lane_end"]:
            assert s["merge"] == pytest.approx(s["merge_true"], rel=1e-9)
        else:
            assert s["merge"] is None
    assert any(abs(s["merge"] - s["limit"]) > 1.0 for s in seen if s["lane_end"])  # the advice is not the limit
    assert any(s["lead_gap"] < 150.0 and not s["lane_end"] for s in seen)  # a vehicle ahead is no lane end
    for s in seen:
        if s["lane"] not in ("accel_0", "ramp_0") and not s["lane"].startswith(":"):
            assert not s["lane_end"]  # a lane whose route goes on without a lane change
        if s["lane"] == "ramp_0" and s["lane_end"]:  # the end seen from the ramp is beyond the whole accel lane
            assert s["gap"] > s["left_true"] + 0.99 * 250.0
