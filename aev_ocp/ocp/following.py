"""The car-following problem of model guide §9 — stated ONCE, as a :class:`ProblemBuilder`.

OCP-D (the oracle lower bound, :mod:`aev_ocp.ocp.oracle`) and the MPC (:mod:`aev_ocp.mpc`) are both
built from :func:`following_problem`, so they solve the same problem; a user adds a cost term, a
constraint or a state to the builder before building either (README, "Your own MPC terms").

Model units throughout (model guide §1): gap h, speed v, acceleration a, time in model time units;
the cell states V1, V2 [V] and S [-] evolve in seconds, converted with ``ev.units.time_s``.
State ``z = (h, v, V1, V2, S)``; control ``a`` held constant over each interval of length dt.

Stage cost (model guide §9):
    ℓ = w_Q Q_pack/(1 kW) + w_V (V(h) − v)² + w_r (v̂_l − v)² + w_a a²,
summed as Σ ℓ(z_k, a_k)·dt (dt in model time units), evaluated at the start of each interval.
``objective="omega"`` replaces Q_pack/(1 kW) by the paper's inertial measure rate v g(a) (model units; stated
exactly by an epigraph; not battery energy). The first term is named after the objective ('heat' or 'omega').
The old name ``objective="energy"`` is still accepted, with a FutureWarning naming 'omega'.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import casadi as ca

from ..models import energy
from ..models.carfollowing import optimal_velocity
from ..models.ego import STATE_NAMES, battery_side, following_ode
from ..params import PAPER_ACCEL_BOUNDS_MODEL, EVParams, ParameterError, PowertrainOptions, spec, validate_fields
from .problem import ProblemBuilder

WEIGHT_NAMES = ("w_Q", "w_V", "w_r", "w_a")
#: The vehicle's float fields that stay numbers when a problem takes the vehicle's numbers as run-time parameters
#: (``runtime_parameters``): the models branch on them in Python (a rotating mass of 0 skips the inertia term) or
#: take them through the math module (math.sin(grade), which turns a CasADi symbol into NaN without an error)
EV_NUMBERS = ("vehicle.rotating_mass_kg", "vehicle.grade_rad")
#: §9's objectives: pack heat Q_pack/(1 kW) (model guide §9) or the paper's inertial measure rate v g(a) ('omega')
OBJECTIVES = ("heat", "omega")
#: Old names still accepted (with a FutureWarning naming the new one): 'energy' was the paper's ω, not battery energy.
RENAMED_OBJECTIVES = {"energy": "omega"}


def objective_name(objective: str, where: str = "objective") -> str:
    """The §9 objective of ``objective``: 'heat' or 'omega'; the old name 'energy' gives 'omega' with a
    FutureWarning naming the new value (``where``: the key or argument it came from). Anything else: ParameterError."""
    new = RENAMED_OBJECTIVES.get(objective) if isinstance(objective, str) else None
    if new is not None:
        warnings.warn(
            f"{where} = {objective!r} is deprecated: use {new!r} (the paper's inertial measure "
            "ω = ∫ v g(a) dt, not battery energy)",
            FutureWarning,
            stacklevel=3,
        )
        return new
    if objective not in OBJECTIVES:
        raise ParameterError(f"{where} = {objective!r} is not allowed: must be one of {OBJECTIVES}")
    return objective


def term_names(objective: str = "heat") -> tuple[str, str, str, str]:
    """The four §9 terms, weighted by w_Q, w_V, w_r, w_a: the objective's own ('heat' or 'omega'), 'ovm',
    'relative', 'accel'."""
    return (objective_name(objective), "ovm", "relative", "accel")


@dataclass(frozen=True)
class FollowingWeights:
    """Stage-cost weights (model guide §9 defaults w_Q = 1, w_V = 1, w_r = 1, w_a = 0.1), each a finite number >= 0."""

    w_Q: float = spec(1.0, ge=0.0)  # model guide §9
    w_V: float = spec(1.0, ge=0.0)  # model guide §9
    w_r: float = spec(1.0, ge=0.0)  # model guide §9
    w_a: float = spec(0.1, ge=0.0)  # model guide §9

    def __post_init__(self) -> None:
        validate_fields(self)


@dataclass(frozen=True)
class FollowingBounds:
    """Bounds of model guide §9 (model units): h ≥ h_min and v_min ≤ v ≤ v_max at nodes 1…N,
    a_min ≤ a ≤ a_max; |I| ≤ cell.max_current_A and disc ≥ 0 at the start of every interval."""

    h_min: float = spec(0.2)  # model guide §9 (2 m at L = 10 m)
    v_min: float = spec(0.0)  # model guide §9
    v_max: float = spec(2.0)  # model guide §9
    a_min: float = spec(PAPER_ACCEL_BOUNDS_MODEL[0])  # model guide §9: −3 (−7.5 m/s² at default units)
    a_max: float = spec(PAPER_ACCEL_BOUNDS_MODEL[1])  # model guide §9: 2 (5 m/s² at default units)

    def __post_init__(self) -> None:
        validate_fields(self)
        if self.v_min >= self.v_max:
            raise ParameterError(f"FollowingBounds.v_min = {self.v_min} must be < v_max = {self.v_max}")
        if self.a_min >= self.a_max:
            raise ParameterError(f"FollowingBounds.a_min = {self.a_min} must be < a_max = {self.a_max}")


def following_stage_terms(
    z: Any,
    a: Any,
    v_l_hat: Any,
    ev: EVParams,
    smooth: PowertrainOptions | None = PowertrainOptions(),
    objective: str = "heat",
    T_K: Any = None,
) -> dict[str, Any]:
    """The four UNWEIGHTED terms of ℓ (model guide §9) [model units; multiply by dt in model time], keyed by
    :func:`term_names`: 'heat' Q_pack/(1 kW) (objective 'heat', η switch smoothed by ``smooth``) or 'omega'
    v g(a), the paper's inertial measure rate (objective 'omega', the exact g, η = ev.vehicle.efficiency), 'ovm'
    (V(h) − v)², 'relative' (v̂_l − v)², 'accel' a². The optimisers never see the non-smooth v g(a):
    :func:`following_problem` states it exactly by an epigraph."""
    objective = objective_name(objective)
    h, v = z[0], z[1]
    if objective == "heat":
        e = battery_side(v, a, z[2], z[3], z[4], ev, smooth, T_K)["Q_pack"] / 1000.0
    else:
        e = v * energy.g_exact(a, ev.vehicle.efficiency)
    return {objective: e, "ovm": (optimal_velocity(h) - v) ** 2, "relative": (v_l_hat - v) ** 2, "accel": a**2}


#: Finite upper bound of the temperature slack [K] (never active: a pack 100 K above its limit is not a driving
#: situation); a finite bound keeps the QP solvers' stand-in for infinity away from the variable's scale.
SLACK_MAX_K = 100.0


#: Default ρ_T per formulation (our choice; each is an exact L1 penalty, i.e. above the limit's multiplier, and small
#: enough for the QP solvers). Traffic [W/kg per K]: a kelvin over a 5 s horizon frees C_pack·1 K/5 s ≈ 100 kW of
#: pack heat, worth ~1e3 W/kg at w_Q = 20, so 1e5 is exact on the EPA cycles. §9 [model-cost units per K per model
#: time]: its costs are ~1e2 smaller; measured on a hot start (T(0) 0.5 K above the limit, 4 s, N = 15, HPIPM):
#: 1e2 lets T rise 1 mK (not exact), 1e3 and 1e4 hold it with 0 fallbacks, 1e5 made 19 of 40 QPs fail.
PENALTY_DEFAULTS = {"traffic": 1.0e5, "s9": 1.0e3}
#: ProblemBuilder.meta key naming the state that is the pack temperature [K] (set by add_temperature_state)
PACK_TEMPERATURE_KEY = "pack_temperature_state"


@dataclass(frozen=True)
class TemperatureTerms:
    """The pack temperature in an MPC's prediction model (``[mpc]`` keys of the same names), SI.

    temperature_state: the lumped pack temperature T [K] (:mod:`aev_ocp.models.thermal`) is a state of the
    prediction model, measured at every step (needs ``[thermal] enabled = true``); temperature_max_K: the soft
    limit T ≤ T_max at the start of every interval (nodes 0…N−1, like every path constraint; None: the scenario's
    ``[thermal] T_max_K``); temperature_penalty: ρ_T, the
    exact L1 penalty per kelvin above the limit per second [W/kg per K with the traffic formulation, whose cost
    is in W/kg·s; model-cost units per K per model time with §9's], so every QP stays feasible (None: the
    formulation's default, :meth:`penalty`)."""

    temperature_state: bool = spec(False, kind="bool")  # off: the paper's MPC has no temperature
    temperature_max_K: float | None = spec(None, gt=0, optional=True)  # None: ThermalParams.T_max_K
    temperature_penalty: float | None = spec(None, gt=0, optional=True)  # None: PENALTY_DEFAULTS[formulation]

    def __post_init__(self) -> None:
        validate_fields(self)

    def penalty(self, kind: str) -> float:
        """ρ_T for a formulation of ``kind`` ('traffic' or 's9'): temperature_penalty, or that kind's default."""
        return PENALTY_DEFAULTS[kind] if self.temperature_penalty is None else float(self.temperature_penalty)

    def limit_K(self, ev: EVParams) -> float:
        """T_max [K]: temperature_max_K, or the thermal model's T_max_K."""
        return ev.thermal.T_max_K if self.temperature_max_K is None else float(self.temperature_max_K)


def add_temperature_state(pb: ProblemBuilder, ev: EVParams, hard_limit: bool = True) -> Any:
    """The pack temperature T [K] as a state of ``pb`` (after the others), bounded by T ≤ ev.thermal.T_max_K
    when ``hard_limit`` (the OCPs built ``with_temperature``; the MPC's limit is soft: :func:`add_temperature_limit`);
    ParameterError when ``ev.thermal`` is off. Its derivative is set by :func:`set_temperature_rate` once the
    battery side is known."""
    if not ev.thermal.enabled:
        raise ParameterError(
            "with_temperature needs the thermal model: ev.thermal.enabled = True ([thermal] enabled = true)"
        )
    T = pb.state("T", 0.0, ev.thermal.T_max_K if hard_limit else ca.inf, scale=100.0)
    # marks the state as the pack temperature: an MPC starts it from the measured T_K (a user's own state named
    # 'T', a timer say, is left alone)
    pb.meta[PACK_TEMPERATURE_KEY] = "T"
    return T


def add_temperature_limit(pb: ProblemBuilder, T_state: Any, T_max_K: float, penalty: float, time_scale: float) -> None:
    """The soft limit T − σ_T ≤ T_max_K at the start of every interval, σ_T ≥ 0 [K] a control (``slack_T``) with
    the cost time_scale·(penalty σ_T + 1e-3 σ_T²) per unit of the problem's time (the quadratic keeps the Hessian
    PD); ``time_scale`` converts the penalty's per-second rate to the problem's time unit (the traffic cost's T)."""
    sig = pb.control("slack_T", 0.0, SLACK_MAX_K, scale=0.01)
    # written against a zero bound: IPOPT relaxes a bound b by 1e-8·|b| (bound_relax_factor), ~3e-6 K at 300 K,
    # more than the MPC's plan tolerance, so 'T − σ ≤ T_max' made every solve with an active limit a rejected plan
    pb.subject_to(T_state - sig - T_max_K, -ca.inf, 0.0, name="temperature")
    pb.add_stage_cost(time_scale * (penalty * sig + 1e-3 * sig**2), "penalty_temperature")


def set_temperature_rate(pb: ProblemBuilder, T_state: Any, cell: dict[str, Any], ev: EVParams) -> None:
    """dT/dt of the lumped pack model (model time) from the battery side ``cell`` (its 'dT'), and the output T_K."""
    pb.set_der(T_state, ev.units.time_s * cell["dT"])
    pb.add_output("T_K", T_state)


def weight_vector(weights: FollowingWeights) -> list[float]:
    """The problem's global parameter p = (w_Q, w_V, w_r, w_a)."""
    return [float(getattr(weights, k)) for k in WEIGHT_NAMES]


def following_problem(
    ev: EVParams,
    bounds: FollowingBounds | None = None,
    smooth: PowertrainOptions | None = PowertrainOptions(),
    objective: str = "heat",
    name: str = "following",
    with_temperature: bool = False,
    temperature: TemperatureTerms | None = None,
    runtime_parameters: bool = False,
    ev_numbers: Sequence[str] = (),
) -> ProblemBuilder:
    """The §9 problem as a builder (model units, time in model time units):

    states z = (h, v, V1, V2, S) (scales 1, 1, 0.01 V, 0.01 V, 1); control a; stage parameters
    (v̄_l interval-mean leader speed, v̂_l(t_k)); parameters p = (w_Q, w_V, w_r, w_a);
    stage cost Σ_k (w_Q·heat (or omega) + w_V·ovm + w_r·relative + w_a·accel)·dt; bounds h ≥ h_min,
    v_min ≤ v ≤ v_max, S ∈ [0, 1] at nodes 1…N, a_min ≤ a ≤ a_max; |I| ≤ I_max and disc ≥ 0 at
    the start of every interval. ``smooth``: η-switch smoothing of the optimiser (model guide §7).
    Objective 'omega' (the paper's ω; old name 'energy'): v g(a) through an epigraph control ``omega_rate``
    ≥ v a/η, ≥ η v a (exact).
    Outputs: I [A], Q [W per cell], Q_pack_W, Q_irr_pack_W, disc [V²] and each weighted term.
    ``with_temperature``: the lumped pack temperature T [K] (:mod:`aev_ocp.models.thermal`) is a 6th state
    with T ≤ ev.thermal.T_max_K, setting the cell's resistances when the cell has an activation energy
    (needs ``ev.thermal.enabled``); output T_K. ``temperature`` with ``temperature_state`` (the MPC's): the same
    state with the soft limit of :class:`TemperatureTerms` instead of the hard bound. ``runtime_parameters``: the
    vehicle's float fields (units, body, cell, thermal, …) are global parameters after the weights
    (:meth:`ProblemBuilder.parameters_of`, prefix ``ev``, their values the defaults) instead of numbers in the
    expressions, so the MPC's generated C serves every vehicle of the same structure; the bounds stay numbers, and
    so do the fields or groups named in ``ev_numbers`` (e.g. ``"limits"``).
    """
    b = bounds or FollowingBounds()
    pb = ProblemBuilder(name, time_unit="model")
    z = ca.vertcat(
        pb.state("h", b.h_min),
        pb.state("v", b.v_min, b.v_max),
        pb.state("V1", scale=0.01),
        pb.state("V2", scale=0.01),
        pb.state("S", 0.0, 1.0),
    )
    soft_T = temperature is not None and temperature.temperature_state
    Tst = add_temperature_state(pb, ev, hard_limit=not soft_T) if with_temperature or soft_T else None
    a = pb.control("a", b.a_min, b.a_max)
    v_mean, v_hat = pb.stage_parameter("v_l_mean"), pb.stage_parameter("v_l_hat")
    wt = [pb.parameter(k) for k in WEIGHT_NAMES]
    evn, ev = (
        ev,
        (pb.parameters_of(ev, "ev", (*EV_NUMBERS, *ev_numbers)) if runtime_parameters else ev),
    )  # numbers (bounds), the model's
    rhs = following_ode(z, a, v_mean, ev, smooth, Tst)
    for i, nm in enumerate(STATE_NAMES):
        pb.set_der(pb.x[nm], rhs[i])
    objective = objective_name(objective)
    terms = following_stage_terms(z, a, v_hat, ev, smooth, objective, Tst)
    if objective == "omega":
        # v g(a) = max(v a/η, η v a) for v ≥ 0: minimising an epigraph variable e ≥ both is exact and
        # smooth (no width to exploit, model guide §9 deviation: §9 smooths g; see README)
        e = pb.control("omega_rate")
        eta = ev.vehicle.efficiency
        pb.subject_to(e - z[1] * a / eta, 0.0, ca.inf, name="omega_epi_drive")
        pb.subject_to(e - eta * z[1] * a, 0.0, ca.inf, name="omega_epi_brake")
        terms["omega"] = e
    for wk, nm in zip(wt, term_names(objective)):
        pb.add_stage_cost(wk * terms[nm], nm)
    cell = battery_side(z[1], a, z[2], z[3], z[4], ev, smooth, Tst)
    if Tst is not None:
        set_temperature_rate(pb, Tst, cell, ev)
    if soft_T:
        assert temperature is not None
        add_temperature_limit(pb, Tst, temperature.limit_K(ev), temperature.penalty("s9"), 1.0)
    Imax = evn.cell.max_current_A
    pb.subject_to(cell["I"], -Imax, Imax, name="I")  # |I| ≤ 20C (model guide §9)
    pb.subject_to(cell["disc"], 0.0, ca.inf, name="disc")  # current map feasible (model guide §7)
    for nm, key in (("I", "I"), ("Q", "Q"), ("Q_pack_W", "Q_pack"), ("Q_irr_pack_W", "Q_irr_pack"), ("disc", "disc")):
        pb.add_output(nm, cell[key])
    pb.meta.update({"objective": objective, "bounds": b})
    return pb
