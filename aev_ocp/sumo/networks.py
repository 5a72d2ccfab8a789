"""Shipped SUMO networks, built at run time by SUMO's own netconvert from small plain-XML files written here.

* ``ring``: the Sugiyama ring (Sugiyama et al. 2008, New J. Phys. 10 033001: one lane, 230 m, 22 vehicles), two
  half-circle edges of exactly half the circumference each, no internal junction links, so a lane position
  continues exactly across the junction. Every vehicle's route repeats the ring often enough for the run.
* ``merge``: a straight highway with an on-ramp: two main lanes, a single-lane ramp joining an acceleration lane,
  from which ramp vehicles must change lanes before it ends (lane changes and mixed flow); flows on the main road
  and the ramp (vehicles per hour) with SUMO's own human-driver model.

Each builder writes the plain XML (``*.nod.xml``, ``*.edg.xml``, ``*.con.xml``), the network and the routes into a
folder and returns their paths; the same parameters give the same files. netconvert runs once per process for the
same plain XML (:func:`netconvert`): a study or a test file running many SUMO runs on one network pays for one build.
"""

from __future__ import annotations

import hashlib
import math
import subprocess
from dataclasses import dataclass
from pathlib import Path

from ..params import ParameterError, spec, validate_fields
from . import SumoError, sumo_binary

#: Length of the toolkit's vehicle: 2022 Tesla Model 3 (manufacturer's data: 4694 mm), the car of
#: aev_ocp.params.VehicleParams.
VEHICLE_LENGTH_M = 4.694


#: Upper bounds of the shipped networks' keys: a lane speed of 100 m/s (360 km/h) is above every road's limit, a
#: road or ring of 100 km above any SUMO study of one corridor, 10 000 vehicles/h above the capacity of the merge's
#: two main lanes (HCM: ~2 400 vehicles/h/lane); SUMO refuses larger values without a message, or runs for ever.
MAX_LANE_SPEED_MPS = 100.0
MAX_ROAD_M = 100_000.0
MAX_FLOW_VPH = 10_000.0


class NetworkError(SumoError, ParameterError):
    """A network's field outside its declared range: a ParameterError of the Python API ('RingNetwork.length_m = …')
    that is also a SumoError (a scenario file's keys are checked against the same declarations, naming
    ``sumo.ring.length_m``, before the network is built)."""


def _checked(obj: object) -> None:
    """Every declared field of a network (:func:`aev_ocp.params.validate_fields`); :class:`NetworkError`."""
    try:
        validate_fields(obj)
    except ParameterError as exc:
        raise NetworkError(str(exc)) from None


#: SUMO driver models of the ring's human cars (RingNetwork.human)
RING_HUMANS = ("krauss", "idm")


def ring_vtype(net: "RingNetwork") -> str:
    """The ``<vType>`` of the ring's cars (every car; the toolkit's speed mode overrides it for the ones it drives)."""
    head = f'<vType id="ring_car" length="{net.vehicle_length_m!r}"'
    if net.human == "krauss":  # SUMO's Krauss defaults (accel, decel, sigma)
        return f'{head} minGap="0" maxSpeed="{net.lane_speed_mps}" accel="2.6" decel="4.5" sigma="0.5"/>'
    return (
        f'{head} carFollowModel="IDM" accel="{net.idm_a_mps2!r}" decel="{net.idm_b_mps2!r}" '
        f'maxSpeed="{net.idm_v0_mps!r}" minGap="{net.idm_s0_m!r}" tau="{net.idm_T_s!r}" delta="{net.idm_delta!r}" '
        'speedFactor="1" speedDev="0"/>'
    )


