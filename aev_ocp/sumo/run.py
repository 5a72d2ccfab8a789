"""One SUMO run with the toolkit's controllers in the loop (libsumo in-process; one SUMO per process).

Each SUMO step (length dt [s], ballistic position update: a speed set for the step is reached linearly, so the
command is an acceleration held over the step, exactly the toolkit's zero-order hold):

1. SUMO advances; the toolkit reads every vehicle's speed, odometer and lane, records departures, arrivals (the
   vehicle left the network), teleports and collisions (the last two are events that end the vehicle's record);
2. the battery of every vehicle is integrated over the step on the motion SUMO realised (:mod:`.energy`);
3. every controlled vehicle observes what a car can: its leader's bumper-to-bumper gap and speed from SUMO
   (``getLeader`` within ``lookahead_m``; no leader: gap = lookahead and leader speed = own speed, i.e. free road;
   a lane that ends before the leader: a standing obstacle at its end) and its own speed; its controller commands
   an acceleration, saturated to the vehicle's [limits] (and never below standstill; with ``speed_limits`` never
   above the lane's legal limit), and ``setSpeed`` hands SUMO the speed reached at the end of the next step. A
   sampled controller commands every ``dt`` (a whole number of steps) and its command is held in between.

The speed mode of controlled vehicles (default 24, :data:`.scenario.DEFAULT_SPEED_MODE`) switches off SUMO's own
safe speed and acceleration bounds, so the controller alone decides (and a collision is possible: it is an
event). Ctrl-C (or any error) closes SUMO before the exception leaves :func:`run_sumo`.
"""

from __future__ import annotations

import hashlib
import importlib
import math
import os
import subprocess
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import interrupts
from ..loop import Controller, Observation, VehicleStep, stages_for
from ..models.carfollowing import CarFollowingLaw, make_law, optimal_velocity
from ..numerics import trapezoid
from ..plant import CURRENT_LIMIT, current_limit_events
from ..params import EVParams, VehicleLimits
from ..results import Event, SimulationResult
from . import SumoError, require_sumo, sumo_binary
from ..models import battery_step as energy
from .networks import build_merge, build_ring, first_error
from .scenario import SumoScenario, _few

ProgressFn = Callable[[float, float], None]
MEASUREMENT_WINDOW = 100  # leader-speed samples a controller keeps (the MPC's predictors use the last few)
#: the kinds of events that do not end a vehicle's record (its violations), counted in the fleet's tables
FLEET_EVENT_KINDS = ("emergency_braking", "lane_end_stop", CURRENT_LIMIT)
#: The statuses after which ``aev-ocp sumo`` exits 1 (as ``aev-ocp mpc`` does after an event that ends its run): a
#: vehicle's record ended (collision, teleport, a battery event), the run failed or was cut short. The fleet events
#: above are counted and reported, but the run went on: exit 0.
FAILED_STATUSES = ("collision", "teleport", "infeasible_current", "soc_out_of_range", "error", "interrupted")


def _draw(seed: int, vid: str) -> float:
    """A uniform number in [0, 1) from a hash of (seed, vehicle id): the same for the same seed and id."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{vid}".encode()).digest()[:8], "big") / 2.0**64


def is_controlled(vid: str, vtype: str, scenario: SumoScenario) -> bool:
    """Whether the toolkit drives vehicle ``vid`` of type ``vtype``: listed by id or type, or drawn by ``share``.

    Flows (vehicles not known in advance): each vehicle with probability ``share``, drawn by a hash of (seed, id).
    The shipped ring (its n cars known): exactly round(share·n) cars, those with the smallest draws. Either way the
    same vehicles for the same seed, and a larger share controls a superset."""
    s = scenario.spec
    if vid in s.ids or vtype in s.vtypes:
        return True
    if s.share <= 0:
        return False
    if s.network == "ring" and s.ring is not None:
        return vid in _ring_selection(s.seed, s.ring.vehicles, s.share)
    return _draw(s.seed, vid) < s.share


@lru_cache(maxsize=64)
def _ring_selection(seed: int, n: int, share: float) -> frozenset[str]:
    ids = sorted((f"ring.{i}" for i in range(n)), key=lambda v: _draw(seed, v))
    return frozenset(ids[: int(round(share * n))])


def controller_steps(period_s: float, step_s: float, name: str) -> int:
    """How many SUMO steps of ``step_s`` [s] one period ``period_s`` [s] of a sampled controller spans; SumoError
    naming ``sumo.controller`` when it is no whole number of steps (a controller sampled at another period than the
    one it plans with holds each command longer or shorter than it assumed)."""
    k = period_s / step_s
    if not (round(k) >= 1 and abs(k - round(k)) <= 1e-9 * max(1.0, k)):
        raise SumoError(
            f"sumo.controller = {name!r}: its controller's dt = {period_s:g} s is not allowed: must be a whole "
            f"number of SUMO steps (sumo.step_s = {step_s:g} s); a controller's dt is in model time, so it "
            "changes with [units]"
        )
    return int(round(k))


def check_ids_seen(scenario: SumoScenario, departed: list[str], t_s: float) -> None:
    """SumoError (bad input) naming ``sumo.ids`` if an id it lists never departed in a run of ``t_s`` [s]: it is
    not a vehicle of the network's routes (or departs after the run's end), so the toolkit drove nothing for it."""
    seen = sorted(set(departed))
    missing = [i for i in scenario.spec.ids if i not in seen]
    if missing:
        raise SumoError(
            f"sumo.ids = {list(scenario.spec.ids)!r} is not allowed: {', '.join(map(repr, missing))} never departed "
            f"in the {t_s:g} s run (no such vehicle in the routes, or it departs later); vehicles that did: {_few(seen) or 'none'}"
        )


@dataclass
class _Track:
    """What one vehicle did (SI, as read from SUMO) and its controller's bookkeeping."""

    vid: str
    vtype: str
    route: str
    controlled: bool
    controller: str
    min_gap_m: float
    depart_s: float
    t_s: list[float] = field(default_factory=list)
    v: list[float] = field(default_factory=list)
    odo: list[float] = field(default_factory=list)
    gap: list[float] = field(default_factory=list)
    v_lead: list[float] = field(default_factory=list)
    lane: list[str] = field(default_factory=list)
    lane_pos0: float = 0.0
    x_bat: list[np.ndarray] = field(default_factory=list)
    current: list[float] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    end: str = ""  # '' while live; 'arrived', 'teleport', 'collision', or a battery event
    end_s: float = math.nan
    ctrl: Controller | None = None
    law: CarFollowingLaw | None = None
    a_cmd_mps2: float = 0.0
    meas_t: deque[float] = field(default_factory=lambda: deque(maxlen=MEASUREMENT_WINDOW))
    meas_v: deque[float] = field(default_factory=lambda: deque(maxlen=MEASUREMENT_WINDOW))
    a_prev: float = 0.0
    step: VehicleStep | None = None  # the loop core of a controlled vehicle (aev_ocp.loop)
    a_floor_mps2: float = -math.inf  # the hardest deceleration the vehicle can make [m/s²] (below: an event)
    violations: list[Event] = field(default_factory=list)  # events that did not end the record
    at_lane_end: bool = False  # its obstacle at the last sample was the end of its lane


