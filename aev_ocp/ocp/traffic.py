"""The car-following MPC problem for real traffic — the default formulation of ``[mpc]``.

model guide §9 states the canonical MPC: model-unit weights, a hard gap bound h ≥ 0.2, the OVM
tracking term (V(h) − v)² and no terminal ingredient. Under an imperfect forecast (a drive cycle
with a constant-velocity forecast) that problem closes to h_min at every stop, brakes hard when the
forecast is wrong, and its weights change meaning with ``[units]``. :func:`traffic_problem` keeps
§9's model, states and layout (z = (h, v, V1, V2, S), control a first, stage parameters (v̄_l, v̂_l)),
and changes the objective and constraints, every parameter declared in SI in :class:`TrafficParams`
and converted with the scenario's units (so a user does not retune when L or U change):

* **Cost [W/kg·s = J/kg].** ℓ = w_ω·e + w_Q·Q_pack/m + w_a a² + w_j ȧ² + w_r (v̂_l − v)² + w_g (h − h_des(v))²
  with every quantity in SI, integrated over time in seconds (the model-time sum Σ ℓ·dt is multiplied by
  the time unit T). e ≥ v a/η, e ≥ η v a is the exact rate of the paper's inertial measure ω, v g(a) of
  model guide §4 (term and weight ``omega``/``omega_weight``; not battery energy, which also pays the road load;
  §9: smoothed g weighted in model units). Q_pack/m is the pack heat per
  vehicle mass (§9: Q_pack/1 kW). w_j penalises Δa/dt (jerk; §9 has none) through an own state
  ``a_prev`` (the command applied last step). w_r and w_g replace §9's OVM term: the gap is drawn to
  h_des(v) = s_0 + T_des·v (a constant-time-gap policy in SI; §9's V(h) is a model-unit curve whose
  time gap changes with L, U), so lagging behind is penalised and the ω term cannot be lowered by
  falling back.
* **Terminal cost** (§9: none): w_T (h_N − h_des(v_N))², so a short horizon does not plan to close (or
  open) the gap after its end.
* **Constraints on the gap, soft with an exact L1 penalty** (§9: a hard h ≥ 0.2): a time headway
  h ≥ s_min + T_h v and a braking-distance constraint h ≥ s_min + v t_r + (v² − v̂_l²)/(2 b): with b the
  deceleration both cars can brake at, the follower can stop s_min behind a predecessor that brakes at b
  from its forecast speed, even when the forecast said it would not brake. Both imply the standstill
  floor h ≥ s_min (v ≥ 0 is hard). One slack σ ≥ 0 [m] enters both and the cost ρ_safe σ (+ 1e-3 σ²
  for a PD Hessian), so every QP is feasible; the L1 penalty is exact: for ρ_safe above the
  constraints' multipliers the slack is 0 whenever the hard problem is feasible. An optional soft margin
  (``margin_weight`` > 0; off by default) adds h + σ_m ≥ s_min + T_m v and h + σ_m ≥ s_min + TTC_m (v − v̂_l) with
  the quadratic cost w_m σ_m²: more than the floor is kept where that costs little. Hard: 0 ≤ v ≤ v_max,
  a_min ≤ a ≤ a_max (SI; default: the vehicle's limits, EVParams.limits), |I| ≤ 20C and the current map,
  as §9 (always satisfiable together: a = 0 keeps every one; at v = 0 braking is not possible and not needed).
* **Actuator lag**: when the vehicle has one (VehicleLimits.lag_s, or a jerk limit), the prediction model
  carries the plant's actuator state a_act (da_act/dt = (a − a_act)/τ, measured at every step) and the
  motion, ω and battery terms use a_act; the jerk term stays on the command a.
"""

from __future__ import annotations

import warnings
from dataclasses import InitVar, dataclass
from typing import Any, Sequence

import casadi as ca

from ..models.actuator import actuator_rate
from ..models.ego import STATE_NAMES, battery_side, following_ode
from ..params import PAPER_ACCEL_BOUNDS_MODEL, EVParams, ParameterError, PowertrainOptions, Units, spec, validate_fields
from .following import (
    EV_NUMBERS,
    FollowingBounds,
    TemperatureTerms,
    add_temperature_limit,
    add_temperature_state,
    set_temperature_rate,
)
from .problem import ProblemBuilder

