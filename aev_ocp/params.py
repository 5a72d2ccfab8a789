"""Parameter sets: frozen dataclasses with SI units in the field names and the source of each default.

Every numeric default cites where it comes from; section numbers "§" refer to the model guide
(docs/guide/model.md, "The model" in the documentation). Validation happens in ``__post_init__`` and raises
:class:`ParameterError`, whose message names the field, the value and what is allowed.

The car-following model is dimensionless (the paper's units). :class:`Units` is the one place
that converts model units to SI and back.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from typing import Any, Sequence

from .errors import AevOcpError


class ParameterError(AevOcpError, ValueError):
    """A parameter is out of its allowed range; the message names the field and the value."""


#: The longest echo of a value in an error message [characters]: a key path and a short echo say what is wrong;
#: a 10 000-character string or a big inline table pasted into the one error line would hide it.
ECHO_CHARS = 60


def echo(value: Any, limit: int = ECHO_CHARS) -> str:
    """``repr(value)`` for an error message, at most ``limit`` characters (cut with '…'). Tables, arrays and
    strings are formatted only as far as shown, so a huge or deeply nested value costs nothing."""
    parts: list[str] = []
    size = 0

    class Full(Exception):
        pass

    def put(text: str) -> None:
        nonlocal size
        parts.append(text)
        size += len(text)
        if size > limit:
            raise Full

    def walk(v: Any) -> None:
        if isinstance(v, dict):
            put("{")
            for i, (k, x) in enumerate(v.items()):
                put(", " if i else "")
                walk(k)
                put(": ")
                walk(x)
            put("}")
        elif isinstance(v, (list, tuple)):
            put("[" if isinstance(v, list) else "(")
            for i, x in enumerate(v):
                put(", " if i else "")
                walk(x)
            put("]" if isinstance(v, list) else ",)" if len(v) == 1 else ")")
        elif isinstance(v, str):
            put(repr(v[: limit + 1]))  # longer than shown: cut below
        elif isinstance(v, int) and v.bit_length() > 4 * limit:  # repr would refuse it (over 4300 digits)
            put(f"{'-' if v < 0 else ''}{'9' * (limit + 1)}")
        else:
            put(repr(v)[: limit + 1])

    try:
        walk(value)
    except Full:
        pass
    text = "".join(parts)
    return text if len(text) <= limit else text[: limit - 1] + "…"


# ----------------------------------------------------------------------------- declared validation
def type_name(value: Any) -> str:
    """'a string', 'an integer', ... for messages (TOML's names for Python types)."""
    names = {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "an array", dict: "a table"}
    return names.get(type(value), f"a {type(value).__name__}")


@dataclass(frozen=True)
class Check:
    """The type and range of one dataclass field, declared once beside the field (see :func:`spec`).

    kind: "number" (finite float; int accepted), "integer" (int, not bool), "choice" (one of
    ``choices``), "bool", or "instance" (an instance of ``cls``). gt/ge/lt/le: bounds of numbers
    and integers. Read by :func:`validate_fields` (Python API) and by the scenario loader (TOML
    tables), so a range is written in exactly one place.
    """

    kind: str = "number"
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None
    cls: type | None = None
    optional: bool = False  # None is allowed too (an optional limit: "no limit")

    def allowed(self) -> str:
        """What is allowed, in words (e.g. 'a finite number > 0', 'a finite number in (0, 1]')."""
        if self.kind == "choice":
            return f"one of {self.choices}"
        if self.kind == "bool":
            return "true or false"
        if self.kind == "instance":
            return f"a {getattr(self.cls, '__name__', self.cls)}"
        what = "an integer" if self.kind == "integer" else "a finite number"
        lo = (
            (f"({self.gt:g}", self.gt)
            if self.gt is not None
            else (f"[{self.ge:g}", self.ge)
            if self.ge is not None
            else None
        )
        hi = (
            (f"{self.lt:g})", self.lt)
            if self.lt is not None
            else (f"{self.le:g}]", self.le)
            if self.le is not None
            else None
        )
        if lo and hi:
            return f"{what} in {lo[0]}, {hi[0]}"
        bounds = [
            f"{op} {b:g}"
            for op, b in ((">", self.gt), (">=", self.ge), ("<", self.lt), ("<=", self.le))
            if b is not None
        ]
        return what + (" " + " and ".join(bounds) if bounds else "")

    def problem(self, value: Any) -> str | None:
        """None if ``value`` is allowed, else 'must be ...' (type errors included)."""
        if value is None and self.optional:
            return None
        if self.kind == "choice":
            if not isinstance(value, str) and all(isinstance(c, str) for c in self.choices or ()):
                return f"expected {self.allowed()}, got {type_name(value)}"
            return None if value in (self.choices or ()) else f"must be {self.allowed()}"
        if self.kind == "bool":
            return None if isinstance(value, bool) else f"must be {self.allowed()}, got {type_name(value)}"
        if self.kind == "instance":
            return None if self.cls is not None and isinstance(value, self.cls) else f"must be {self.allowed()}"
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or (self.kind == "integer" and not isinstance(value, int))
        ):
            return f"expected {self.allowed()}, got {type_name(value)}"
        x = float(value)
        ok = (
            math.isfinite(x)
            and (self.gt is None or x > self.gt)
            and (self.ge is None or x >= self.ge)
            and (self.lt is None or x < self.lt)
            and (self.le is None or x <= self.le)
        )
        return None if ok else f"must be {self.allowed()}"


