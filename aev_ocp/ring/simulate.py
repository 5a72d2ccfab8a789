"""Ring roads and their simulation: a closed chain of vehicles, each with its own controller and its EV + battery.

Geometry (SI): a ring of length ``length_m`` with n vehicles of length ``vehicle_length_m``; vehicle i follows
vehicle i − 1 and vehicle 0 follows vehicle n − 1. Vehicle i's gap (bumper to bumper) is
h_i = x_{i−1} − x_i − ℓ (mod the ring), so Σ h_i = L − n ℓ at all times.

State per vehicle (model units of ``ev.units`` for h, v): h, v, V1, V2 [V], S [-] (the 2-RC cell of
:func:`aev_ocp.models.ego.battery_side`, every vehicle carries the pack), the actuator state when the vehicle
limits have one; quadratures: distance, the paper's ω, battery energy ∫P_b [J], pack heat ∫Q and ∫Q_irr [J],
∫(v_l − v)² and ∫(V(h) − v)². The vehicle limits (``ev.limits``, :mod:`aev_ocp.models.actuator`) act on every
vehicle's command as in the open-chain plant.

Controllers: a :class:`~aev_ocp.models.carfollowing.CarFollowingLaw` is integrated continuously; any sampled
:class:`~aev_ocp.control.Controller` (Stern's PI with saturation, the MPC, a user's own) is a zero-order hold:
every dt it receives an :class:`~aev_ocp.loop.Observation` (its own state, the measured speeds of its
predecessor so far) and its command is held over the next dt while the whole ring is integrated — the ring
closed loop (the open-chain :class:`~aev_ocp.control.ClosedLoop` runs behind a prescribed leader, which a
ring does not have, so the ring integrates its own way, but each control instant is the same step core as the
platoon's and SUMO's, :class:`aev_ocp.loop.VehicleStep`: the command checked, conditioned, bounded by the
safety layer and saturated). An automated vehicle's law whose run declares a conditioning or the safety layer
(``ev.limits``) is sampled every dt (LAW_DT_S without another controller); human drivers never are.

Human drivers may get seeded acceleration noise: N(0, σ²) [m/s²] per human vehicle, held over ``noise_dt_s``,
and a reaction time τ_i (``RingRoad.delay_s``): such a driver's law is evaluated every ``delay_dt_s`` (0.1 s) on
the gap, speed and leader speed it saw τ_i − delay_dt_s/2 earlier (linear between the updates; before t = 0 the
initial state) and held until the next update, so that the lag averaged over a hold is τ_i — the update scheme of
Treiber & Kesting's Human Driver Model (reaction time with a finite update time), integrated exactly in between.

Integrators (:class:`RingOptions.method`): "compiled" (``aev_ocp/c/ring.c``: one adaptive Dormand–Prince 5(4)
over the whole ring with the CasADi-generated per-vehicle right-hand side, OpenMP over vehicles; why one
system and not the cascade's vehicle-by-vehicle sweep: the ring's closure would need a fixed-point iteration
of whole trajectories around the ring, each sweep costing a full cascade run, and its convergence degrades
exactly where waves grow) or "cvodes" (the same right-hand side in one CasADi CVODES integrator: the
independent check, for small rings).
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import casadi as ca
import numpy as np

from ..compiled import dense_outputs, driver_source, exact_tuned_flags, load_fastest
from ..fastcall import column_call
from ..limits import check_ring_cuts, check_ring_size
from ..control import SampledLaw
from ..loop import NO_STAGES, CommandStages, Controller, History, Observation, VehicleStep, stages_for
from ..models import energy
from ..models.actuator import actuator_rate, saturate, speed_cut
from ..models.carfollowing import CarFollowingLaw, optimal_velocity
from ..models.battery import ocv_inputs, ocv_segments, ocv_table, piecewise_ocv
from ..models.ego import battery_side
from ..params import EVParams, ParameterError, check_argument, remember
from ..plant import EVENT_RULES, current_limit_events, event_at, event_header, rule_of_code
from ..results import Event, SimulationResult, fmt_value, summary_html, summary_text
from .. import interrupts
from ..progress import check_deadline
from ..simulate import _interruptible_call, _law_template, _law_templates

RING_METHODS = ("auto", "compiled", "cvodes")
#: columns of one vehicle in a sample: states, quadratures, outputs
QUAD_NAMES = ("distance", "omega", "energy_J", "heat_J", "heat_irr_J", "rel_speed2", "ovm_err2")
OUT_NAMES = ("a", "I", "disc")
_BUILT: dict[Any, Any] = {}
#: The symbolic right-hand sides of a ring's laws (:meth:`RingSimulator._vehicle_function`) and its compiled ring's C
#: source in this process, by structure: (the law templates' keys in order, the number of runtime parameters, the
#: vehicle) -> (the laws' functions, their motion parts, {local_factor: C source}). Rings of the same laws and vehicle
#: with other coefficients (a calibration's simulations, a sweep's points) build them once (issue 40: the calibration
#: test's 154 rings spent 6 of its 7 s of CPU building them). At most _STRUCTURES_MAX structures, the oldest dropped.
_STRUCTURES: dict[Any, tuple[list[ca.Function], list[ca.Function], dict[float, str]]] = {}
_STRUCTURES_MAX = 64
MAX_DELAY_S = 5.0  # the longest reaction time a ring driver may have [s] (the stability CLI's --delay-s bound)
LAW_DT_S = 0.1  # the control period [s] of a law sampled for its command stages when no other controller sets one
#: Wall time [s] below which the next compiled advance is called directly instead of in an interruptible helper
#: thread: a Ctrl-C then waits about this long (the advances of one run are alike: noise holds, control intervals).
DIRECT_CALL_S = 0.02


@dataclass(frozen=True)
class HeldCommand(CarFollowingLaw):
    """A sampled controller's command held over a sample interval (the ring loop sets ``a_cmd`` every dt)."""

    a_cmd: float = 0.0
    name = "held"

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.a_cmd + 0 * h