FORMULATIONS = ("traffic", "s9")  # 'traffic': this module (default); 's9': model guide §9 exactly
#: Finite upper bounds of the epigraph and slack controls (never active: |v g(a)| ≤ 45 m/s × 7.5 m/s² / 0.8
#: = 422 W/kg; a gap 1 km short of its bound is not a traffic situation): finite bounds keep the QP solver's
#: stand-in for infinity away from the variables' scale.
OMEGA_RATE_MAX_W_PER_KG = 1000.0
SLACK_MAX_M = 1000.0


@dataclass(frozen=True)
class TrafficParams:
    """Parameters of :func:`traffic_problem`, all in SI (cost unit: W/kg of vehicle mass, integrated
    over seconds). Sources: 'our choice' unless stated; measured with benchmarks/bench_mpc_cycles.py."""

    omega_weight: float = spec(1.0, ge=0.0)  # w_ω [-] on v g(a) [W/kg], the paper's ω rate (the reference unit of
    # the cost; scenario files' old key energy_weight is still read, with a FutureWarning)
    heat_weight: float = spec(20.0, ge=0.0)  # w_Q [-] on pack heat Q_pack/m [W/kg] (our choice: I² matters)
    accel_weight: float = spec(6.0, ge=0.0)  # w_a [W/kg per (m/s²)²] (our choice: small currents; 1 → 3 lowered
    # pack heat per km 7 % on UDDS-300 s and 25 % behind the paper leader; 3 → 6: ω/km behind the paper leader
    # with the decaying-acceleration forecast 1.787 → 1.652 (the laws: 1.747, 1.768), UDDS/US06 within 1.3 %)
    jerk_weight: float = spec(0.3, ge=0.0)  # w_j [W/kg per (m/s³)²] (our choice)
    relative_speed_weight: float = spec(0.1, ge=0.0)  # w_r [W/kg per (m/s)²] (our choice: small, so the follower
    # does not copy a leader's oscillations that its gap can absorb; 1.0 cost 27 % more heat behind the paper leader)
    gap_weight: float = spec(0.02, ge=0.0)  # w_g [W/kg per m²] on (h − h_des(v))² (our choice: the gap breathes)
    terminal_gap_weight: float = spec(1.0, ge=0.0)  # w_T [J/kg per m²] on (h_N − h_des(v_N))² (our choice)
    standstill_gap_m: float = spec(2.0, gt=0.0)  # s_min [m]: §9's h_min = 0.2 at L = 10 m
    target_gap_m: float = spec(4.0, gt=0.0)  # s_0 [m] of h_des (our choice: s_min + 2 m)
    target_time_gap_s: float = spec(2.5, gt=0.0)  # T_des [s] of h_des (our choice: between the proposed law's
    # equilibrium time gaps 1.7–2.4 s (L = 15 m, U = 17 m/s, 10–20 m/s) and 3.5 s (L = 10, U = 5, 8.5 m/s), so the
    # distance travelled stays within 1 % of the law's; 1.6 s ended 1.4 % ahead behind the paper leader)
    time_headway_s: float = spec(1.0, ge=0.0)  # T_h [s] (ACC practice 1–2 s; ISO 15622 allows ≥ 0.8 s)
    reaction_time_s: float = spec(0.3, ge=0.0)  # t_r [s] of the braking-distance constraint (our choice)
    brake_decel_mps2: float = spec(6.0, gt=0.0)  # b [m/s²]: emergency braking both cars can do (dry road ≈ 8)
    safe_penalty: float = spec(100.0, gt=0.0)  # ρ_safe [W/kg per m of violation] (above every multiplier seen)
    v_max_mps: float = spec(45.0, gt=0.0)  # [m/s] (§9: 2 model = 10 m/s at L = 10, U = 5; 162 km/h here)
    # a bounds [m/s²]: None = the vehicle's (EVParams.limits: a_min_mps2, a_max_mps2); an explicit value must lie
    # inside the vehicle's limits. A vehicle without limits (UNLIMITED) gets UNLIMITED_A_BOUNDS_MPS2.
    a_min_mps2: float | None = spec(None, lt=0.0, optional=True)
    a_max_mps2: float | None = spec(None, gt=0.0, optional=True)
    # the soft safety margin (issue 34; off by default: the shipped and the paper's MPC unchanged): w_m σ_m² with
    # h + σ_m ≥ s_min + T_m v and h + σ_m ≥ s_min + TTC_m (v − v̂_l), σ_m ≥ 0 [m]: a quadratic penalty, so a small
    # shortfall costs little and the floor constraints above stay the hard-ish limit
    margin_weight: float = spec(0.0, ge=0.0)  # w_m [W/kg per m²] (0: off; the safety suite's 'mpc-margin': 1.0)
    margin_time_gap_s: float = spec(1.8, ge=0.0)  # T_m [s] (ours: above T_h = 1 s, the German "half the
    # speedometer" rule's 1.8 s; Vogel 2003, Accid. Anal. Prev. 35: time gaps under 1 s are dangerous)
    margin_ttc_s: float = spec(4.0, ge=0.0)  # TTC_m [s] (Hirst & Graham 1997: a TTC of 4 s separates safe from
    # critical approaches; Euro NCAP's CCR runs start at TTC 4 s)
    energy_weight: InitVar[float | None] = None  # the old name of omega_weight: read with a FutureWarning

    def __post_init__(self, energy_weight: float | None = None) -> None:
        if energy_weight is not None:
            if self.omega_weight != 1.0:
                raise ParameterError(
                    "TrafficParams: energy_weight and omega_weight are both given: energy_weight is the old name of "
                    "omega_weight"
                )
            warnings.warn(
                "TrafficParams.energy_weight is deprecated: use omega_weight (the weight of the paper's inertial "
                "measure rate v g(a), not of battery energy)",
                FutureWarning,
                stacklevel=3,
            )
            object.__setattr__(self, "omega_weight", energy_weight)
        validate_fields(self)
        if self.target_gap_m < self.standstill_gap_m:
            raise ParameterError(
                f"TrafficParams.target_gap_m = {self.target_gap_m} must be >= standstill_gap_m = "
                f"{self.standstill_gap_m}"
            )