def spec(
    default: Any = MISSING,
    *,
    kind: str = "number",
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Sequence[Any] | None = None,
    cls: type | None = None,
    default_factory: Any = MISSING,
    optional: bool = False,
) -> Any:
    """A dataclass field whose type and range are declared once (``metadata["check"]``); ``optional``: None
    is allowed too."""
    check = Check(kind, gt, ge, lt, le, tuple(choices) if choices is not None else None, cls, optional)
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata={"check": check})
    return field(default=default, metadata={"check": check})


_FIELD_CHECKS: dict[type, dict[str, Check]] = {}  # a dataclass's fields are fixed once the class exists


def field_checks(cls: Any) -> dict[str, Check]:
    """{field name: Check} of a dataclass or of an instance's class (fields declared with :func:`spec`)."""
    key = cls if isinstance(cls, type) else type(cls)
    checks = _FIELD_CHECKS.get(key)
    if checks is None:
        checks = _FIELD_CHECKS[key] = {f.name: f.metadata["check"] for f in fields(key) if "check" in f.metadata}
    return dict(checks)


def check_declared(cls: Any, name: str, value: Any, where: str) -> Any:
    """``value`` checked against field ``name``'s declaration in dataclass ``cls`` (e.g. a ``soc0`` argument
    against CellParams.soc0); ParameterError '<where>: <name> = <value> is not allowed: ...' otherwise."""
    problem = field_checks(cls)[name].problem(value)
    if problem is not None:
        raise ParameterError(f"{where}: {name} = {echo(value)} is not allowed: {problem}")
    return value


def check_argument(where: str, name: str, value: Any, expected: type | tuple[type, ...]) -> Any:
    """``value`` if it is an instance of ``expected``, else a one-line TypeError naming the argument, what
    was expected and what was given (instead of an AttributeError deep inside)."""
    if not isinstance(value, expected):
        kinds = expected if isinstance(expected, tuple) else (expected,)
        names = " or ".join("None" if k is type(None) else k.__name__ for k in kinds)
        raise TypeError(f"{where}: {name} must be {names}, got {type(value).__name__} {echo(value)}")
    return value


def exact_key(obj: Any) -> Any:
    """A key equal only for dataclasses of the same type whose fields are identical to the bit (floats by their hex,
    so 0.0 and -0.0 differ; their types too, so 1 and 1.0 differ): what a process may keep a result of a law or a
    leader by; None when ``obj`` is not a dataclass or a field is not hashable."""
    if not is_dataclass(obj):
        return None
    vals = tuple(
        (f.name, type(v), v.hex() if isinstance(v, float) else v) for f in fields(obj) for v in (getattr(obj, f.name),)
    )
    try:
        hash(vals)
    except TypeError:
        return None
    return type(obj), vals


def remember(cache: dict[Any, Any], key: Any, value: Any, kept: int) -> Any:
    """Put ``value`` under ``key`` in a process cache and forget its oldest entries beyond ``kept``; returns
    ``value`` (the one bound for every per-process cache of results keyed by :func:`exact_key` and the like)."""
    cache[key] = value
    while len(cache) > kept:
        del cache[next(iter(cache))]
    return value


def validate_fields(obj: Any) -> None:
    """Check every declared field of a dataclass instance; ParameterError names class, field, value, range."""
    for name, check in field_checks(obj).items():
        value = getattr(obj, name)
        problem = check.problem(value)
        if problem is not None:
            raise ParameterError(f"{type(obj).__name__}.{name} = {echo(value)} is not allowed: {problem}")


@dataclass(frozen=True)
class Units:
    """Scaling between the paper's dimensionless car-following units and SI (model guide §1).

    length_m: length unit L [m]; speed_mps: speed unit U [m/s]. Time unit T = L/U [s],
    acceleration unit U²/L [m/s²].
    """

    length_m: float = spec(10.0, gt=0)  # model guide §1 default L = 10 m
    speed_mps: float = spec(5.0, gt=0)  # model guide §1 default U = 5 m/s (paper's v_l = 1.7 -> 8.5 m/s)

    def __post_init__(self) -> None:
        validate_fields(self)
        # each field may be finite and positive while a derived unit overflows or underflows (U = 1e308: U² = inf)
        L, U = float(self.length_m), float(self.speed_mps)
        derived = (
            ("time unit L/U", L / U),
            ("unit of ω (per unit mass) U²", U * U),
            ("acceleration unit U²/L", U * U / L),
        )
        for what, value in derived:
            if not (math.isfinite(value) and value > 0):
                raise ParameterError(
                    f"Units.speed_mps = {self.speed_mps!r} is not allowed with length_m = {self.length_m!r}: "
                    f"the {what} = {value!r} is not a finite positive number (choose units of everyday size, "
                    "e.g. length_m = 10, speed_mps = 5)"
                )

    @property
    def time_s(self) -> float:
        """Time unit T = L/U [s]."""
        return self.length_m / self.speed_mps

    @property
    def accel_mps2(self) -> float:
        """Acceleration unit U²/L [m/s²]."""
        return self.speed_mps**2 / self.length_m

    # conversions (work on floats, numpy arrays and CasADi expressions alike)
    def speed_to_si(self, v: Any) -> Any:
        """Model speed -> m/s."""
        return v * self.speed_mps

    def speed_from_si(self, v_mps: Any) -> Any:
        """m/s -> model speed."""
        return v_mps / self.speed_mps

    def length_to_si(self, x: Any) -> Any:
        """Model length -> m."""
        return x * self.length_m

    def length_from_si(self, x_m: Any) -> Any:
        """m -> model length."""
        return x_m / self.length_m

    def time_to_si(self, t: Any) -> Any:
        """Model time -> s."""
        return t * self.time_s

    def time_from_si(self, t_s: Any) -> Any:
        """s -> model time."""
        return t_s / self.time_s

    def accel_to_si(self, a: Any) -> Any:
        """Model acceleration -> m/s²."""
        return a * self.accel_mps2

    def accel_from_si(self, a_mps2: Any) -> Any:
        """m/s² -> model acceleration."""
        return a_mps2 / self.accel_mps2

    def energy_per_mass_to_si(self, omega: Any) -> Any:
        """The paper's ω in model units (per unit mass: speed × acceleration × time = U²) -> J/kg."""
        return omega * self.speed_mps**2