@dataclass
class SumoRun:
    """A finished SUMO run: one :class:`SimulationResult` per vehicle (keyed by SUMO id; a single follower each,
    its leader whoever SUMO reported), which of them the toolkit controlled, fleet-level events (departures are
    not events; arrivals, teleports, collisions are), wall time and SUMO time, the space-time offsets and the ring
    length (for wrapping positions; None off the ring)."""

    name: str
    scenario: SumoScenario
    vehicles: dict[str, SimulationResult]
    controlled: dict[str, bool]
    events: list[dict[str, Any]]
    t_end_s: float
    step_s: float
    steps: int
    wall_s: float
    controller_s: float
    offsets_m: dict[str, float] = field(default_factory=dict)
    ring_length_m: float | None = None
    interrupted: bool = False
    build_s: float = 0.0

    @property
    def status(self) -> str:
        """'ok' when no vehicle had an event; else the most severe kind that happened: 'interrupted', 'collision',
        'teleport', a battery event, then the events that did not end a record ('emergency_braking', 'lane_end_stop',
        'current_limit')."""
        if self.interrupted:
            return "interrupted"
        kinds = {e["kind"] for e in self.events if e["kind"] != "left_network"}
        kinds |= {r.status for r in self.vehicles.values() if r.status not in ("ok", "violated")}
        order = ["collision", "teleport", "infeasible_current", "soc_out_of_range", *FLEET_EVENT_KINDS]
        return next((k for k in order if k in kinds), next(iter(sorted(kinds)), "ok"))

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return self.t_end_s / self.wall_s if self.wall_s > 0 else math.inf

    def metrics(self) -> list[dict[str, Any]]:
        """The usual per-vehicle metrics (:func:`aev_ocp.metrics.vehicle_metrics`) of every vehicle, with its SUMO
        id, route, type and whether the toolkit drove it."""
        rows = []
        for vid, r in self.vehicles.items():
            m = r.metrics()[0]
            m.update(
                sumo_id=vid,
                controlled=self.controlled[vid],
                vtype=r.meta.get("vtype"),
                route=r.meta.get("route"),
                mean_speed_mps=_mean_speed(r),
            )
            rows.append(m)
        return rows

    def fleet_totals(self) -> dict[str, Any]:
        """Totals over all vehicles and over the controlled / SUMO-driven groups: count, distance [km], battery
        energy ∫P_b [MJ] and per km (kJ/km, kWh/100 km), pack heat [kJ] and per km [J/km], charge throughput per km
        [Ah/km], the paper's ω × vehicle mass per km (``omega_mass_kJ_per_km``: its inertial measure, road load
        excluded; not battery energy), mean speed [m/s], collisions, teleports, vehicles that left the network."""
        rows = self.metrics()
        mass = self.scenario.ev.vehicle.mass_kg

        def group(sel: list[dict[str, Any]]) -> dict[str, Any]:
            km = sum(_f(m["distance_m"]) for m in sel) / 1000.0
            e_J = sum(_f(m["battery_energy_J"]) for m in sel)
            w_J = sum(_f(m["omega_J_per_kg"]) * mass for m in sel)
            q_J = sum(_f(m["heat_pack_J"]) for m in sel)
            ah = sum(_f(m["charge_throughput_Ah_per_km"]) * _f(m["distance_m"]) / 1000.0 for m in sel)
            dur = sum(_f(m["duration_s"]) for m in sel)
            steps = [self.vehicles[m["sumo_id"]].meta.get("speed_steps", [0, 0.0, 0.0]) for m in sel]
            ns, s1, s2 = sum(x[0] for x in steps), sum(x[1] for x in steps), sum(x[2] for x in steps)
            brakes = sum(int(self.vehicles[m["sumo_id"]].meta.get("braking_events", 0)) for m in sel)
            return {
                "vehicles": len(sel),
                "distance_km": km,
                "battery_energy_MJ": e_J / 1e6,
                "heat_pack_kJ": q_J / 1e3,
                "battery_energy_kJ_per_km": e_J / 1e3 / km if km > 0 else math.nan,
                "battery_energy_kWh_per_100km": e_J / 3.6e4 / km if km > 0 else math.nan,
                "heat_pack_J_per_km": q_J / km if km > 0 else math.nan,
                "charge_throughput_Ah_per_km": ah / km if km > 0 else math.nan,
                "omega_mass_kJ_per_km": w_J / 1e3 / km if km > 0 else math.nan,
                "mean_speed_mps": 1000 * km / dur if dur > 0 else math.nan,
                "min_gap_m": min((_f(m["min_gap_m"]) for m in sel), default=math.nan),
                # over every vehicle's SUMO steps (not the thinned output)
                "speed_std_mps": math.sqrt(max(s2 / ns - (s1 / ns) ** 2, 0.0)) if ns else math.nan,
                "braking_events": brakes,
                "braking_events_per_veh_km": brakes / km if km > 0 else math.nan,
                "collisions": sum(1 for m in sel if m["status"] == "collision"),
                "teleports": sum(1 for m in sel if m["status"] == "teleport"),
                # the events that did not end a vehicle's record, counted over the group's vehicles
                **{
                    f"{k}_events": sum(1 for m in sel for e in self.vehicles[m["sumo_id"]].violations if e.kind == k)
                    for k in FLEET_EVENT_KINDS
                },
            }

        allg = group(rows)
        if self.ring_length_m:  # a ring: the flow k v̄ (density × mean speed) over the whole ring
            throughput = allg["vehicles"] / self.ring_length_m * 1000.0 * allg["mean_speed_mps"] * 3.6
            how = "density x mean speed"
        else:  # an open network: the vehicles that left it per hour (a detector at its exits)
            throughput = sum(1 for e in self.events if e["kind"] == "left_network") / self.t_end_s * 3600.0
            how = "vehicles leaving the network per hour"
        return {
            "throughput_veh_per_h": throughput,
            "throughput_from": how,
            "travel_time_per_lap_s": (
                self.ring_length_m / allg["mean_speed_mps"]
                if self.ring_length_m and allg["mean_speed_mps"] > 0
                else math.nan
            ),
            "all": allg,
            "controlled": group([m for m in rows if m["controlled"]]),
            "sumo": group([m for m in rows if not m["controlled"]]),
            "left_network": sum(1 for e in self.events if e["kind"] == "left_network"),
            "realtime_factor": self.realtime_factor,
            "wall_s": self.wall_s,
            "controller_s": self.controller_s,
        }

    def plot(self, panel: str | None = None) -> Any:
        """The space-time diagram (a matplotlib Figure) of one panel: a route's name, or ``"ring"`` on the ring
        (default the first panel); :func:`aev_ocp.sumo.plots.plot_space_time` draws every panel."""
        import matplotlib.pyplot as plt

        from .plots import plot_space_time

        figs = plot_space_time(self)
        if not figs:
            raise ValueError(f"SumoRun.plot: run {self.name!r} has no vehicle with two samples to draw")
        key = next(iter(figs)) if panel is None else panel
        if key not in figs:
            raise ValueError(f"SumoRun.plot: panel = {panel!r} is not one of {list(figs)}")
        for k, fig in figs.items():
            if k != key:
                plt.close(fig)
        return figs[key]

    def __repr__(self) -> str:
        n_c = sum(self.controlled.values())
        return (
            f"SumoRun({self.name!r}: {len(self.vehicles)} vehicles, {n_c} controlled, {self.t_end_s:g} s "
            f"simulated in {self.wall_s:.3g} s)"
        )