@dataclass(frozen=True)
class RingNetwork:
    """The single-lane ring. length_m: circumference [m]; vehicles: how many, equally spaced; perturbation_m:
    vehicle 0 starts this far behind its equal-spacing place (the wave's seed); speed0_mps: every vehicle's
    initial speed [m/s] (at most the lane's limit); lane_speed_mps: the lane's speed limit [m/s] (high, so that
    only the controllers and SUMO's drivers set the speed). human: SUMO's driver model of the cars the toolkit does
    not drive: "krauss" (SUMO's default Krauss driver, sigma 0.5, no standstill gap) or "idm" (SUMO's IDM with the
    SI parameters idm_*: Treiber, Hennecke & Helbing 2000's city values by default, the humans of the toolkit's
    ``ring_stern`` ring; a = accel, b = decel, v0 = maxSpeed, s0 = minGap, T = tau, δ = delta, no speed spread)."""

    length_m: float = spec(230.0, gt=0, le=MAX_ROAD_M)  # Sugiyama et al. 2008
    vehicles: int = spec(22, kind="integer", ge=1)  # Sugiyama et al. 2008
    perturbation_m: float = spec(0.0, ge=0)
    speed0_mps: float = spec(0.0, ge=0, le=MAX_LANE_SPEED_MPS)  # Sugiyama et al. 2008 start from rest
    vehicle_length_m: float = spec(VEHICLE_LENGTH_M, gt=0, le=30.0)  # 30 m: longer than any road vehicle
    lane_speed_mps: float = spec(40.0, gt=0, le=MAX_LANE_SPEED_MPS)
    human: str = spec("krauss", kind="choice", choices=RING_HUMANS)
    # the IDM's SI parameters (human = "idm"; aev_ocp.ring.laws.IDM_SI: Treiber et al. 2000, v0 a ring's 30 m/s)
    idm_a_mps2: float = spec(1.0, gt=0, le=10.0)
    idm_b_mps2: float = spec(1.5, gt=0, le=10.0)
    idm_v0_mps: float = spec(30.0, gt=0, le=MAX_LANE_SPEED_MPS)
    idm_s0_m: float = spec(2.0, ge=0, le=30.0)
    idm_T_s: float = spec(1.0, gt=0, le=10.0)
    idm_delta: float = spec(4.0, gt=0, le=10.0)

    def __post_init__(self) -> None:
        _checked(self)
        if self.vehicles * self.vehicle_length_m >= self.length_m:
            raise SumoError(
                f"sumo.ring.vehicles = {self.vehicles} cars of {self.vehicle_length_m} m do not fit "
                f"on a ring of {self.length_m} m"
            )
        if not self.perturbation_m < self.length_m / self.vehicles - self.vehicle_length_m:
            raise SumoError(
                f"sumo.ring.perturbation_m = {self.perturbation_m!r} is not allowed: must be >= 0 "
                f"and below the equal bumper-to-bumper gap "
                f"{self.length_m / self.vehicles - self.vehicle_length_m:.4g} m"
            )
        if self.speed0_mps > self.lane_speed_mps:
            raise SumoError(
                f"sumo.ring.speed0_mps = {self.speed0_mps!r} is not allowed: must be in [0, {self.lane_speed_mps:g}] "
                "m/s (sumo.ring.lane_speed_mps, the lane's limit)"
            )

    def positions_m(self) -> list[float]:
        """Initial arc positions of the vehicles' fronts [m], vehicle 0 first (the ring's own coordinate)."""
        s = self.length_m / self.vehicles
        return [(i * s - (self.perturbation_m if i == 0 else 0.0)) % self.length_m for i in range(self.vehicles)]


@dataclass(frozen=True)
class MergeNetwork:
    """The highway on-ramp merge. main_flow_vph / ramp_flow_vph: flows [vehicles/h]; main_length_m: road length
    before the merge [m] (the ramp starts 400 m before the merge); accel_lane_m: acceleration-lane length [m];
    after_m: road after it [m]; speeds [m/s]."""

    main_flow_vph: float = spec(
        2400.0, ge=0, le=MAX_FLOW_VPH
    )  # 1200 veh/h/lane: a busy two-lane motorway (HCM LOS C-D)
    ramp_flow_vph: float = spec(500.0, ge=0, le=MAX_FLOW_VPH)  # a busy on-ramp (HCM ramp capacity ~ 1800 veh/h)
    main_length_m: float = spec(800.0, gt=0, le=MAX_ROAD_M)
    accel_lane_m: float = spec(250.0, gt=0, le=MAX_ROAD_M)  # German RAA 2008: 250 m lane for a motorway entry
    after_m: float = spec(1000.0, gt=0, le=MAX_ROAD_M)
    main_speed_mps: float = spec(33.33, gt=0, le=MAX_LANE_SPEED_MPS)  # 120 km/h motorway limit
    ramp_speed_mps: float = spec(22.22, gt=0, le=MAX_LANE_SPEED_MPS)  # 80 km/h ramp limit

    def __post_init__(self) -> None:
        _checked(self)

    @property
    def road_m(self) -> float:
        """Length of road a vehicle may occupy [m]: the main road, the ramp (400 m), the acceleration lane (3
        lanes) and the road after it (2 lanes)."""
        return 2 * self.main_length_m + 400.0 + 3 * self.accel_lane_m + 2 * self.after_m