@dataclass(frozen=True)
class CarFollowingParams:
    """Coefficients of OVM / OVFL / the proposed law (paper eq. main_dynamics; model guide §2).

    The laws are the paper's dimensionless ones at their own length scale h_scale_m ℓ [m] and speed scale
    v_scale_mps u [m/s] (law parameters, not the scenario's [units]): alpha: relaxation rate to V(h) [u/ℓ 1/s];
    beta: follow-the-leader gain [ℓ u m²/s]; kappa: weight of the deceleration term [1/ℓ 1/m]; eps: smoothing of
    the term [u² m²/s²]. model_units: the model units the laws are simulated in (set by scenario loaders from
    [units]; None: the laws' own scales), see :meth:`aev_ocp.models.carfollowing.CarFollowingLaw.in_units`.
    """

    alpha: float = spec(2.0, ge=0)  # paper Fig. 1-2 captions, Table 1 setup
    beta: float = spec(3.0, ge=0)  # paper Fig. 1-2 captions
    kappa: float = spec(0.03, ge=0)  # paper Fig. 1-2 captions
    eps: float = spec(1e-6, gt=0)  # paper §2 ("e.g. 10^-6")
    h_scale_m: float = spec(10.0, gt=0)  # model guide §1: the paper read at L = 10 m
    v_scale_mps: float = spec(5.0, gt=0)  # model guide §1: U = 5 m/s (the paper's v_l = 1.7 is 8.5 m/s)
    model_units: Units | None = spec(None, kind="instance", cls=Units, optional=True)  # set by loaders

    def __post_init__(self) -> None:
        validate_fields(self)


#: The powertrain models between wheel and battery (VehicleParams.powertrain, :mod:`aev_ocp.models.powertrain`).
POWERTRAINS = ("constant", "map")
#: FASTSim 3.1's 2022 Tesla Model 3 RWD (vehicle file "2022 Tesla Model 3 RWD thrml.yaml"): the wheels' inertia as an
#: equivalent mass, wheel_inertia 0.815 kg m² × 4 wheels / wheel_radius (0.33435 m)² [kg].
MODEL3_ROTATING_MASS_KG = 0.815 * 4 / 0.33435**2
#: The same file's base auxiliary load, pwr_aux_base_watts [W] (HVAC off at its 22 °C set point).
MODEL3_AUX_POWER_W = 250.0
#: FASTSim's constant air density (SimParams.f2_const_air_density = True): 1.2 kg/m³.
FASTSIM_AIR_DENSITY_KGPM3 = 1.2