def _f(x: Any) -> float:
    try:
        return float(x) if x is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


def _mean_speed(r: SimulationResult) -> float:
    d = float(r.t[-1] - r.t[0]) if r.t.size > 1 else 0.0
    return (
        float(r.units.speed_to_si(trapezoid(r.speed[:, 0], r.t) / d))
        if d > 0
        else float(r.units.speed_to_si(r.speed[0, 0]))
    )


# ----------------------------------------------------------------------------- network and SUMO start
def prepare_inputs(scenario: SumoScenario, folder: Path) -> list[str]:
    """SUMO's input options of the scenario (a shipped network is built into ``folder``); user files are checked
    first by a separate SUMO process (which loads every route), so that a bad file gives SUMO's message as one
    line here and never reaches the in-process SUMO (a failed libsumo start cannot be retried in a process)."""
    s = scenario.spec
    if s.network == "ring":
        assert s.ring is not None
        net, routes = build_ring(s.ring, folder, s.t_end_s)
        return ["-n", str(net), "-r", ",".join(map(str, routes))]
    if s.network == "merge":
        assert s.merge is not None
        net, routes = build_merge(s.merge, folder, s.t_end_s)
        return ["-n", str(net), "-r", ",".join(map(str, routes))]
    if s.config_file is not None:
        args = ["-c", str(s.config_file)]
        files = [s.config_file]
    else:
        assert s.net_file is not None
        args = ["-n", str(s.net_file)] + (["-r", ",".join(map(str, s.route_files))] if s.route_files else [])
        files = [s.net_file, *s.route_files]
    for f in files:
        if not Path(f).is_file():
            raise SumoError(f"{f}: no such file")
    check_inputs(args)
    return args


def check_inputs(args: list[str]) -> None:
    """Load the network and every route with the ``sumo`` binary (no simulation); SumoError with SUMO's message."""
    cmd = [sumo_binary("sumo"), *args, "--end", "0", "--route-steps", "0", "--no-step-log", "true"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=300, env=_env())
    except subprocess.TimeoutExpired:
        raise SumoError("SUMO took more than 300 s to load the network and routes") from None
    if proc.returncode < 0:
        raise SumoError(
            f"SUMO crashed (signal {-proc.returncode}) reading {' '.join(args[1::2])}: a malformed "
            "network or route file?"
        )
    if proc.returncode != 0:
        raise SumoError(f"SUMO: {first_error(proc.stderr + proc.stdout)}")


def _env() -> dict[str, str]:
    import sumo

    return {**os.environ, "SUMO_HOME": sumo.SUMO_HOME}


def _start(ts: Any, args: list[str]) -> None:
    """libsumo.start with SUMO's stderr captured: a failure is a one-line SumoError with SUMO's message."""
    import sumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    with tempfile.TemporaryFile(mode="w+b") as err:
        saved = os.dup(2)
        try:
            os.dup2(err.fileno(), 2)
            try:
                ts.start(args)
                failed = None
            except Exception as exc:  # noqa: BLE001 - libsumo raises TraCIException / FatalTraCIError
                failed = exc
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if failed is not None:
            err.seek(0)
            raise SumoError(f"SUMO: {first_error(err.read().decode(errors='replace'))}")