def run_tool(args: list[str], what: str, cwd: Path | None = None) -> None:
    """Run a SUMO tool (in folder ``cwd``, if given); its first error line becomes a one-line :class:`SumoError`."""
    proc = subprocess.run(args, capture_output=True, text=True, check=False, cwd=cwd)
    if proc.returncode != 0:
        raise SumoError(f"{what}: {first_error(proc.stderr + proc.stdout)}")


def first_error(text: str) -> str:
    """The first 'Error: ...' line of a SUMO tool's output (else its last non-empty line), stripped."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    err = next((ln for ln in lines if ln.startswith("Error")), lines[-1] if lines else "failed without a message")
    return err.removeprefix("Error:").strip()


#: netconvert's networks built in this process: a hash of its binary, its options and the plain XML it read (the
#: names and texts of its input files) -> the network it wrote (bytes; its header names the inputs relative to the
#: folder, so the same bytes are right in any folder)
_BUILT: dict[str, bytes] = {}


def netconvert(folder: Path, inputs: list[tuple[str, str]], out: str, options: list[str], what: str) -> Path:
    """``netconvert <flag> <file> ... -o out <options>`` run in ``folder`` on its plain-XML files ``inputs``
    ((flag, file name) pairs, written there before), or, when this process built a network from the same files
    (names and texts), options and netconvert binary before, that network written to ``folder / out``."""
    binary = sumo_binary("netconvert")
    key = hashlib.sha256()
    for part in (binary, out, *options):
        key.update(part.encode() + b"\0")
    for flag, name in inputs:
        key.update(f"{flag}\0{name}\0".encode() + (folder / name).read_bytes() + b"\0")
    digest = key.hexdigest()
    target = folder / out
    if digest in _BUILT:
        target.write_bytes(_BUILT[digest])
        return target
    args = [binary, *(x for pair in inputs for x in pair), "-o", out, *options]
    run_tool(args, what, cwd=folder)
    _BUILT[digest] = target.read_bytes()
    return target


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def build_ring(net: RingNetwork, folder: Path, t_end_s: float) -> tuple[Path, list[Path]]:
    """Write the ring's plain XML, netconvert it and write routes for a run of t_end_s [s]: (net, [routes])."""
    folder.mkdir(parents=True, exist_ok=True)
    R = net.length_m / (2 * math.pi)
    half = net.length_m / 2

    def arc(a0: float, a1: float, n: int = 12) -> str:
        return " ".join(
            f"{R * math.cos(a0 + (a1 - a0) * k / n):.4f},{R * math.sin(a0 + (a1 - a0) * k / n):.4f}"
            for k in range(n + 1)
        )

    _write(
        folder / "ring.nod.xml",
        f'<nodes>\n  <node id="a" x="{R:.4f}" y="0" type="priority"/>\n'
        f'  <node id="b" x="{-R:.4f}" y="0" type="priority"/>\n</nodes>\n',
    )
    edge = '  <edge id="{id}" from="{f}" to="{t}" numLanes="1" speed="{v}" length="{L!r}" shape="{s}"/>\n'
    _write(
        folder / "ring.edg.xml",
        "<edges>\n"
        + edge.format(id="top", f="a", t="b", v=net.lane_speed_mps, L=half, s=arc(0, math.pi))
        + edge.format(id="bottom", f="b", t="a", v=net.lane_speed_mps, L=half, s=arc(math.pi, 2 * math.pi))
        + "</edges>\n",
    )
    out = netconvert(
        folder,
        [("-n", "ring.nod.xml"), ("-e", "ring.edg.xml")],
        "ring.net.xml",
        ["--no-internal-links", "--no-turnarounds", "--no-warnings"],
        "netconvert (ring)",
    )
    laps = int(math.ceil(t_end_s * net.lane_speed_mps / net.length_m)) + 2
    rows = [
        "<routes>",
        f"  {ring_vtype(net)}",
        f'  <route id="from_top" edges="{" ".join(["top bottom"] * laps)}"/>',
        f'  <route id="from_bottom" edges="{" ".join(["bottom top"] * laps)}"/>',
    ]
    for i, x in enumerate(net.positions_m()):
        route, pos = ("from_top", x) if x < half else ("from_bottom", x - half)
        rows.append(
            f'  <vehicle id="ring.{i}" type="ring_car" route="{route}" depart="0" departPos="{pos!r}" '
            f'departSpeed="{net.speed0_mps!r}" insertionChecks="none"/>'
        )
    rows.append("</routes>\n")
    return out, [_write(folder / "ring.rou.xml", "\n".join(rows))]