@dataclass(frozen=True)
class VehicleParams:
    """Longitudinal vehicle and powertrain parameters (model guide §5), SI units.

    Defaults: 2022 Tesla Model 3 RWD (LFP), NREL FASTSim vehicle file; eta is the paper's and so is the
    default powertrain ("constant": the η switch). ``powertrain = "map"`` selects FASTSim's Model 3 powertrain
    (transmission, motor/inverter map, regenerative power limit with friction blending); :meth:`model3` is the
    whole FASTSim vehicle (map, 250 W auxiliary load, wheel inertia, FASTSim's air density).
    """

    mass_kg: float = spec(1752.0, gt=0)  # FASTSim 2022 Tesla Model 3 RWD
    frontal_area_m2: float = spec(2.22, gt=0)  # FASTSim 2022 Tesla Model 3 RWD
    drag_coefficient: float = spec(0.23, ge=0)  # FASTSim 2022 Tesla Model 3 RWD
    rolling_coefficient: float = spec(0.007, ge=0)  # FASTSim 2022 Tesla Model 3 RWD
    air_density_kgpm3: float = spec(1.225, gt=0)  # ISA sea level
    gravity_mps2: float = spec(9.81, gt=0)  # paper §3.3
    grade_rad: float = spec(0.0, gt=-math.pi / 2, lt=math.pi / 2)  # flat road (model guide §5)
    efficiency: float = spec(0.8, gt=0, le=1)  # paper eq. g_function / Table 1 (eta = 80 %)
    aux_power_W: float = spec(0.0, ge=0)  # model guide §5 (P_aux = 0 by default)
    # --- the powertrain between wheel and battery (aev_ocp.models.powertrain, model guide §5)
    powertrain: str = spec("constant", kind="choice", choices=POWERTRAINS)  # "constant": the paper's η switch
    # (P_b = P_w/η or η P_w, the paper's reproduction); "map": transmission + FASTSim's motor/inverter map + regen limit
    transmission_efficiency: float = spec(0.98, gt=0, le=1)  # FASTSim 3.1 2022 Tesla Model 3 RWD: transmission
    # eff_interp = 0.98 (both directions); used by powertrain = "map" only
    motor_power_max_W: float = spec(239_000.0, gt=0)  # FASTSim 3.1 Model 3 RWD: em.pwr_out_max_watts = 239 kW; the
    # motor map's abscissa is |P_motor| / motor_power_max_W ("map" only)
    regen_efficiency: float | None = spec(0.84, gt=0, le=1, optional=True)  # motor/inverter efficiency when
    # recuperating: FASTSim 3.1 applies its map's zero-power entry, 0.84, to every regenerative step of the Model 3
    # (its em history on UDDS/HWFET/US06: P_elec/P_mech = 0.84 at every braking step); None: the map at |P_motor|
    regen_power_max_W: float = spec(212_081.4988, gt=0)  # largest mechanical power the motor recuperates [W]:
    # FASTSim 3.1 Model 3 RWD em.state.pwr_mech_regen_max_watts (its pack's 201.2 kW charge limit seen from the
    # shaft; constant over UDDS/HWFET/US06); braking beyond it goes to the friction brakes ("map" only)
    rotating_mass_kg: float = spec(0.0, ge=0)  # equivalent mass of the wheels' inertia, J_w n_w / r_w² [kg]; 0: the
    # paper's point mass. FASTSim's Model 3: 4 × 0.815 kg m² / (0.33435 m)² = 29.16 kg (MODEL3_ROTATING_MASS_KG)

    def __post_init__(self) -> None:
        validate_fields(self)

    @classmethod
    def model3(cls, **overrides: Any) -> "VehicleParams":
        """FASTSim 3.1's 2022 Tesla Model 3 RWD as FASTSim simulates it: the map powertrain, its 250 W auxiliary
        load, its wheels' inertia and its constant air density 1.2 kg/m³; ``overrides``: any other field."""
        base: dict[str, Any] = {
            "powertrain": "map",
            "aux_power_W": MODEL3_AUX_POWER_W,
            "rotating_mass_kg": MODEL3_ROTATING_MASS_KG,
            "air_density_kgpm3": FASTSIM_AIR_DENSITY_KGPM3,
        }
        return cls(**{**base, **overrides})


RC_TABLE_KEYS = ("R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F")


@dataclass(frozen=True)
class RCTable:
    """R_s [Ω], R1 [Ω], C1 [F], R2 [Ω], C2 [F] of a 2-RC cell over SOC [-] and temperature [K]: each table has
    one row per ``T_K`` and one column per ``soc`` (a cell file's ``[rc_table]``, :mod:`aev_ocp.cells`). The
    plant interpolates linearly and holds the end values outside the grid; optimisers take a cubic B-spline
    (:func:`aev_ocp.models.battery.rc_function`). ``soc_ref``: the SOC of the cell's scalar values."""

    soc: tuple[float, ...]
    T_K: tuple[float, ...]
    R_s_ohm: tuple[tuple[float, ...], ...]
    R1_ohm: tuple[tuple[float, ...], ...]
    C1_F: tuple[tuple[float, ...], ...]
    R2_ohm: tuple[tuple[float, ...], ...]
    C2_F: tuple[tuple[float, ...], ...]
    soc_ref: float = 0.5

    def __post_init__(self) -> None:
        def floats(x: Any, what: str) -> tuple[float, ...]:
            try:
                v = tuple(float(a) for a in x)
            except (TypeError, ValueError):
                raise ParameterError(f"RCTable.{what} is not allowed: must be an array of numbers") from None
            if not all(math.isfinite(a) for a in v):
                raise ParameterError(f"RCTable.{what} is not allowed: every value must be finite")
            return v

        soc, temps = floats(self.soc, "soc"), floats(self.T_K, "T_K")
        if len(soc) < 2 or any(b <= a for a, b in zip(soc, soc[1:])) or soc[0] < 0 or soc[-1] > 1:
            raise ParameterError(f"RCTable.soc = {list(soc)!r:.80} is not allowed: ≥ 2 increasing values in [0, 1]")
        if not temps or any(b <= a for a, b in zip(temps, temps[1:])) or temps[0] <= 0:
            raise ParameterError(f"RCTable.T_K = {list(temps)!r:.80} is not allowed: ≥ 1 increasing values > 0 K")
        object.__setattr__(self, "soc", soc)
        object.__setattr__(self, "T_K", temps)
        object.__setattr__(self, "soc_ref", float(self.soc_ref))
        if not soc[0] <= self.soc_ref <= soc[-1]:
            raise ParameterError(f"RCTable.soc_ref = {self.soc_ref!r} is not allowed: must lie in the soc grid")
        for key in RC_TABLE_KEYS:
            raw = getattr(self, key)
            rows = tuple(floats(r, key) for r in raw) if isinstance(raw, (list, tuple)) else ()
            if len(rows) != len(temps) or any(len(r) != len(soc) for r in rows):
                raise ParameterError(
                    f"RCTable.{key} is not allowed: needs {len(temps)} rows (one per T_K) of {len(soc)} values "
                    "(one per soc)"
                )
            if any(a <= 0 for r in rows for a in r):
                raise ParameterError(f"RCTable.{key} is not allowed: every value must be > 0")
            object.__setattr__(self, key, rows)

    def value(self, key: str, soc: float, T_K: float) -> float:
        """The table ``key`` at (soc, T_K), bilinear with the end values held (NumPy; the plant's values)."""
        along_soc = [_interp_held(soc, self.soc, r) for r in getattr(self, key)]
        return _interp_held(T_K, self.T_K, along_soc) if len(self.T_K) > 1 else along_soc[0]


