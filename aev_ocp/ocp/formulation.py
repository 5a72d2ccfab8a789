"""Which problem an MPC (and its OCP-D) solves, stated ONCE: :class:`Formulation`.

A formulation is a frozen value that carries the problem builder's choice and parameters and everything
derived from them, so no second setting beside it can disagree:

* the problem itself, on a given interval dt (:meth:`Formulation.builder`, :meth:`Formulation.build`), the
  same for the MPC and for OCP-D (:meth:`Formulation.oracle_problem`);
* its model-unit bounds (:meth:`Formulation.bounds_model`): what the fallback clips to, what
  ``gap_violations`` / ``speed_violations`` count against and what the plots draw;
* its cold start (:attr:`Formulation.rti_cold_start`) and its family (the QP solvers' settings);
* the name shown in tables (:attr:`Formulation.controller_name`), and which cost is its own
  (:attr:`Formulation.cost_key`: the verdict) and which are another formulation's (:attr:`Formulation.other_costs`:
  a labelled secondary table, never a verdict).

Three kinds: ``traffic_formulation()`` (the default, :mod:`aev_ocp.ocp.traffic`, SI parameters),
``s9_formulation()`` (model guide §9 exactly: weights, bounds, objective) and ``problem_formulation(pb)`` (a user
problem, e.g. the §9 problem plus a headway constraint: every derived item then follows that problem: its
declared bounds, its name, its own cost). Model units throughout (model guide §1) unless a name says otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from ..models.battery import ocv_form
from ..params import EVParams, ParameterError, PowertrainOptions, remember, spec, validate_fields
from .following import (
    OBJECTIVES,
    RENAMED_OBJECTIVES,
    objective_name,
    WEIGHT_NAMES,
    FollowingBounds,
    FollowingWeights,
    TemperatureTerms,
    following_problem,
    weight_vector,
)
from .problem import OCPProblem, ProblemBuilder
from .traffic import TrafficParams, traffic_bounds, traffic_problem

#: Kinds of formulation: 'traffic' (aev_ocp/ocp/traffic.py, the default), 's9' (model guide §9), 'problem' (a user's).
KINDS = ("traffic", "s9", "problem")
#: The built-in problems' own costs (keys of the metrics): what OCP-D minimises and what is ranked.
COST_KEYS = {"traffic": "cost_traffic", "s9": "cost_s9", "problem": "cost_problem"}

#: A user problem: a builder, a built problem, or a function (ev, dt [model time]) -> either (rebuilt per grid).
ProblemSource = OCPProblem | ProblemBuilder | Callable[[EVParams, float], OCPProblem | ProblemBuilder]


@dataclass(frozen=True)
class ModelBounds:
    """A formulation's bounds in model units (None: that side has no hard bound): the gap floor h_min
    (traffic: its soft standstill floor), v_min ≤ v ≤ v_max, a_min ≤ a ≤ a_max."""

    h_min: float | None
    v_min: float | None
    v_max: float | None
    a_min: float | None
    a_max: float | None

    def as_dict(self) -> dict[str, float | None]:
        """{'h_min': …, 'v_min': …, 'v_max': …, 'a_min': …, 'a_max': …} [model units]."""
        return {k: getattr(self, k) for k in ("h_min", "v_min", "v_max", "a_min", "a_max")}


@dataclass(frozen=True)
class Formulation:
    """One MPC problem and everything derived from it (module docstring). Build it with
    :func:`traffic_formulation`, :func:`s9_formulation` or :func:`problem_formulation`.

    kind: one of KINDS; traffic: the traffic problem's SI parameters (kind 'traffic'); weights, bounds,
    objective: model guide §9's (kind 's9'; the weights are also the default values of a user problem's
    parameters named w_Q, w_V, w_r, w_a); smooth: the optimiser's η-switch smoothing (model guide §7; the
    built-in kinds); temperature: the pack temperature as a state with a soft limit (the built-in kinds;
    :class:`aev_ocp.ocp.following.TemperatureTerms`, off by default); problem: the user problem (kind 'problem');
    parameter_values: values of a user problem's further parameters by name; initial_values: initial values of
    its own states by name (default 0)."""

    kind: str = spec("traffic", kind="choice", choices=KINDS)
    traffic: TrafficParams = spec(kind="instance", cls=TrafficParams, default_factory=TrafficParams)
    weights: FollowingWeights = spec(
        kind="instance", cls=FollowingWeights, default_factory=FollowingWeights
    )  # model guide §9: 1, 1, 1, 0.1
    bounds: FollowingBounds = spec(
        kind="instance", cls=FollowingBounds, default_factory=FollowingBounds
    )  # model guide §9
    objective: str = spec("heat", kind="choice", choices=OBJECTIVES)  # model guide §9 ('omega': the paper's ω)
    smooth: PowertrainOptions = spec(
        kind="instance", cls=PowertrainOptions, default_factory=PowertrainOptions
    )  # model guide §7: 300 W
    temperature: TemperatureTerms = spec(
        kind="instance", cls=TemperatureTerms, default_factory=TemperatureTerms
    )  # off: no temperature state
    problem: Any = field(default=None, compare=False)
    parameter_values: Mapping[str, float] = field(default_factory=dict, compare=False)
    initial_values: Mapping[str, float] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.objective in RENAMED_OBJECTIVES:  # the old name 'energy' (the paper's ω): warn, use the new one
            object.__setattr__(self, "objective", objective_name(self.objective, "Formulation.objective"))
        validate_fields(self)
        if (self.kind == "problem") != (self.problem is not None):
            raise ParameterError(
                "Formulation.problem must be given exactly for kind = 'problem' "
                f"(kind = {self.kind!r}, problem {'given' if self.problem is not None else 'missing'})"
            )
        if self.problem is not None and not (
            isinstance(self.problem, (OCPProblem, ProblemBuilder)) or callable(self.problem)
        ):
            raise ParameterError(
                f"Formulation.problem must be a ProblemBuilder, an OCPProblem or a function (ev, dt) -> "
                f"either, got {type(self.problem).__name__}"
            )

    # ------------------------------------------------------------------ the problem
    def builder(
        self,
        ev: EVParams,
        dt: float,
        name: str | None = None,
        runtime_parameters: bool = False,
        ev_numbers: tuple[str, ...] = (),
    ) -> OCPProblem | ProblemBuilder:
        """The problem on intervals of length dt [model time] (the traffic problem's jerk term uses dt).
        A user's builder or built problem is returned as given (it was stated for the MPC's dt).
        ``runtime_parameters``: a built-in problem takes the vehicle's (and the traffic formulation's SI) numbers as
        global parameters with defaults (the MPC's: one compiled library per structure)."""
        if self.kind == "traffic":
            return traffic_problem(
                ev,
                self.traffic,
                dt,
                self.smooth,
                name=name or "mpc_traffic",
                temperature=self.temperature,
                runtime_parameters=runtime_parameters,
                ev_numbers=ev_numbers,
            )
        if self.kind == "s9":
            return following_problem(
                ev,
                self.bounds,
                self.smooth,
                self.objective,
                name=name or "mpc",
                temperature=self.temperature,
                runtime_parameters=runtime_parameters,
                ev_numbers=ev_numbers,
            )
        p = self.problem
        if isinstance(p, (OCPProblem, ProblemBuilder)):
            return p
        out = p(ev, dt)
        if not isinstance(out, (OCPProblem, ProblemBuilder)):
            raise ParameterError(
                f"Formulation.problem(ev, dt) must return a ProblemBuilder or an OCPProblem, got {type(out).__name__}"
            )
        return out

    def mpc_problem(self, ev: EVParams, dt: float) -> OCPProblem:
        """The MPC's problem: a built-in one with the vehicle's (and the traffic formulation's SI) numbers as global
        parameters with defaults (``runtime_parameters``: one compiled library serves every vehicle of the same
        structure), checked against the problem with the numbers in (:func:`same_problem`); if they
        disagree (a model that turns a symbol into a number, e.g. through the math module), the numbers-in problem,
        with a warning. A user problem as :meth:`build` gives it.

        A built-in problem is built once per process for equal (formulation, vehicle, dt, OCV form): the MPCs of a
        platoon, a sweep or a study's points share it (it is read, never changed: its Functions are immutable);
        :func:`clear_mpc_problems` forgets them (after a change of the models' code, e.g. a test's monkeypatch)."""
        if self.kind == "problem":
            return self.build(ev, dt)
        form = ocv_form()
        try:
            key = (self, ev, float(dt), form)
            hash(key)
        except TypeError:  # a field that cannot be a key (not expected of the built-in kinds): no sharing
            key = None
        if key is None or form[1]:  # under ocv_inputs the problem's OCV symbols are the caller's own: never shared
            problem, why = self._mpc_problem(ev, dt)
        else:
            hit = _MPC_PROBLEMS.get(key)
            if hit is None:
                hit = remember(_MPC_PROBLEMS, key, self._mpc_problem(ev, dt), _MPC_PROBLEMS_KEPT)
            problem, why = hit
        if why:
            import warnings

            from ..errors import AevOcpWarning

            warnings.warn(
                AevOcpWarning(
                    f"the {self.name} problem with the vehicle's numbers as run-time parameters differs from the one "
                    f"with the numbers in ({why}): the MPC uses the numbers in (its compiled C is specific to this "
                    "vehicle)"
                ),
                stacklevel=2,
            )
        return problem

    def _mpc_problem(self, ev: EVParams, dt: float) -> tuple[OCPProblem, str]:
        """:meth:`mpc_problem` built: (the problem, '' or why the run-time parameters' problem was not used)."""
        baked = self.build(ev, dt)
        why = ""
        # the vehicle's groups a model may need as numbers (a jerk limit converted with float(), a lag's τ compared
        # with 0), kept as numbers in turn until the problem builds: each tier is one library per such value
        for keep in EV_NUMBER_TIERS:
            try:
                b = self.builder(ev, dt, baked.name, runtime_parameters=True, ev_numbers=keep)
                pr = b.build() if isinstance(b, ProblemBuilder) else b
            except (RuntimeError, TypeError, ValueError, NotImplementedError) as exc:
                why = f"{type(exc).__name__}: {str(exc).splitlines()[-1][:120]}"
                continue
            why = same_problem(baked, pr)
            if not why:
                return pr, ""
        return baked, why

    def build(self, ev: EVParams, dt: float, name: str | None = None) -> OCPProblem:
        """:meth:`builder`, built."""
        b = self.builder(ev, dt, name)
        return b.build() if isinstance(b, ProblemBuilder) else b

    def oracle_problem(self, ev: EVParams, dt: float) -> OCPProblem:
        """OCP-D's problem: the same formulation on the OCP-D grid step dt [model time]."""
        return self.build(ev, dt, name={"traffic": "ocp_d_traffic", "s9": "ocp_d"}.get(self.kind))

    # ------------------------------------------------------------------ derived items
    @property
    def family(self) -> str:
        """'traffic' or 's9': the built-in problem this one is (or, kind 'problem', was built from: its
        builder's meta 'objective'); 'custom' when unknown. Decides the cold start and QP settings."""
        if self.kind != "problem":
            return self.kind
        meta = _meta(self.problem)
        obj = meta.get("objective")
        return "traffic" if obj == "traffic" else "s9" if obj in OBJECTIVES else "custom"

    @property
    def rti_cold_start(self) -> bool:
        """The 'rti' path starts cold by RTI iterations from the closed-form law's rollout (True), or by a cold
        IPOPT solve (False: model guide §9, so its published numbers stay as they are)."""
        return self.family != "s9"

    @property
    def name(self) -> str:
        """The formulation's name: 'traffic', 's9' or the user problem's name."""
        if self.kind != "problem":
            return self.kind
        p = self.problem
        return str(getattr(p, "name", None) or getattr(p, "__name__", "problem"))

    @property
    def controller_name(self) -> str:
        """The MPC's name in tables and results: 'mpc(traffic)', 'mpc(w_Q=1)' (§9) or 'mpc(<problem name>)'."""
        if self.kind == "s9":
            return f"mpc(w_Q={self.weights.w_Q:g})"
        return f"mpc({self.name})"

    @property
    def cost_key(self) -> str:
        """The metrics key of this formulation's own cost: 'cost_traffic', 'cost_s9' or 'cost_problem'."""
        return COST_KEYS[self.kind]

    @property
    def other_costs(self) -> tuple[str, ...]:
        """Costs of another formulation reported beside this one's (a secondary table, never a verdict): the
        model guide §9 cost, unless this is §9."""
        return () if self.kind == "s9" else ("cost_s9",)

    def bounds_model(self, ev: EVParams) -> ModelBounds:
        """The hard (traffic: its soft floor) bounds on h, v, a in model units. A user problem's are its declared
        state/control bounds on h, v and a (finite ones), else its builder's meta 'bounds' (the built-ins'), else None."""
        if self.kind == "traffic":
            b = traffic_bounds(ev, self.traffic)
            return ModelBounds(b.h_min, b.v_min, b.v_max, b.a_min, b.a_max)
        if self.kind == "s9":
            b = self.bounds
            return ModelBounds(b.h_min, b.v_min, b.v_max, b.a_min, b.a_max)
        meta_b = _meta(self.problem).get("bounds")
        declared = _declared_bounds(self.problem)

        def pick(key: str) -> float | None:
            v = declared.get(key)
            if v is not None and math.isfinite(v):
                return float(v)
            m = getattr(meta_b, key, None)
            return float(m) if m is not None else None

        return ModelBounds(*(pick(k) for k in ("h_min", "v_min", "v_max", "a_min", "a_max")))

    def accel_bounds(self, ev: EVParams) -> tuple[float, float]:
        """(a_min, a_max) [model acceleration] that the fallback clips to (±inf where the problem has none)."""
        b = self.bounds_model(ev)
        return (b.a_min if b.a_min is not None else -math.inf, b.a_max if b.a_max is not None else math.inf)

    def parameter_vector(self, names: list[str], weights: FollowingWeights | None = None) -> list[float]:
        """Values of a problem's global parameters by name: the §9 weights (``weights``, else this formulation's)
        for w_Q, w_V, w_r, w_a, ``parameter_values`` for the others (ParameterError naming a missing one)."""
        w = weights or self.weights
        out = []
        for k in names:
            if k in WEIGHT_NAMES:
                out.append(float(getattr(w, k)))
            elif k in self.parameter_values:
                out.append(float(self.parameter_values[k]))
            else:
                raise ParameterError(
                    f"Formulation {self.name!r}: parameter {k!r} has no value: give parameter_values={{{k!r}: ...}}"
                )
        return out

    def s9_weight_vector(self) -> list[float]:
        """model guide §9's p = (w_Q, w_V, w_r, w_a) of this formulation."""
        return weight_vector(self.weights)

    def describe(self) -> dict[str, Any]:
        """A JSON-friendly summary: kind, name, family, cost key and the parameters of the kind."""
        from ..params import as_dict

        d: dict[str, Any] = {"kind": self.kind, "name": self.name, "family": self.family, "cost_key": self.cost_key}
        if self.kind == "traffic":
            d["traffic"] = as_dict(self.traffic)
        elif self.kind == "s9":
            d.update({"weights": as_dict(self.weights), "bounds": as_dict(self.bounds), "objective": self.objective})
        if self.kind != "problem":
            d["smoothing_width_W"] = self.smooth.smoothing_width_W
            if self.temperature.temperature_state:
                d["temperature"] = as_dict(self.temperature)
        else:
            d["parameter_values"] = dict(self.parameter_values)
        return d

    def with_(self, **changes: Any) -> "Formulation":
        """A validated copy with some fields changed."""
        from dataclasses import replace

        return replace(self, **changes)


def _meta(p: Any) -> dict[str, Any]:
    return dict(getattr(p, "meta", None) or {})


def _declared_bounds(p: Any) -> dict[str, float]:
    """Declared bounds of states h, v and control a of a builder or built problem (none for a function)."""
    out: dict[str, float] = {}
    if isinstance(p, ProblemBuilder):
        xi, ui = p._x_info, p._u_info
        if "h" in xi:
            out["h_min"] = xi["h"][0]
        if "v" in xi:
            out["v_min"], out["v_max"] = xi["v"][0], xi["v"][1]
        if "a" in ui:
            out["a_min"], out["a_max"] = ui["a"][0], ui["a"][1]
    elif isinstance(p, OCPProblem):
        sn, cn = list(p.state_names), list(p.control_names)
        if p.x_lb is not None and "h" in sn:
            out["h_min"] = float(p.x_lb[sn.index("h")])
        if p.x_lb is not None and p.x_ub is not None and "v" in sn:
            out["v_min"], out["v_max"] = float(p.x_lb[sn.index("v")]), float(p.x_ub[sn.index("v")])
        if p.u_lb is not None and p.u_ub is not None and "a" in cn:
            out["a_min"], out["a_max"] = float(p.u_lb[cn.index("a")]), float(p.u_ub[cn.index("a")])
    return out


def traffic_formulation(
    traffic: TrafficParams | None = None,
    smooth: PowertrainOptions | None = None,
    temperature: TemperatureTerms | None = None,
) -> Formulation:
    """The traffic formulation (aev_ocp/ocp/traffic.py; the default) with its SI parameters; ``temperature``: the
    pack temperature as a state with a soft limit (default off)."""
    return Formulation(
        "traffic",
        traffic=traffic or TrafficParams(),
        smooth=smooth or PowertrainOptions(),
        temperature=temperature or TemperatureTerms(),
    )


def s9_formulation(
    weights: FollowingWeights | None = None,
    bounds: FollowingBounds | None = None,
    objective: str = "heat",
    smooth: PowertrainOptions | None = None,
    temperature: TemperatureTerms | None = None,
) -> Formulation:
    """model guide §9's formulation (defaults: §9's weights 1, 1, 1, 0.1, bounds and the heat objective)."""
    return Formulation(
        "s9",
        weights=weights or FollowingWeights(),
        bounds=bounds or FollowingBounds(),
        objective=objective,
        smooth=smooth or PowertrainOptions(),
        temperature=temperature or TemperatureTerms(),
    )


def problem_formulation(
    problem: ProblemSource,
    parameter_values: Mapping[str, float] | None = None,
    initial_values: Mapping[str, float] | None = None,
    weights: FollowingWeights | None = None,
) -> Formulation:
    """A user problem as a formulation: every derived item (bounds, name, cost, cold start) follows it.
    ``weights``: values of its parameters named w_Q, w_V, w_r, w_a (default model guide §9's)."""
    if isinstance(problem, Formulation):
        return problem
    return Formulation(
        "problem",
        problem=problem,
        parameter_values=dict(parameter_values or {}),
        initial_values=dict(initial_values or {}),
        weights=weights or FollowingWeights(),
    )


#: Groups of the vehicle's numbers kept as numbers, in turn, when a problem with them as parameters does not build
#: (:meth:`Formulation.mpc_problem`): none, then the limits (a lag's τ is compared with 0, a jerk limit goes through
#: float()), then the limits and the units.
EV_NUMBER_TIERS: tuple[tuple[str, ...], ...] = ((), ("limits",), ("limits", "units"))

#: :meth:`Formulation.mpc_problem`'s problems of this process, by (formulation, vehicle, dt, OCV form), the oldest
#: forgotten first beyond :data:`_MPC_PROBLEMS_KEPT`
_MPC_PROBLEMS: dict[tuple[Any, ...], tuple[OCPProblem, str]] = {}
_MPC_PROBLEMS_KEPT = 64


def clear_mpc_problems() -> None:
    """Forget the problems :meth:`Formulation.mpc_problem` keeps (the next call builds its problem again)."""
    _MPC_PROBLEMS.clear()


def same_problem(baked: OCPProblem, runtime: OCPProblem, rtol: float = 1e-9) -> str:
    """'' if ``runtime`` (the problem with extra global parameters after ``baked``'s, their values its meta
    'parameter_defaults') gives ``baked``'s functions (ode, costs, path constraints, outputs, discrete update,
    terminal cost) within ``rtol`` at fixed probe points (NaN where NaN) and the same bounds; else what differs."""
    import numpy as np

    if list(baked.state_names) != list(runtime.state_names) or list(baked.control_names) != list(runtime.control_names):
        return "states or controls"
    for k in ("x_lb", "x_ub", "u_lb", "u_ub", "path_lb", "path_ub", "x_scale", "u_scale"):
        if list(getattr(baked, k) or []) != list(getattr(runtime, k) or []):
            return k
    d = runtime.meta.get("parameter_defaults", {})
    extra = [k for k in runtime.meta.get("parameter_names", [])[baked.np_ :]]
    if runtime.np_ != baked.np_ + len(extra) or any(k not in d for k in extra):
        return "parameters"
    pv = np.array([d[k] for k in extra])
    rng = np.random.default_rng(40)  # fixed probe points: the choice must not depend on the run
    lo = {"h": 0.3, "v": 0.0, "V1": -0.01, "V2": -0.01, "S": 0.2, "T": 290.0}
    hi = {"h": 3.0, "v": 2.0, "V1": 0.01, "V2": 0.01, "S": 0.9, "T": 320.0}
    names = list(baked.state_names)
    for j in range(8):
        x = np.array([rng.uniform(lo.get(n, -0.5), hi.get(n, 0.5)) for n in names])
        if j == 0 and "V1" in names and "V2" in names:  # the closed loop's start: RC voltages 0
            x[[names.index("V1"), names.index("V2")]] = 0.0
        u, w = rng.uniform(-1.0, 1.0, baked.nu), rng.uniform(0.5, 1.5, baked.nw)
        p = rng.uniform(0.5, 1.5, baked.np_)
        for nm in ("ode", "stage", "lagrange", "path", "outputs", "discrete_next", "terminal_cost", "terminal"):
            fa, fb = getattr(baked, nm), getattr(runtime, nm)
            if (fa is None) != (fb is None):
                return nm
            if fa is None:
                continue
            args = [x, u, w] if fa.n_in() == 4 else [x]
            for ra, rb in zip(fa.call([*args, p]), fb.call([*args, np.concatenate([p, pv])])):
                a, b = np.asarray(ra, float).ravel(), np.asarray(rb, float).ravel()
                if a.shape != b.shape or not np.allclose(a, b, rtol=rtol, atol=1e-300, equal_nan=True):
                    return f"{nm} at a probe point"
    return ""


#: The default formulation of an MPC (``MPCVehicle(settings)`` and an ``[mpc]`` table without formulation keys).
DEFAULT_FORMULATION = traffic_formulation()


#: Formulation keys renamed: old key -> new key. The old key is still read, with a FutureWarning naming the new one
#: ('energy_weight' weighted the paper's ω rate v g(a), not battery energy).
RENAMED_KEYS = {"energy_weight": "omega_weight"}


def renamed_formulation_keys(d: Mapping[str, Any], prefix: str = "", file: str = "") -> dict[str, Any]:
    """``d`` with the old names of :data:`RENAMED_KEYS` (and the objective value 'energy', now 'omega') replaced
    by the new ones, a FutureWarning naming the new key for each (``prefix``: the table's key path such as 'mpc.',
    ``file``: the file's name); both the old and the new key given: ParameterError naming both."""
    import warnings

    out = dict(d)
    for old, new in RENAMED_KEYS.items():
        if old in out:
            if new in out:
                raise ParameterError(
                    f"{file}{prefix}{old} and {prefix}{new} are both given: {old} is the old name of {new}"
                )
            warnings.warn(
                f"{file}{prefix}{old} is deprecated: use {prefix}{new} (the weight of the paper's inertial measure rate "
                "v g(a), not of battery energy)",
                FutureWarning,
                stacklevel=3,
            )
            out = {(new if k == old else k): v for k, v in out.items()}
    if out.get("objective") in RENAMED_OBJECTIVES:
        out["objective"] = objective_name(out["objective"], f"{file}{prefix}objective")
    return out


def formulation_from_dict(d: Mapping[str, Any]) -> Formulation:
    """A formulation from flat keys: ``formulation`` ('traffic' default, or 's9'), the TrafficParams fields
    (traffic), w_Q, w_V, w_r, w_a, h_min, v_min, v_max, a_min, a_max and ``objective`` (§9), and
    ``smoothing_width_W`` and the TemperatureTerms fields (both kinds). A key of the other kind raises
    ParameterError naming it (it would be ignored)."""
    from dataclasses import fields

    d = renamed_formulation_keys(d)
    kind = d.get("formulation", "traffic")
    if kind not in ("traffic", "s9"):
        raise ParameterError(f"formulation = {kind!r} is not allowed: must be one of ('traffic', 's9')")
    wn, bn = {f.name for f in fields(FollowingWeights)}, {f.name for f in fields(FollowingBounds)}
    tn = {f.name for f in fields(TrafficParams)}
    thn = {f.name for f in fields(TemperatureTerms)}
    th: dict[str, Any] = {}
    w: dict[str, Any] = {}
    b: dict[str, Any] = {}
    t: dict[str, Any] = {}
    s: dict[str, Any] = {}
    obj = "heat"
    for k, v in d.items():
        if k == "formulation":
            continue
        if k in wn or k in bn or k == "objective":
            if kind != "s9":
                raise ParameterError(
                    f'{k} applies to the §9 formulation only: set formulation = "s9", or use the '
                    "traffic formulation's SI parameters (standstill_gap_m, time_headway_s, a_min_mps2, "
                    "...; see aev_ocp/ocp/traffic.py)"
                )
            if k == "objective":
                obj = v
            else:
                (w if k in wn else b)[k] = v
        elif k in tn:
            if kind != "traffic":
                raise ParameterError(
                    f'{k} applies to the traffic formulation only (aev_ocp/ocp/traffic.py), not to formulation = "s9"'
                )
            t[k] = v
        elif k == "smoothing_width_W":
            s[k] = v
        elif k in thn:
            th[k] = v
        else:
            raise ParameterError(
                f"formulation option {k!r} is unknown: known options are "
                f"{sorted(wn | bn | tn | thn | {'formulation', 'objective', 'smoothing_width_W'})}"
            )
    smooth = PowertrainOptions(**s)
    temp = TemperatureTerms(**th)
    if kind == "traffic":
        return traffic_formulation(TrafficParams(**t), smooth, temp)
    return s9_formulation(FollowingWeights(**w), FollowingBounds(**b), obj, smooth, temp)


def formulation_keys() -> set[str]:
    """Every flat key :func:`formulation_from_dict` reads."""
    from dataclasses import fields

    return (
        {"formulation", "objective", "smoothing_width_W"}
        | {f.name for f in fields(FollowingWeights)}
        | {f.name for f in fields(FollowingBounds)}
        | {f.name for f in fields(TrafficParams)}
        | {f.name for f in fields(TemperatureTerms)}
    )