# ----------------------------------------------------------------------------- controllers
def make_controller_factory(scenario: SumoScenario) -> tuple[CarFollowingLaw | None, Callable[[], Controller] | None]:
    """(law, None) for a law by name (evaluated for all its vehicles at once every step), else (None, factory)
    giving one new Controller per controlled vehicle."""
    name = scenario.spec.controller
    ev = scenario.ev
    if name == "mpc":
        from ..mpc.policy import MPCPolicy
        from ..mpc.predictors import make_predictor
        from ..models.carfollowing import Proposed

        cfg = scenario.mpc
        cf = scenario.cf
        fallback = Proposed(alpha=cf.alpha, beta=cf.beta, kappa=cf.kappa, eps=cf.eps)

        def mpc() -> Controller:
            pred = make_predictor(cfg.settings.predictor, None, cfg.settings.predictor_window, ev.units.time_s)
            return MPCPolicy(cfg.settings, ev, fallback, pred, formulation=cfg.formulation)

        return None, mpc
    if name == "wave-mpc":  # the wave-damping MPC: [mpc]'s solver settings (a whole number of SUMO steps)
        from ..mpc.wave import WaveMPC, WaveParams

        wave_cfg, wave_fallback = scenario.mpc, make_law("proposed", scenario.cf)  # the ring's wave MPC's SI law
        wave = WaveParams(**scenario.spec.wave) if scenario.spec.wave else None  # [sumo.wave]; None: the defaults
        return None, lambda: WaveMPC(ev, wave_fallback, wave, settings=wave_cfg.settings)
    if name == "followerstopper":  # Stern et al. 2018's law with the scenario's desired speed
        from ..ring.laws import FollowerStopper

        assert scenario.spec.desired_speed_mps is not None  # required by the scenario's parser
        return FollowerStopper.from_si(ev.units, scenario.spec.desired_speed_mps), None
    if ":" in name:
        mod, fn = name.split(":", 1)
        try:
            factory = getattr(importlib.import_module(mod), fn)
        except Exception as exc:  # noqa: BLE001 - the user's module: ImportError, AttributeError, SyntaxError, its own
            raise SumoError(f"sumo.controller = {name!r}: cannot import it ({type(exc).__name__}: {exc})") from None

        if not callable(factory):
            raise SumoError(f"sumo.controller = {name!r}: {fn} in {mod} is a {type(factory).__name__}, not a function")

        def user() -> Controller:
            try:
                c = factory(ev)
            except Exception as exc:  # noqa: BLE001 - the user's function: its error, named with the key that chose it
                raise SumoError(f"sumo.controller = {name!r}: {name}(ev) raised {type(exc).__name__}: {exc}") from exc
            if not isinstance(c, Controller):
                raise SumoError(
                    f"sumo.controller = {name!r} returned a {type(c).__name__}, not a Controller "
                    "(name, dt, reset, command, describe)"
                )
            dt = getattr(c, "dt", None)
            if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
                raise SumoError(
                    f"sumo.controller = {name!r}: its controller's dt = {dt!r} is not allowed: must be a finite "
                    "sampling period > 0 [model time]"
                )
            return c

        return None, user
    return make_law(name, scenario.cf), None


# ----------------------------------------------------------------------------- the run
def run_sumo(
    scenario: SumoScenario, workdir: str | Path | None = None, *, progress: ProgressFn | None = None, gui: bool = False
) -> SumoRun:
    """Run ``scenario`` in SUMO with its controlled vehicles driven by the toolkit; returns a :class:`SumoRun`.

    workdir: where a shipped network is built (default a temporary folder). progress(t_s, t_end_s) is called
    every simulated second. Bad SUMO inputs raise :class:`aev_ocp.sumo.SumoError` (SUMO's message, one line)."""
    ts = require_sumo()
    s = scenario.spec
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="aev_ocp_sumo_")
        workdir = tmp.name
    try:
        inputs = prepare_inputs(scenario, Path(workdir))
        args = [
            sumo_binary("sumo-gui" if gui else "sumo"),
            *inputs,
            "--step-length",
            repr(s.step_s),
            "--step-method.ballistic",
            "true",
            "--collision.action",
            s.collision_action,
            "--seed",
            str(s.seed),
            "--no-step-log",
            "true",
            "--no-warnings",
            "true",
            "--end",
            repr(s.t_end_s),
            *s.sumo_args,
        ]
        _start(ts, args)
        try:
            return _loop(ts, scenario, progress)
        finally:
            ts.close()
    finally:
        if tmp is not None:
            tmp.cleanup()


def _loop(ts: Any, sc: SumoScenario, progress: ProgressFn | None) -> SumoRun:
    """Step SUMO to the scenario's end with the toolkit driving its controlled vehicles (module docstring)."""
    lp = _SumoLoop(ts, sc)
    t0 = time.perf_counter()
    try:
        lp.run(progress)
    except KeyboardInterrupt:
        lp.interrupted = True
        raise
    finally:
        wall = time.perf_counter() - t0
    return lp.result(wall)


