"""Car-following laws with SI meaning (paper §2, model guide §2).

A law maps (gap h, own speed v, leader speed v_l) to the acceleration v̇. Every law works on
floats, numpy arrays and CasADi SX/MX expressions alike, so the same law feeds the simulator,
the optimisers and the tests. Add a law by subclassing :class:`CarFollowingLaw` and calling
:func:`register_law`; nothing else needs to change.

Units. Every law's behaviour in SI is fixed by its own parameters, stated once:

* the OV-type laws (:class:`OVM`, :class:`OVFL`, :class:`Proposed`) are the paper's dimensionless laws with their
  own length and speed scales ``h_scale_m`` ℓ [m] and ``v_scale_mps`` u [m/s] (law parameters; default the model
  guide §1 reading of the paper, ℓ = 10 m, u = 5 m/s): the gap enters as h/ℓ, speeds as v/u, and the acceleration
  is the dimensionless one times u²/ℓ. Their coefficients are the paper's dimensionless ones, so in SI
  α·u/ℓ [1/s], β·ℓ·u [m²/s], κ/ℓ [1/m], ε·u² [m²/s²] (:meth:`OVLaw.si_coefficients`);
* :class:`IDM` is Treiber's, in SI (a, b [m/s²], v0 [m/s], s0 [m], T [s], δ).

Simulators work in a scenario's model units (``[units]``: length L, speed U). :meth:`CarFollowingLaw.in_units`
gives the law a simulator in those units evaluates: the same SI behaviour whatever L and U are. When an OV-type
law's scales equal the units (every paper scenario), it is the paper's dimensionless expression itself, so the
paper's reproduction is bit-identical. A law not given units (``model_units`` None) is evaluated in its own
units: an OV-type law in its scales (the paper's dimensionless form), the IDM in SI. :class:`IDMModelUnits` (and
FollowerStopper and user laws) are written directly in a simulator's model units.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import Field, dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import casadi as ca

from ..params import CarFollowingParams, ParameterError, Units

SI_UNITS = Units(1.0, 1.0)  # model units that are SI: a law in them takes m and m/s and returns m/s²

TANH2 = math.tanh(2.0)
V_INF = 1.0 + TANH2  # sup of the optimal-velocity function (model speed)
V_MIN = TANH2 - 1.0  # inf of the optimal-velocity function (model speed)


def optimal_velocity(h: Any) -> Any:
    """V(h) = tanh(h − 2) + tanh 2 (paper eq. ovm_function); h and V in model units."""
    return ca.tanh(h - 2.0) + TANH2


def equilibrium_gap(v: float) -> float:
    """V⁻¹(v) = 2 + atanh(v − tanh 2), the equilibrium gap for speed v ∈ (tanh2 − 1, 1 + tanh2)."""
    if not (V_MIN < v < V_INF):
        raise ParameterError(f"equilibrium_gap: speed {v!r} is outside the range of V, ({V_MIN:.6f}, {V_INF:.6f})")
    return 2.0 + math.atanh(v - TANH2)


def energy_term(v: Any, v_l: Any, kappa: float, eps: float) -> Any:
    """The paper's deceleration term −κ v² (v_l − v)² / ((v_l − v)² + ε) (paper eq. control_term)."""
    dv2 = (v_l - v) ** 2
    return -kappa * v**2 * dv2 / (dv2 + eps)


def ovfl_accel(h: Any, v: Any, v_l: Any, alpha: Any, beta: Any) -> Any:
    """OVFL's v̇ = α (V(h) − v) + β (v_l − v)/h² (paper §2); coefficients may be symbolic."""
    return alpha * (optimal_velocity(h) - v) + beta * (v_l - v) / h**2