def build_merge(net: MergeNetwork, folder: Path, t_end_s: float) -> tuple[Path, list[Path]]:
    """Write the on-ramp merge's plain XML, netconvert it and write its flows: (net, [routes])."""
    folder.mkdir(parents=True, exist_ok=True)
    x1 = net.main_length_m
    x2 = x1 + net.accel_lane_m
    x3 = x2 + net.after_m
    _write(
        folder / "merge.nod.xml",
        "<nodes>\n"
        f'  <node id="west" x="0" y="0"/>\n  <node id="merge" x="{x1}" y="0" type="priority"/>\n'
        f'  <node id="accel_end" x="{x2}" y="0" type="priority"/>\n  <node id="east" x="{x3}" y="0"/>\n'
        f'  <node id="ramp_start" x="{x1 - 400}" y="-60"/>\n</nodes>\n',
    )
    _write(
        folder / "merge.edg.xml",
        "<edges>\n"
        f'  <edge id="main" from="west" to="merge" numLanes="2" speed="{net.main_speed_mps}" priority="3"/>\n'
        f'  <edge id="ramp" from="ramp_start" to="merge" numLanes="1" speed="{net.ramp_speed_mps}" priority="1"/>\n'
        f'  <edge id="accel" from="merge" to="accel_end" numLanes="3" speed="{net.main_speed_mps}" priority="3"/>\n'
        f'  <edge id="after" from="accel_end" to="east" numLanes="2" speed="{net.main_speed_mps}" priority="3"/>\n'
        "</edges>\n",
    )
    _write(
        folder / "merge.con.xml",
        "<connections>\n"
        '  <connection from="main" to="accel" fromLane="0" toLane="1"/>\n'
        '  <connection from="main" to="accel" fromLane="1" toLane="2"/>\n'
        '  <connection from="ramp" to="accel" fromLane="0" toLane="0"/>\n'
        '  <connection from="accel" to="after" fromLane="1" toLane="0"/>\n'
        '  <connection from="accel" to="after" fromLane="2" toLane="1"/>\n'
        "</connections>\n",
    )
    out = netconvert(
        folder,
        [("-n", "merge.nod.xml"), ("-e", "merge.edg.xml"), ("-x", "merge.con.xml")],
        "merge.net.xml",
        ["--no-turnarounds", "--no-warnings"],
        "netconvert (merge)",
    )
    rows = [
        "<routes>",
        '  <vType id="human" length="4.694" sigma="0.5"/>',  # SUMO's Krauss driver (sigma default 0.5)
        '  <route id="main_route" edges="main accel after"/>',
        '  <route id="ramp_route" edges="ramp accel after"/>',
    ]
    if net.main_flow_vph > 0:
        rows.append(
            f'  <flow id="main" type="human" route="main_route" begin="0" end="{t_end_s!r}" '
            f'vehsPerHour="{net.main_flow_vph!r}" departLane="best" departSpeed="max"/>'
        )
    if net.ramp_flow_vph > 0:
        rows.append(
            f'  <flow id="ramp" type="human" route="ramp_route" begin="0" end="{t_end_s!r}" '
            f'vehsPerHour="{net.ramp_flow_vph!r}" departLane="best" departSpeed="max"/>'
        )
    rows.append("</routes>\n")
    return out, [_write(folder / "merge.rou.xml", "\n".join(rows))]


NETWORKS = ("ring", "merge")