class _SumoLoop:
    """One SUMO run's loop state: the vehicles' records (live in ``tracks``, finished in ``done``), the fleet's
    events, each controlled vehicle's step core (:class:`aev_ocp.loop.VehicleStep`) and the run's clocks."""

    def __init__(self, ts: Any, sc: SumoScenario) -> None:
        s, ev = sc.spec, sc.ev
        self.ts, self.sc, self.s, self.ev, self.u, self.dt = ts, sc, s, ev, ev.units, s.step_s
        self.law, self.factory = make_controller_factory(sc)
        self.law_stages = stages_for(ev.limits, law=True, sensed=False)  # SUMO hands the controllers exact measurements
        self.ctrl_stages = stages_for(ev.limits, law=False, sensed=False)
        lim = ev.limits
        self.a_lo, self.a_hi = (lim.a_min_mps2, lim.a_max_mps2) if lim.enabled else (-math.inf, math.inf)
        # what a law's non-finite output becomes (a law evaluated where it has no value: brake as hard as the car can)
        self.a_emergency = self.a_lo if math.isfinite(self.a_lo) else VehicleLimits().a_min_mps2
        # a controlled car decelerating beyond its a_min (without limits: the tyre-road friction of the default
        # limits) was stopped by SUMO, not by its controller: an event (SUMO's emergency stop, e.g. at a lane end)
        self.a_floor = self.a_emergency
        self.floors: dict[str, float] = {}
        self.v_max = lim.v_max_mps if lim.enabled else math.inf
        self.ctrl_every = 1
        self.tracks: dict[str, _Track] = {}
        self.done: list[_Track] = []
        self.fleet_events: list[dict[str, Any]] = []
        self.min_gaps: dict[str, float] = {}
        self.ring = s.ring if s.network == "ring" else None
        self.offsets: dict[str, float] = {}
        self.lane_ends: dict[tuple[str, int, str], float | None] = {}
        self.limits: dict[str, float] = {}  # the lanes' speed limits [m/s]
        self.V = ts.vehicle
        self.t_ctrl = 0.0
        self.t_build = 0.0  # building sampled controllers (an MPC builds its NLP once per vehicle)
        self.k = 0
        self.interrupted = False

    # ------------------------------------------------------------------ records
    def finish(self, tr: _Track, why: str, t_s: float) -> None:
        tr.end, tr.end_s = why, t_s
        self.tracks.pop(tr.vid, None)
        self.done.append(tr)

    def release(self, vid: str) -> None:
        """Give a vehicle whose record ended back to SUMO."""
        try:
            self.V.setSpeed(vid, -1)
            self.V.setSpeedMode(vid, 31)
        except Exception:  # noqa: BLE001 - it may have left already
            pass

    def stop(self, tr: _Track, kind: str, t_s: float, message: str, **extra: Any) -> None:
        """The record of ``tr`` ends with an Event of ``kind`` at t_s [s]; the vehicle goes back to SUMO."""
        tr.events.append(Event(kind, self.u.time_from_si(t_s), 0, message, time_s=t_s, **extra))
        self.finish(tr, kind, t_s)
        self.release(tr.vid)

    # ------------------------------------------------------------------ the loop
    def run(self, progress: ProgressFn | None) -> None:
        """Every SUMO step: advance SUMO, record who came and went, read the state, integrate the batteries,
        end the records of vehicles with a battery event, command the controlled vehicles."""
        ts, s, dt = self.ts, self.s, self.dt
        K = int(round(s.t_end_s / dt))
        next_progress = 1.0
        while self.k < K:
            interrupts.check()
            ts.simulationStep()
            self.k += 1
            t_s = ts.simulation.getTime()
            for vid in ts.simulation.getDepartedIDList():
                self.depart(vid, t_s)
            self.fleet_changes(t_s)
            live = list(self.tracks.values())
            for tr in live:  # read the state SUMO reached at t_s
                self.read(tr, t_s)
            _battery(self.ev, live, dt)  # battery over the step just made
            for tr in [tr for tr in live if tr.events]:
                self.finish(tr, tr.events[-1].kind, t_s)
                if tr.controlled:
                    self.release(tr.vid)
            live = [tr for tr in live if not tr.end]
            tc = time.perf_counter()  # commands for [t_s, t_s + dt]
            self.command([tr for tr in live if tr.controlled], t_s)
            self.t_ctrl += time.perf_counter() - tc
            if progress is not None and t_s >= next_progress:
                next_progress = math.floor(t_s) + 1.0
                progress(t_s, s.t_end_s)

    def depart(self, vid: str, t_s: float) -> None:
        """A vehicle entered the network at t_s [s]: its record, and for a controlled one its controller (a law
        or a new sampled Controller) with its step core."""
        ts, s, u, V, dt = self.ts, self.s, self.u, self.V, self.dt
        vt = V.getTypeID(vid)
        if vt not in self.min_gaps:
            self.min_gaps[vt] = ts.vehicletype.getMinGap(vt)
        ctl = is_controlled(vid, vt, self.sc)
        tr = _Track(vid, vt, V.getRouteID(vid), ctl, "", self.min_gaps[vt], t_s, lane_pos0=V.getLanePosition(vid))
        if self.ring is not None:
            tr.lane_pos0 += self.ring.length_m / 2 if V.getRoadID(vid) == "bottom" else 0.0
        self.offsets[vid] = tr.lane_pos0
        if ctl:
            V.setSpeedMode(vid, s.speed_mode)
            if self.law is not None:
                tr.law, tr.controller = self.law, self.law.name
                # a law is evaluated every SUMO step: its loop core steps at dt
                tr.step = VehicleStep(
                    self.law.name, f"vehicle {vid!r}", u, self.ev.limits, self.law_stages, dt / u.time_s, "sumo"
                )
            else:
                assert self.factory is not None
                tb = time.perf_counter()
                tr.ctrl = self.factory()
                tr.ctrl.reset()
                self.t_build += time.perf_counter() - tb
                tr.controller = tr.ctrl.name
                self.ctrl_every = controller_steps(tr.ctrl.dt * u.time_s, dt, s.controller)
                period = self.ctrl_every * dt / u.time_s
                tr.step = VehicleStep(
                    tr.ctrl.name, f"vehicle {vid!r}", u, self.ev.limits, self.ctrl_stages, period, "sumo"
                )
        else:
            tr.controller = f"sumo:{vt}"  # SUMO's own driver model of the vehicle's type
        if vt not in self.floors:  # SUMO's own drivers: their type's emergency deceleration
            self.floors[vt] = -float(ts.vehicletype.getEmergencyDecel(vt))
        tr.a_floor_mps2 = self.a_floor if ctl else self.floors[vt]
        self.tracks[vid] = tr

    def fleet_changes(self, t_s: float) -> None:
        """The teleports and collisions of the step (events that end the records) and the arrivals (vehicles
        that left the network), each a fleet event."""
        sim, tracks, fleet = self.ts.simulation, self.tracks, self.fleet_events
        for vid in sim.getStartingTeleportIDList():
            if vid in tracks:
                tr = tracks[vid]
                fleet.append({"kind": "teleport", "t_s": t_s, "vehicle": vid, "controlled": tr.controlled})
                self.stop(
                    tr,
                    "teleport",
                    t_s,
                    "SUMO teleported the vehicle (a jam or a lane it could not leave); its record ends here",
                )
        for c in sim.getCollisions():
            dv = c.colliderSpeed - c.victimSpeed
            fleet.append(
                {
                    "kind": "collision",
                    "t_s": t_s,
                    "vehicle": c.collider,
                    "victim": c.victim,
                    "impact_speed_mps": dv,
                    "type": c.type,
                }
            )
            for vid in (c.collider, c.victim):
                if vid in tracks:
                    who = "hit " + c.victim if vid == c.collider else "hit by " + c.collider
                    self.stop(tracks[vid], "collision", t_s, f"{who} at {dv:.3g} m/s ({c.type})", impact_speed_mps=dv)
        for vid in sim.getArrivedIDList():
            if vid in tracks:
                tr = tracks[vid]
                fleet.append({"kind": "left_network", "t_s": t_s, "vehicle": vid, "controlled": tr.controlled})
                self.finish(tr, "arrived", t_s)

    def read(self, tr: _Track, t_s: float) -> None:
        """Record what vehicle ``tr`` did up to t_s [s]: speed, odometer, lane, its leader's gap and speed (for a
        controlled car a lane that ends is a standing obstacle), and the step's events that do not end it."""
        V, s, vid = self.V, self.s, tr.vid
        v = V.getSpeed(vid)
        lead = V.getLeader(vid, s.lookahead_m)
        if lead and lead[0]:
            g, vl = lead[1] + tr.min_gap_m, V.getSpeed(lead[0])
        else:
            g, vl = math.nan, math.nan
        left = None
        if tr.controlled:  # a lane that ends (no continuation on the route) is a standing obstacle
            left = _lane_end_m(V, vid, tr.route, self.lane_ends)
            if left is not None and left < s.lookahead_m and not (g <= left):
                g, vl = left, 0.0
        tr.t_s.append(t_s)
        tr.v.append(v)
        tr.odo.append(V.getDistance(vid))
        tr.gap.append(g)
        tr.v_lead.append(vl)
        tr.lane.append(V.getLaneID(vid))
        lane_end = tr.controlled and left is not None and g == left
        if len(tr.v) > 1:
            _check_motion(tr, self.dt, self.u, self.fleet_events, lane_end=lane_end)
        else:  # (its first sample: no motion to check, but the controller's Observation.lane_end is known)
            tr.at_lane_end = lane_end

    def command(self, ctl_live: list[_Track], t_s: float) -> None:
        """The accelerations [m/s²] of the live controlled vehicles for [t_s, t_s + dt] through their step cores,
        handed to SUMO as the speeds they reach at the end of the step."""
        if not ctl_live:
            return
        s, dt = self.s, self.dt
        gaps = np.array([tr.gap[-1] for tr in ctl_live])
        vs = np.array([tr.v[-1] for tr in ctl_live])
        vls = np.array([tr.v_lead[-1] for tr in ctl_live])
        free = ~np.isfinite(gaps)  # no leader within the lookahead: free road
        gaps = np.where(free, s.lookahead_m, gaps)
        vls = np.where(free, vs, vls)
        a = self.law_commands(ctl_live, gaps, vs, vls)
        for i, tr in enumerate(ctl_live):
            a[i] = self.vehicle_command(tr, t_s, float(a[i]) if tr.ctrl is None else 0.0, gaps[i], vs[i], vls[i])
        a = np.clip(a, self.a_lo, self.a_hi)  # (the loop core saturated in model units: this only rounds to SI)
        v_next = np.clip(vs + a * dt, 0.0, np.maximum(self.v_max, vs))
        if s.speed_limits:  # the lane's legal limit; a car above it (it entered a slower lane, or departed above
            # the limit with its speed factor) slows down to it at no more than LIMIT_DECEL_MPS2
            cap = np.array([self.lane_limit(tr.lane[-1]) for tr in ctl_live])
            v_next = np.minimum(v_next, np.maximum(cap, vs - LIMIT_DECEL_MPS2 * dt))
            a = (v_next - vs) / dt
        for i, tr in enumerate(ctl_live):
            self.V.setSpeed(tr.vid, float(v_next[i]))
            tr.a_prev = float(self.u.accel_from_si(a[i]))

    def lane_limit(self, lane: str) -> float:
        """The legal speed limit [m/s] of SUMO lane ``lane`` (cached: a lane's limit does not change)."""
        if lane not in self.limits:
            self.limits[lane] = float(self.ts.lane.getMaxSpeed(lane))
        return self.limits[lane]

    def law_commands(self, ctl_live: list[_Track], gaps: np.ndarray, vs: np.ndarray, vls: np.ndarray) -> np.ndarray:
        """The law's raw accelerations [m/s²] of the vehicles a law drives (all of them in one call; a non-finite
        value: :attr:`a_emergency`); the other entries are left for their controllers."""
        u, law = self.u, self.law
        a = np.empty(len(ctl_live))
        law_idx = [i for i, tr in enumerate(ctl_live) if tr.law is not None]
        if law_idx:
            assert law is not None
            h = u.length_from_si(np.maximum(gaps[law_idx], 1e-6))
            a_model = np.asarray(
                law.function(h[None, :], u.speed_from_si(vs[law_idx])[None, :], u.speed_from_si(vls[law_idx])[None, :])
            ).ravel()
            a_law = u.accel_to_si(a_model)
            a[law_idx] = np.where(np.isfinite(a_law), a_law, self.a_emergency)
        return a

    def vehicle_command(self, tr: _Track, t_s: float, a_law: float, gap: float, v: float, v_lead: float) -> float:
        """The acceleration [m/s²] vehicle ``tr`` applies from t_s: a law's ``a_law`` through its step core's
        stages (without any, only counted), or its sampled controller's last command (a new one every controller
        dt since the vehicle departed)."""
        u, dt, step = self.u, self.dt, tr.step
        assert step is not None
        if tr.ctrl is None:  # a law: its command through the loop core's stages (model units)
            if not step.stages.active:  # no stage: only the saturation of command(), counted as the core counts it
                step.count_unstaged(not (self.a_lo <= a_law <= self.a_hi))
                return a_law
            a_l = (v_lead - tr.v_lead[-2]) / dt if len(tr.v_lead) > 1 and np.isfinite(tr.v_lead[-2]) else 0.0
            return u.accel_to_si(
                step.apply(
                    float(u.accel_from_si(a_law)),
                    float(u.length_from_si(gap)),
                    float(u.speed_from_si(v)),
                    float(u.speed_from_si(v_lead)),
                    float(u.accel_from_si(a_l)),
                )
            )
        tr.meas_t.append(u.time_from_si(t_s))
        tr.meas_v.append(u.speed_from_si(v_lead))
        if (len(tr.t_s) - 1) % self.ctrl_every == 0:  # every controller dt since the vehicle departed
            limit = u.speed_from_si(self.lane_limit(tr.lane[-1]))
            # at its lane's end, the speed SUMO's lane-change model asks of the car to reach a gap in the next lane
            # (a merge assistant's advice: the driver model's speed without the controller's command)
            merge = float(u.speed_from_si(self.V.getSpeedWithoutTraCI(tr.vid))) if tr.at_lane_end else None
            tr.a_cmd_mps2 = _call(tr, u, v, gap, self.follower(tr), float(limit), tr.at_lane_end, merge)
        return tr.a_cmd_mps2

    def follower(self, tr: _Track) -> np.ndarray | None:
        """The vehicle behind ``tr`` within the lookahead as a rear radar sees it: (its gap to ``tr`` [model length],
        its speed [model speed]); None when there is none. SUMO's ``getFollower`` measures from the follower's front
        plus its minGap to ``tr``'s back, so its minGap is added back (as ``getLeader``'s is for the leader); it may
        return a follower farther back than the distance asked (its documentation), which is then None here."""
        V = self.V
        f = V.getFollower(tr.vid, self.s.lookahead_m)
        if not f or not f[0]:
            return None
        vt = V.getTypeID(f[0])
        if vt not in self.min_gaps:
            self.min_gaps[vt] = self.ts.vehicletype.getMinGap(vt)
        gap = f[1] + self.min_gaps[vt]
        if gap > self.s.lookahead_m:  # beyond the radar's range
            return None
        return np.array([self.u.length_from_si(gap), self.u.speed_from_si(V.getSpeed(f[0]))])

    # ------------------------------------------------------------------ the result
    def result(self, wall: float) -> SumoRun:
        """The finished run: every vehicle's record as a SimulationResult, the fleet's events (with each cell
        current breach), the clocks."""
        s, dt, k = self.s, self.dt, self.k
        for tr in list(self.tracks.values()):
            self.finish(tr, "", math.nan)
        check_ids_seen(self.sc, [tr.vid for tr in self.done], k * dt)
        vehicles: dict[str, SimulationResult] = {}
        controlled: dict[str, bool] = {}
        for tr in self.done:
            if len(tr.t_s) < 1:
                continue
            vehicles[tr.vid] = _result(tr, self.ev, s.lookahead_m, dt, s.record_every)
            controlled[tr.vid] = tr.controlled
            for e in vehicles[tr.vid].violations:  # the cell's current limit: the plants' one rule (aev_ocp.plant)
                if e.kind == CURRENT_LIMIT:
                    peak = float(np.max(np.abs(tr.current)))  # the largest |I| [A]
                    self.fleet_events.append(
                        {"kind": e.kind, "t_s": e.time_s, "vehicle": tr.vid, "controlled": tr.controlled, "value": peak}
                    )
        return SumoRun(
            self.sc.name,
            self.sc,
            vehicles,
            controlled,
            self.fleet_events,
            k * dt,
            dt,
            k,
            wall,
            self.t_ctrl,
            {v: self.offsets[v] for v in vehicles},
            self.ring.length_m if self.ring is not None else None,
            self.interrupted,
            self.t_build,
        )


