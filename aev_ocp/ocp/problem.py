"""The optimal-control problem description (states, controls, parameters, costs, constraints).

:class:`OCPProblem` is the compiled description (CasADi Functions of ``(x, u, w, p)``: ``w`` a
per-interval parameter such as a leader forecast, ``p`` a global one such as cost weights). It is
what the transcription (:mod:`aev_ocp.ocp.transcription`, whole horizon: OCP-A…D) and the MPC
(:mod:`aev_ocp.mpc.controller`, receding horizon) are built from, so both solve the same problem.

:class:`ProblemBuilder` states a problem the way it reads in maths (like rockit's ``Ocp``):
``x = pb.state("h", lb=0.2)``, ``a = pb.control("a", -3, 2)``, ``pb.set_der(x, rhs)``,
``pb.add_stage_cost(expr)``, ``pb.subject_to(expr, lb, ub, soft=penalty)``, then ``pb.build()``.
A soft constraint gets a slack control σ ≥ 0 with the exact L1 penalty ``soft·σ`` plus a small
quadratic ``soft_quadratic·σ²`` (keeps the QP Hessian positive definite), so every NLP/QP stays
feasible; σ is reported like any other control.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Sequence, cast

import casadi as ca

from ..models.battery import runtime_cell
from ..params import CellParams, ParameterError, RCTable


@dataclass
class OCPProblem:
    """A continuous-time OCP with piecewise-constant controls, as CasADi Functions — the one problem
    description from which :class:`~aev_ocp.ocp.transcription.OCPSolver` (the whole horizon) and
    :class:`~aev_ocp.mpc.controller.MPCController` (receding horizon) are both built.

    ode: Function (x, u, w, p) -> dx/dt [state units per problem time unit].
    lagrange: optional Function (x, u, w, p) -> integrand, integrated over [0, t_f].
    stage: optional Function (x, u, w, p) -> ℓ, summed as Σ_k ℓ(x_k, u_k, w_k, p)·h.
    path: optional Function (x, u, w, p) -> c with ``path_lb ≤ c ≤ path_ub`` at nodes 0 … N−1.
    terminal: optional Function (x_N, p) -> c_T with ``terminal_lb ≤ c_T ≤ terminal_ub``.
    terminal_cost: optional Function (x_N, p) -> Mayer cost added to the objective.
    discrete_next / discrete_states: discrete-time states (indices; their ode entry is 0): at the end of
    an interval they take the value discrete_next(x_k, u_k, w_k, p) (e.g. the previous control, for a
    penalty on Δu), in every transcription and in the MPC.
    outputs: optional Function (x, u, w, p) -> named scalars (e.g. I, Q) reported at the nodes.
    x_lb/x_ub, u_lb/u_ub: bounds; x_scale/u_scale: nominal magnitudes (NLP variables are x/x_scale).
    """

    name: str
    state_names: Sequence[str]
    control_names: Sequence[str]
    ode: ca.Function
    lagrange: ca.Function | None = None
    stage: ca.Function | None = None
    path: ca.Function | None = None
    path_lb: Sequence[float] = ()
    path_ub: Sequence[float] = ()
    path_at_collocation: bool = False
    terminal: ca.Function | None = None
    terminal_lb: Sequence[float] = ()
    terminal_ub: Sequence[float] = ()
    terminal_cost: ca.Function | None = None
    discrete_next: ca.Function | None = None
    discrete_states: Sequence[int] = ()
    outputs: ca.Function | None = None
    x_lb: Sequence[float] | None = None
    x_ub: Sequence[float] | None = None
    u_lb: Sequence[float] | None = None
    u_ub: Sequence[float] | None = None
    x_scale: Sequence[float] | None = None
    u_scale: Sequence[float] | None = None
    time_unit: str = "s"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Number of controls."""
        return len(self.control_names)

    @property
    def nw(self) -> int:
        """Size of the per-interval parameter w."""
        return int(self.ode.size1_in(2))

    @property
    def np_(self) -> int:
        """Size of the global parameter p."""
        return int(self.ode.size1_in(3))

    def state_indices(self, names: Sequence[str]) -> list[int]:
        """Positions of the states ``names`` in x (e.g. the measured states of a closed loop, mapped by name,
        never by position); ParameterError naming the first state the problem does not have."""
        have = list(self.state_names)
        missing = [n for n in names if n not in have]
        if missing:
            raise ParameterError(f"{self.name}: no state named {missing[0]!r}; its states are {have}")
        return [have.index(n) for n in names]

    def validate(self) -> None:
        """Check the shapes of the functions and bounds; raise ParameterError naming the field."""
        nx, nu = self.nx, self.nu
        if self.ode.n_in() != 4 or self.ode.size1_in(0) != nx or self.ode.size1_in(1) != nu:
            raise ParameterError(f"OCPProblem.ode must map (x[{nx}], u[{nu}], w, p) -> dx/dt[{nx}]")
        if self.ode.size1_out(0) != nx:
            raise ParameterError(f"OCPProblem.ode returns {self.ode.size1_out(0)} values, expected {nx}")
        if self.lagrange is None and self.stage is None:
            raise ParameterError("OCPProblem: give a lagrange and/or a stage cost")
        if self.discrete_next is not None and self.discrete_next.size1_out(0) != len(self.discrete_states):
            raise ParameterError(f"OCPProblem.discrete_next must return {len(self.discrete_states)} values")
        if self.terminal_cost is not None and (
            self.terminal_cost.size1_in(0) != nx or self.terminal_cost.numel_out(0) != 1
        ):
            raise ParameterError(f"OCPProblem.terminal_cost must map (x_N[{nx}], p) -> a scalar")
        for nm in ("lagrange", "stage", "path", "outputs"):
            f = getattr(self, nm)
            if f is not None and (f.n_in() != 4 or f.size1_in(0) != nx or f.size1_in(1) != nu):
                raise ParameterError(f"OCPProblem.{nm} must take (x[{nx}], u[{nu}], w, p)")
        if self.path is not None:
            nc = self.path.size1_out(0)
            if len(self.path_lb) != nc or len(self.path_ub) != nc:
                raise ParameterError(f"OCPProblem.path_lb/path_ub must have {nc} entries")
        if self.terminal is not None:
            nt = self.terminal.size1_out(0)
            if len(self.terminal_lb) != nt or len(self.terminal_ub) != nt:
                raise ParameterError(f"OCPProblem.terminal_lb/terminal_ub must have {nt} entries")
        for nm, n in (("x_lb", nx), ("x_ub", nx), ("x_scale", nx), ("u_lb", nu), ("u_ub", nu), ("u_scale", nu)):
            v = getattr(self, nm)
            if v is not None and len(v) != n:
                raise ParameterError(f"OCPProblem.{nm} must have {n} entries, got {len(v)}")


