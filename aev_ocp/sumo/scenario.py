"""The SUMO scenario file: a ``[sumo]`` table plus the toolkit's own parameter tables.

Top level: ``name``, ``description``; the vehicle tables every scenario knows (``[units]``, ``[vehicle]``, ``[cell]``,
``[pack]``, ``[limits]``, ``[carfollowing]``: the controlled cars' and every car's battery), an optional ``[mpc]``
(the MPC's settings, when ``sumo.controller = "mpc"``) and ``[sumo]``:

* the network: ``network = "ring" | "merge"`` (shipped, built by netconvert; its parameters in
  ``[sumo.ring]`` or ``[sumo.merge]``), or ``net_file`` with ``route_files``, or ``config_file`` (a .sumocfg); paths relative to the
  scenario file;
* ``t_end_s`` [s] and ``step_s`` [s] (default 0.1 s, SUMO's own default step);
* which vehicles the toolkit controls: ``ids`` (vehicle ids; one that is no vehicle is refused: on a shipped
  network when the file is read, on the user's network when it never departed in the run), ``vtypes`` (vehicle types) and/or ``share`` (each
  vehicle of a flow is controlled with probability ``share``, decided by a hash of ``seed`` and its id; on the
  shipped ring exactly round(share × cars) cars: reproducible, and a larger share controls a superset); none of
  them: SUMO drives everything (the baseline);
* ``controller``: a car-following law by name (``proposed``, ``ovfl``, ``ovm``, ``idm``, …), ``"mpc"`` (the MPC with
  a measured forecast, settings from ``[mpc]``), ``"wave-mpc"`` (the wave-damping MPC,
  :class:`aev_ocp.mpc.wave.WaveMPC` with the parameters of ``[sumo.wave]``, solver settings from ``[mpc]`` as the
  MPC's, the paper's law of ``[carfollowing]`` as its fallback), ``"followerstopper"`` (Stern et al. 2018's FollowerStopper with
  the desired speed ``desired_speed_mps`` [m/s]), or ``"module:function"`` (``function(ev)`` returns a new
  :class:`aev_ocp.control.Controller` for one vehicle, sampled every ``dt``: a whole number of SUMO steps);
* ``speed_mode`` (default 24: SUMO still obeys right of way and red lights at junctions, the toolkit alone sets the
  speed: no SUMO safe-speed cap, no SUMO acceleration bounds, the vehicle's ``[limits]`` apply instead),
  ``speed_limits`` (default false; true: every speed the toolkit hands SUMO is capped at the legal limit of the
  car's lane, as SUMO's own drivers keep it: speed mode 24 lifts it, and a controller does not know it),
  ``collision_action`` (SUMO's, default ``remove``), ``lookahead_m`` (how far a car sees its leader, default 250 m),
  ``seed``, ``record_every`` (keep every k-th step), ``sumo_args`` (more SUMO options);
* ``[sumo.sweep]``: ``share = [...]`` and/or ``controller = [...]``: ``aev-ocp sumo FILE --sweep`` runs every pair;
* ``[sumo.wave]`` (optional): the wave MPC's :class:`aev_ocp.mpc.wave.WaveParams` fields in SI (e.g.
  ``speed_weight``, ``target_gap_m``, ``follower_speed_weight``; not ``traffic`` nor ``follower_law``), read and
  range-checked as the ring's ``[ring.wave]`` (the same reader), the others at their defaults; absent: the defaults.
  Every run whose controller is ``"wave-mpc"`` uses it, wherever the controller was chosen (``sumo.controller``,
  ``[sumo.sweep]``, ``--controller wave-mpc``, a study's point), so a file may carry it with another
  ``sumo.controller``; the other controllers ignore it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..limits import MAX_SUMO_T_END_S, check_sumo_size
from ..models.carfollowing import LAW_REGISTRY
from ..params import CarFollowingParams, EVParams, ParameterError
from ..scenarios import ScenarioError, TableReader, read_declared, read_scenario_doc, standalone_header
from ..scenarios.followers import _carfollowing
from . import SumoError
from .networks import MAX_LANE_SPEED_MPS, NETWORKS, MergeNetwork, RingNetwork

#: SUMO speed mode of controlled vehicles: bits 3 (right of way at junctions) and 4 (brake at red lights) on; safe
#: speed (bit 0) and SUMO's acceleration/deceleration bounds (bits 1, 2) off: the controller and the vehicle's own
#: [limits] decide (SUMO TraCI documentation, "speed mode" bit table).
DEFAULT_SPEED_MODE = 24
STEP_S = 0.1  # SUMO's default step length
MIN_STEP_S = 0.001  # SUMO counts time in whole milliseconds (its DELTA_T): a shorter step does not exist
COLLISION_ACTIONS = ("remove", "warn", "teleport", "none")  # SUMO's --collision.action
_TOP = ("name", "description", "units", "vehicle", "cell", "pack", "limits", "carfollowing", "mpc", "sumo")


@dataclass(frozen=True)
class SumoSpec:
    """The validated ``[sumo]`` table (see the module docstring); times in s, lengths in m."""

    t_end_s: float
    network: str | None = None
    ring: RingNetwork | None = None
    merge: MergeNetwork | None = None
    net_file: Path | None = None
    route_files: tuple[Path, ...] = ()
    config_file: Path | None = None
    step_s: float = STEP_S
    controller: str = "proposed"
    ids: tuple[str, ...] = ()
    vtypes: tuple[str, ...] = ()
    share: float = 0.0
    speed_mode: int = DEFAULT_SPEED_MODE
    collision_action: str = "remove"
    lookahead_m: float = 250.0  # a long-range automotive radar sees ~250 m (e.g. Bosch LRR4)
    seed: int = 42
    record_every: int = 1
    sumo_args: tuple[str, ...] = ()
    sweep_share: tuple[float, ...] = ()
    sweep_controller: tuple[str, ...] = ()
    desired_speed_mps: float | None = None  # FollowerStopper's r (controller "followerstopper")
    speed_limits: bool = False  # cap the toolkit's speeds at the lane's legal limit (SUMO's drivers keep it)
    #: [sumo.wave]: WaveParams fields of the "wave-mpc" cars (SI; empty: WaveParams' defaults)
    wave: dict[str, Any] = field(default_factory=dict)


#: controllers by name beside the registered laws: the MPC and the wave MPC (sampled; settings from [mpc]) and
#: FollowerStopper (a law with a desired speed)
MPC_NAMES = ("mpc", "wave-mpc")
NAMED_CONTROLLERS = (*MPC_NAMES, "followerstopper")


@dataclass(frozen=True)
class SumoScenario:
    """A SUMO scenario: name, description, the [sumo] spec, the vehicles' parameters, the law coefficients,
    the [mpc] configuration (None without one), the source file and the TOML document."""

    name: str
    spec: SumoSpec
    ev: EVParams = field(default_factory=EVParams)
    cf: CarFollowingParams = field(default_factory=CarFollowingParams)
    mpc: Any = None
    description: str = ""
    source: Path | None = None
    document: dict[str, Any] = field(default_factory=dict)

    def with_point(self, share: float | None = None, controller: str | None = None) -> "SumoScenario":
        """The same scenario with another share and/or controller (a sweep point)."""
        kw: dict[str, Any] = {}
        if share is not None:
            kw["share"] = share
        if controller is not None:
            kw["controller"] = controller
        spec = dataclasses.replace(self.spec, **kw)
        return dataclasses.replace(self, spec=spec, mpc=mpc_for(spec, self.ev, self.mpc, str(self.source or self.name)))


def _controller(r: TableReader, key: str, value: Any) -> str:
    named = ", ".join(f'"{n}"' for n in NAMED_CONTROLLERS)
    if not isinstance(value, str) or not value:
        raise r.error(key, value, f'expected a law name, {named} or "module:function"')
    v = value.strip()
    if v.lower() in LAW_REGISTRY or v.lower() in NAMED_CONTROLLERS:
        return v.lower()
    if re.fullmatch(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*", v):
        return v
    raise r.error(key, value, f'must be a law ({sorted(LAW_REGISTRY)}), {named} or "module:function"')


def _path(r: TableReader, key: str, value: Any, base: Path | None) -> Path:
    if not isinstance(value, str) or not value:
        raise r.error(key, value, "expected a file path (a string)")
    p = Path(value)
    return p if p.is_absolute() or base is None else base / p


def _network(r: TableReader, name: str) -> RingNetwork | MergeNetwork:
    cls: type = RingNetwork if name == "ring" else MergeNetwork
    sub = r.sub(name)
    kw = read_declared(cls, sub)  # each key against the range the network declares beside the field
    sub.finish(allowed_hint=[f.name for f in dataclasses.fields(cls)])
    try:
        net: RingNetwork | MergeNetwork = cls(**kw)
    except SumoError as exc:
        raise ScenarioError(f"{r.file}: {exc}") from None
    return net


def parse_sumo_table(r: TableReader, base: Path | None) -> SumoSpec:
    """Validate the ``[sumo]`` table (``base``: folder that relative paths start from)."""
    kw: dict[str, Any] = {"t_end_s": r.number("t_end_s", gt=0, le=MAX_SUMO_T_END_S)}
    sources = [k for k in ("network", "net_file", "config_file") if r.has(k)]
    if len(sources) != 1:
        raise ScenarioError(
            f'{r.file}: [sumo] needs exactly one of network ("ring" or "merge"), net_file '
            f"(with route_files) or config_file; found {sources or 'none'}"
        )
    if r.has("network"):
        name = r.string("network", choices=list(NETWORKS))
        kw["network"] = name
        kw[name] = _network(r, name)
    elif r.has("net_file"):
        kw["net_file"] = _path(r, "net_file", r.string("net_file"), base)
        routes = (
            [r.string("route_files")] if isinstance(r.table.get("route_files"), str) else r.strings("route_files", [])
        )
        kw["route_files"] = tuple(_path(r, "route_files", x, base) for x in routes)
    else:
        kw["config_file"] = _path(r, "config_file", r.string("config_file"), base)
    kw["step_s"] = r.number("step_s", STEP_S, ge=MIN_STEP_S, le=1.0)
    if kw["step_s"] > kw["t_end_s"]:
        raise r.error("step_s", kw["step_s"], f"must be <= sumo.t_end_s = {kw['t_end_s']:g}")
    if r.has("controller"):
        kw["controller"] = _controller(r, "controller", r.string("controller"))
    kw["ids"] = tuple(r.strings("ids", []))
    kw["vtypes"] = tuple(r.strings("vtypes", []))
    kw["share"] = r.number("share", 0.0, ge=0, le=1)
    mode = r.integer("speed_mode", DEFAULT_SPEED_MODE, ge=0)
    if mode > 63:
        raise r.error("speed_mode", mode, "must be an integer 0-63 (SUMO's speed-mode bits)")
    kw["speed_mode"] = mode
    kw["speed_limits"] = r.boolean("speed_limits", False)
    kw["collision_action"] = r.string("collision_action", "remove", choices=list(COLLISION_ACTIONS))
    kw["lookahead_m"] = r.number("lookahead_m", 250.0, gt=0)
    kw["seed"] = r.integer("seed", 42, ge=0)
    kw["record_every"] = r.integer("record_every", 1, ge=1)
    kw["sumo_args"] = check_sumo_args(r, r.strings("sumo_args", []))
    if r.has("desired_speed_mps"):
        kw["desired_speed_mps"] = r.number("desired_speed_mps", gt=0, le=MAX_LANE_SPEED_MPS)
    sw = r.sub("sweep")
    kw["sweep_share"] = tuple(sw.numbers("share", [], ge=0))
    if any(s > 1 for s in kw["sweep_share"]):
        raise sw.error("share", sw.table["share"], "every share must be in [0, 1]")
    if sw.has("controller"):
        kw["sweep_controller"] = tuple(_controller(sw, "controller", c) for c in sw.strings("controller"))
    sw.finish(allowed_hint=["share", "controller"])
    kw["wave"] = _wave_table(r.sub("wave"))
    r.finish()
    spec = SumoSpec(**kw)
    if "followerstopper" in (spec.controller, *spec.sweep_controller) and spec.desired_speed_mps is None:
        raise r.error(
            "desired_speed_mps", None, 'is required with controller "followerstopper" (its desired speed r [m/s])'
        )
    _check_ids(r, spec)
    check_sumo_spec(spec, r.file)
    return spec


def _wave_table(w: TableReader) -> dict[str, Any]:
    """``[sumo.wave]``: the :class:`aev_ocp.mpc.wave.WaveParams` fields of the "wave-mpc" cars ({} when absent),
    read by the ring's reader of ``[ring.wave]`` (the same keys, ranges and errors, naming ``sumo.wave.<field>``).
    Not tied to ``sumo.controller``: the command line and the studies choose a run's controller after the file is
    read (module docstring)."""
    from ..mpc.wave import WAVE_NAME
    from ..ring.scenario import _wave_table as ring_wave_table

    return ring_wave_table(w, (WAVE_NAME,)) if w.table else {}  # (WAVE_NAME: the ring's controller rule is not SUMO's)


#: SUMO options a scenario may pass in ``sumo_args`` (allow-listed): {option: takes a value}. Everything else is
#: refused: options that write files (``--*-output``, ``--log``, ``--save-*``: they could overwrite a file outside
#: the run's folder), load more inputs (``-a``, ``-r``, ``-c``: use ``net_file``/``route_files``/``config_file``),
#: print and exit (``--help``, ``--version``), or that the scenario sets with its own keys (``--end``,
#: ``--step-length``, ``--seed``, ``--collision.action``).
SUMO_ARGS_ALLOWED: dict[str, bool] = {
    "--time-to-teleport": True,
    "--time-to-teleport.highways": True,
    "--time-to-teleport.disconnected": True,
    "--max-depart-delay": True,
    "--scale": True,
    "--lateral-resolution": True,
    "--default.action-step-length": True,
    "--default.speeddev": True,
    "--default.emergencydecel": True,
    "--emergencydecel.warning-threshold": True,
    "--time-to-impatience": True,
    "--ignore-junction-blocker": True,
    "--collision.mingap-factor": True,
    "--collision.check-junctions": False,
    "--collision.stoptime": True,
    "--lanechange.duration": True,
    "--lanechange.overtake-right": False,
    "--ignore-route-errors": False,
    "--random-depart-offset": True,
    "--max-num-teleports": True,
}


def check_sumo_args(r: TableReader, args: list[str]) -> tuple[str, ...]:
    """``sumo_args`` if every option is one of :data:`SUMO_ARGS_ALLOWED` with its value (``--opt value`` or
    ``--opt=value``; an on/off option alone or with true/false), else ScenarioError naming the key and the option."""
    allowed = sorted(SUMO_ARGS_ALLOWED)
    i = 0
    while i < len(args):
        name, eq, _ = args[i].partition("=")
        if name not in SUMO_ARGS_ALLOWED:
            raise r.error(
                "sumo_args",
                args,
                f"{args[i]!r:.60} is not an allowed SUMO option here; allowed: {allowed} (each followed by its value)",
            )
        if SUMO_ARGS_ALLOWED[name] and not eq:
            if i + 1 >= len(args):
                raise r.error("sumo_args", args, f"{name} needs a value after it")
            i += 1
        elif not SUMO_ARGS_ALLOWED[name] and not eq and i + 1 < len(args) and args[i + 1] in ("true", "false"):
            i += 1
        i += 1
    return tuple(args)


def _sumo_vehicles(spec: SumoSpec) -> tuple[float, float, str]:
    """(vehicles at once, laps of the ring's route, the keys that set them) of a run of ``spec``: the shipped
    ring's cars; the merge's flows over the run, at most its road full (a car every 7 m of lane, a jam); one
    vehicle on a user's network (its vehicles are known only once they depart)."""
    if spec.ring is not None:
        laps = spec.t_end_s * spec.ring.lane_speed_mps / spec.ring.length_m
        return float(spec.ring.vehicles), laps, "sumo.ring.vehicles or sumo.t_end_s"
    if spec.merge is not None:
        m = spec.merge
        arriving = (m.main_flow_vph + m.ramp_flow_vph) * spec.t_end_s / 3600.0
        return min(arriving, m.road_m / 7.0) + 1.0, 0.0, "sumo.merge flows or sumo.t_end_s"
    return 1.0, 0.0, "sumo.t_end_s (or raise sumo.step_s, sumo.record_every)"


def check_sumo_spec(spec: SumoSpec, file: str, keys: dict[str, str | None] | None = None) -> None:
    """The size budget (:func:`aev_ocp.limits.check_sumo_size`) of a run of ``spec``, before SUMO starts;
    ScenarioError naming ``file`` and the keys (``keys``: {"t_end_s": "--t-end-s"} when an option set it)."""
    if not (math.isfinite(spec.t_end_s) and 0 < spec.t_end_s <= MAX_SUMO_T_END_S):
        t_key = (keys or {}).get("t_end_s") or "sumo.t_end_s"
        raise ScenarioError(
            f"{file}: {t_key} = {spec.t_end_s!r} is not allowed: must be a finite number in (0, {MAX_SUMO_T_END_S:g}] s"
        )
    n, laps, what = _sumo_vehicles(spec)
    if (keys or {}).get("t_end_s"):
        what = what.replace("sumo.t_end_s", str((keys or {})["t_end_s"]))
    try:
        check_sumo_size(n, spec.t_end_s, spec.step_s, spec.record_every, laps, what)
    except ParameterError as exc:
        raise ScenarioError(f"{file}: {exc}") from None


#: SUMO options that load more vehicles than the network's own routes (then the shipped network's ids are not all)
_MORE_VEHICLES = ("-r", "--route-files", "-a", "--additional-files", "-c", "--configuration-file")


def _few(ids: list[str], n: int = 5) -> str:
    """The first ``n`` of ``ids`` for a message, with how many there are in all."""
    return ", ".join(ids[:n]) + (f", … ({len(ids)} in all)" if len(ids) > n else "")


def _check_ids(r: TableReader, spec: SumoSpec) -> None:
    """Refuse an ``ids`` entry that no vehicle of a shipped network can have (before SUMO starts): the ring's cars
    are ``ring.0`` … ``ring.<n-1>``, the merge's flow vehicles ``main.<k>`` / ``ramp.<k>``. User networks are checked
    at the end of the run (:func:`aev_ocp.sumo.run.check_ids_seen`): their vehicles are known only once they depart."""
    if spec.network is None or any(a.split("=")[0] in _MORE_VEHICLES for a in spec.sumo_args):
        return
    vtypes = {"ring": ["ring_car"], "merge": ["human"]}[spec.network]  # the routes networks.py writes
    unknown = [v for v in spec.vtypes if v not in vtypes]
    if unknown:
        raise r.error(
            "vtypes",
            list(spec.vtypes),
            f"{_few([repr(v) for v in unknown])}: the shipped {spec.network}'s "
            f"vehicles are all of type {vtypes[0]!r} (no vehicle would be controlled by this type)",
        )
    if not spec.ids:
        return
    if spec.ring is not None:
        valid = [f"ring.{i}" for i in range(spec.ring.vehicles)]
        bad = [i for i in spec.ids if i not in valid]
        hint = f"the shipped ring's {len(valid)} cars are {_few(valid)}"
    else:
        assert spec.merge is not None
        flows = [f for f, vph in (("main", spec.merge.main_flow_vph), ("ramp", spec.merge.ramp_flow_vph)) if vph > 0]
        bad = [i for i in spec.ids if not any(re.fullmatch(rf"{f}\.\d+", i) for f in flows)]
        hint = f"the shipped merge's vehicles are {' and '.join(f'{f}.0, {f}.1, …' for f in flows) or 'none'}"
    if bad:
        is_are = "is" if len(bad) == 1 else "are"
        raise r.error("ids", list(spec.ids), f"{_few([repr(b) for b in bad])} {is_are} no vehicle here: {hint}")


def mpc_for(spec: SumoSpec, ev: EVParams, mpc: Any, file: str) -> Any:
    """The [mpc] configuration a run of ``spec`` needs: ``mpc`` as given, or the default MPC when a controller (the
    run's, or one of [sumo.sweep]'s; also one chosen with ``--controller mpc``) is "mpc" or "wave-mpc" and the file
    has no [mpc];
    ScenarioError naming ``file`` when its interval is no whole number of SUMO steps or its predictor needs what a
    SUMO car cannot measure."""
    if not set(MPC_NAMES) & {spec.controller, *spec.sweep_controller}:
        return mpc
    if mpc is None:
        from ..mpc.scenario import MPCConfig
        from ..mpc.settings import MPCSettings

        # the MPC settings' default interval, 0.2 s at the default units, rounded to whole SUMO steps
        mpc = MPCConfig(MPCSettings(dt=max(1, round(0.2 / spec.step_s)) * spec.step_s / ev.units.time_s))
    k = mpc.settings.dt * ev.units.time_s / spec.step_s
    if abs(k - round(k)) > 1e-9 or round(k) < 1:
        raise ScenarioError(
            f"{file}: mpc.dt = {mpc.settings.dt:g} model time = "
            f"{mpc.settings.dt * ev.units.time_s:g} s must be a whole number of SUMO steps "
            f"(sumo.step_s = {spec.step_s:g} s)"
        )
    if mpc.settings.predictor in ("oracle", "cooperative"):
        raise ScenarioError(
            f"{file}: mpc.predictor = {mpc.settings.predictor!r} is not available in SUMO (a car "
            "measures its leader): use a measured predictor (constant-velocity, "
            "constant-acceleration, decaying-acceleration)"
        )
    return mpc


def parse_sumo_scenario(doc: dict[str, Any], file: str = "<sumo scenario>", source: Path | None = None) -> SumoScenario:
    """Validate a parsed TOML document into a :class:`SumoScenario` (errors name the file and key)."""
    top, name, description, ev = standalone_header(doc, file, source, _TOP, "sumo")
    # the laws' coefficients and scales (SI, aev_ocp.scenarios.followers); they run in [units] with the same SI
    # behaviour whatever the units (model_units: make_law returns them in those units)
    cf = dataclasses.replace(_carfollowing(top.sub("carfollowing"), sub_tables=False)[0], model_units=ev.units)
    spec = parse_sumo_table(top.sub("sumo", required=True), source.parent if source is not None else None)
    mpc = None
    if "mpc" in doc:
        from ..mpc.scenario import validate_mpc_table

        mpc = validate_mpc_table(top.sub("mpc"))
    mpc = mpc_for(spec, ev, mpc, file)
    top.finish()
    return SumoScenario(
        name=name, spec=spec, ev=ev, cf=cf, mpc=mpc, description=description, source=source, document=copy.deepcopy(doc)
    )


def load_sumo_scenario(path: str | Path) -> SumoScenario:
    """Read and validate a SUMO scenario file; a name without a path finds a shipped one (e.g. ``sumo_ring``)."""
    p = Path(path)
    if not p.exists() and p.suffix == "" and (Path(__file__).parent / "scenarios" / f"{p.name}.toml").is_file():
        p = Path(__file__).parent / "scenarios" / f"{p.name}.toml"
    doc = read_scenario_doc(p, str(path))  # a regular file of a stated size, parsed like every scenario file
    return parse_sumo_scenario(doc, str(path), p.resolve())


def shipped_sumo_scenarios() -> dict[str, Path]:
    """{name: path} of the SUMO scenarios shipped with the package."""
    folder = Path(__file__).parent / "scenarios"
    return {p.stem: p for p in sorted(folder.glob("*.toml"))}
