"""Plant ≠ model: the controller's (and estimator's) model of a vehicle differs from the plant by declared
amounts, fixed or drawn from a seeded distribution.

The plant is the scenario's :class:`~aev_ocp.params.EVParams` (every controller drives the same plant, so laws and
MPC stay comparable); the model of follower i is the plant with each parameter p scaled by (1 + δ_p,i): δ = the
declared relative error ('fixed'), δ ~ U(−e, e) ('uniform') or δ ~ N(0, e²) clipped to ±3e ('normal'), seeded
per vehicle. ``ocv_offset_V`` is an additive error of the estimator's OCV curve [V per cell].
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..params import EVParams, ParameterError, as_dict, spec, validate_fields

#: relative-error field -> (EVParams part, parameter)
PARAMETERS: dict[str, tuple[str, str]] = {
    "mass_rel": ("vehicle", "mass_kg"),
    "drag_rel": ("vehicle", "drag_coefficient"),
    "rolling_rel": ("vehicle", "rolling_coefficient"),
    "efficiency_rel": ("vehicle", "efficiency"),
    "R0_rel": ("cell", "R_s_ohm"),
    "R1_rel": ("cell", "R1_ohm"),
    "R2_rel": ("cell", "R2_ohm"),
    "C1_rel": ("cell", "C1_F"),
    "C2_rel": ("cell", "C2_F"),
    "capacity_rel": ("cell", "capacity_Ah"),
}


@dataclass(frozen=True)
class Mismatch:
    """Relative errors of the model against the plant (0.1 = +10 %); see the module docstring. All default to 0
    (the model is exact, as before this option existed)."""

    mass_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    drag_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    rolling_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    efficiency_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    R0_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    R1_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    R2_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    C1_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    C2_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    capacity_rel: float = spec(0.0, gt=-0.9, lt=9.0)
    ocv_offset_V: float = spec(0.0, gt=-0.5, lt=0.5)  # per cell
    distribution: str = spec("fixed", kind="choice", choices=("fixed", "uniform", "normal"))
    seed: int = spec(0, kind="integer", ge=0)

    def __post_init__(self) -> None:
        validate_fields(self)

    @staticmethod
    def spread(
        mass_rel: float = 0.0,
        resistance_rel: float = 0.0,
        seed: int = 0,
        distribution: str = "uniform",
        capacitance_rel: float = 0.0,
        capacity_rel: float = 0.0,
        ocv_offset_V: float = 0.0,
    ) -> "Mismatch":
        """A seeded spread: ±``mass_rel`` on the mass, ±``resistance_rel`` on the driving resistances (drag,
        rolling) and on the cell's R0, R1, R2, ±``capacitance_rel`` on C1 and C2, ±``capacity_rel`` on the
        capacity, ±``ocv_offset_V`` [V per cell] on the OCV."""
        r = resistance_rel
        return Mismatch(
            mass_rel=mass_rel,
            drag_rel=r,
            rolling_rel=r,
            R0_rel=r,
            R1_rel=r,
            R2_rel=r,
            C1_rel=capacitance_rel,
            C2_rel=capacitance_rel,
            capacity_rel=capacity_rel,
            ocv_offset_V=ocv_offset_V,
            distribution=distribution,
            seed=seed,
        )

    @property
    def active(self) -> bool:
        """True when any error is declared."""
        return any(getattr(self, k) for k in PARAMETERS) or self.ocv_offset_V != 0.0

    def draws(self, vehicle: int) -> dict[str, float]:
        """The relative errors δ (and the OCV offset [V]) of follower ``vehicle`` (0-based)."""
        rng = np.random.default_rng([self.seed, vehicle])
        out: dict[str, float] = {}
        for k in (*PARAMETERS, "ocv_offset_V"):
            e = float(getattr(self, k))
            u = float(rng.uniform(-1.0, 1.0)), float(rng.standard_normal())  # drawn always: stable streams
            out[k] = (
                e
                if self.distribution == "fixed"
                else e * u[0]
                if self.distribution == "uniform"
                else e * float(np.clip(u[1], -3.0, 3.0))
            )
        return out

    def model_ev(self, plant: EVParams, vehicle: int) -> EVParams:
        """The model of follower ``vehicle``: ``plant`` with its parameters scaled by (1 + δ)."""
        d = self.draws(vehicle)
        parts: dict[str, dict[str, Any]] = {"vehicle": {}, "cell": {}}
        for k, (part, name) in PARAMETERS.items():
            parts[part][name] = getattr(getattr(plant, part), name) * (1.0 + d[k])
        eff = parts["vehicle"]["efficiency"]
        if eff > 1.0:
            raise ParameterError(
                f"mismatch: efficiency_rel = {d['efficiency_rel']:.4g} for vehicle {vehicle + 1} "
                f"gives a model efficiency {eff:.4g} > 1; declare a smaller error"
            )
        return replace(
            plant, vehicle=replace(plant.vehicle, **parts["vehicle"]), cell=replace(plant.cell, **parts["cell"])
        )

    def describe(self, plant: EVParams, n: int) -> dict[str, Any]:
        """Both sets for results: the declaration, the plant and each follower's model and its drawn errors."""
        return {
            "declared": as_dict(self),
            "plant": as_dict(plant),
            "models": [
                {"vehicle": i + 1, "errors": self.draws(i), "ev": as_dict(self.model_ev(plant, i))} for i in range(n)
            ],
        }