class ProblemBuilder:
    """A problem stated symbolically, term by term; :meth:`build` returns the :class:`OCPProblem`.

    Time is in the problem's own unit (``time_unit``). Stage costs are sampled at the start of each
    interval and summed with weight h (the interval length); integral costs are integrated by the
    transcription; path constraints hold at the start of every interval.

    Every name is used once: variables (states, controls, stage parameters, parameters) share one set of
    names; cost terms and outputs share another (every term is also an output); path constraints and
    terminal constraints have one each. A name given twice raises ParameterError, except a cost term or
    an output given again with ``replace=True`` (e.g. ``add_stage_cost(expr, "accel", replace=True)``
    replaces §9's ``w_a·a²``; without it, the call is refused instead of silently replacing the term).
    """

    def __init__(self, name: str, time_unit: str = "s") -> None:
        self.name, self.time_unit = name, time_unit
        self.x: dict[str, ca.SX] = {}
        self.u: dict[str, ca.SX] = {}
        self.w: dict[str, ca.SX] = {}
        self.p: dict[str, ca.SX] = {}
        self._x_info: dict[str, tuple[float, float, float]] = {}
        self._u_info: dict[str, tuple[float, float, float]] = {}
        self._der: dict[str, Any] = {}
        self._next: dict[str, Any] = {}
        self.stage_terms: dict[str, Any] = {}
        self.integral_terms: dict[str, Any] = {}
        self._terminal_cost: Any = 0
        self._path: list[tuple[str, Any, float, float]] = []
        self._terminal: list[tuple[str, Any, float, float]] = []
        self._outputs: dict[str, Any] = {}
        self._p_values: dict[str, float] = {}
        self.meta: dict[str, Any] = {}

    # ---------------------------------------------------------------- variables
    def _new(self, table: dict[str, ca.SX], kind: str, name: str) -> ca.SX:
        if not isinstance(name, str) or not name.isidentifier():
            raise ParameterError(f"{self.name}: {kind} name {name!r} must be an identifier")
        for other, t in (("state", self.x), ("control", self.u), ("stage parameter", self.w), ("parameter", self.p)):
            if name in t:
                raise ParameterError(f"{self.name}: {kind} {name!r}: a {other} named {name!r} exists already")
        table[name] = ca.SX.sym(name)
        return table[name]

    def _bounds(self, what: str, lb: Any, ub: Any) -> tuple[float, float]:
        """(lb, ub) as floats with lb ≤ ub (±inf allowed, NaN not); ParameterError naming ``what``."""
        try:
            lo, hi = float(lb), float(ub)
        except (TypeError, ValueError):
            raise ParameterError(f"{self.name}: {what}: bounds must be numbers, got lb = {lb!r}, ub = {ub!r}") from None
        if not lo <= hi:  # also catches NaN
            raise ParameterError(
                f"{self.name}: {what} has lb = {lo} > ub = {hi}"
                if lo == lo and hi == hi
                else f"{self.name}: {what}: bounds must not be NaN, got lb = {lb!r}, ub = {ub!r}"
            )
        return lo, hi

    def state(self, name: str, lb: float = -ca.inf, ub: float = ca.inf, scale: float = 1.0) -> ca.SX:
        """A state with simple bounds (nodes 1…N) and a nominal magnitude ``scale``."""
        lo, hi = self._bounds(f"state {name!r}", lb, ub)
        sym = self._new(self.x, "state", name)
        self._x_info[name] = (lo, hi, scale)
        return sym

    def control(self, name: str, lb: float = -ca.inf, ub: float = ca.inf, scale: float = 1.0) -> ca.SX:
        """A piecewise-constant control with simple bounds."""
        lo, hi = self._bounds(f"control {name!r}", lb, ub)
        sym = self._new(self.u, "control", name)
        self._u_info[name] = (lo, hi, scale)
        return sym

    def stage_parameter(self, name: str) -> ca.SX:
        """A parameter with one value per interval (e.g. a forecast)."""
        return self._new(self.w, "stage parameter", name)

    def parameter(self, name: str, value: float | None = None) -> ca.SX:
        """A global parameter (e.g. a cost weight), set at every solve without rebuilding; ``value``: its default
        (an MPC uses it when its ``parameter_values`` do not name the parameter; OCPProblem.meta
        ``parameter_defaults``)."""
        if value is not None:
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise ParameterError(
                    f"{self.name}: parameter {name!r}: value must be a number, got {value!r}"
                ) from None
            if not math.isfinite(v):
                raise ParameterError(f"{self.name}: parameter {name!r}: value = {v!r} is not a finite number")
        sym = self._new(self.p, "parameter", name)
        if value is not None:
            self._p_values[name] = v
        return sym

    def parameters_of(self, obj: Any, prefix: str, numbers: Sequence[str] = ()) -> Any:
        """A copy of the (frozen, nested) dataclass ``obj`` whose float fields are global parameters of this problem,
        named ``<prefix>__<field>__<subfield>``, their values the defaults (:meth:`parameter`): a model written
        against ``obj`` (a vehicle's EVParams, SI parameters of a formulation) then takes the numbers at run time,
        so the code generated from the problem does not depend on them (one compiled library for every vehicle of
        the same structure). Bools, ints, strings and None stay as they are (they shape the model), and so do the
        float fields and nested dataclasses named in ``numbers`` (dotted paths below ``obj``, e.g.
        ``"vehicle.rotating_mass_kg"`` or ``"limits"``: what a model branches on in Python). The copy bypasses the dataclass's validation (which ran on ``obj``).
        A cell (CellParams) also gets its RC tables' values and its OCV curve as parameters, its grids as numbers
        (:func:`~aev_ocp.models.battery.runtime_cell`): cells on the same grids share one compiled library."""
        if not (dataclasses.is_dataclass(obj) and not isinstance(obj, type)):
            raise ParameterError(f"{self.name}: parameters_of needs a dataclass instance, got {type(obj).__name__}")
        twin = copy.copy(obj)
        for f in dataclasses.fields(obj):
            x = getattr(obj, f.name)
            name = f"{prefix}__{f.name}"
            if isinstance(x, float) and f.name not in numbers:
                object.__setattr__(twin, f.name, self.parameter(name, x))
            elif isinstance(x, RCTable):
                continue  # its owner's (the cell's) twin takes its values (runtime_cell below), not its soc_ref
            elif dataclasses.is_dataclass(x) and not isinstance(x, type) and f.name not in numbers:
                below = [k.split(".", 1)[1] for k in numbers if k.startswith(f"{f.name}.")]
                object.__setattr__(twin, f.name, self.parameters_of(x, name, below))
        if isinstance(obj, CellParams) and "rc_table" not in numbers:  # "rc_table": the cell's tables as numbers
            twin = runtime_cell(obj, cast(CellParams, twin), self.parameter, prefix)
        return twin

    # ---------------------------------------------------------------- dynamics, costs, constraints
    def set_der(self, x: ca.SX, rhs: Any) -> None:
        """dx/dt = rhs for the state symbol x."""
        name = self._state_name(x, "set_der")
        if name in self._next:
            raise ParameterError(f"{self.name}: state {name!r} is discrete (set_next): it has no derivative")
        self._der[name] = self._expression(f"set_der of state {name!r}", rhs)

    def set_next(self, x: ca.SX, expr: Any) -> None:
        """Make x a discrete-time state: constant over an interval, x_{k+1} = expr(x_k, u_k, w_k, p).
        E.g. ``a_prev = pb.state("a_prev"); pb.set_next(a_prev, a)`` and a stage cost on (a − a_prev)²."""
        name = self._state_name(x, "set_next")
        self._next[name] = self._expression(f"set_next of state {name!r}", expr)
        self._der[name] = ca.SX(0)

    def _state_name(self, x: ca.SX, what: str) -> str:
        name = next((k for k, s in self.x.items() if s is x or ca.is_equal(s, x)), None)
        if name is None:
            raise ParameterError(f"{self.name}: {what} needs a state made by state(), got {x}")
        return name

    def _term_name(self, kind: str, name: str | None, default: str, replace: bool) -> str:
        """The name of a new cost term or output: unique among terms and outputs unless ``replace``."""
        taken = {**self._outputs, **self.stage_terms, **self.integral_terms}
        if name is None:
            k = 0
            while f"{default}{k}" in taken:
                k += 1
            return f"{default}{k}"
        if not isinstance(name, str) or not name.isidentifier():
            raise ParameterError(f"{self.name}: {kind} name {name!r} must be an identifier")
        if name in taken and not replace:
            where = (
                "a stage cost term"
                if name in self.stage_terms
                else "an integral cost term"
                if name in self.integral_terms
                else "an output"
            )
            raise ParameterError(
                f"{self.name}: {kind} {name!r}: {where} named {name!r} exists already; "
                f"pass replace=True to replace it, or choose another name"
            )
        for table in (self._outputs, self.stage_terms, self.integral_terms):
            table.pop(name, None)  # replace=True: the old term goes, whichever kind it was
        return name

    def add_stage_cost(self, expr: Any, name: str | None = None, *, replace: bool = False) -> None:
        """Add ℓ(x_k, u_k, w_k, p) to the stage cost Σ_k ℓ·h as the term ``name``; a name that exists already
        (e.g. §9's "accel") is refused unless ``replace=True``."""
        e = self._expression(f"stage cost term {name or 'stage'!r}", expr)
        self.stage_terms[self._term_name("stage cost term", name, "stage", replace)] = e

    def add_integral_cost(self, expr: Any, name: str | None = None, *, replace: bool = False) -> None:
        """Add ∫ expr dt (integrated by the transcription's quadrature) as the term ``name``; a name that
        exists already is refused unless ``replace=True``."""
        e = self._expression(f"integral cost term {name or 'integral'!r}", expr)
        self.integral_terms[self._term_name("integral cost term", name, "integral", replace)] = e

    def add_terminal_cost(self, expr: Any) -> None:
        """Add a cost on the final state (expression of states and global parameters)."""
        e = self._expression("terminal cost", expr, terminal=True)
        self._terminal_cost = self._terminal_cost + e

    def subject_to(
        self,
        expr: Any,
        lb: float = -ca.inf,
        ub: float = ca.inf,
        *,
        soft: float | None = None,
        soft_quadratic: float = 1e-3,
        name: str | None = None,
    ) -> None:
        """lb ≤ expr ≤ ub at the start of every interval; ``soft`` = L1 penalty per unit of violation
        (per unit time) of a soft constraint, which then never makes the problem infeasible."""
        name, lb, ub = self._constraint(
            "constraint",
            self._path,
            expr,
            lb,
            ub,
            name,
            "c",
        )
        if soft is None:
            self._path.append((name, expr, lb, ub))
            return
        if not (
            isinstance(soft, (int, float))
            and isinstance(soft_quadratic, (int, float))
            and soft > 0
            and soft_quadratic >= 0
        ):
            raise ParameterError(
                f"{self.name}: soft constraint {name!r} needs a penalty soft > 0 and soft_quadratic "
                f">= 0, got soft = {soft!r}, soft_quadratic = {soft_quadratic!r}"
            )
        taken = {c[0] for c in self._path}
        parts = [f"{name}_{side}" for side, on in (("lb", lb > -ca.inf), ("ub", ub < ca.inf)) if on]
        clash = [p for p in parts if p in taken]
        if clash:
            raise ParameterError(
                f"{self.name}: soft constraint {name!r}: a constraint named {clash[0]!r} exists already"
            )
        self._term_name("stage cost term", f"penalty_{name}", "stage", False)  # refused before anything is added
        sigma = self.control(f"slack_{name}", 0.0, ca.inf)
        self.add_stage_cost(soft * sigma + soft_quadratic * sigma**2, f"penalty_{name}")
        if lb > -ca.inf:
            self._path.append((f"{name}_lb", expr + sigma, lb, ca.inf))
        if ub < ca.inf:
            self._path.append((f"{name}_ub", expr - sigma, -ca.inf, ub))

    def subject_to_terminal(self, expr: Any, lb: float = -ca.inf, ub: float = ca.inf, name: str | None = None) -> None:
        """lb ≤ expr(x_N, p) ≤ ub at the final node (an expression of states and global parameters only);
        checked like a path constraint: a unique name, lb ≤ ub, a scalar expression."""
        name, lb, ub = self._constraint("terminal constraint", self._terminal, expr, lb, ub, name, "t")
        self._terminal.append((name, expr, lb, ub))

    def _constraint(
        self,
        kind: str,
        table: list[tuple[str, Any, float, float]],
        expr: Any,
        lb: Any,
        ub: Any,
        name: str | None,
        default: str,
    ) -> tuple[str, float, float]:
        """The checks every constraint meets, path or terminal: a new identifier name, numeric lb ≤ ub, a scalar
        expression of the allowed symbols only. Returns (name, lb, ub)."""
        taken = {c[0] for c in table}
        if name is None:
            k = len(table)
            while f"{default}{k}" in taken:
                k += 1
            name = f"{default}{k}"
        elif not isinstance(name, str) or not name.isidentifier():
            raise ParameterError(f"{self.name}: {kind} name {name!r} must be an identifier")
        elif name in taken:
            raise ParameterError(f"{self.name}: {kind} {name!r}: a {kind} named {name!r} exists already")
        lo, hi = self._bounds(f"{kind} {name!r}", lb, ub)
        self._expression(f"{kind} {name!r}", expr, kind.startswith("terminal"), "(state one constraint per entry)")
        return name, lo, hi

    def _expression(self, what: str, expr: Any, terminal: bool = False, hint: str = "") -> ca.SX:
        """``expr`` as a scalar SX of the problem's symbols only (``terminal``: of states and parameters), with no
        constant NaN or ±inf; otherwise one ParameterError naming ``what`` (instead of a CasADi error at build())."""
        try:
            e = ca.SX(expr)
        except Exception:  # noqa: BLE001 - any non-expression: one clear message
            raise ParameterError(
                f"{self.name}: {what} must be a CasADi SX expression or a number, got {type(expr).__name__}"
            ) from None
        if e.numel() != 1:
            raise ParameterError(
                f"{self.name}: {what} must be a scalar expression, got {e.numel()} entries {hint}".rstrip()
            )
        tables = (self.x, self.p) if terminal else (self.x, self.u, self.w, self.p)
        allowed = {s.element_hash() for t in tables for s in t.values()}
        free = [str(s) for s in ca.symvar(e) if s.element_hash() not in allowed]
        if free:
            kinds = "states and parameters" if terminal else "the problem's variables"
            raise ParameterError(
                f"{self.name}: {what} depends on {free[0]!r}, which is not one of {kinds} (symbols made by this "
                "builder's state(), control(), stage_parameter() or parameter())"
            )
        if e.is_constant() and not math.isfinite(float(ca.DM(e))):
            raise ParameterError(f"{self.name}: {what} = {float(ca.DM(e))!r} is not a finite number")
        return e

    def add_output(self, name: str, expr: Any, *, replace: bool = False) -> None:
        """A named quantity reported at the nodes of a solution (e.g. the cell current); names are shared
        with the cost terms, and one that exists already is refused unless ``replace=True``."""
        e = self._expression(f"output {name!r}", expr)
        self._outputs[self._term_name("output", name, "output", replace)] = e

    # ---------------------------------------------------------------- build
    def build(self, path_at_collocation: bool = False) -> OCPProblem:
        """The compiled :class:`OCPProblem` (every stage and integral term is also an output)."""
        missing = [k for k in self.x if k not in self._der]
        if missing:
            raise ParameterError(f"{self.name}: no set_der (or set_next) for state(s) {missing}")
        if not self.stage_terms and not self.integral_terms:
            raise ParameterError(f"{self.name}: add a stage or integral cost")
        x, u = ca.vertcat(*self.x.values()), ca.vertcat(*self.u.values())
        w, p = ca.vertcat(*self.w.values()), ca.vertcat(*self.p.values())
        w = w if w.numel() else ca.SX.sym("w", 0)
        p = p if p.numel() else ca.SX.sym("p", 0)
        args, names = [x, u, w, p], ["x", "u", "w", "p"]
        fn = lambda nm, e, on: ca.Function(f"{self.name}_{nm}", args, [ca.vertcat(*e)], names, on)  # noqa: E731
        stage = sum(self.stage_terms.values()) if self.stage_terms else None
        lag = sum(self.integral_terms.values()) if self.integral_terms else None
        outs = {**self._outputs, **self.stage_terms, **self.integral_terms}
        pr = OCPProblem(
            name=self.name,
            state_names=list(self.x),
            control_names=list(self.u),
            ode=fn("ode", [self._der[k] for k in self.x], ["xdot"]),
            stage=None if stage is None else fn("stage", [stage], ["ell"]),
            lagrange=None if lag is None else fn("lagrange", [lag], ["L"]),
            outputs=ca.Function(f"{self.name}_out", args, list(outs.values()), names, list(outs)) if outs else None,
            x_lb=[i[0] for i in self._x_info.values()],
            x_ub=[i[1] for i in self._x_info.values()],
            x_scale=[i[2] for i in self._x_info.values()],
            u_lb=[i[0] for i in self._u_info.values()],
            u_ub=[i[1] for i in self._u_info.values()],
            u_scale=[i[2] for i in self._u_info.values()],
            time_unit=self.time_unit,
            meta={
                **self.meta,
                "parameter_names": list(self.p),
                "stage_parameter_names": list(self.w),
                "parameter_defaults": dict(self._p_values),
            },
        )
        if self._next:
            pr.discrete_states = [list(self.x).index(k) for k in self._next]
            pr.discrete_next = fn("next", list(self._next.values()), ["x_next"])
        if self._path:
            pr.path = fn("path", [c[1] for c in self._path], ["c"])
            pr.path_lb, pr.path_ub = [c[2] for c in self._path], [c[3] for c in self._path]
            pr.path_at_collocation = path_at_collocation
            pr.meta["path_names"] = [c[0] for c in self._path]
        xN, pT = ca.SX.sym("xN", x.numel()), p
        if self._terminal:
            e = ca.substitute(ca.vertcat(*[c[1] for c in self._terminal]), x, xN)
            pr.terminal = ca.Function(f"{self.name}_terminal", [xN, pT], [e])
            pr.terminal_lb, pr.terminal_ub = [c[2] for c in self._terminal], [c[3] for c in self._terminal]
        if not (isinstance(self._terminal_cost, (int, float)) and self._terminal_cost == 0):
            pr.terminal_cost = ca.Function(
                f"{self.name}_mayer", [xN, pT], [ca.substitute(ca.SX(self._terminal_cost), x, xN)]
            )
        pr.validate()
        return pr