def _interp_held(x: float, xs: Sequence[float], ys: Sequence[float]) -> float:
    """Linear interpolation of (xs, ys) at x, the end values held outside [xs[0], xs[-1]]."""
    x = min(max(float(x), xs[0]), xs[-1])
    k = max(i for i in range(len(xs) - 1) if xs[i] <= x) if len(xs) > 1 else 0
    num = (lambda v: float(v)) if all(isinstance(y, (int, float)) for y in ys) else (lambda v: v)  # noqa: E731
    if len(xs) == 1 or x == xs[k]:
        return num(ys[k])  # the values may be symbols (a problem's run-time parameters): kept as they are
    w = (x - xs[k]) / (xs[k + 1] - xs[k])
    return num(ys[k] + w * (ys[k + 1] - ys[k]))


@dataclass(frozen=True)
class CellParams:
    """2-RC equivalent-circuit cell (paper §3; model guide §6), SI units. I > 0 discharges.

    Defaults: A123 ANR26650 LFP at 25 °C.
    """

    capacity_Ah: float = spec(2.3, gt=0)  # A123 ANR26650 datasheet, nominal capacity
    R_s_ohm: float = spec(0.010, gt=0)  # A123 enhanced self-correcting model at 25 °C: R0 = 9.95 mΩ
    R1_ohm: float = spec(0.0085, gt=0)  # same model: R1 = 8.45 mΩ
    C1_F: float = spec(460.0, gt=0)  # same model: tau1 = 3.92 s -> C1 = tau1/R1 ≈ 460 F
    R2_ohm: float = spec(0.010, gt=0)  # representative, inside Lin et al. 2014 range R2 = 5-45 mΩ (not fitted)
    C2_F: float = spec(10_000.0, gt=0)  # representative, Lin et al. 2014: C2 tens of kF (tau2 = 100 s; not fitted)
    soc0: float = spec(0.8, ge=0, le=1)  # model guide §6: S(0) = 0.8
    max_current_A: float = spec(46.0, gt=0)  # model guide §8: 20C = 20 × 2.3 A
    # thermal properties of one cell (used only when EVParams.thermal.enabled)
    heat_capacity_JpK: float = spec(67.2, gt=0)  # Lin et al. 2014 (J. Power Sources 257:1-11), A123 26650:
    # core + surface heat capacities Cc + Cs = 62.7 + 4.5 J/K (lumped into one node here)
    surface_area_m2: float = spec(6.37e-3, gt=0)  # 26650 geometry (d = 26 mm, L = 65 mm): π d L + 2 π (d/2)²
    activation_energy_Jpmol: float | None = spec(None, gt=0, optional=True)  # None: R_s, R1, R2 independent of T
    T_ref_K: float = spec(298.15, gt=0)  # temperature at which R_s, R1, R2 were identified (25 °C, as above)
    # OCV table (SOC grid 0..1, volts); None: the shipped A123 table aev_ocp/data/a123_ocv_25C.csv
    ocv_soc: tuple[float, ...] | None = spec(None, kind="instance", cls=tuple, optional=True)
    ocv_V: tuple[float, ...] | None = spec(None, kind="instance", cls=tuple, optional=True)
    # R_s, R1, C1, R2, C2 over SOC and T (a cell file's [rc_table], e.g. tools/identify_cell.py); None: the
    # constants above. With a table, the constants are its level at (rc_table.soc_ref, T_ref_K): the plant uses
    # table(S, T) × R_s_ohm / table(soc_ref, T_ref_K), so a shipped file (constants = the table there) uses the
    # table as it is and an override of R_s_ohm (or a mismatch factor) scales the whole table
    rc_table: RCTable | None = spec(None, kind="instance", cls=RCTable, optional=True)

    def __post_init__(self) -> None:
        if isinstance(self.rc_table, dict):  # a saved run's cell (saved.py writes dataclasses as tables)
            object.__setattr__(self, "rc_table", RCTable(**self.rc_table))
        validate_fields(self)
        if self.rc_table is not None and self.activation_energy_Jpmol is not None:
            raise ParameterError(
                "CellParams.activation_energy_Jpmol is not allowed with rc_table: the table holds the temperature "
                "dependence (set one or the other)"
            )
        if (self.ocv_soc is None) != (self.ocv_V is None):
            raise ParameterError("CellParams.ocv_soc and CellParams.ocv_V: give both or neither")
        if self.ocv_soc is not None and self.ocv_V is not None:
            check_ocv_table(self.ocv_soc, self.ocv_V, "CellParams")

    @property
    def tau1_s(self) -> float:
        """R1·C1 [s]."""
        return self.R1_ohm * self.C1_F

    @property
    def tau2_s(self) -> float:
        """R2·C2 [s]."""
        return self.R2_ohm * self.C2_F


