"""The MPC as a :class:`~aev_ocp.control.Controller`: forecast, solve, fall back.

At every step the policy forecasts its predecessor (a :class:`LeaderPredictor`, or the predecessor's
published plan for 'cooperative'), solves its :class:`MPCController` and returns the first control.
A failed solve applies the fallback: the smaller of the fallback law (the proposed law with the scenario's
α, β, κ at the measured predecessor speed v_l(t_k), clipped to the a bounds) and the safe controller of
:mod:`aev_ocp.mpc.safe_fallback` (never accelerates into a gap it could not stop in), counted as a fallback with
its cause. With the traffic formulation every successful command passes the same safe bound (a safety filter). :class:`MPCSettings` and :class:`MPCVehicle` are accepted by
:class:`aev_ocp.control.ClosedLoop` directly (registered adapters).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import logging

import numpy as np

from ..limits import check_mpc_size
from ..control import ClosedLoop, Command, Observation, register_controller_adapter, run_closed_loop
from ..models.carfollowing import CarFollowingLaw
from ..models.leader import LeaderProfile, PaperLeader
from ..ocp.formulation import Formulation
from ..ocp.problem import OCPProblem, ProblemBuilder
from ..params import EVParams, ParameterError, as_dict
from ..results import SimulationResult
from .safe_fallback import SafeFallback
from .controller import MPCController, resolve_formulation
from .predictors import LeaderPredictor, Measurements, forecast_intervals, make_predictor, plan_forecast
from .settings import MPCSettings


_LOG = logging.getLogger("aev_ocp.mpc")  # one INFO record per fallback, with its cause


@dataclass
class MPCVehicle:
    """An MPC follower: its solver settings, optionally its own predictor (default: settings.predictor;
    'cooperative' = the predecessor's last MPC plan), and what it solves: a ``formulation``
    (:class:`aev_ocp.ocp.formulation.Formulation`; default the traffic formulation) or a user ``problem``
    (with ``parameter_values``), which then is its formulation (its bounds, name, cost and cold start)."""

    settings: MPCSettings = field(default_factory=MPCSettings)
    predictor: LeaderPredictor | str | None = None
    problem: OCPProblem | ProblemBuilder | None = None
    parameter_values: dict[str, float] | None = None
    formulation: Formulation | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.settings, MPCSettings):
            raise ParameterError(f"MPCVehicle.settings must be an MPCSettings, got {type(self.settings).__name__}")
        resolve_formulation(self.formulation, self.problem, self.parameter_values)  # refuse a conflict now

    @property
    def resolved_formulation(self) -> Formulation:
        """The one formulation this vehicle's MPC solves (see the class docstring)."""
        return resolve_formulation(self.formulation, self.problem, self.parameter_values)


class MPCPolicy:
    """One vehicle's MPC as a Controller (see the module docstring)."""

    def __init__(
        self,
        settings: MPCSettings,
        ev: EVParams,
        fallback_law: CarFollowingLaw,
        predictor: LeaderPredictor | str,
        problem: OCPProblem | ProblemBuilder | None = None,
        parameter_values: dict[str, float] | None = None,
        formulation: Formulation | None = None,
    ) -> None:
        self.settings, self.fallback_law, self.predictor = settings, fallback_law, predictor
        self.formulation = resolve_formulation(formulation, problem, parameter_values)
        self.controller = MPCController(settings, ev, fallback_law, formulation=self.formulation)
        self._fallback = fallback_controller(fallback_law, settings.dt, self.formulation, ev)
        # for the shipped traffic formulation (not a user's own problem) also a safety filter on every command
        self._filter = self.formulation.kind == "traffic"
        self.dt = settings.dt
        self.name = self.formulation.controller_name

    def reset(self) -> None:
        """Forget the warm start."""
        self.controller.reset()
        self._fallback.reset()

    def forecast(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """(v̄_l, v̂_l) per interval over the horizon [model speed]."""
        N, dt = self.settings.N, self.dt
        p = self.predictor
        if p == "cooperative":
            if obs.predecessor_plan is not None:
                return forecast_intervals(*plan_forecast(obs.predecessor_plan, dt, N), dt)
            p = make_predictor("constant-velocity")  # the predecessor fell back this step: no plan
        assert isinstance(p, LeaderPredictor)
        return forecast_intervals(*p.predict(obs.t, dt, N, Measurements(obs.meas_t, obs.meas_v)), dt)

    def own_states(self, obs: Observation) -> dict[str, float]:
        """The values of the problem's own states at this step, by name: 'a_prev' (a Δa penalty) from the command
        really applied last step, 'a_act' (the realised acceleration of a vehicle with an actuator lag, when the
        problem models it); names the problem lacks are ignored. A subclass adds its own (e.g. a reference speed);
        'T' (the pack temperature, TemperatureTerms) is set from the measured T_K by :meth:`command`."""
        return {"a_prev": obs.a_prev, "a_act": obs.a_act or 0.0}

    def command(self, obs: Observation) -> Command:
        vm, vh = self.forecast(obs)
        own = self.own_states(obs)
        Tn = self.controller.temperature_state_name
        if Tn is not None and obs.T_K is not None:
            own[Tn] = obs.T_K
        elif Tn is not None:
            raise ParameterError(
                "MPC: temperature_state needs the measured pack temperature (Observation.T_K), which "
                "this plant does not give: turn on [thermal] (enabled = true) in a platoon scenario "
                "(the ring road and SUMO have no thermal model)"
            )
        sol = self.controller.solve(obs.z, vm, vh, own=own)
        info = {"cost": sol.cost, "violation": sol.violation, "v_hat": vh}
        if "qp_acceptable" in sol.stats:  # the compiled step's QPs ended at their acceptable level this step
            info["qp_acceptable"] = int(sol.stats["qp_acceptable"])
        if sol.success:
            a0 = self._fallback.limit(obs, float(sol.a[0])) if self._filter else float(sol.a[0])
            return Command(a0, True, sol.status, sol.solve_time_s, sol.iterations, sol.X[1], info)
        # the fallback: the law on the measurements, clipped to the a bounds and so that the speed stays
        # >= 0 over the step (a plant never reverses; the law at a tiny gap may ask for a_min at v ≈ 0)
        a = max(self._fallback.command(obs).a, min(0.0, -float(obs.z[1]) / self.dt))
        _LOG.info(
            "MPC fallback at t = %.4g (vehicle %d): %s (%.3g ms)",
            obs.t,
            obs.vehicle + 1,
            sol.status,
            1e3 * sol.solve_time_s,
        )
        return Command(a, False, sol.status, sol.solve_time_s, sol.iterations, None, info)

    def describe(self) -> dict[str, Any]:
        d = as_dict(self.settings)
        d["formulation"] = self.formulation.describe()
        p = self.predictor
        d["predictor"] = p if isinstance(p, str) else getattr(p, "name", type(p).__name__)
        d["solver_path"] = self.settings.solver + ("+codegen" if self.controller.codegen_active else "")
        d["qp_in_use"] = self.controller.qp_in_use  # the QP solver that runs (qp_solver resolved, after fallbacks)
        d["problem"] = self.controller.problem.name
        # what the metrics count violations against and the plots draw: the formulation's own bounds
        d["bounds_model"] = self.formulation.bounds_model(self.controller.ev).as_dict()
        d["safety"] = {**self._fallback.describe(), "filter": self._filter}
        return d


def fallback_controller(law: CarFollowingLaw, dt: float, formulation: Formulation, ev: EVParams) -> SafeFallback:
    """The policy's fallback (the one place it is built): min(``law`` on the measurements sampled every dt [model
    time] and clipped to the formulation's a bounds, the safe controller of :mod:`aev_ocp.mpc.safe_fallback`)."""
    return SafeFallback.for_mpc(law, formulation, dt, ev)


def _adapt(obj: MPCSettings | MPCVehicle, i: int, loop: ClosedLoop) -> MPCPolicy:
    """MPCSettings / MPCVehicle of follower i -> MPCPolicy (predictor rules of model guide §9)."""
    veh = obj if isinstance(obj, MPCVehicle) else MPCVehicle(obj)
    n_mpc = 1 + sum(isinstance(c, MPCPolicy) for c in loop.ctrl)
    check_mpc_size(veh.settings.N, n_mpc)  # the NLPs built so far and this one fit the memory budget
    p = veh.predictor if veh.predictor is not None else veh.settings.predictor
    if isinstance(p, str):
        if p == "cooperative":
            if i == 0 or not isinstance(loop.ctrl[i - 1], MPCPolicy):
                raise ParameterError(f"vehicle {i + 1}: predictor 'cooperative' needs an MPC vehicle ahead")
        elif p == "oracle" and i > 0:
            raise ParameterError(
                f"vehicle {i + 1}: predictor 'oracle' is only available to the first "
                "follower (use 'cooperative' behind an MPC vehicle, or a measured predictor)"
            )
        else:
            p = make_predictor(p, loop.leader, veh.settings.predictor_window, loop.ev.units.time_s)
    return MPCPolicy(veh.settings, loop.model_ev(i), loop.fallback_law, p, formulation=veh.resolved_formulation)


register_controller_adapter(MPCSettings, _adapt)
register_controller_adapter(MPCVehicle, _adapt)


def run_single(
    settings: MPCSettings | None = None,
    leader: LeaderProfile | None = None,
    h0: float = 0.3,
    v0: float = 1.87,
    t_end: float = 70.0,
    ev: EVParams | None = None,
    fallback_law: CarFollowingLaw | None = None,
    formulation: Formulation | None = None,
) -> SimulationResult:
    """One MPC follower behind ``leader`` (default the paper's Table 1 leader) from h0, v0 (model units; model guide
    §9's canonical start) over [0, t_end]; ``settings`` default MPCSettings() and ``formulation`` default the traffic
    formulation with a measured forecast: for model guide §9's canonical MPC pass formulation=s9_formulation() and
    MPCSettings(N=40, predictor='oracle'), as scenarios/mpc_paper_single.toml states."""
    veh = MPCVehicle(settings or MPCSettings(), formulation=formulation)
    return run_closed_loop(leader or PaperLeader(), [veh], [h0], [v0], t_end, ev=ev, fallback_law=fallback_law)