#: (a_min, a_max) [m/s²] of the formulation on a vehicle without limits (UNLIMITED): §9's −3 and 2 at the
#: default units (L = 10 m, U = 5 m/s), the bounds this formulation had before vehicles had limits
UNLIMITED_A_BOUNDS_MPS2 = (
    float(Units().accel_to_si(PAPER_ACCEL_BOUNDS_MODEL[0])),
    float(Units().accel_to_si(PAPER_ACCEL_BOUNDS_MODEL[1])),
)


def traffic_accel_bounds_mps2(ev: EVParams, tp: TrafficParams) -> tuple[float, float]:
    """(a_min, a_max) [m/s²] of the formulation: TrafficParams' values, None meaning the vehicle's limits; an
    explicit value outside the vehicle's limits is a ParameterError naming both."""
    lim = ev.limits
    veh = (lim.a_min_mps2, lim.a_max_mps2) if lim.enabled else UNLIMITED_A_BOUNDS_MPS2
    a_min = veh[0] if tp.a_min_mps2 is None else tp.a_min_mps2
    a_max = veh[1] if tp.a_max_mps2 is None else tp.a_max_mps2
    if lim.enabled and a_min < lim.a_min_mps2:
        raise ParameterError(
            f"TrafficParams.a_min_mps2 = {a_min:g} is outside the vehicle's limits: it must be >= "
            f"VehicleLimits.a_min_mps2 = {lim.a_min_mps2:g} (the plant cannot brake harder)"
        )
    if lim.enabled and a_max > lim.a_max_mps2:
        raise ParameterError(
            f"TrafficParams.a_max_mps2 = {a_max:g} is outside the vehicle's limits: it must be <= "
            f"VehicleLimits.a_max_mps2 = {lim.a_max_mps2:g} (the plant cannot accelerate harder)"
        )
    return a_min, a_max


def traffic_bounds(ev: EVParams, tp: TrafficParams) -> FollowingBounds:
    """The model-unit bounds of the traffic formulation (h_min = the standstill floor, which is soft)."""
    u = ev.units
    a_min, a_max = traffic_accel_bounds_mps2(ev, tp)
    return FollowingBounds(
        h_min=float(u.length_from_si(tp.standstill_gap_m)),
        v_min=0.0,
        v_max=float(u.speed_from_si(tp.v_max_mps)),
        a_min=float(u.accel_from_si(a_min)),
        a_max=float(u.accel_from_si(a_max)),
    )


def models_lag(ev: EVParams, dt: float) -> bool:
    """True when the prediction model carries the actuator state a_act (the vehicle has a lag, or a jerk limit,
    and τ ≥ dt/2.5 [model time], so that the prediction's RK4 step dt stays stable on it; a shorter lag is
    below the prediction's resolution and the model treats the actuator as ideal, the plant still has it)."""
    lim = ev.limits
    return lim.has_actuator_state and float(ev.units.time_from_si(lim.actuator_tau_s)) >= dt / 2.5