class CarFollowingLaw(ABC):
    """A car-following law v̇ = f(h, v, v_l) in model units."""

    name: str = "law"
    if TYPE_CHECKING:  # every concrete law is a dataclass: lets dataclasses.fields/replace take any law
        __dataclass_fields__: ClassVar[dict[str, Field[Any]]]
    _nonnegative: tuple[str, ...] = ()  # coefficients that must be finite and >= 0
    _positive: tuple[str, ...] = ()  # coefficients that must be finite and > 0

    def __post_init__(self) -> None:
        for attr, strict in [(a, False) for a in self._nonnegative] + [(a, True) for a in self._positive]:
            v = getattr(self, attr)
            ok = (
                isinstance(v, (int, float))
                and not isinstance(v, bool)
                and math.isfinite(v)
                and (v > 0 if strict else v >= 0)
            )
            if not ok:
                raise ParameterError(
                    f"{type(self).__name__}.{attr} = {v!r} is not allowed: must be a finite "
                    f"number {'> 0' if strict else '>= 0'}"
                )

    @abstractmethod
    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        """Acceleration v̇ [model units] for gap h, speed v and leader speed v_l."""

    #: whether the law's parameters have an SI meaning of their own (OV-type laws, IDM): then :meth:`in_units`
    #: maps it to any model units and :meth:`accel_si` evaluates it in SI
    has_si: ClassVar[bool] = False

    def in_units(self, units: Units) -> "CarFollowingLaw":
        """The law a simulator working in ``units`` evaluates (h [L], v [U], v̇ [U²/L]), with the same SI
        behaviour whatever the units. A law written in model units (no SI meaning of its own) is returned as is."""
        return self

    def accel_si(self, h_m: Any, v_mps: Any, v_l_mps: Any) -> Any:
        """Acceleration [m/s²] for gap h_m [m], speed v_mps and leader speed v_l_mps [m/s]."""
        if not self.has_si:
            raise ParameterError(
                f"{type(self).__name__} is written in a simulator's model units: it has no SI meaning of its own "
                "(use a law with SI parameters: OVM, OVFL, Proposed, IDM)"
            )
        return self.in_units(SI_UNITS).accel(h_m, v_mps, v_l_mps)

    def equilibrium_gap_m(self, v_mps: float) -> float:
        """The gap [m] at which a follower at v_mps [m/s] behind a leader at the same speed keeps its speed
        (accel_si(h, v, v) = 0), found by bracketing and bisection on (1 mm, 10 km); ParameterError when the law
        has no such gap at that speed."""
        f = self.in_units(SI_UNITS).function
        v = float(v_mps)
        lo, hi = 1e-3, 1e4
        flo, fhi = float(f(lo, v, v)), float(f(hi, v, v))
        if not (flo < 0 < fhi):
            raise ParameterError(
                f"{type(self).__name__}: no equilibrium gap at v = {v!r} m/s (the acceleration does not change sign "
                f"between a gap of {lo} m and {hi} m)"
            )
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if float(f(mid, v, v)) < 0:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-13 * hi:
                break
        return 0.5 * (lo + hi)

    @cached_property
    def function(self) -> ca.Function:
        """The law as a CasADi Function f(h, v, v_l) -> v̇ (built once per law object)."""
        h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("v_l")
        return ca.Function(f"{self.name}_accel", [h, v, vl], [self.accel(h, v, vl)], ["h", "v", "v_l"], ["a"])

    def describe(self) -> dict[str, Any]:
        """Name and coefficients, for reports (the model units a law was given are not a coefficient)."""
        out: dict[str, Any] = {"law": self.name}
        out.update({k: getattr(self, k) for k in getattr(self, "__dataclass_fields__", {}) if k != "model_units"})
        return out


def _check_units(law: CarFollowingLaw) -> None:
    u = getattr(law, "model_units", None)
    if u is not None and not isinstance(u, Units):
        raise ParameterError(f"{type(law).__name__}.model_units = {u!r:.60} is not allowed: must be a Units or None")


