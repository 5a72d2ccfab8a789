"""One result type for every controller (closed-form law, MPC, offline optimum) and atomic writers.

A :class:`SimulationResult` holds sampled trajectories of a platoon (model units unless the name
says otherwise) and the *cumulative* integrals that the metrics of PROBLEM.md §10 need, integrated
by the plant's own quadrature (exact across control jumps, unlike a trapezoid on samples).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .params import EVParams, Units, as_dict

_UMASK = os.umask(0)
os.umask(_UMASK)

EVENT_KINDS = ("collision", "negative_speed", "infeasible_current", "soc_out_of_range", "integration_failed")


def write_atomic(path: str | os.PathLike[str], data: str | bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, then os.replace)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = "wb" if isinstance(data, bytes) else "w"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the file the mode open() would
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def to_jsonable(x: Any) -> Any:
    """numpy arrays/scalars -> lists/floats, non-finite floats -> None, dataclasses -> dicts, recursively."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.floating, float)):
        xf = float(x)
        return xf if math.isfinite(xf) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if hasattr(x, "__dataclass_fields__"):
        return to_jsonable(as_dict(x))
    return x


def write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Atomically write ``obj`` as indented JSON (numpy values converted, non-finite -> null)."""
    return write_atomic(path, json.dumps(to_jsonable(obj), indent=2) + "\n")


@dataclass
class Event:
    """Something the simulation must not integrate through: kind, time [model], vehicle (0-based follower index)."""

    kind: str
    time: float
    vehicle: int
    message: str

    def __str__(self) -> str:
        return f"{self.kind} at t = {self.time:.4f} (vehicle {self.vehicle + 1}): {self.message}"


@dataclass
class SimulationResult:
    """Sampled platoon trajectories. Arrays are (K,) or (K, n) with n followers; model units unless named.

    cumulative integrals (K, n): omega (the paper's ω, model units), heat_J and heat_irr_J (pack ∫Q,
    ∫Q_irr [J]), int_ovm_err2 = ∫(V(h) − v)² dt, int_rel_speed2 = ∫(v_l − v)² dt, int_jerk2 = ∫ jerk² dt.
    """

    t: np.ndarray
    leader_speed: np.ndarray
    leader_position: np.ndarray
    gap: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    V1: np.ndarray
    V2: np.ndarray
    S: np.ndarray
    current_A: np.ndarray
    omega: np.ndarray
    heat_J: np.ndarray
    heat_irr_J: np.ndarray
    int_ovm_err2: np.ndarray
    int_rel_speed2: np.ndarray
    int_jerk2: np.ndarray
    controllers: list[str]
    ev: EVParams = field(default_factory=EVParams)
    events: list[Event] = field(default_factory=list)
    jerk_sampled: bool = False
    solver_stats: list[dict[str, Any] | None] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def status(self) -> str:
        """'ok', or the kind of the first event."""
        return self.events[0].kind if self.events else "ok"

    @property
    def n_vehicles(self) -> int:
        """Number of followers."""
        return int(self.gap.shape[1])

    @property
    def units(self) -> Units:
        """The scenario's units."""
        return self.ev.units

    def positions(self) -> np.ndarray:
        """Follower positions x_n(t) [model length], leader at x_l(0) = 0."""
        return self.leader_position[:, None] - np.cumsum(self.gap, axis=1)

    def metrics(self) -> list[dict[str, Any]]:
        """Per-vehicle metrics of PROBLEM.md §10 (see :mod:`aev_ocp.metrics`)."""
        from .metrics import vehicle_metrics

        return [vehicle_metrics(self, i) for i in range(self.n_vehicles)]

    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """Long-format CSV (one row per time and vehicle), written atomically."""
        buf = io.StringIO()
        w = csv.writer(buf)
        cols = ["gap", "speed", "accel", "V1", "V2", "S", "current_A", "omega", "heat_J", "heat_irr_J"]
        w.writerow(["t", "t_s", "vehicle", "controller", "leader_speed"] + cols)
        T = self.units.time_s
        for i in range(self.n_vehicles):
            arrs = [getattr(self, c)[:, i] for c in cols]
            for k in range(self.t.size):
                w.writerow([f"{self.t[k]:.6g}", f"{self.t[k] * T:.6g}", i + 1, self.controllers[i],
                            f"{self.leader_speed[k]:.10g}"] + [f"{a[k]:.10g}" for a in arrs])
        return write_atomic(path, buf.getvalue())

    def summary(self) -> dict[str, Any]:
        """Status, events, metrics and settings as a JSON-ready dict."""
        return {"status": self.status, "events": [vars(e) for e in self.events],
                "controllers": self.controllers, "metrics": self.metrics(),
                "units": as_dict(self.units), "meta": self.meta}

    def to_json(self, path: str | os.PathLike[str]) -> Path:
        """Metrics and events as JSON, written atomically."""
        return write_json(path, self.summary())