@dataclass(frozen=True)
class RingRoad:
    """A ring road: its length [m], one controller per vehicle (a law or a sampled Controller; vehicle i follows
    vehicle i − 1, vehicle 0 follows the last), the vehicles' length [m], the EV model every vehicle carries,
    which vehicles are human (they get the acceleration noise) and the noise: standard deviation [m/s²], hold
    time [s] and seed."""

    length_m: float
    vehicles: tuple[Any, ...]
    vehicle_length_m: float = 5.0  # the ring benchmarks of Wu et al. 2017 (Flow); a 2022 Model 3 is 4.69 m long
    ev: EVParams = field(default_factory=EVParams)
    human: tuple[bool, ...] | None = None  # None: every vehicle that is a law and not an AEV law (see is_human)
    noise_mps2: float = 0.0
    noise_dt_s: float = 0.5
    seed: int = 0
    #: per-vehicle reaction time [s] of the human drivers' laws (None or 0: none; see RingSimulator "delays")
    delay_s: tuple[float, ...] | None = None
    delay_dt_s: float = 0.1  # update period [s] of a delayed driver's command (Treiber & Kesting's HDM-style update)

    def __post_init__(self) -> None:
        object.__setattr__(self, "vehicles", tuple(self.vehicles))
        n = len(self.vehicles)
        if self.delay_s is not None:
            d = tuple(float(x) for x in self.delay_s)
            object.__setattr__(self, "delay_s", d)
            if len(d) != n:
                raise ParameterError(f"ring: delay_s needs {n} reaction times (one per vehicle), got {len(d)}")
            if not all(math.isfinite(x) and 0 <= x <= MAX_DELAY_S for x in d):
                raise ParameterError(
                    f"ring: delay_s = {list(d)!r:.80} is not allowed: every reaction time must be a finite number of "
                    f"seconds in [0, {MAX_DELAY_S:g}]"
                )
            for i, x in enumerate(d):
                if x > 0 and not isinstance(self.vehicles[i], CarFollowingLaw):
                    raise ParameterError(
                        f"ring: delay_s gives vehicle {i + 1} a reaction time, but it is driven by a sampled "
                        "controller (only a law's driver reacts late)"
                    )
        if not (
            isinstance(self.delay_dt_s, (int, float)) and math.isfinite(self.delay_dt_s) and 0 < self.delay_dt_s <= 1
        ):
            raise ParameterError(f"ring: delay_dt_s = {self.delay_dt_s!r} is not allowed: must be a number in (0, 1] s")
        if n < 2:
            raise ParameterError(f"ring: vehicles needs at least 2 vehicles, got {n}")
        for name in ("length_m", "noise_dt_s"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
                raise ParameterError(f"ring: {name} = {x!r} is not allowed: must be a finite number > 0")
        for name in ("vehicle_length_m", "noise_mps2"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x >= 0):
                raise ParameterError(f"ring: {name} = {x!r} is not allowed: must be a finite number >= 0")
        if n * self.vehicle_length_m >= self.length_m:
            raise ParameterError(
                f"ring: {n} vehicles of {self.vehicle_length_m:g} m do not fit on length_m = "
                f"{self.length_m:g} (need length_m > n × vehicle_length_m)"
            )
        check_argument("ring", "ev", self.ev, EVParams)
        for i, c in enumerate(self.vehicles):
            if not isinstance(c, (CarFollowingLaw, Controller)):
                raise ParameterError(
                    f"ring: vehicle {i + 1} must be a CarFollowingLaw or a Controller, got {type(c).__name__}"
                )
        if self.human is not None:
            object.__setattr__(self, "human", tuple(bool(x) for x in self.human))
            if len(self.human) != n:
                raise ParameterError(f"ring: human needs {n} flags (one per vehicle), got {len(self.human)}")

    @property
    def n(self) -> int:
        """Number of vehicles."""
        return len(self.vehicles)

    @property
    def spacing_m(self) -> float:
        """Mean spacing (front to front) L/n [m]."""
        return self.length_m / self.n

    @property
    def density_per_km(self) -> float:
        """Vehicles per km."""
        return 1000.0 * self.n / self.length_m

    def is_human(self, i: int) -> bool:
        """Whether vehicle i is a human driver (default: an OVM or IDM law)."""
        if self.human is not None:
            return self.human[i]
        return isinstance(self.vehicles[i], CarFollowingLaw) and self.vehicles[i].name in ("ovm", "idm")


@dataclass(frozen=True)
class RingOptions:
    """Integration settings: tolerances, sample spacing of the output [s] (thin it for big rings), step limit
    per integration call, the integrator (RING_METHODS), ``local_factor`` (the error norm is max(ring RMS,
    largest vehicle RMS / local_factor): 1 = every vehicle within the tolerance; big jammed rings run several
    times faster with 30, see benchmarks/bench_ring.py) and OpenMP ``threads``."""

    rtol: float = 1e-8  # converged ring metrics to < 1e-5 relative (tests compare with 1e-10)
    atol: float = 1e-8
    dt_out_s: float = 0.5
    max_num_steps: int = 10_000_000
    method: str = "auto"
    local_factor: float = 1.0  # the error norm: max(ring RMS, largest vehicle RMS / local_factor); see ring.c
    threads: int = 1  # OpenMP threads over the vehicles (rings of >= 256 vehicles); 1 on a shared machine
    #: a braking event: the acceleration below braking_mps2 held at least braking_hold_s, counted on the
    #: integrator's own steps (independent of dt_out_s); the count from braking_from_s on (None: the second half)
    braking_mps2: float = -1.0  # aev_ocp.ring.run.BRAKING_MPS2
    braking_hold_s: float = 0.5  # our choice: a press, not a blip of noise
    braking_from_s: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.threads, int) and not isinstance(self.threads, bool) and 1 <= self.threads <= 256):
            raise ParameterError(
                f"RingOptions.threads = {self.threads!r} is not allowed: must be an integer in [1, 256]"
            )
        for name in ("rtol", "atol", "dt_out_s", "local_factor"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
                raise ParameterError(f"RingOptions.{name} = {x!r} is not allowed: must be a finite number > 0")
        if not (
            isinstance(self.braking_mps2, (int, float)) and math.isfinite(self.braking_mps2) and self.braking_mps2 < 0
        ):
            raise ParameterError(
                f"RingOptions.braking_mps2 = {self.braking_mps2!r} is not allowed: must be a number < 0"
            )
        if not (
            isinstance(self.braking_hold_s, (int, float))
            and math.isfinite(self.braking_hold_s)
            and self.braking_hold_s >= 0
        ):
            raise ParameterError(
                f"RingOptions.braking_hold_s = {self.braking_hold_s!r} is not allowed: must be a number >= 0"
            )
        if self.braking_from_s is not None and not (
            isinstance(self.braking_from_s, (int, float))
            and math.isfinite(self.braking_from_s)
            and self.braking_from_s >= 0
        ):
            raise ParameterError(f"RingOptions.braking_from_s = {self.braking_from_s!r} is not allowed: must be >= 0")
        if self.method not in RING_METHODS:
            raise ParameterError(f"RingOptions.method = {self.method!r} is not allowed: must be one of {RING_METHODS}")


@dataclass(frozen=True)
class RingInitial:
    """Initial positions [m] along the ring (vehicle i − 1 ahead of vehicle i) and speeds [m/s]; soc0 (None: the
    cell's S(0)). ``perturbation`` says in words what was perturbed (for reports)."""

    positions_m: tuple[float, ...]
    speeds_mps: tuple[float, ...]
    soc0: float | None = None
    perturbation: str = "given positions and speeds"


def _equilibrium_speed(law: CarFollowingLaw, gap: float, v_hi: float) -> float:
    """The speed v [model] with law(gap, v, v) = 0 (bisection on [0, v_hi]); 0 when the law brakes at every speed."""
    f = law.function
    lo, hi = 0.0, v_hi
    if float(f(gap, lo, lo)) <= 0:
        return 0.0
    if float(f(gap, hi, hi)) >= 0:
        return hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if float(f(gap, mid, mid)) > 0:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-14 * (1 + hi):
            break
    return 0.5 * (lo + hi)


def uniform_speed_mps(ring: RingRoad) -> float:
    """The uniform-flow speed [m/s] of the ring's first law-driven human vehicle at the mean gap L/n − ℓ."""
    u = ring.ev.units
    gap = float(u.length_from_si(ring.spacing_m - ring.vehicle_length_m))
    laws = [c for i, c in enumerate(ring.vehicles) if isinstance(c, CarFollowingLaw) and ring.is_human(i)]
    laws = laws or [c for c in ring.vehicles if isinstance(c, CarFollowingLaw)]
    if not laws:
        raise ParameterError("ring: no vehicle drives a law; give the initial speeds (RingInitial)")
    v_hi = float(u.speed_from_si(ring.ev.limits.v_max_mps))
    return float(u.speed_to_si(_equilibrium_speed(laws[0], gap, v_hi)))


def uniform_flow(
    ring: RingRoad,
    speed_mps: float | None = None,
    shift_m: float = 0.0,
    vehicle: int = 0,
    speed_dip_mps: float = 0.0,
    soc0: float | None = None,
) -> RingInitial:
    """Equal spacing L/n at one speed (default :func:`uniform_speed_mps`), then the stated perturbation: vehicle
    ``vehicle`` (0-based) moved back by ``shift_m`` and slowed by ``speed_dip_mps``."""
    n, s = ring.n, ring.spacing_m
    v = uniform_speed_mps(ring) if speed_mps is None else float(speed_mps)
    if not (0 <= vehicle < n):
        raise ParameterError(f"ring: perturbed vehicle {vehicle + 1} is not on the ring of {n} vehicles")
    gap = s - ring.vehicle_length_m
    for name, val, hi in (("shift_m", shift_m, gap), ("speed_dip_mps", speed_dip_mps, math.inf)):
        if not (isinstance(val, (int, float)) and math.isfinite(val) and 0 <= val < hi):
            raise ParameterError(
                f"ring: uniform_flow {name} = {val!r:.30} is not allowed: must be a finite number >= 0"
                + (f" and < {hi:.6g} m (the equal bumper-to-bumper gap)" if math.isfinite(hi) else "")
            )
    x = [-(i * s) % ring.length_m for i in range(n)]
    vs = [v] * n
    x[vehicle] = (x[vehicle] - shift_m) % ring.length_m
    vs[vehicle] = max(0.0, v - speed_dip_mps)
    what = (
        f"uniform flow at {v:.4g} m/s, spacing {s:.4g} m; vehicle {vehicle + 1} moved back {shift_m:g} m"
        f" and slowed by {speed_dip_mps:g} m/s"
    )
    return RingInitial(tuple(x), tuple(vs), soc0, what)


def start_problem(
    length_m: float, vehicle_length_m: float, v_max_mps: float, positions_m: Any, speeds_mps: Any
) -> tuple[str, str] | None:
    """(key, what is wrong) of a ring's start, or None when it is physical: ``positions_m`` [m] finite, listed front
    to back (vehicle i − 1 ahead of vehicle i: the gaps go once around the ring, adding up to ``length_m``), no two
    vehicles of ``vehicle_length_m`` overlapping; ``speeds_mps`` [m/s] in [0, ``v_max_mps``]. One check for the
    Python API (:meth:`RingSimulator.run`) and the scenario file (``[ring.initial]``)."""
    x = np.asarray(positions_m, float)
    v = np.asarray(speeds_mps, float)
    if not np.all(np.isfinite(v)) or np.any(v < 0) or np.any(v > v_max_mps):
        i = int(np.flatnonzero(~((v >= 0) & (v <= v_max_mps)))[0])
        return "speeds_mps", (
            f"every speed must be a finite number in [0, {v_max_mps:g}] m/s (limits.v_max_mps, the vehicle's top "
            f"speed); vehicle {i + 1} has {float(v[i])!r:.30}"
        )
    if not np.all(np.isfinite(x)):
        return "positions_m", "every position must be a finite number of metres"
    ahead = (np.roll(x, 1) - x) % length_m  # front-to-front distance of each vehicle to its predecessor
    gaps = ahead - vehicle_length_m
    if np.any(gaps <= 0):
        i = int(np.argmin(gaps))
        return "positions_m", (
            f"vehicle {i + 1} overlaps its predecessor (gap {gaps[i]:.4g} m; vehicle i − 1 must be ahead of "
            f"vehicle i, vehicles {vehicle_length_m:g} m long)"
        )
    if abs(float(np.sum(ahead)) - length_m) > 1e-9 * length_m * x.size:
        return "positions_m", (
            f"must list the vehicles front to back (vehicle i − 1 ahead of vehicle i, once around the ring): "
            f"the distances to each predecessor add up to {float(np.sum(ahead)):.6g} m, not the ring's {length_m:g} m"
        )
    return None


def gaps_from_positions(ring: RingRoad, positions_m: Sequence[float] | np.ndarray) -> np.ndarray:
    """Bumper-to-bumper gaps [m] of every vehicle to its predecessor on the ring."""
    x = np.asarray(positions_m, float)
    return (np.roll(x, 1) - x) % ring.length_m - ring.vehicle_length_m


# ----------------------------------------------------------------------------------------------- results
@dataclass
class RingResult:
    """A ring run. ``sim``: per-vehicle trajectories as the toolkit's one result type (model units; the
    'leader' of vehicle 0 is the ring's last vehicle), so :mod:`aev_ocp.metrics` applies unchanged;
    ``distance``, ``energy_J``: cumulative distance [model length] and battery energy [J] per vehicle (K, n)."""

    ring: RingRoad
    initial: RingInitial
    sim: SimulationResult
    distance: np.ndarray
    energy_J: np.ndarray
    wall_s: float = math.nan
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def t_s(self) -> np.ndarray:
        """Sample times [s]."""
        return np.asarray(self.sim.t * self.ring.ev.units.time_s)

    @property
    def status(self) -> str:
        """'ok' or the first event's kind."""
        return self.sim.status

    @property
    def speed_mps(self) -> np.ndarray:
        """Speeds (K, n) [m/s]."""
        return np.asarray(self.sim.speed * self.ring.ev.units.speed_mps)

    @property
    def gap_m(self) -> np.ndarray:
        """Gaps (K, n) [m]."""
        return np.asarray(self.sim.gap * self.ring.ev.units.length_m)

    @property
    def accel_mps2(self) -> np.ndarray:
        """Realised accelerations (K, n) [m/s²]."""
        return np.asarray(self.sim.accel * self.ring.ev.units.accel_mps2)

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        v = self.speed_mps
        half = v[v.shape[0] // 2 :]
        aevs = sum(not self.ring.is_human(i) for i in range(self.ring.n))
        return (
            f"RingResult: {self.ring.n} vehicles ({aevs} AEV) on {self.ring.length_m:g} m, status {self.status}",
            [
                ("duration_s", float(self.t_s[-1])),
                ("samples", int(self.t_s.size)),
                ("mean speed, second half [m/s]", float(half.mean())),
                ("speed std, second half [m/s]", float(half.std())),
                ("min gap [m]", float(self.gap_m.min())),
            ],
        )

    def __repr__(self) -> str:
        """A few lines: the ring, the status, duration [s], the speeds over the second half [m/s], the min gap [m]."""
        title, fields = self._repr_fields()
        return summary_text(
            title,
            [
                ", ".join(f"{k} {fmt_value(x)}" for k, x in fields[:2]),
                ", ".join(f"{k} {fmt_value(x)}" for k, x in fields[2:]),
            ],
        )

    def _repr_html_(self) -> str:
        title, fields = self._repr_fields()
        return summary_html(title, fields)

    def positions_m(self, wrap: bool = True) -> np.ndarray:
        """Positions (K, n) [m] along the ring (in [0, L) when ``wrap``)."""
        x = np.asarray(self.initial.positions_m)[None, :] + self.distance * self.ring.ev.units.length_m
        return x % self.ring.length_m if wrap else x

    def metrics(self) -> list[dict[str, Any]]:
        """Per-vehicle metrics (aev_ocp.metrics.vehicle_metrics) plus the battery energy ∫P_b dt of the ring's own
        quadrature [J] per km [J/km] and in kWh/100 km."""
        out = self.sim.metrics()
        for i, m in enumerate(out):
            d_km = float(self.distance[-1, i] * self.ring.ev.units.length_m) / 1000.0
            m["battery_energy_J"] = float(self.energy_J[-1, i])
            m["battery_energy_J_per_km"] = m["battery_energy_J"] / d_km if d_km > 0 else math.nan
            m["battery_energy_kWh_per_100km"] = m["battery_energy_J_per_km"] / 36000.0
            m["heat_pack_J_per_km"] = m["heat_pack_J"] / d_km if d_km > 0 else math.nan
        return out


# ----------------------------------------------------------------------------------------------- simulator
def _compile(source: str, stem: str) -> tuple[ctypes.CDLL | None, str]:
    """Compile with OpenMP, -O3 for the resolved native CPU, contraction off and no semantic interposition
    (:func:`aev_ocp.compiled.exact_tuned_flags`: the same bits as the plain build, so a ring's numbers do not depend
    on the machine's CPU; benchmarks/bench_ring.py), falling back to OpenMP at -O2, then to a plain build."""
    tuned = exact_tuned_flags()
    return load_fastest(source, stem, "ring", (*((("-fopenmp", *tuned),) if tuned else ()), ("-fopenmp",), ()))


def _quadrature(h: Any, v: Any, vl: Any, a: Any, b: dict[str, Any], ev: EVParams) -> list[Any]:
    """The quadrature integrands of one ring vehicle (model time): distance, ω's v·g(a), pack power, ∫Q, ∫Q_irr, the
    relative speed² and the optimal-velocity error², from its gap, speeds, acceleration and battery side ``b``."""
    T = ev.units.time_s
    return [
        v,
        v * energy.g_exact(a, ev.vehicle.efficiency),
        T * b["P_b"],
        T * b["Q_pack"],
        T * b["Q_irr_pack"],
        (vl - v) ** 2,
        (optimal_velocity(h) - v) ** 2,
    ]


@dataclass
class _RingRun:
    """The state of one :meth:`RingSimulator.run` (model units): the state z (n, nz), the sample times ``ts`` and
    the samples so far (``out``, ``s_done`` of them), the cuts of the integration (``grid``), the noise held now and
    how it is drawn (humans ``noisy``, σ, hold ``ndt``, the hold index ``k_noise``), the delayed drivers' update
    period ``ddt`` and history (H, V: a ring buffer of gaps and speeds), the sampled controllers with their
    measurements, last commands and step cores, the compiled integrator's step size and statistics, the events."""

    z: np.ndarray
    ts: np.ndarray
    grid: np.ndarray
    out: np.ndarray
    noise: np.ndarray
    noisy: np.ndarray
    use_noise: bool
    sigma: float
    ndt: float
    ddt: float
    rng: np.random.Generator
    H: np.ndarray
    V: np.ndarray
    ctrl: dict[int, Any]
    meas_v: dict[int, History]
    a_prev: dict[int, float]
    steps: dict[int, VehicleStep]
    meas_t: History = field(default_factory=History)  # the measured times (History: read without copies)
    h_io: np.ndarray = field(default_factory=lambda: np.zeros(1))
    stats: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))
    events: list[Event] = field(default_factory=list)
    s_done: int = 1
    k_noise: int = -1