def check_ocv_table(soc: Sequence[Any], ocv_V: Sequence[Any], where: str) -> None:
    """An OCV table: ≥ 4 points, SOC strictly increasing from 0 to 1, OCV finite, > 0 [V] and never falling with SOC
    (rising from SOC 0 to 1); ParameterError
    '<where>.ocv_soc …' otherwise."""
    s = [float(x) for x in soc]
    v = [float(x) for x in ocv_V]
    if len(s) != len(v) or len(s) < 4:
        raise ParameterError(
            f"{where}.ocv_soc / ocv_V: need the same number of points (at least 4), got {len(s)} and {len(v)}"
        )
    if not all(math.isfinite(x) for x in s + v) or any(b <= a for a, b in zip(s, s[1:])):
        raise ParameterError(f"{where}.ocv_soc = {s!r:.80} is not allowed: must be finite and strictly increasing")
    if s[0] != 0.0 or s[-1] != 1.0:
        raise ParameterError(f"{where}.ocv_soc is not allowed: must run from 0 to 1, got {s[0]:g} … {s[-1]:g}")
    if any(x <= 0 for x in v):
        raise ParameterError(f"{where}.ocv_V is not allowed: every voltage must be > 0 V")
    fall = next((i for i in range(1, len(v)) if v[i] < v[i - 1]), None)
    if fall is not None or v[-1] <= v[0]:  # a cell's OCV rises with its charge (flat plateaus allowed, never falls)
        at = (
            f"it falls from {v[fall - 1]:g} V to {v[fall]:g} V between SOC {s[fall - 1]:g} and {s[fall]:g}"
            if fall
            else (f"it does not rise ({v[0]:g} V at SOC 0, {v[-1]:g} V at SOC 1)")
        )
        raise ParameterError(
            f"{where}.ocv_V is not allowed: must not decrease with SOC and must end above its start (the open-circuit "
            f"voltage of a cell rises as it charges); {at}"
        )


#: Molar gas constant [J/(mol K)] (CODATA 2018, exact).
R_GAS_JPMOLK = 8.314462618


#: Highest temperature a pack, its ambient or its limit may have [K]: lithium-ion cells go into thermal runaway
#: at 400-500 K (Feng et al. 2018, Energy Storage Materials 10:246-267); 1000 K is far beyond any of them.
MAX_TEMPERATURE_K = 1000.0


@dataclass(frozen=True)
class ThermalParams:
    """Lumped thermal model of the pack (one temperature node per vehicle's pack), SI units.

    C_pack dT/dt = Q_irr_pack − hA (T − T_amb) − P_cool with C_pack = n_cells · cell.heat_capacity_JpK and
    hA = n_cells · h · cell.surface_area_m2 (:mod:`aev_ocp.models.thermal`). ``enabled = False`` (default):
    no temperature state; every run is exactly the model without it.
    """

    enabled: bool = spec(False, kind="bool")  # off by default: the paper's model has no temperature
    ambient_K: float = spec(298.15, gt=0)  # 25 °C: the temperature of the cell tables (T_ref_K); below T_max_K
    T0_K: float | None = spec(
        None, gt=0, le=MAX_TEMPERATURE_K, optional=True
    )  # initial pack temperature; None: ambient
    h_Wpm2K: float = spec(51.0, gt=0)  # forced air: Lin et al. 2014 measured R_u = 3.08 K/W for an A123 26650
    # in their fan-cooled fixture, i.e. h = 1/(R_u A) = 1/(3.08 × 6.37e-3 m²) ≈ 51 W/(m² K)
    cooling_power_W: float = spec(0.0, ge=0)  # extra heat removed from the pack [W] (active cooling); 0: none
    T_max_K: float = spec(328.15, gt=0, le=MAX_TEMPERATURE_K)  # A123 ANR26650M1-B datasheet: discharge limit 55 °C

    def __post_init__(self) -> None:
        validate_fields(self)
        if not self.T_max_K > self.ambient_K:  # a limit the pack exceeds at rest, before it moves
            raise ParameterError(
                f"ThermalParams.T_max_K = {echo(self.T_max_K)} is not allowed: must be a finite number in "
                f"({self.ambient_K:g}, {MAX_TEMPERATURE_K:g}] K (above ambient_K = {self.ambient_K:g} K)"
            )

    @property
    def initial_K(self) -> float:
        """T(0) [K]: T0_K, or the ambient."""
        return self.ambient_K if self.T0_K is None else self.T0_K


