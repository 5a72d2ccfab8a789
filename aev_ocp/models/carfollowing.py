"""Car-following laws in the paper's dimensionless units (paper §2, model guide §2).

A law maps (gap h, own speed v, leader speed v_l) to the acceleration v̇. Every law works on
floats, numpy arrays and CasADi SX/MX expressions alike, so the same law feeds the simulator,
the optimisers and the tests. Add a law by subclassing :class:`CarFollowingLaw` and calling
:func:`register_law`; nothing else needs to change.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import Field, dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import casadi as ca

from ..params import CarFollowingParams, ParameterError

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

    @cached_property
    def function(self) -> ca.Function:
        """The law as a CasADi Function f(h, v, v_l) -> v̇ (built once per law object)."""
        h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("v_l")
        return ca.Function(f"{self.name}_accel", [h, v, vl], [self.accel(h, v, vl)], ["h", "v", "v_l"], ["a"])

    def describe(self) -> dict[str, Any]:
        """Name and coefficients, for reports."""
        out: dict[str, Any] = {"law": self.name}
        out.update({k: getattr(self, k) for k in getattr(self, "__dataclass_fields__", {})})
        return out


@dataclass(frozen=True)
class OVM(CarFollowingLaw):
    """Optimal Velocity Model: v̇ = α (V(h) − v)."""

    alpha: float = 2.0  # paper §2
    name = "ovm"
    _nonnegative = ("alpha",)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.alpha * (optimal_velocity(h) - v)


@dataclass(frozen=True)
class OVFL(CarFollowingLaw):
    """Optimal Velocity Follow-the-Leader: v̇ = α (V(h) − v) + β (v_l − v)/h²."""

    alpha: float = 2.0  # paper §2
    beta: float = 3.0  # paper §2
    name = "ovfl"
    _nonnegative = ("alpha", "beta")

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return ovfl_accel(h, v, v_l, self.alpha, self.beta)


@dataclass(frozen=True)
class Proposed(CarFollowingLaw):
    """The paper's model: OVFL − κ v² (v_l − v)²/((v_l − v)² + ε)."""

    alpha: float = 2.0  # paper §2
    beta: float = 3.0  # paper §2
    kappa: float = 0.03  # paper Fig. 1 caption
    eps: float = 1e-6  # paper §2
    name = "proposed"
    _nonnegative = ("alpha", "beta", "kappa")
    _positive = ("eps",)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return ovfl_accel(h, v, v_l, self.alpha, self.beta) + energy_term(v, v_l, self.kappa, self.eps)


@dataclass(frozen=True)
class IDM(CarFollowingLaw):
    """Intelligent Driver Model (Treiber et al. 2000) in model units — an example of a user law.

    v̇ = a_max [1 − (v/v0)^4 − (s*/h)²], s* = s0 + v T_h + v (v − v_l)/(2 sqrt(a_max b)).
    Defaults are illustrative, chosen to sit near the OV equilibrium at v = 1.7.
    """

    a_max: float = 1.0
    b: float = 1.5
    v0: float = 2.0
    s0: float = 0.2
    T_h: float = 0.8
    name = "idm"
    _positive = ("a_max", "b", "v0")
    _nonnegative = ("s0", "T_h")

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        s_star = self.s0 + v * self.T_h + v * (v - v_l) / (2.0 * ca.sqrt(self.a_max * self.b))
        return self.a_max * (1.0 - (v / self.v0) ** 4 - (s_star / h) ** 2)


LAW_REGISTRY: dict[str, Callable[..., CarFollowingLaw]] = {
    "ovm": OVM,
    "ovfl": OVFL,
    "proposed": Proposed,
    "idm": IDM,
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
    """Build a law by name; ovm/ovfl/proposed take their coefficients from ``params``."""
    key = name.lower() if isinstance(name, str) else None
    if key not in LAW_REGISTRY:
        raise ParameterError(f"unknown car-following law {name!r}: known laws are {sorted(LAW_REGISTRY)}")
    p = params or CarFollowingParams()
    base = {
        "ovm": {"alpha": p.alpha},
        "ovfl": {"alpha": p.alpha, "beta": p.beta},
        "proposed": {"alpha": p.alpha, "beta": p.beta, "kappa": p.kappa, "eps": p.eps},
    }.get(key, {})
    base.update(overrides)
    return LAW_REGISTRY[key](**base)