def _structure_key(laws: tuple[Any, ...], n_par: int, ev: EVParams) -> Any:
    """The key of :data:`_STRUCTURES` (None when a law template or the vehicle cannot be a key: then nothing is
    kept)."""
    key = (laws, n_par, ev)
    try:
        hash(key)
    except TypeError:
        return None
    return key


class RingSimulator:
    """A ring road built once (compiled right-hand sides), run from any initial state.

    ``run(initial, t_end_s)`` returns a :class:`RingResult`; the run stops at the first event of
    :data:`aev_ocp.plant.EVENT_RULES` (collision located on the dense output, with the impact speed)."""

    def __init__(self, ring: RingRoad, options: RingOptions | None = None) -> None:
        check_argument("ring", "ring", ring, RingRoad)
        check_argument("ring", "options", options, (RingOptions, type(None)))
        self.ring, self.opts = ring, options or RingOptions()
        self.ev, self.n = ring.ev, ring.n
        # the loop core's stages of every automated vehicle (the humans' laws drive as they are)
        self.stages: list[CommandStages] = [
            NO_STAGES
            if ring.is_human(i)
            else stages_for(self.ev.limits, law=isinstance(c, (CarFollowingLaw, SampledLaw)), sensed=False)
            for i, c in enumerate(ring.vehicles)
        ]
        dts = {float(c.dt) for c in ring.vehicles if not isinstance(c, CarFollowingLaw)}
        if len(dts) > 1:
            raise ParameterError(f"ring: every sampled controller must use the same dt, got {sorted(dts)}")
        # an automated law whose run declares a conditioning or the safety layer is sampled (like an ECU) at the
        # controllers' dt, else every LAW_DT_S
        dt_law = next(iter(dts)) if dts else float(self.ev.units.time_from_si(LAW_DT_S))
        lo, hi = self.ev.limits.accel_bounds_model(self.ev.units)
        self.vehicles: list[Any] = [
            SampledLaw(c, dt_law, lo, hi) if isinstance(c, CarFollowingLaw) and self.stages[i].active else c
            for i, c in enumerate(ring.vehicles)
        ]
        self.sampled = [i for i, c in enumerate(self.vehicles) if not isinstance(c, CarFollowingLaw)]
        self.dt = dt_law if self.sampled else None  # model time
        # drivers with a reaction time: their law is evaluated every delay_dt_s on the state they saw a reaction
        # time ago and held in between (HeldCommand), see _delayed_commands
        delays = ring.delay_s or (0.0,) * self.n
        self.delayed = [i for i in range(self.n) if delays[i] > 0]
        for i in self.delayed:
            if not isinstance(self.vehicles[i], CarFollowingLaw):
                raise ParameterError(
                    f"ring: vehicle {i + 1} has a reaction time (delay_s) but is sampled for its command stages "
                    "(an automated vehicle); reaction times are for human drivers"
                )
        self.delay_model = np.asarray(delays, float) / self.ev.units.time_s
        delayed_laws = {i: self.vehicles[i] for i in self.delayed}
        self.laws: list[CarFollowingLaw] = [
            c if isinstance(c, CarFollowingLaw) and i not in delayed_laws else HeldCommand()
            for i, c in enumerate(self.vehicles)
        ]
        self._delay_groups = self._delay_functions(delayed_laws)
        templates = _law_templates(self.laws)
        distinct: dict[Any, int] = {}
        first: dict[int, Any] = {}
        self.law_of = np.zeros(self.n, np.int32)
        n_par = max(1, *(len(t[2]) for t in templates))
        self.params = np.zeros((self.n, n_par))
        for i, (key, make, values) in enumerate(templates):
            k = distinct.setdefault(key, len(distinct))
            first.setdefault(k, make)
            self.law_of[i] = k
            self.params[i, : len(values)] = values
        self.n_par = n_par
        self.nx = 5 + int(self.ev.limits.has_actuator_state)
        self._structure = _structure_key(tuple(distinct), n_par, self.ev)
        known = _STRUCTURES.get(self._structure) if self._structure is not None else None
        if known is None:
            p = ca.SX.sym("p", n_par)
            self._split: list[ca.Function] = []  # the motion part of each law (ring.c), filled by _vehicle_function
            self.funcs = [self._vehicle_function(make(p), k, p) for k, make in first.items()]
            known = (self.funcs, self._split, {})
            if self._structure is not None:
                remember(_STRUCTURES, self._structure, known, _STRUCTURES_MAX)
        self.funcs, self._split, self._sources = known
        self.nq, self.ny = len(QUAD_NAMES), len(OUT_NAMES)
        self.nz = self.nx + self.nq
        self._lib: ctypes.CDLL | None = None
        self.build_error = ""
        if self.opts.method in ("auto", "compiled"):
            self._build()
            if self._lib is None and self.opts.method == "compiled":
                raise ParameterError(f"ring: method 'compiled' needs a working C compiler: {self.build_error}")
            if self._lib is None:
                warnings.warn(
                    f"ring: the compiled ring is unavailable ({self.build_error}); using CVODES (slower)",
                    RuntimeWarning,
                    stacklevel=2,
                )
        self.method = "compiled" if self._lib is not None else "cvodes"
        self._cvodes: dict[float, Any] = {}
        self._direct = False  # whether the next compiled advance is called directly (see _advance_compiled)
        self._brake = np.zeros((self.n, 4))  # the braking counters of a run (ring.c; set by run)
        self._brake_args: tuple[float, float, float] = (-1.0, 0.0, 0.0)  # threshold, hold, from (model units)

    @staticmethod
    def _delay_functions(laws: dict[int, CarFollowingLaw]) -> list[tuple[np.ndarray, Any, np.ndarray]]:
        """(vehicles, law function (h, v, v_l, p) -> a, their parameters) per distinct law template of the delayed
        drivers: one call (:func:`aev_ocp.fastcall.column_call`) evaluates every delayed driver of a template (model
        units)."""
        groups: dict[Any, tuple[Any, list[tuple[int, list[float]]]]] = {}
        for i, law in laws.items():
            key, make, values = _law_template(law)
            groups.setdefault(key, (make, []))[1].append((i, values))
        out = []
        h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl")
        for make, members in groups.values():
            n_par = max(1, len(members[0][1]))
            p = ca.SX.sym("p", n_par)
            f = ca.Function("aevring_delayed", [h, v, vl, p], [make(p).accel(h, v, vl)])
            P = np.zeros((n_par, len(members)))
            for j, (_, values) in enumerate(members):
                P[: len(values), j] = values
            out.append((np.array([m[0] for m in members], int), f, P))
        return out

    def _delayed_commands(self, k: int, ddt: float, H: np.ndarray, V: np.ndarray) -> None:
        """Set the held command of every delayed driver at the k-th update (time k·ddt, model units): its law at
        the gap, speed and leader speed it saw at k·ddt + ddt/2 − τ (linear in the update history H, V, a ring
        buffer of rows; before t = 0 the initial state), so that over the hold [k·ddt, (k+1)·ddt) the mean lag is
        τ (τ ≥ ddt/2; a shorter τ acts as ddt/2)."""
        nb, n = H.shape[0], self.n
        for idx, f, P in self._delay_groups:
            x = np.clip(k + 0.5 - self.delay_model[idx] / ddt, 0.0, float(k))
            j0 = np.floor(x).astype(int)
            w = x - j0
            j1 = np.minimum(j0 + 1, k)
            pr = np.where(idx > 0, idx - 1, n - 1)
            hh = (1 - w) * H[j0 % nb, idx] + w * H[j1 % nb, idx]
            vv = (1 - w) * V[j0 % nb, idx] + w * V[j1 % nb, idx]
            vl = (1 - w) * V[j0 % nb, pr] + w * V[j1 % nb, pr]
            self.params[idx, 0] = column_call(f)(hh, vv, vl, P)[0].ravel()

    def _vehicle_function(self, law: CarFollowingLaw, k: int, p: ca.SX) -> ca.Function:
        """(u = (v_l, noise), x, p) -> (dz = (ẋ, quadrature integrands), y = (a, I, disc)), model units; the
        quadratures per model time unit (energy and heat in J per model time unit)."""
        ev, T = self.ev, self.ev.units.time_s
        u = ca.SX.sym("u", 2)
        vl, noise = u[0], u[1]
        h, v, V1, V2, S = (ca.SX.sym(s) for s in ("h", "v", "V1", "V2", "S"))
        a = law.accel(h, v, vl) + noise
        lim = ev.limits
        x = [h, v, V1, V2, S]
        extra: list[Any] = []
        if lim.enabled:  # the vehicle's limits, exactly as the open-chain plant applies them
            a = saturate(a, lim, ev.units)
            if lim.has_actuator_state:
                act = ca.SX.sym("a_act")
                extra = [actuator_rate(a, act, lim, ev.units)]
                x.append(act)
                a = act
            a = speed_cut(a, v, lim, ev.units)
        with piecewise_ocv():  # the same OCV as the B-spline (1e-14 V), as plain SX arithmetic: cheaper in C
            b = battery_side(v, a, V1, V2, S, ev)
        ode = [vl - v, a, T * b["dV1"], T * b["dV2"], T * b["dS"], *extra]
        quad = _quadrature(h, v, vl, a, b, ev)
        self._split.append(
            ca.Function(
                f"aevring_mot{k}", [u, ca.vertcat(*x), p], [ca.vertcat(vl - v, a, *extra), ca.vertcat(h, v, vl, a)]
            )
        )
        return ca.Function(
            f"aevring_law{k}", [u, ca.vertcat(*x), p], [ca.vertcat(*ode, *quad), ca.vertcat(a, b["I"], b["disc"])]
        )

    def _battery_functions(self) -> tuple[ca.Function, ca.Function, str]:
        """The battery and quadrature part of every vehicle's right-hand side, the same for every law, with the cell's
        OCV as an input (:func:`aev_ocp.models.battery.ocv_inputs`): ``aevring_bat_ocv`` (w = (h, v, v_l, a), x) ->
        the OCV's arguments S, and ``aevring_bat`` (w, x, OCV(S)) -> ((V̇1, V̇2, Ṡ, quadrature integrands),
        y = (a, I, disc)); and the prologue lines of the OCV table for ring.c's lookup (ocv_lookup.h: the values of
        the piecewise cubic the other right-hand sides use, to the bit). The compiled ring evaluates them only on
        accepted steps (the step size is set by the motion alone, see ring.c)."""
        ev, T = self.ev, self.ev.units.time_s
        w = ca.SX.sym("w", 4)
        h, v, vl, a = w[0], w[1], w[2], w[3]
        x = ca.SX.sym("x", self.nx)
        with ocv_inputs() as calls:
            b = battery_side(v, a, x[2], x[3], x[4], ev)
        own = [t.tolist() for t in ocv_table(ev.cell)]
        if not calls or any([t.tolist() for t in ocv_table(c)] != own for _, _, c in calls):
            raise RuntimeError("the ring's battery side must read the OCV of its own cell: ring.c has its table only")
        S = ca.vertcat(*(ca.vec(s) for s, _, _ in calls))
        E = ca.vertcat(*(ca.vec(e) for _, e, _ in calls))
        quad = _quadrature(h, v, vl, a, b, ev)
        pre = ca.Function("aevring_bat_ocv", [w, x], [S])
        bat = ca.Function(
            "aevring_bat",
            [w, x, E],
            [ca.vertcat(T * b["dV1"], T * b["dV2"], T * b["dS"], *quad), ca.vertcat(a, b["I"], b["disc"])],
        )
        grid, coef = ocv_segments(ev.cell)
        table = (
            f"#define AEV_OCV_CALLS {S.numel()}\n#define AEV_OCV_NSEG {len(coef)}\n"
            f"#define AEV_OCV_GRID {{{', '.join(map(repr, map(float, grid)))}}}\n"
            f"#define AEV_OCV_COEF {{{', '.join('{' + ', '.join(map(repr, map(float, r))) + '}' for r in coef)}}}\n"
        )
        return pre, bat, table

    def _motion_functions(self) -> tuple[list[ca.Function], list[ca.Function]]:
        """The motion of each law (``self._split``) with its parts that depend on the vehicle's coefficients p alone
        (e.g. the law's SI coefficients in model units, IDM's 2 √(a b)) taken out (CasADi's extract_parametric):
        ``aevring_coef{k}`` p -> q, evaluated by ring.c once per vehicle and advance, and ``aevring_mot{k}``
        (u, x, q) -> (motion rates, w). The same operations on the same numbers as the law's, once instead of at
        every stage."""
        motion, coefs = [], []
        extract = getattr(ca, "extract_parametric", None)  # CasADi >= 3.6; without it the motion reads p itself
        for k, f in enumerate(self._split):
            u, x, p = f.sx_in()
            outs, syms, parts = extract(f.call([u, x, p]), p) if extract else (f.call([u, x, p]), [], [])
            q = ca.vertcat(*syms) if syms else ca.SX.sym("q", 1)
            if ca.depends_on(ca.vertcat(*outs), p):  # not all of p's uses taken out: p itself as the coefficients
                outs, q, parts = f.call([u, x, p]), p, [p]
            motion.append(ca.Function(f"aevring_mot{k}", [u, x, q], outs))
            coefs.append(ca.Function(f"aevring_coef{k}", [p], [ca.vertcat(*parts) if parts else ca.DM.zeros(1)]))
        return motion, coefs

    def _build(self) -> None:
        source = self._sources.get(float(self.opts.local_factor)) or self._source()
        if self._structure is not None:
            self._sources[float(self.opts.local_factor)] = source
        lib = _BUILT.get(source)
        if lib is None:
            lib, self.build_error = _compile(source, "aevring")
            if lib is None:
                return
            fn = lib.aevring_advance
            dp, ip, lp = (
                np.ctypeslib.ndpointer(dtype=d, flags="C_CONTIGUOUS") for d in (np.float64, np.int32, np.int64)
            )
            fn.argtypes = [
                ctypes.c_int,
                ip,
                dp,
                dp,
                dp,
                ctypes.c_double,
                ctypes.c_double,
                ctypes.c_int64,
                dp,
                dp,
                ctypes.c_double,
                ctypes.c_double,
                ctypes.c_int64,
                dp,
                dp,
                lp,
                ctypes.c_int,
                dp,
                ctypes.c_double,
                ctypes.c_double,
                ctypes.c_double,
            ]
            fn.restype = ctypes.c_int64
            _BUILT[source] = lib
        self._lib = lib

    def _source(self) -> str:
        """The compiled ring's C source: the laws' motion and the battery side generated by CasADi, ring.c's
        definitions, ring.c."""
        cg = ca.CodeGenerator("aevring_rhs.c", {"with_header": False})
        # ring.c reads every output as a dense vector (see dense_outputs)
        # the law's whole right-hand side (self.funcs) is not compiled: ring.c evaluates it as its motion and battery
        pre, battery_fn, ocv_table_lines = self._battery_functions()
        motion, coefs = self._motion_functions()
        fs = [dense_outputs(f) for f in (*motion, *coefs, pre, battery_fn)]
        n_coef = max(1, *(f.size1_out(0) for f in coefs))
        for f in fs:
            cg.add(f)
        head = (
            f"#define SZ_ARG {max(3, *(f.sz_arg() for f in fs))}\n#define SZ_RES {max(2, *(f.sz_res() for f in fs))}\n"
            f"#define SZ_IW {max(f.sz_iw() for f in fs)}\n#define SZ_W {max(f.sz_w() for f in fs)}\n"
            f"#define NX {self.nx}\n#define NCTRL {2 + int(self.nx > 5)}\n#define NQ {self.nq}\n#define NY {self.ny}\n#define BATTERY 1\n"
            f"#define AEV_NP {self.n_par}\n#define AEV_NQ {n_coef}\n#define SPEED_FLOOR {int(self.ev.limits.enabled)}\n"
            f"#define LOCAL_FACTOR {float(self.opts.local_factor)!r}\n"
        )
        head += "#define AEV_LAW_SWITCH\n"  # dopri5.h's aev_law: not called by ring.c
        head += (
            "#define AEV_MOT_SWITCH "
            + " ".join(
                f"case {k}: return aevring_mot{k}(c->arg, c->res, c->iw, c->w, 0);" for k in range(len(self.funcs))
            )
            + "\n"
        )
        head += (
            "#define AEV_COEF_SWITCH "
            + " ".join(
                f"case {k}: return aevring_coef{k}(c->arg, c->res, c->iw, c->w, 0);" for k in range(len(self.funcs))
            )
            + "\n"
        )
        mot = [0, 1] + ([self.nx - 1] if self.nx > 5 else [])
        bat = [j for j in range(self.nz) if j not in mot]
        xb = pre.sx_in(1)  # the entries of x the battery reads (V1, V2, S): its stages 1..5 compute only these
        outs = ca.vertcat(*pre.call([pre.sx_in(0), xb]), *battery_fn.call([pre.sx_in(0), xb, battery_fn.sx_in(2)]))
        read = [j for j in bat if j < self.nx and ca.depends_on(outs, xb[j])]
        head += (
            f"#define MOT_IDX_INIT {{{', '.join(map(str, mot))}}}\n#define NB {len(bat)}\n"
            f"#define BAT_IDX_INIT {{{', '.join(map(str, bat))}}}\n"
            f"#define NBR {len(read)}\n#define BAT_READ_IDX_INIT {{{', '.join(map(str, read))}}}\n"
        )
        head += event_header() + ocv_table_lines
        return driver_source("fminmax.h") + cg.dump() + "\n" + head + driver_source("ring.c")

    # ------------------------------------------------------------------ one interval
    def _advance_compiled(
        self,
        z: np.ndarray,
        noise: np.ndarray,
        t0: float,
        t1: float,
        ts: np.ndarray,
        out: np.ndarray,
        h_io: np.ndarray,
        stats: np.ndarray,
    ) -> tuple[int, np.ndarray]:
        ev = np.zeros(4)
        assert self._lib is not None
        args = (
            self.n,
            self.law_of,
            self.params,
            noise,
            z,
            t0,
            t1,
            ts.size,
            ts,
            out,
            self.opts.rtol,
            self.opts.atol,
            self.opts.max_num_steps,
            h_io,
            ev,
            stats,
            self.opts.threads,
            self._brake,
            *self._brake_args,
        )
        # in a helper thread, so that Ctrl-C, SIGTERM and --time-limit stop it within a step (aevring_cancel); an
        # advance after one that took less than DIRECT_CALL_S is called directly (a thread costs ~1 ms a call, twice
        # the whole advance of a small ring between two noise changes), the signal handled when it returns
        fn, tc = self._lib.aevring_advance, time.perf_counter()
        if self._direct:
            check_deadline()
            m = fn(*args)
        else:
            m = _interruptible_call(fn, args, ctypes.c_int.in_dll(self._lib, "aevring_cancel"))
        self._direct = time.perf_counter() - tc < DIRECT_CALL_S
        if m == -2:  # stopped through aevring_cancel by another thread's interrupt of the same library
            raise interrupts.Interrupted("the compiled ring was cancelled")
        if m < 0:
            raise MemoryError("ring: the compiled ring ran out of memory")
        return int(m), ev

    def _cvodes_fn(self, dt: float) -> Any:
        """CVODES integrator of the whole ring over dt (model time), parameters: all coefficients and noise."""
        fn = self._cvodes.get(dt)
        if fn is None:
            n, nz = self.n, self.nz
            Z = ca.MX.sym("Z", nz * n)
            P = ca.MX.sym("P", self.n_par * n + n)
            Zr = ca.reshape(Z, nz, n)
            cols = []
            for i in range(n):
                pr = i - 1 if i > 0 else n - 1
                u = ca.vertcat(Zr[1, pr], P[self.n_par * n + i])
                cols.append(
                    self.funcs[int(self.law_of[i])](u, Zr[: self.nx, i], P[i * self.n_par : (i + 1) * self.n_par])[0]
                )
            dae = {"x": Z, "p": P, "ode": ca.vertcat(*cols)}
            fn = ca.integrator(
                "ring",
                "cvodes",
                dae,
                0.0,
                dt,
                {"abstol": self.opts.atol, "reltol": self.opts.rtol, "max_num_steps": 10**6},
            )
            self._cvodes[dt] = fn
        return fn

    def _outputs(self, z: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """(n, ny) outputs at state z (n, nz)."""
        y = np.zeros((self.n, self.ny))
        for i in range(self.n):
            pr = i - 1 if i > 0 else self.n - 1
            _, yi = self.funcs[int(self.law_of[i])]([z[pr, 1], noise[i]], z[i, : self.nx], self.params[i])
            y[i] = np.asarray(yi).ravel()
        return y

    def _advance_cvodes(
        self, z: np.ndarray, noise: np.ndarray, t0: float, t1: float, ts: np.ndarray, out: np.ndarray
    ) -> tuple[int, np.ndarray]:
        ev = np.zeros(4)
        grid = np.concatenate([[t0], ts[(ts > t0) & (ts <= t1 + 1e-12)], [t1]])
        P = np.concatenate([self.params.ravel(), noise])
        m = 0
        for a, b in zip(grid[:-1], grid[1:]):
            if b - a <= 1e-12:
                continue
            fn = self._cvodes_fn(round(b - a, 12))
            zf = np.asarray(fn(x0=z.ravel(), p=P)["xf"]).ravel().reshape(self.n, self.nz)
            z[:] = zf
            if m < ts.size and abs(b - ts[m]) <= 1e-12 * (1 + abs(b)):
                y = self._outputs(z, noise)
                out[m] = np.hstack([z, y])
                m += 1
            y = self._outputs(z, noise)
            self._count_braking(b, y[:, 0])
            bad = self._check(z, y)
            if bad is not None:
                ev[:] = [bad[0], bad[1], b, bad[2]]
                break
        return m, ev

    def _count_braking(self, te: float, a: np.ndarray) -> None:
        """The braking counters at time te (model) with the accelerations a (model): as ring.c does per step (the
        CVODES path counts at the ends of its integration intervals)."""
        lim, hold, start = self._brake_args
        b = self._brake
        on = a < lim
        b[~on, 0] = -1.0
        new = on & (b[:, 0] < 0)
        b[new, 0], b[new, 1] = te, 0.0
        done = on & (b[:, 1] == 0) & (te - b[:, 0] >= hold * (1 - 1e-12))
        b[done, 1] = 1.0
        b[done, 2] += 1.0
        b[done & (b[:, 0] >= start), 3] += 1.0

    def _check(self, z: np.ndarray, y: np.ndarray) -> tuple[int, int, float] | None:
        """(code, vehicle, value) of the first rule of EVENT_RULES violated at a sample, else None."""
        q = {"h": z[:, 0], "v": z[:, 1], "disc": y[:, 2], "S": z[:, 4]}
        for r in EVENT_RULES:
            hit = np.flatnonzero(r.violated(q[r.quantity]))
            if hit.size:
                return r.code, int(hit[0]), float(q[r.quantity][hit[0]])
        return None

    def _cut_intervals_s(self) -> dict[str, float]:
        """{what: interval [s]} of the integration cuts of a run: the sampled controllers' dt, the noise's hold."""
        T, ring = self.ev.units.time_s, self.ring
        out = {} if self.dt is None else {"the sampled controllers' dt": self.dt * T}
        if ring.noise_mps2 > 0 and any(ring.is_human(i) for i in range(self.n)):
            out["noise_dt_s"] = ring.noise_dt_s
        if self.delayed:
            out["delay_dt_s"] = ring.delay_dt_s
        return out

    # ------------------------------------------------------------------ running
    def run(self, initial: RingInitial, t_end_s: float) -> RingResult:
        """Integrate the ring from ``initial`` over [0, t_end_s] [s]: at each cut of the time grid (samples,
        control instants, noise holds, reaction-time updates) the held inputs are set, then the whole ring is
        integrated to the next cut; an event ends the run."""
        z = self._initial_state(initial, t_end_s)
        r = self._prepare(z, t_end_s)
        wall = time.perf_counter()
        t0 = 0.0
        for t1 in r.grid:
            self._inputs(r, t0)
            if self._integrate(r, t0, t1):
                break
            t0 = float(t1)
        wall = time.perf_counter() - wall
        return self._result(initial, r.ts[: r.s_done], r.out[: r.s_done], r.events, wall, r.stats, r.steps)

    def _initial_state(self, initial: RingInitial, t_end_s: float) -> np.ndarray:
        """The state z (n, nz) at t = 0 from ``initial`` (model units), every input checked first, and the run's
        size and integration cuts checked against the budgets before anything is allocated or integrated."""
        check_argument("ring", "initial", initial, RingInitial)
        if not (isinstance(t_end_s, (int, float)) and math.isfinite(t_end_s) and t_end_s > 0):
            raise ParameterError(f"ring: t_end_s = {t_end_s!r} is not allowed: must be a finite number > 0")
        ring, u, n = self.ring, self.ev.units, self.n
        x0 = np.asarray(initial.positions_m, float)
        v0 = np.asarray(initial.speeds_mps, float)
        if x0.size != n or v0.size != n:
            raise ParameterError(f"ring: the initial state needs {n} positions and speeds, got {x0.size} and {v0.size}")
        bad = start_problem(ring.length_m, ring.vehicle_length_m, self.ev.limits.v_max_mps, x0, v0)
        if bad is not None:
            raise ParameterError(f"ring: RingInitial.{bad[0]} is not allowed: {bad[1]}")
        gaps = gaps_from_positions(ring, x0)
        soc0 = self.ev.cell.soc0 if initial.soc0 is None else initial.soc0
        if not (0 <= soc0 <= 1):
            raise ParameterError(f"ring: soc0 = {soc0!r} is not allowed: must be in [0, 1]")
        check_ring_size(n, t_end_s, self.opts.dt_out_s)  # the budget, before anything is allocated or integrated
        check_ring_cuts(t_end_s, self._cut_intervals_s())  # the cuts too, before their grid is built
        self._direct = False  # the first advance runs interruptibly (see _advance_compiled)
        z = np.zeros((n, self.nz))
        z[:, 0], z[:, 1], z[:, 4] = u.length_from_si(gaps), u.speed_from_si(v0), soc0
        return z

    def _prepare(self, z: np.ndarray, t_end_s: float) -> _RingRun:
        """A run's state at t = 0 from the initial state z: the sample times and the grid of cuts, the noise, the
        reaction-time history, the braking counters, the controllers reset with one step core each."""
        ring, u, n, T = self.ring, self.ev.units, self.n, self.ev.units.time_s
        t_end = t_end_s / T
        dt_out = self.opts.dt_out_s / T
        ts = np.linspace(0.0, t_end, max(1, int(math.ceil(t_end / dt_out - 1e-9))) + 1)
        noisy = np.array([ring.is_human(i) for i in range(n)], bool)
        use_noise = bool(ring.noise_mps2 > 0 and noisy.any())
        ndt, ddt = ring.noise_dt_s / T, ring.delay_dt_s / T
        grid = self._grid(t_end, ndt if use_noise else None, ddt if self.delayed else None)
        nb = int(math.ceil(float(np.max(self.delay_model)) / ddt)) + 3 if self.delayed else 0  # rows a delay spans
        rng = np.random.default_rng(ring.seed)
        sigma = float(u.accel_from_si(ring.noise_mps2))
        out = np.zeros((ts.size, n, self.nz + self.ny))
        noise = np.zeros(n)
        out[0] = np.hstack([z, self._outputs(z, noise)])
        o = self.opts
        b_from = 0.5 * t_end_s if o.braking_from_s is None else o.braking_from_s
        self._brake = np.zeros((n, 4))
        self._brake[:, 0] = -1.0
        self._brake_args = (float(u.accel_from_si(o.braking_mps2)), o.braking_hold_s / T, b_from / T)
        ctrl = {i: self.vehicles[i] for i in self.sampled}
        for c in ctrl.values():
            c.reset()
        assert self.dt is not None or not ctrl
        steps = {
            i: VehicleStep(c.name, f"vehicle {i + 1}", u, self.ev.limits, self.stages[i], self.dt or 1.0, "ring")
            for i, c in ctrl.items()
        }
        return _RingRun(
            z=z,
            ts=ts,
            grid=grid,
            out=out,
            noise=noise,
            noisy=noisy,
            use_noise=use_noise,
            sigma=sigma,
            ndt=ndt,
            ddt=ddt,
            rng=rng,
            H=np.zeros((nb, n)),
            V=np.zeros((nb, n)),
            ctrl=ctrl,
            meas_v={i: History() for i in ctrl},
            a_prev=dict.fromkeys(ctrl, 0.0),
            steps=steps,
        )

    def _grid(self, t_end: float, ndt: float | None, ddt: float | None) -> np.ndarray:
        """The cuts of the integration up to t_end (model time, sorted): the control instants, the noise's holds
        (``ndt``; None: no noise) and the delayed drivers' updates (``ddt``; None: none), and t_end."""
        cuts = {t_end}
        if self.dt is not None:
            k = int(round(t_end / self.dt))
            cuts |= {j * self.dt for j in range(1, k) if j * self.dt < t_end - 1e-12}
        for step in (ndt, ddt):
            if step is not None:
                cuts |= {j * step for j in range(1, int(math.ceil(t_end / step))) if j * step < t_end - 1e-12}
        return np.array(sorted(cuts))

    def _inputs(self, r: _RingRun, t0: float) -> None:
        """The inputs held from the cut t0 [model] on: a new noise draw at each noise hold, the delayed drivers'
        commands at each of their updates, the sampled controllers' commands at each control instant."""
        z = r.z
        if r.use_noise:
            kn = int(math.floor(t0 / r.ndt + 1e-9))
            if kn != r.k_noise:
                r.k_noise = kn
                r.noise = np.where(r.noisy, r.rng.normal(0.0, r.sigma, self.n), 0.0)
        if self.delayed and abs(t0 / r.ddt - round(t0 / r.ddt)) < 1e-9:
            k_upd = int(round(t0 / r.ddt))
            nb = r.H.shape[0]
            r.H[k_upd % nb], r.V[k_upd % nb] = z[:, 0], z[:, 1]
            self._delayed_commands(k_upd, r.ddt, r.H, r.V)
        if r.ctrl and self.dt is not None and abs(t0 / self.dt - round(t0 / self.dt)) < 1e-9:
            self._control(r, t0)

    def _control(self, r: _RingRun, t0: float) -> None:
        """Every sampled controller's command at the control instant t0 [model] through its step core (checked,
        conditioned, safety layer, limits: :mod:`aev_ocp.loop`), held over the step as its law's parameter."""
        assert self.dt is not None
        z, n = r.z, self.n
        r.meas_t.append(t0)
        for i, c in r.ctrl.items():
            pr = i - 1 if i > 0 else n - 1
            r.meas_v[i].append(float(z[pr, 1]))
            obs = Observation(
                t0,
                self.dt,
                i,
                z[i, :5].copy(),
                r.meas_t.view(),
                r.meas_v[i].view(),
                None,
                r.a_prev[i],
                float(z[i, 5]) if self.nx > 5 else None,
                follower=np.array([z[(i + 1) % n, 0], z[(i + 1) % n, 1]]),  # the vehicle behind it (a rear radar)
            )
            _, r.a_prev[i] = r.steps[i].command(c, obs)
            self.params[i, 0] = r.a_prev[i]

    def _integrate(self, r: _RingRun, t0: float, t1: Any) -> bool:
        """Integrate the ring from t0 to the cut t1 [model], storing the samples in between; True when an event
        (a rule of EVENT_RULES, or the integrator's failure) ends the run, its state the run's last sample."""
        ts, z = r.ts, r.z
        sel = (ts > t0 + 1e-12 * (1 + t0)) & (ts <= t1 + 1e-12 * (1 + t1))
        tsel = np.ascontiguousarray(ts[sel])
        buf = np.zeros((tsel.size, self.n, self.nz + self.ny))
        if self.method == "compiled":
            m, ev = self._advance_compiled(z, r.noise, t0, t1, tsel, buf, r.h_io, r.stats)
        else:
            m, ev = self._advance_cvodes(z, r.noise, t0, t1, tsel, buf)
        r.out[r.s_done : r.s_done + m] = buf[:m]
        r.s_done += m
        if not ev[0]:
            return False
        r.events.append(self._event(z, ev))
        t_ev = float(ev[2])
        if t_ev > ts[r.s_done - 1]:  # the state at the event is the run's last sample
            r.ts = np.concatenate([ts[: r.s_done], [t_ev]])
            r.out[r.s_done] = np.hstack([z, self._outputs(z, r.noise)])
            r.s_done += 1
        return True

    def _event(self, z: np.ndarray, ev: np.ndarray) -> Event:
        """The Event of an integration that stopped (``ev``: code, vehicle, time [model], value) at state z: the
        plants' rule (:data:`aev_ocp.plant.EVENT_RULES`) it broke, or the integrator's failure."""
        n = self.n
        code, who, t_ev = int(ev[0]), int(ev[1]), float(ev[2])
        if code in [r.code for r in EVENT_RULES]:
            rule = rule_of_code(code)
            pr = who - 1 if who > 0 else n - 1
            return event_at(
                rule,
                t_ev,
                who,
                self.ev.units,
                float(z[who, 0]),
                float(z[who, 1]),
                float(z[pr, 1]),
                float({"h": z[who, 0], "v": z[who, 1], "S": z[who, 4], "disc": ev[3]}[rule.quantity]),
            )
        return Event(
            "integration_failed",
            t_ev,
            who,
            "the ring integrator failed (step size underflow or the step limit)",
            time_s=t_ev * self.ev.units.time_s,
        )

    def _result(
        self,
        initial: RingInitial,
        ts: np.ndarray,
        out: np.ndarray,
        events: list[Event],
        wall: float,
        stats: np.ndarray,
        steps: dict[int, VehicleStep],
    ) -> RingResult:
        nx, n = self.nx, self.n
        col = lambda j: np.ascontiguousarray(out[:, :, j])  # noqa: E731
        q = {name: col(nx + j) for j, name in enumerate(QUAD_NAMES)}
        y = {name: col(self.nz + j) for j, name in enumerate(OUT_NAMES)}
        speed = col(1)
        lead_pos = (
            np.asarray(self.ring.length_m if False else initial.positions_m[-1]) / self.ev.units.length_m
            + q["distance"][:, -1]
        )
        names = [getattr(c, "name", type(c).__name__) for c in self.vehicles]
        settings = [  # an automated vehicle's settings name its conditioning (aev_ocp.loop)
            steps[i].settings(c) if i in steps else c.describe() for i, c in enumerate(self.vehicles)
        ]
        solver: list[dict[str, Any] | None] = [None] * n
        for i, step in steps.items():
            call = np.asarray(step.rec["call"]) * 1e3
            solver[i] = {
                "steps": len(call),
                "call_ms_median": float(np.median(call)) if call.size else math.nan,
                "call_ms_max": float(np.max(call)) if call.size else math.nan,
                "fallbacks": int(sum(1 for ok in step.rec["ok"] if not ok)),
                "conditioning": step.stages.label(),
                **{k: v for k, v in step.counts().items() if k != "steps"},
            }
        sim = SimulationResult(
            t=ts,
            leader_speed=speed[:, -1],
            leader_position=lead_pos,
            gap=col(0),
            speed=speed,
            accel=y["a"],
            V1=col(2),
            V2=col(3),
            S=col(4),
            current_A=y["I"],
            omega=q["omega"],
            heat_J=q["heat_J"],
            heat_irr_J=q["heat_irr_J"],
            int_ovm_err2=q["ovm_err2"],
            int_rel_speed2=q["rel_speed2"],
            int_jerk2=np.zeros_like(speed),
            controllers=names,
            ev=self.ev,
            events=events,
            violations=current_limit_events(ts, y["I"], self.ev),  # the plants' one rule (aev_ocp.plant)
            jerk_sampled=True,
            solver_stats=solver,
            meta={
                "plant": f"ring ({self.method})",
                "rtol": self.opts.rtol,
                "atol": self.opts.atol,
                "controllers": settings,
                # each automated vehicle's conditioning and safety layer (None: a human's law), with their counts
                "command_stages": [steps[i].describe() if i in steps else None for i in range(n)],
                "ring_length_m": self.ring.length_m,
                "vehicle_length_m": self.ring.vehicle_length_m,
                "initial": initial.perturbation,
                "delay_s": list(self.ring.delay_s) if self.ring.delay_s is not None else None,
            },
        )
        return RingResult(
            self.ring,
            initial,
            sim,
            q["distance"],
            q["energy_J"],
            wall,
            {
                "steps": int(stats[0]),
                "rejected": int(stats[1]),
                "rhs_evaluations": int(stats[2]),
                "method": self.method,
                # braking events per vehicle (RingOptions.braking_*), counted on the integrator's steps
                "braking_events": self._brake[:, 2].astype(int).tolist(),
                "braking_events_window": self._brake[:, 3].astype(int).tolist(),
                "braking_from_s": self._brake_args[2] * self.ev.units.time_s,
            },
        )


def simulate_ring(
    ring: RingRoad, t_end_s: float, initial: RingInitial | None = None, options: RingOptions | None = None
) -> RingResult:
    """Simulate ``ring`` over [0, t_end_s] [s] from ``initial`` (default :func:`uniform_flow` unperturbed)."""
    sim = RingSimulator(ring, options)
    return sim.run(initial if initial is not None else uniform_flow(ring), t_end_s)


__all__ = [
    "HeldCommand",
    "RingInitial",
    "RingOptions",
    "RingResult",
    "RingRoad",
    "RingSimulator",
    "gaps_from_positions",
    "simulate_ring",
    "uniform_flow",
    "uniform_speed_mps",
]
_ = (dataclasses, Callable)