@dataclass(frozen=True)
class PackParams:
    """Pack of n_series × n_parallel identical cells (model guide §5: 106s70p ≈ 350 V, 161 Ah, 56 kWh,
    chosen to mirror the 2022 Model 3 RWD LFP pack)."""

    n_series: int = spec(106, kind="integer", ge=1)  # model guide §5
    n_parallel: int = spec(70, kind="integer", ge=1)  # model guide §5

    def __post_init__(self) -> None:
        validate_fields(self)

    @property
    def n_cells(self) -> int:
        """Number of cells N_s·N_p."""
        return self.n_series * self.n_parallel


@dataclass(frozen=True)
class PowertrainOptions:
    """How optimisers smooth the eta switch (model guide §7).

    smoothing_width_W: width w of sigma = ½(1 + tanh(P_w / w)) [W] (default 300 W, model guide §7).
    """

    smoothing_width_W: float = spec(300.0, gt=0)  # model guide §7

    def __post_init__(self) -> None:
        validate_fields(self)


#: τ [s] of the actuator when a jerk limit is set with lag_s = 0: the realised acceleration follows the command
#: at the jerk limit and, near it, within jerk_max·τ (0.05 m/s² at 2.5 m/s³); 0.02 s is well below the
#: 0.1–0.5 s of real brake and drive actuators, so it only makes the rate limiter a well-posed ODE.
JERK_ONLY_LAG_S = 0.02


#: the slowest command filter [s] and the smallest non-zero command jerk limit [m/s^3] a vehicle may declare:
#: production ACCs filter their commands over 0.1–0.5 s and limit jerk to 2.5–5 m/s^3 (ISO 15622, ISO 22179;
#: aev_ocp.loop.PRODUCTION_ACC); 10x slower / 25x lower than those still lets a command act within a run, beyond
#: that the controller is silently ignored (a 1e300 s filter, a 1e-300 m/s^3 jerk limit ran with status ok).
MAX_COMMAND_FILTER_S = 5.0
MIN_COMMAND_JERK_MPS3 = 0.1


@dataclass(frozen=True)
class VehicleLimits:
    """The physical limits of one vehicle's longitudinal motion, SI units, declared once and enforced by the
    plant for every controller (closed-form laws, the MPC, replayed sequences, a user's own).

    The commanded acceleration a_cmd is saturated to [a_min, a_max]; with ``lag_s`` > 0 the realised acceleration
    follows it through a first-order actuator lag (da/dt = (a_cmd − a)/τ), its rate bounded by ``jerk_max_mps3``
    when that is set; the speed never exceeds ``v_max_mps`` (the acceleration is cut to ≤ 0 there).
    ``enabled = False`` switches every limit off: the paper's unbounded laws (its reproduction states this).
    """

    a_min_mps2: float = spec(-8.0, lt=0)  # tyre-road friction on dry asphalt, mu ~ 0.8: 0.8 g = 7.85 m/s^2 (emergency
    # braking; Euro NCAP AEB tests reach 8-10 m/s^2 on their dry test tracks)
    a_max_mps2: float = spec(4.0, gt=0)  # ISO 22179 (full-speed-range ACC): at most 4 m/s^2 at low speed
    jerk_max_mps3: float | None = spec(None, gt=0, optional=True)  # None: no jerk limit (ISO 22179: 2.5 m/s^3
    # averaged over 1 s for comfort, a choice left to the scenario)
    lag_s: float = spec(0.0, ge=0)  # first-order actuator lag tau [s]; 0: ideal actuator (the paper's model)
    v_max_mps: float = spec(62.5, gt=0)  # 2022 Tesla Model 3 RWD top speed, 225 km/h (manufacturer's data)
    enabled: bool = spec(True, kind="bool")  # False: no limit at all (the paper's laws; stated by its scenarios)
    # The closed loop's command stages (aev_ocp.loop), between every sampled controller and the actuator: a
    # first-order command filter (time constant [s]) and a jerk limit on the commands (|Δa|/dt [m/s^3]), and
    # the braking-distance safety layer. None: the default (a production ACC's conditioning, PRODUCTION_ACC, for
    # car-following laws under realistic sensors; off otherwise); 0 / False: off. The paper's runs leave them off.
    # Upper bound of the filter: MAX_COMMAND_FILTER_S (a slower filter ignores the controller); a jerk limit is 0
    # (off) or at least MIN_COMMAND_JERK_MPS3 (below, the command cannot change in any run's horizon).
    command_filter_s: float | None = spec(None, ge=0, le=MAX_COMMAND_FILTER_S, optional=True)
    command_jerk_max_mps3: float | None = spec(None, ge=0, optional=True)
    safety_layer: bool = spec(False, kind="bool")  # min(command, braking-distance bound) on every sampled command

    def __post_init__(self) -> None:
        validate_fields(self)
        j = self.command_jerk_max_mps3
        if j is not None and 0 < j < MIN_COMMAND_JERK_MPS3:
            raise ParameterError(
                f"VehicleLimits.command_jerk_max_mps3 = {j!r} is not allowed: must be 0 (off) or a finite number "
                f">= {MIN_COMMAND_JERK_MPS3:g}"
            )

    @property
    def actuator_tau_s(self) -> float:
        """τ of the actuator [s]: ``lag_s``, or :data:`JERK_ONLY_LAG_S` when only a jerk limit is set (a rate
        limiter needs a state that follows the command; the small lag makes that state well defined)."""
        return self.lag_s if self.lag_s > 0 else JERK_ONLY_LAG_S

    @property
    def has_actuator_state(self) -> bool:
        """True when the realised acceleration is a state of the plant (a lag or a jerk limit is set)."""
        return self.enabled and (self.lag_s > 0 or self.jerk_max_mps3 is not None)

    def accel_bounds_model(self, units: "Units") -> tuple[float, float]:
        """(a_min, a_max) in model acceleration units (±inf when the limits are off)."""
        if not self.enabled:
            return -math.inf, math.inf
        return float(units.accel_from_si(self.a_min_mps2)), float(units.accel_from_si(self.a_max_mps2))