#: how hard a controlled car above its lane's speed limit slows down to it ([sumo] speed_limits) [m/s²]: the IDM's
#: comfortable deceleration b (Treiber, Hennecke & Helbing 2000)
LIMIT_DECEL_MPS2 = 1.5
#: a realised deceleration may exceed the vehicle's floor by this much [m/s²] (the speeds' round-off in SUMO)
DECEL_TOLERANCE_MPS2 = 1e-3
EMERGENCY_BRAKING, LANE_END_STOP = FLEET_EVENT_KINDS[:2]
STANDSTILL_MPS = 0.1  # a speed below this counts as standing [m/s]


def _check_motion(tr: _Track, dt: float, u: Any, fleet: list[dict[str, Any]], lane_end: bool) -> None:
    """The events of the step SUMO just made that do not end the vehicle's record (they go to its violations and to
    the fleet's events, each with time, vehicle and value): a realised deceleration beyond the vehicle's floor
    (value: the deceleration [m/s²]; SUMO's emergency stop), and a controlled car coming to a stop at the end of
    its lane (``lane_end``: its obstacle is the lane's end, now or at the sample before, SUMO may move a car it
    stops there to the next lane; value: the speed it stopped from [m/s])."""
    t_s, a = tr.t_s[-1], (tr.v[-1] - tr.v[-2]) / dt

    def record(kind: str, value: float, message: str) -> None:
        tr.violations.append(Event(kind, float(u.time_from_si(t_s)), 0, message, time_s=t_s))
        fleet.append({"kind": kind, "t_s": t_s, "vehicle": tr.vid, "controlled": tr.controlled, "value": value})

    if a < tr.a_floor_mps2 - DECEL_TOLERANCE_MPS2:
        record(
            EMERGENCY_BRAKING,
            a,
            f"deceleration {a:.4g} m/s² beyond the vehicle's {tr.a_floor_mps2:.4g} m/s² (from {tr.v[-2]:.3g} to "
            f"{tr.v[-1]:.3g} m/s in {dt:g} s: SUMO stopped it)",
        )
    was_at_end, tr.at_lane_end = tr.at_lane_end, lane_end
    if (lane_end or was_at_end) and tr.v[-1] < STANDSTILL_MPS <= tr.v[-2]:
        left = tr.gap[-1] if lane_end else tr.gap[-2]
        record(
            LANE_END_STOP,
            tr.v[-2],
            f"stopped from {tr.v[-2]:.3g} m/s {left:.3g} m before the end of its lane {tr.lane[-2]} (its route goes on)",
        )