class OVLaw(CarFollowingLaw):
    """An OV-type law: the paper's dimensionless law :meth:`dimensionless` at its own scales h_scale_m ℓ [m] and
    v_scale_mps u [m/s] (module docstring). Subclasses are frozen dataclasses with those two fields and
    ``model_units``."""

    has_si: ClassVar[bool] = True
    #: fields the compiled simulators keep as constants, not runtime parameters (aev_ocp.simulate._law_template):
    #: a law at its own scales then compiles to the paper's expression with the paper's parameter vector (α, β, …)
    compile_constants: ClassVar[tuple[str, ...]] = ("h_scale_m", "v_scale_mps")
    if TYPE_CHECKING:
        h_scale_m: Any
        v_scale_mps: Any
        model_units: Units | None

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_units(self)

    @abstractmethod
    def dimensionless(self, h: Any, v: Any, v_l: Any) -> Any:
        """v̇/(u²/ℓ) for h/ℓ, v/u and v_l/u: the law as the paper writes it."""

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        u = self.model_units
        if u is None:  # the law's own units: the paper's expression, untouched
            return self.dimensionless(h, v, v_l)
        lam = u.length_m / self.h_scale_m  # model length in law lengths
        mu = u.speed_mps / self.v_scale_mps  # model speed in law speeds
        return self.dimensionless(lam * h, mu * v, mu * v_l) * (lam / (mu * mu))

    def in_units(self, units: Units) -> "CarFollowingLaw":
        if not isinstance(units, Units):
            raise ParameterError(f"{type(self).__name__}.in_units: units must be a Units, got {type(units).__name__}")
        if units.length_m == self.h_scale_m and units.speed_mps == self.v_scale_mps:
            return replace(self, model_units=None)  # the scales are the units: the paper's dimensionless law
        return replace(self, model_units=units)

    def si_coefficients(self) -> dict[str, float]:
        """The coefficients in SI (module docstring): alpha_per_s, and where the law has them beta_m2ps,
        kappa_per_m, eps_m2ps2, with h_scale_m and v_scale_mps."""
        ell, u = float(self.h_scale_m), float(self.v_scale_mps)
        out = {"h_scale_m": ell, "v_scale_mps": u, "alpha_per_s": float(getattr(self, "alpha")) * u / ell}
        if hasattr(self, "beta"):
            out["beta_m2ps"] = float(getattr(self, "beta")) * ell * u
        if hasattr(self, "kappa"):
            out["kappa_per_m"] = float(getattr(self, "kappa")) / ell
            out["eps_m2ps2"] = float(getattr(self, "eps")) * u * u
        return out

    def equilibrium_gap_m(self, v_mps: float) -> float:
        """ℓ V⁻¹(v/u) [m]: the OV function's inverse (every OV-type law is at rest relative to an equal-speed
        leader exactly at h = V⁻¹(v); the κ term vanishes there)."""
        return float(self.h_scale_m) * equilibrium_gap(float(v_mps) / float(self.v_scale_mps))

    def describe(self) -> dict[str, Any]:
        out = super().describe()
        out.update({k: v for k, v in self.si_coefficients().items() if k not in out})
        return out