#: The paper's laws as printed: no physical limit (Table 1, Fig. 1-5 and §9's canonical MPC state this).
UNLIMITED = VehicleLimits(enabled=False)

#: (a_min, a_max) [model acceleration] of the paper's canonical MPC (model guide §9: −3 ≤ a ≤ 2), the bounds of a
#: controller on a vehicle without limits (UNLIMITED); −7.5 and 5 m/s² at the default units (L = 10 m, U = 5 m/s).
PAPER_ACCEL_BOUNDS_MODEL = (-3.0, 2.0)


@dataclass(frozen=True)
class EVParams:
    """Everything one vehicle needs besides its controller: units, vehicle, cell, pack, physical limits."""

    units: Units = field(default_factory=Units)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    cell: CellParams = field(default_factory=CellParams)
    pack: PackParams = field(default_factory=PackParams)
    limits: VehicleLimits = field(default_factory=VehicleLimits)
    thermal: ThermalParams = field(default_factory=ThermalParams)

    def __post_init__(self) -> None:
        for name, cls in (("units", Units), ("vehicle", VehicleParams), ("cell", CellParams), ("pack", PackParams)):
            check_argument("EVParams", name, getattr(self, name), cls)
        check_argument("EVParams", "limits", self.limits, VehicleLimits)
        check_argument("EVParams", "thermal", self.thermal, ThermalParams)
        # the rules between tables: a constant cooling power above hA·T_amb would drive the pack's steady state
        # T_amb − P_cool/hA (no heat from the cells, aev_ocp.models.thermal) below 0 K
        th, cell, pack = self.thermal, self.cell, self.pack
        hA = pack.n_cells * th.h_Wpm2K * cell.surface_area_m2  # as aev_ocp.models.thermal.conductance_WpK
        cap = hA * th.ambient_K
        if not th.cooling_power_W < cap:
            raise ParameterError(
                f"ThermalParams.cooling_power_W = {echo(th.cooling_power_W)} is not allowed: must be a finite number "
                f"in [0, {cap:.6g}) W (hA x ambient_K = {hA:.6g} W/K x {th.ambient_K:g} K for this pack: more "
                "cooling would drive the pack below 0 K)"
            )


def as_dict(obj: Any) -> dict[str, Any]:
    """Plain dict of a parameter dataclass (nested dataclasses become dicts)."""
    out: dict[str, Any] = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        out[f.name] = as_dict(v) if hasattr(v, "__dataclass_fields__") else v
    return out


METHODS = ("auto", "cascade", "cvodes")  # simulation integrators (aev_ocp.simulate)


#: Tolerances the integrators can honour (CVODES and the cascade's Dormand–Prince 5(4)). Below
#: rtol = 1e-14 the requested relative error is within ~50 ulp of double precision (2.2e-16), so the
#: error test cannot pass and the step size underflows (rtol = atol = 1e-30 crashed the cascade).
#: atol is an absolute error on states of order 1e-3 … 1e3 (V1, V2 [V], S, h, v, ∫Q [J]); 1e-16 is below
#: every state's resolution. Both corners (1e-14, 1e-16) run Table 1 to the converged ω. The loose ends
#: run but are for quick looks only: rtol = atol = 1e-2 gives ω of follower 1 = 2.36 (cascade) and
#: 1.72 (CVODES) against the converged 1.764 (measured on Table 1, proposed law).
RTOL_RANGE = (1e-14, 1e-2)
ATOL_RANGE = (1e-16, 1.0)


@dataclass(frozen=True)
class SimOptions:
    """Integration settings. dt_out: largest sample spacing [model time]; rtol/atol: relative and
    absolute tolerances (ranges RTOL_RANGE, ATOL_RANGE); chunk: nominal length between event checks of
    the CVODES path [model time]; max_num_steps: step limit (per chunk for CVODES, per vehicle for the
    cascade); method: "cascade" (compiled vehicle-by-vehicle Dormand–Prince 5(4), needs a C compiler),
    "cvodes" (the whole platoon in one CVODES integrator) or "auto" (cascade when a compiler
    works, else CVODES)."""

    dt_out: float = spec(0.01, gt=0)  # 100 samples per model time unit: resolves the paper's 3.2π forcing
    rtol: float = spec(1e-10, ge=RTOL_RANGE[0], le=RTOL_RANGE[1])  # converged Table 1 (README tolerance study)
    atol: float = spec(1e-10, ge=ATOL_RANGE[0], le=ATOL_RANGE[1])  # as rtol
    chunk: float = spec(5.0, gt=0)
    max_num_steps: int = spec(200_000, kind="integer", ge=1)
    method: str = spec("auto", kind="choice", choices=METHODS)

    def __post_init__(self) -> None:
        validate_fields(self)