def desired_gap_m(v_mps: Any, tp: TrafficParams) -> Any:
    """h_des(v) = s_0 + T_des v [m] at speed v [m/s]."""
    return tp.target_gap_m + tp.target_time_gap_s * v_mps


def _add_soft_gap(
    pb: ProblemBuilder,
    h_m: Any,
    v_ms: Any,
    vl_ms: Any,
    tp: TrafficParams,
    tpn: TrafficParams,
    u: Any,
    length_m: float,
) -> None:
    """The soft constraints on the gap [m] (:func:`traffic_problem`). One slack σ ≥ 0 [model length] is shared by
    the time-headway and the braking floors (the larger violation sets it), with the exact L1 penalty ρ_safe per
    metre per second (×T per model time, ×L per model length) plus 1e-3 σ² (a PD Hessian); the standstill floor
    h ≥ s_min is implied (v ≥ 0 is hard). The soft margin (time gap and TTC) has a slack of its own, and no
    variable at all when its weight is 0. ``tp``: the expressions' values (numbers or parameters); ``tpn``: the
    numbers (bounds, structure); ``length_m``: the model length unit [m] (the slacks' bound)."""
    T = u.time_s
    s_min = tpn.standstill_gap_m
    sig = pb.control("slack_gap", 0.0, SLACK_MAX_M / length_m)
    sig_m = u.length_to_si(sig)
    pb.subject_to(h_m + sig_m - tp.time_headway_s * v_ms, s_min, ca.inf, name="headway")
    pb.subject_to(
        h_m + sig_m - v_ms * tp.reaction_time_s - (v_ms**2 - vl_ms**2) / (2 * tp.brake_decel_mps2),
        s_min,
        ca.inf,
        name="braking",
    )
    pb.add_stage_cost(T * (tp.safe_penalty * sig_m + 1e-3 * sig_m**2), "penalty_gap")
    if tpn.margin_weight > 0.0:  # the soft margin (TrafficParams): no variable at all when it is off
        sig_mg = pb.control("slack_margin", 0.0, SLACK_MAX_M / length_m)
        sig_mg_m = u.length_to_si(sig_mg)
        pb.subject_to(h_m + sig_mg_m - tp.margin_time_gap_s * v_ms, s_min, ca.inf, name="margin_time_gap")
        pb.subject_to(h_m + sig_mg_m - tp.margin_ttc_s * (v_ms - vl_ms), s_min, ca.inf, name="margin_ttc")
        pb.add_stage_cost(T * tp.margin_weight * sig_mg_m**2, "margin")