def _lane_end_m(V: Any, vid: str, route: str, cache: dict[tuple[str, int, str], float | None]) -> float | None:
    """Distance [m] from the vehicle's front to the end of the lane sequence it can drive without changing lanes,
    when its route goes on beyond (a merge lane ending), else None. SUMO's best-lane length counts from the lane's
    start, so it is cached per (route, route index, lane)."""
    lane = V.getLaneID(vid)
    key = (route, V.getRouteIndex(vid), lane)
    if key not in cache:
        b = next((b for b in V.getBestLanes(vid) if b[0] == lane), None)
        cache[key] = float(b[1]) if b is not None and _route_goes_on(V, vid, b) else None
    end = cache[key]
    return None if end is None else end - V.getLanePosition(vid)


def _route_goes_on(V: Any, vid: str, best: Any) -> bool:
    """Whether the route continues past the end of the lane sequence ``best`` (else the lane end is the route's)."""
    edges = V.getRoute(vid)
    idx = V.getRouteIndex(vid)
    last = best[5][-1] if best[5] else best[0]
    edge = last.rsplit("_", 1)[0]
    return edge in edges[idx:] and edges.index(edge, idx) < len(edges) - 1


def _call(
    tr: _Track,
    u: Any,
    v: float,
    gap: float,
    follower: np.ndarray | None = None,
    speed_limit: float | None = None,
    lane_end: bool = False,
    merge_speed: float | None = None,
) -> float:
    """One control instant of a sampled Controller on the vehicle's measurements (and its follower's, when one is
    behind it: Observation.follower; its lane's limit [model speed] and whether its obstacle is its lane's end:
    Observation.speed_limit, Observation.lane_end; there the speed SUMO's driver model would drive [model speed]:
    Observation.merge_speed) through the loop core (checked, conditioned, safety layer,
    limits); returns the acceleration the vehicle applies [m/s²]."""
    assert tr.ctrl is not None and tr.step is not None
    x = tr.x_bat[-1]
    z = np.array([u.length_from_si(gap), u.speed_from_si(v), x[0], x[1], x[2]])
    obs = Observation(
        tr.meas_t[-1],
        tr.ctrl.dt,
        0,
        z,
        np.asarray(tr.meas_t),
        np.asarray(tr.meas_v),
        None,
        tr.a_prev,
        follower=follower,
        speed_limit=speed_limit,
        lane_end=lane_end,
        merge_speed=merge_speed,
    )
    _, a = tr.step.command(tr.ctrl, obs)
    tr.step.rec["info"][-1] = {}  # (a SUMO run keeps no forecasts)
    return float(u.accel_to_si(a))