@dataclass(frozen=True)
class OVM(OVLaw):
    """Optimal Velocity Model: v̇ = α (V(h) − v) (dimensionless; SI through h_scale_m, v_scale_mps)."""

    alpha: float = 2.0  # paper §2 (dimensionless: α u/ℓ = 1 1/s at the default scales)
    h_scale_m: float = 10.0  # ℓ [m]: the OV function's length scale (model guide §1 reading of the paper)
    v_scale_mps: float = 5.0  # u [m/s]: its speed scale (model guide §1; the paper's v_l = 1.7 is 8.5 m/s)
    model_units: Units | None = None  # the simulator's model units (set by in_units); None: the law's own scales
    name = "ovm"
    _nonnegative = ("alpha",)
    _positive = ("h_scale_m", "v_scale_mps")

    def dimensionless(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.alpha * (optimal_velocity(h) - v)


@dataclass(frozen=True)
class OVFL(OVLaw):
    """Optimal Velocity Follow-the-Leader: v̇ = α (V(h) − v) + β (v_l − v)/h² (dimensionless; SI through
    h_scale_m, v_scale_mps)."""

    alpha: float = 2.0  # paper §2
    beta: float = 3.0  # paper §2
    h_scale_m: float = 10.0  # ℓ [m] (model guide §1 reading of the paper)
    v_scale_mps: float = 5.0  # u [m/s] (model guide §1)
    model_units: Units | None = None  # set by in_units; None: the law's own scales
    name = "ovfl"
    _nonnegative = ("alpha", "beta")
    _positive = ("h_scale_m", "v_scale_mps")

    def dimensionless(self, h: Any, v: Any, v_l: Any) -> Any:
        return ovfl_accel(h, v, v_l, self.alpha, self.beta)


@dataclass(frozen=True)
class Proposed(OVLaw):
    """The paper's model: OVFL − κ v² (v_l − v)²/((v_l − v)² + ε) (dimensionless; SI through h_scale_m,
    v_scale_mps)."""

    alpha: float = 2.0  # paper §2
    beta: float = 3.0  # paper §2
    kappa: float = 0.03  # paper Fig. 1 caption
    eps: float = 1e-6  # paper §2
    h_scale_m: float = 10.0  # ℓ [m] (model guide §1 reading of the paper)
    v_scale_mps: float = 5.0  # u [m/s] (model guide §1)
    model_units: Units | None = None  # set by in_units; None: the law's own scales
    name = "proposed"
    _nonnegative = ("alpha", "beta", "kappa")
    _positive = ("eps", "h_scale_m", "v_scale_mps")

    def dimensionless(self, h: Any, v: Any, v_l: Any) -> Any:
        return ovfl_accel(h, v, v_l, self.alpha, self.beta) + energy_term(v, v_l, self.kappa, self.eps)


def idm_accel(h: Any, v: Any, v_l: Any, a: Any, b: Any, v0: Any, s0: Any, T: Any, delta: Any) -> Any:
    """The IDM (Treiber, Hennecke & Helbing 2000): a [1 − (v/v0)^δ − (s*/h)²], s* = s0 + v T + v (v − v_l)/(2√(ab)),
    in any consistent units."""
    s_star = s0 + v * T + v * (v - v_l) / (2.0 * ca.sqrt(a * b))
    return a * (1.0 - (v / v0) ** delta - (s_star / h) ** 2)


#: Treiber & Kesting 2013, Traffic Flow Dynamics (Springer), Table 11.2, IDM for motorway traffic
#: (Treiber, Hennecke & Helbing 2000, Phys. Rev. E 62:1805, for the model): a = 1 m/s², b = 1.5 m/s²,
#: v0 = 120 km/h, s0 = 2 m, T = 1.0 s, δ = 4.
IDM_TREIBER = {"a_mps2": 1.0, "b_mps2": 1.5, "v0_mps": 120.0 / 3.6, "s0_m": 2.0, "T_s": 1.0, "delta": 4}


@dataclass(frozen=True)
class IDM(CarFollowingLaw):
    """The Intelligent Driver Model (Treiber, Hennecke & Helbing 2000) in SI, with Treiber & Kesting's parameters
    (:data:`IDM_TREIBER`): v̇ = a [1 − (v/v0)^δ − (s*/h)²], s* = s0 + v T + v (v − v_l)/(2√(ab)).

    a_mps2: maximum acceleration; b_mps2: comfortable deceleration; v0_mps: desired speed; s0_m: standstill
    distance; T_s: time gap; delta: acceleration exponent. Evaluated in SI unless given model units (in_units)."""

    a_mps2: float = 1.0  # Treiber & Kesting 2013, Table 11.2
    b_mps2: float = 1.5  # same
    v0_mps: float = 120.0 / 3.6  # same (motorway, 120 km/h)
    s0_m: float = 2.0  # same
    T_s: float = 1.0  # same
    delta: float = 4  # same (an int by default: the paper-era expression (v/v0)**4, not a runtime parameter)
    model_units: Units | None = None  # the simulator's model units (set by in_units); None: SI
    name = "idm"
    has_si: ClassVar[bool] = True
    _positive = ("a_mps2", "b_mps2", "v0_mps", "delta")
    _nonnegative = ("s0_m", "T_s")

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_units(self)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        u = self.model_units
        if u is None:
            return idm_accel(h, v, v_l, self.a_mps2, self.b_mps2, self.v0_mps, self.s0_m, self.T_s, self.delta)
        return idm_accel(
            h,
            v,
            v_l,
            u.accel_from_si(self.a_mps2),
            u.accel_from_si(self.b_mps2),
            u.speed_from_si(self.v0_mps),
            u.length_from_si(self.s0_m),
            u.time_from_si(self.T_s),
            self.delta,
        )

    def in_units(self, units: Units) -> "CarFollowingLaw":
        if not isinstance(units, Units):
            raise ParameterError(f"IDM.in_units: units must be a Units, got {type(units).__name__}")
        return replace(self, model_units=units)

    def equilibrium_gap_m(self, v_mps: float) -> float:
        """s*(v, v)/√(1 − (v/v0)^δ) = (s0 + v T)/√(1 − (v/v0)^δ) [m] for 0 ≤ v < v0."""
        v = float(v_mps)
        if not 0.0 <= v < self.v0_mps:
            raise ParameterError(f"IDM: no equilibrium gap at v = {v!r} m/s: must be in [0, v0 = {self.v0_mps!r})")
        return (self.s0_m + v * self.T_s) / math.sqrt(1.0 - (v / self.v0_mps) ** self.delta)


@dataclass(frozen=True)
class IDMModelUnits(CarFollowingLaw):
    """The IDM written in a simulator's model units, with illustrative coefficients chosen to sit near the OV
    equilibrium at v = 1.7 (not Treiber's: that is :class:`IDM`). Registered as 'idm_model'.

    v̇ = a_max [1 − (v/v0)^4 − (s*/h)²], s* = s0 + v T_h + v (v − v_l)/(2 sqrt(a_max b)).
    """

    a_max: float = 1.0
    b: float = 1.5
    v0: float = 2.0
    s0: float = 0.2
    T_h: float = 0.8
    name = "idm_model"
    _positive = ("a_max", "b", "v0")
    _nonnegative = ("s0", "T_h")

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return idm_accel(h, v, v_l, self.a_max, self.b, self.v0, self.s0, self.T_h, 4)


LAW_REGISTRY: dict[str, Callable[..., CarFollowingLaw]] = {
    "ovm": OVM,
    "ovfl": OVFL,
    "proposed": Proposed,
    "idm": IDM,
    "idm_model": IDMModelUnits,
}


def register_law(name: str, factory: Callable[..., CarFollowingLaw]) -> None:
    """Make a law available to scenarios under ``name`` (lower case; letters, digits, '_' and '-'); ``factory``
    (the law's class, or any callable taking its coefficients as keywords) builds it. Registering a name again
    replaces the factory (re-running a notebook cell)."""
    if not isinstance(name, str) or not name or not all(c.isascii() and (c.isalnum() or c in "_-") for c in name):
        raise ParameterError(
            f"register_law: name = {name!r:.60} is not allowed: must be a non-empty string of letters, digits, "
            "'_' and '-' (scenario files name the law by it)"
        )
    if not callable(factory):
        raise ParameterError(
            f"register_law({name!r}): factory = {factory!r:.60} is not allowed: must be the law's class or a "
            "callable returning a CarFollowingLaw"
        )
    LAW_REGISTRY[name.lower()] = factory


def make_law(name: str, params: CarFollowingParams | None = None, **overrides: float) -> CarFollowingLaw:
    """Build a law by name; ovm/ovfl/proposed take their coefficients and scales (h_scale_m, v_scale_mps) from
    ``params``; ``overrides`` replace any of them. When ``params.model_units`` is set (scenario loaders set it to
    the scenario's [units]) the law is returned in those units (:meth:`CarFollowingLaw.in_units`)."""
    key = name.lower() if isinstance(name, str) else None
    if key not in LAW_REGISTRY:
        raise ParameterError(f"unknown car-following law {name!r}: known laws are {sorted(LAW_REGISTRY)}")
    p = params or CarFollowingParams()
    scales = {"h_scale_m": p.h_scale_m, "v_scale_mps": p.v_scale_mps}
    base: dict[str, Any] = {
        "ovm": {"alpha": p.alpha, **scales},
        "ovfl": {"alpha": p.alpha, "beta": p.beta, **scales},
        "proposed": {"alpha": p.alpha, "beta": p.beta, "kappa": p.kappa, "eps": p.eps, **scales},
    }.get(key, {})
    base.update(overrides)
    law = LAW_REGISTRY[key](**base)
    if p.model_units is not None and isinstance(law, CarFollowingLaw):
        law = law.in_units(p.model_units)
    return law