def traffic_problem(
    ev: EVParams,
    tp: TrafficParams | None = None,
    dt: float = 0.1,
    smooth: PowertrainOptions | None = PowertrainOptions(),
    name: str = "traffic",
    with_temperature: bool = False,
    temperature: TemperatureTerms | None = None,
    runtime_parameters: bool = False,
    ev_numbers: Sequence[str] = (),
) -> ProblemBuilder:
    """The traffic formulation (module docstring) as a builder in model units: states (h, v, V1, V2, S,
    a_prev), controls (a, omega_rate, slacks), stage parameters (v̄_l, v̂_l), no global parameter.
    ``dt`` [model time] is the MPC interval (for the jerk (a − a_prev)/dt). ``with_temperature``: the pack
    temperature T [K] is a state too (last), T ≤ ev.thermal.T_max_K (:func:`following_problem`); ``temperature``
    with ``temperature_state`` (the MPC's): the same state with the soft limit of :class:`TemperatureTerms`, its
    penalty in the cost's unit (W/kg per K, integrated over seconds). ``runtime_parameters``: the vehicle's and
    the TrafficParams' float fields are the problem's global parameters (:meth:`ProblemBuilder.parameters_of`,
    prefixes ``ev`` and ``tp``, their values the defaults) instead of numbers in the expressions, so the MPC's
    generated C serves every vehicle, unit system and parameter value of the same structure; the bounds (and
    what decides the structure: the actuator state, the margin's presence) stay numbers, and so do the vehicle's
    fields or groups named in ``ev_numbers`` (e.g. ``"limits"``)."""
    tp = tp or TrafficParams()
    if not (isinstance(dt, (int, float)) and dt > 0):
        raise ParameterError(f"traffic_problem: dt = {dt!r} must be > 0")
    u = ev.units
    T, m, eta = u.time_s, ev.vehicle.mass_kg, ev.vehicle.efficiency
    b = traffic_bounds(ev, tp)
    pb = ProblemBuilder(name, time_unit="model")
    z = ca.vertcat(
        pb.state("h"),
        pb.state("v", b.v_min, b.v_max),
        pb.state("V1", scale=0.01),
        pb.state("V2", scale=0.01),
        pb.state("S", 0.0, 1.0),
    )
    a = pb.control("a", b.a_min, b.a_max)
    v_mean, v_hat = pb.stage_parameter("v_l_mean"), pb.stage_parameter("v_l_hat")
    a_prev = pb.state("a_prev")
    pb.set_next(a_prev, a)
    un, evn, tpn = u, ev, tp  # the numbers: bounds and what shapes the problem
    if runtime_parameters:  # the expressions' numbers are global parameters (the generated C does not hold them)
        ev, tp = pb.parameters_of(ev, "ev", (*EV_NUMBERS, *ev_numbers)), pb.parameters_of(tp, "tp")
        u = ev.units
        T, m, eta = u.time_s, ev.vehicle.mass_kg, ev.vehicle.efficiency
    a_real = a  # the acceleration the car realises: the command, or its actuator's state (a lag)
    if models_lag(evn, dt):
        lo, hi = evn.limits.accel_bounds_model(un)  # the plant's a_act, measured at every step
        a_real = pb.state("a_act", lo, hi)
        pb.set_der(a_real, actuator_rate(a, a_real, ev.limits, u))
    soft_T = temperature is not None and temperature.temperature_state
    Tst = add_temperature_state(pb, evn, hard_limit=not soft_T) if with_temperature or soft_T else None
    rhs = following_ode(z, a_real, v_mean, ev, smooth, Tst)
    for i, nm in enumerate(STATE_NAMES):
        pb.set_der(pb.x[nm], rhs[i])
    # SI quantities of the stage (the jerk penalised is the command's, Δa/dt)
    h_m, v_ms, a_ms2 = u.length_to_si(z[0]), u.speed_to_si(z[1]), u.accel_to_si(a_real)
    vl_ms = u.speed_to_si(v_hat)
    jerk = (u.accel_to_si(a) - u.accel_to_si(a_prev)) / (dt * T)
    cell = battery_side(z[1], a_real, z[2], z[3], z[4], ev, smooth, Tst)
    if Tst is not None:
        set_temperature_rate(pb, Tst, cell, ev)
    if soft_T:
        assert temperature is not None
        add_temperature_limit(pb, Tst, temperature.limit_K(ev), temperature.penalty("traffic"), T)
    # exact v g(a) [W/kg], the paper's ω rate, by an epigraph (the omega_rate control, in W/kg)
    e = pb.control("omega_rate", -OMEGA_RATE_MAX_W_PER_KG, OMEGA_RATE_MAX_W_PER_KG, scale=10.0)
    pb.subject_to(e - v_ms * a_ms2 / eta, 0.0, ca.inf, name="omega_epi_drive")
    pb.subject_to(e - eta * v_ms * a_ms2, 0.0, ca.inf, name="omega_epi_brake")
    h_des = desired_gap_m(v_ms, tp)
    terms = {
        "omega": tp.omega_weight * e,
        "heat": tp.heat_weight * cell["Q_pack"] / m,
        "accel": tp.accel_weight * a_ms2**2,
        "jerk": tp.jerk_weight * jerk**2,
        "relative": tp.relative_speed_weight * (vl_ms - v_ms) ** 2,
        "gap": tp.gap_weight * (h_m - h_des) ** 2,
    }
    for nm, expr in terms.items():  # Σ ℓ_SI·dt_s = Σ (T ℓ_SI)·dt_model
        pb.add_stage_cost(T * expr, nm)
    _add_soft_gap(pb, h_m, v_ms, vl_ms, tp, tpn, u, un.length_m)
    Imax = evn.cell.max_current_A
    pb.subject_to(cell["I"], -Imax, Imax, name="I")  # |I| ≤ 20C (model guide §9)
    pb.subject_to(cell["disc"], 0.0, ca.inf, name="disc")  # current map feasible (model guide §7)
    hN_m, vN_ms = u.length_to_si(pb.x["h"]), u.speed_to_si(pb.x["v"])
    pb.add_terminal_cost(tp.terminal_gap_weight * (hN_m - desired_gap_m(vN_ms, tp)) ** 2)
    for nm, key in (("I", "I"), ("Q", "Q"), ("Q_pack_W", "Q_pack"), ("Q_irr_pack_W", "Q_irr_pack"), ("disc", "disc")):
        pb.add_output(nm, cell[key])
    pb.meta.update({"objective": "traffic", "bounds": b, "traffic": tpn})
    return pb