def _battery(ev: EVParams, live: list[_Track], dt: float) -> None:
    """Integrate every live vehicle's battery over the last step (new vehicles start from rest at soc0)."""
    u = ev.units
    new = [tr for tr in live if not tr.x_bat]
    if new:
        x0 = energy.initial_state(ev, len(new))
        for j, tr in enumerate(new):
            tr.x_bat.append(x0[:, j].copy())
            tr.current.append(0.0)
    old = [tr for tr in live if len(tr.x_bat) < len(tr.t_s)]
    if not old:
        return
    x = np.stack([tr.x_bat[-1] for tr in old], axis=1)
    v0 = np.array([tr.v[-2] for tr in old])
    v1 = np.array([tr.v[-1] for tr in old])
    a = (v1 - v0) / dt
    x1, I, disc = energy.step(ev, x, u.speed_from_si(v0), u.accel_from_si(a), dt)
    for j, tr in enumerate(old):
        tr.x_bat.append(x1[:, j])
        tr.current[-1] = float(I[j])  # the current at the start of the step belongs to the previous sample
        tr.current.append(float(I[j]))
        if disc[j] < 0:
            tr.events.append(
                Event(
                    "infeasible_current",
                    u.time_from_si(tr.t_s[-1]),
                    0,
                    "cell cannot deliver the power demand (E² < 4 R_s P_c)",
                    time_s=tr.t_s[-1],
                )
            )
        elif not (0.0 <= x1[2, j] <= 1.0):
            tr.events.append(
                Event("soc_out_of_range", u.time_from_si(tr.t_s[-1]), 0, f"S = {x1[2, j]:.6g}", time_s=tr.t_s[-1])
            )


def _result(tr: _Track, ev: EVParams, lookahead_m: float, dt: float, every: int) -> SimulationResult:
    from ..ring.field import count_braking

    """The vehicle's record as a one-follower SimulationResult (model units; its leader: whoever SUMO reported;
    no leader within the lookahead: gap = lookahead, leader speed = own speed)."""
    u = ev.units
    n = min(len(tr.t_s), len(tr.x_bat))
    t_s = np.asarray(tr.t_s[:n])
    v = np.asarray(tr.v[:n])
    gap = np.asarray(tr.gap[:n])
    vl = np.asarray(tr.v_lead[:n])
    free = ~np.isfinite(gap)
    gap = np.where(free, lookahead_m, gap)
    vl = np.where(free, v, vl)
    a = np.zeros(n)
    if n > 1:
        a[:-1] = np.diff(v) / dt
        a[-1] = a[-2]
    xb = np.stack(tr.x_bat[:n], axis=1)
    t = u.time_from_si(t_s)
    h, vm, vlm, am = u.length_from_si(gap), u.speed_from_si(v), u.speed_from_si(vl), u.accel_from_si(a)
    ovm = np.asarray(optimal_velocity(h), float).ravel() - vm

    def cum(y: np.ndarray) -> np.ndarray:
        out = np.zeros(n)
        if n > 1:
            out[1:] = np.cumsum((y[1:] + y[:-1]) / 2 * np.diff(t))
        return out

    jerk2 = np.zeros(n)
    if n > 1:
        jerk2[1:] = np.cumsum(np.diff(am) ** 2 / np.diff(t))
    pos = u.length_from_si(np.asarray(tr.odo[:n]))
    sel = np.arange(0, n, every)
    if sel[-1] != n - 1:
        sel = np.append(sel, n - 1)

    def col(y: Any) -> np.ndarray:
        return np.asarray(y, float)[sel][:, None]

    stats: list[dict[str, Any] | None] = [None]
    if tr.ctrl is not None and tr.step is not None and tr.step.rec["ok"]:
        stats = [tr.step.stats(tr.ctrl)]
    events = tr.events[:1]
    violations = tr.violations + current_limit_events(t, np.asarray(tr.current[:n], float)[:, None], ev)
    meta = {
        "sumo_id": tr.vid,
        "vtype": tr.vtype,
        "route": tr.route,
        "controlled": tr.controlled,
        "depart_s": tr.depart_s,
        "end": tr.end or "running",
        "end_s": tr.end_s,
        "step_s": dt,
        # the field's metrics on SUMO's own steps, whatever the output thinning (aev_ocp.ring.field)
        "braking_events": count_braking(t_s, a),
        "speed_steps": [int(n), float(np.sum(v)), float(np.sum(v * v))],
        "lookahead_m": lookahead_m,
        "lanes": sorted(set(tr.lane)),
        "call_s_total": float(sum(tr.step.rec["call"])) if tr.step is not None else 0.0,
        # the controlled vehicle's conditioning and safety layer, with the steps each stage changed (aev_ocp.loop)
        "command_stages": [tr.step.describe() if tr.step is not None else None],
        "controllers": [
            tr.step.settings(tr.ctrl if tr.ctrl is not None else tr.law)
            if tr.step is not None
            else {"controller": "sumo", "vtype": tr.vtype}
        ],
    }
    return SimulationResult(
        t=t[sel],
        leader_speed=vlm[sel],
        leader_position=(pos + h)[sel],
        gap=col(h),
        speed=col(vm),
        accel=col(am),
        V1=col(xb[0]),
        V2=col(xb[1]),
        S=col(xb[2]),
        current_A=col(np.asarray(tr.current[:n])),
        omega=col(xb[3]),
        heat_J=col(xb[4]),
        heat_irr_J=col(xb[5]),
        battery_energy_J=col(xb[energy.BATTERY_ENERGY_ROW]),
        int_ovm_err2=col(cum(ovm**2)),
        int_rel_speed2=col(cum((vlm - vm) ** 2)),
        int_jerk2=col(jerk2),
        controllers=[tr.controller],
        ev=ev,
        events=events,
        violations=violations,
        jerk_sampled=True,
        solver_stats=stats,
        meta=meta,
    )
