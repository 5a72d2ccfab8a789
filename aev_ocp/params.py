"""Parameter sets: frozen dataclasses with SI units in the field names and the source of each default.

Every numeric default cites where it comes from (``../shared/PROBLEM.md`` is the project's problem
card; section numbers below refer to it). Validation happens in ``__post_init__`` and raises
:class:`ParameterError`, whose message names the field, the value and what is allowed.

The car-following model is dimensionless (the paper's units). :class:`Units` is the one place
that converts model units to SI and back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any


class ParameterError(ValueError):
    """A parameter is out of its allowed range; the message names the field and the value."""


def _check(cls_name: str, name: str, value: Any, ok: bool, allowed: str) -> None:
    if not ok:
        raise ParameterError(f"{cls_name}.{name} = {value!r} is not allowed: must be {allowed}")


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _positive(obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(type(obj).__name__, n, v, _finite(v) and v > 0, "a finite number > 0")


def _nonnegative(obj: Any, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        _check(type(obj).__name__, n, v, _finite(v) and v >= 0, "a finite number >= 0")


@dataclass(frozen=True)
class Units:
    """Scaling between the paper's dimensionless car-following units and SI (PROBLEM.md §1).

    length_m: length unit L [m]; speed_mps: speed unit U [m/s]. Time unit T = L/U [s],
    acceleration unit U²/L [m/s²].
    """

    length_m: float = 10.0  # PROBLEM.md §1 default L = 10 m
    speed_mps: float = 5.0  # PROBLEM.md §1 default U = 5 m/s (paper's v_l = 1.7 -> 8.5 m/s)

    def __post_init__(self) -> None:
        _positive(self, "length_m", "speed_mps")

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
        """Model energy per unit mass (speed × acceleration × time = U²) -> J/kg."""
        return omega * self.speed_mps**2


@dataclass(frozen=True)
class CarFollowingParams:
    """Coefficients of OVM / OVFL / the proposed law (paper eq. main_dynamics; PROBLEM.md §2).

    alpha: relaxation rate to V(h) [1/model time]; beta: follow-the-leader gain
    [model length²/model time]; kappa: weight of the deceleration term [1/model length];
    eps: smoothing of the term [model speed²].
    """

    alpha: float = 2.0  # paper Fig. 1-2 captions, Table 1 setup
    beta: float = 3.0  # paper Fig. 1-2 captions
    kappa: float = 0.03  # paper Fig. 1-2 captions
    eps: float = 1e-6  # paper §2 ("e.g. 10^-6")

    def __post_init__(self) -> None:
        _nonnegative(self, "alpha", "beta", "kappa")
        _positive(self, "eps")


@dataclass(frozen=True)
class VehicleParams:
    """Longitudinal vehicle and powertrain parameters (PROBLEM.md §5), SI units.

    Defaults: 2022 Tesla Model 3 RWD (LFP), NREL FASTSim vehicle file; eta is the paper's.
    """

    mass_kg: float = 1752.0  # FASTSim 2022 Tesla Model 3 RWD
    frontal_area_m2: float = 2.22  # FASTSim 2022 Tesla Model 3 RWD
    drag_coefficient: float = 0.23  # FASTSim 2022 Tesla Model 3 RWD
    rolling_coefficient: float = 0.007  # FASTSim 2022 Tesla Model 3 RWD
    air_density_kgpm3: float = 1.225  # ISA sea level
    gravity_mps2: float = 9.81  # paper §3.3
    grade_rad: float = 0.0  # flat road (PROBLEM.md §5)
    efficiency: float = 0.8  # paper eq. g_function / Table 1 (eta = 80 %)
    aux_power_W: float = 0.0  # PROBLEM.md §5 (P_aux = 0 by default)

    def __post_init__(self) -> None:
        _positive(self, "mass_kg", "frontal_area_m2", "air_density_kgpm3", "gravity_mps2")
        _nonnegative(self, "drag_coefficient", "rolling_coefficient", "aux_power_W")
        _check("VehicleParams", "efficiency", self.efficiency,
               _finite(self.efficiency) and 0 < self.efficiency <= 1, "in (0, 1]")
        _check("VehicleParams", "grade_rad", self.grade_rad,
               _finite(self.grade_rad) and abs(self.grade_rad) < math.pi / 2, "in (-pi/2, pi/2)")


@dataclass(frozen=True)
class CellParams:
    """2-RC equivalent-circuit cell (paper §3; PROBLEM.md §6), SI units. I > 0 discharges.

    Defaults: A123 ANR26650 LFP at 25 °C.
    """

    capacity_Ah: float = 2.3  # A123 ANR26650 datasheet, nominal capacity
    R_s_ohm: float = 0.010  # A123 enhanced self-correcting model at 25 °C: R0 = 9.95 mΩ
    R1_ohm: float = 0.0085  # same model: R1 = 8.45 mΩ
    C1_F: float = 460.0  # same model: tau1 = 3.92 s -> C1 = tau1/R1 ≈ 460 F
    R2_ohm: float = 0.010  # representative, inside Lin et al. 2014 range R2 = 5-45 mΩ (not fitted)
    C2_F: float = 10_000.0  # representative, Lin et al. 2014: C2 tens of kF (tau2 = 100 s; not fitted)
    soc0: float = 0.8  # PROBLEM.md §6: S(0) = 0.8
    max_current_A: float = 46.0  # PROBLEM.md §8: 20C = 20 × 2.3 A

    def __post_init__(self) -> None:
        _positive(self, "capacity_Ah", "R_s_ohm", "R1_ohm", "C1_F", "R2_ohm", "C2_F", "max_current_A")
        _check("CellParams", "soc0", self.soc0, _finite(self.soc0) and 0 <= self.soc0 <= 1, "in [0, 1]")

    @property
    def tau1_s(self) -> float:
        """R1·C1 [s]."""
        return self.R1_ohm * self.C1_F

    @property
    def tau2_s(self) -> float:
        """R2·C2 [s]."""
        return self.R2_ohm * self.C2_F


@dataclass(frozen=True)
class PackParams:
    """Pack of n_series × n_parallel identical cells (PROBLEM.md §5: 106s70p ≈ 350 V, 161 Ah, 56 kWh,
    chosen to mirror the 2022 Model 3 RWD LFP pack)."""

    n_series: int = 106  # PROBLEM.md §5
    n_parallel: int = 70  # PROBLEM.md §5

    def __post_init__(self) -> None:
        for n in ("n_series", "n_parallel"):
            v = getattr(self, n)
            _check("PackParams", n, v, isinstance(v, int) and not isinstance(v, bool) and v >= 1,
                   "an integer >= 1")

    @property
    def n_cells(self) -> int:
        """Number of cells N_s·N_p."""
        return self.n_series * self.n_parallel


@dataclass(frozen=True)
class PowertrainOptions:
    """How optimisers smooth the eta switch (PROBLEM.md §7).

    smoothing_width_W: width w of sigma = ½(1 + tanh(P_w / w)) [W] (default 300 W, PROBLEM.md §7).
    """

    smoothing_width_W: float = 300.0  # PROBLEM.md §7

    def __post_init__(self) -> None:
        _positive(self, "smoothing_width_W")


@dataclass(frozen=True)
class EVParams:
    """Everything the battery side of one vehicle needs: units, vehicle, cell, pack."""

    units: Units = field(default_factory=Units)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    cell: CellParams = field(default_factory=CellParams)
    pack: PackParams = field(default_factory=PackParams)


def as_dict(obj: Any) -> dict[str, Any]:
    """Plain dict of a parameter dataclass (nested dataclasses become dicts)."""
    out: dict[str, Any] = {}
    for f in fields(obj):
        v = getattr(obj, f.name)
        out[f.name] = as_dict(v) if hasattr(v, "__dataclass_fields__") else v
    return out


METHODS = ("auto", "cascade", "cvodes")  # simulation integrators (aev_ocp.simulate)


@dataclass(frozen=True)
class SimOptions:
    """Integration settings. dt_out: largest sample spacing [model time]; rtol/atol: relative and
    absolute tolerances; chunk: nominal length between event checks of the CVODES path [model time];
    max_num_steps: step limit (per chunk for CVODES, per vehicle for the cascade);
    method: "cascade" (compiled vehicle-by-vehicle Dormand–Prince 5(4), needs a C compiler),
    "cvodes" (the whole platoon in one CVODES integrator) or "auto" (cascade when a compiler
    works, else CVODES)."""

    dt_out: float = 0.01
    rtol: float = 1e-10
    atol: float = 1e-10
    chunk: float = 5.0
    max_num_steps: int = 200_000
    method: str = "auto"

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ParameterError(f"SimOptions.method = {self.method!r} is not allowed: must be one of {METHODS}")
        for name in ("dt_out", "rtol", "atol", "chunk"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ParameterError(f"SimOptions.{name} = {v!r} is not allowed: must be a finite number > 0")
