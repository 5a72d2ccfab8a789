"""OCPResult: the one result type of every optimal-control solve, with atomic CSV/JSON writers."""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .results import FieldsRepr, require_pandas, to_jsonable, write_atomic, write_json


# one implementation of atomic writes and JSON conversion for the whole package
write_json_atomic = write_json


@dataclass(repr=False)  # the short repr of FieldsRepr, not the dataclass's field dump
class OCPResult(FieldsRepr):
    """Solution of one OCP.

    t: node times (N+1) [time_unit]; states: name -> (N+1) values at the nodes; controls: name -> (N)
    piecewise-constant values on [t_k, t_{k+1}); outputs: name -> (N+1) values at the nodes (the
    last one with the last control held), e.g. cell current ``I`` [A] and heat ``Q`` [W per cell];
    objective: optimal NLP objective (``objective_name`` says what it is); status: short status
    ('optimal', 'acceptable', 'infeasible', 'iteration_limit', 'restoration_failed',
    'constraint_violation', 'solver_error: …'); success: usable solution; message: why;
    max_violation: largest bound/constraint violation of the returned point (NLP scaling);
    wall_time_s: wall time of the solve call [s]; t_colloc: collocation-point times, if any.
    objective_exact: the same objective re-evaluated on the exact (unsmoothed) model along the
    applied piecewise-constant controls (NaN until a problem's check fills it, see
    :mod:`aev_ocp.ocp.checks`); warnings: human-readable warnings (e.g. a smoothing gap with both
    numbers), shown by the CLI and the report.
    """

    problem: str
    method: str
    N: int
    t: np.ndarray
    time_unit: str
    states: dict[str, np.ndarray]
    controls: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]
    objective: float
    objective_name: str
    status: str
    success: bool
    message: str
    solver_status: str
    iterations: int
    wall_time_s: float
    solver_time_s: float
    max_violation: float
    t_colloc: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    objective_exact: float = math.nan
    warnings: list[str] = field(default_factory=list)

    @classmethod
    def failed(
        cls,
        problem: str,
        method: str,
        N: int,
        status: str,
        wall: float,
        t: np.ndarray,
        time_unit: str,
        message: str = "",
    ) -> "OCPResult":
        """A result without a solution (status says why)."""
        return cls(
            problem=problem,
            method=method,
            N=N,
            t=t,
            time_unit=time_unit,
            states={},
            controls={},
            outputs={},
            objective=math.nan,
            objective_name="objective",
            status=status,
            success=False,
            message=message or status,
            solver_status=status,
            iterations=-1,
            wall_time_s=wall,
            solver_time_s=wall,
            max_violation=math.inf,
        )

    @property
    def I(self) -> np.ndarray:
        """Cell current at the nodes [A] (empty if the problem does not report it)."""
        return self.outputs.get("I", np.zeros(0))

    @property
    def Q(self) -> np.ndarray:
        """The paper's heat Q = I(V1+V2) + R_s I² at the nodes [W per cell] (empty if not reported)."""
        return self.outputs.get("Q", np.zeros(0))

    def stats(self) -> dict[str, Any]:
        """Solver statistics as a JSON-ready dict."""
        return {
            "problem": self.problem,
            "method": self.method,
            "N": self.N,
            "status": self.status,
            "success": self.success,
            "message": self.message,
            "solver_status": self.solver_status,
            "iterations": self.iterations,
            "wall_time_s": self.wall_time_s,
            "solver_time_s": self.solver_time_s,
            "max_violation": self.max_violation,
            "objective": self.objective,
            "objective_name": self.objective_name,
            "objective_exact": self.objective_exact,
            "warnings": list(self.warnings),
        }

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        title = f"OCPResult {self.problem} ({self.method}, N = {self.N}): {self.status}"
        t_end = float(self.t[-1]) if self.t.size else math.nan
        fields: list[tuple[str, Any]] = [
            (self.objective_name, self.objective),
            ("iterations", self.iterations),
            ("wall_time_s", self.wall_time_s),
            ("max_violation", self.max_violation),
            (f"horizon [{self.time_unit}]", t_end),
            ("states", ", ".join(self.states) or "-"),
            ("controls", ", ".join(self.controls) or "-"),
            ("outputs", ", ".join(self.outputs) or "-"),
        ]
        if math.isfinite(self.objective_exact):
            fields.insert(1, ("objective on the exact model", self.objective_exact))
        if not self.success:
            fields.append(("message", self.message))
        fields += [("warning", w) for w in self.warnings[:3]]
        return title, fields

    def to_dataframe(self) -> Any:
        """One row per node, the columns of :meth:`to_csv` (SI columns first when the units are known; controls
        held, the last row repeating the last control). Needs pandas (``pip install 'aev_ocp[pandas]'``)."""
        pd = require_pandas("OCPResult.to_dataframe()")
        return pd.read_csv(io.StringIO(self._csv_text()))

    def summary(self) -> dict[str, Any]:
        """Statistics plus the trajectories, JSON-ready."""
        out = self.stats()
        out.update(
            {
                "time_unit": self.time_unit,
                "t": self.t,
                "states": self.states,
                "controls": self.controls,
                "outputs": self.outputs,
                "meta": self.meta,
            }
        )
        return to_jsonable(out)

    def plot(self, names: Sequence[str] | None = None) -> Any:
        """States, controls (steps) and outputs against time, one panel each with its name and unit
        (:func:`aev_ocp.ocp.plots.plot_result`; ``names``: only these quantities): a matplotlib Figure. The figure
        module is imported here, when called (a late edge of the layer table)."""
        from .ocp.plots import plot_result

        return plot_result(self, None, names)

    def to_json(self, path: str | os.PathLike[str]) -> Path:
        """Write :meth:`summary` as JSON, atomically."""
        return write_json_atomic(path, self.summary())

    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """One row per node: t, states, controls (held; last row repeats the last control), outputs.

        A model-unit problem whose ``meta["units"]`` gives length_m and speed_mps leads with SI columns
        (``t_s``, ``h_m``, ``v_mps``, ``a_mps2``); the converted model columns then end in ``_model``.
        Column names are unique: an output that repeats a state or control of the same name (OCP-B's
        current ``I`` is both its control and an output) is left out when its values are the same,
        and written as ``<name>_out`` otherwise."""
        return write_atomic(path, self._csv_text())

    def _csv_text(self) -> str:
        buf = io.StringIO()
        wr = csv.writer(buf)
        names_x, names_u = list(self.states), list(self.controls)
        held = {nm: np.append(u, u[-1:]) if u.size else u for nm, u in self.controls.items()}
        cols_o: list[tuple[str, str]] = []  # (column header, output name)
        for nm, v in self.outputs.items():
            if nm in self.states or nm in held:
                ref = self.states.get(nm, held.get(nm))
                if ref is not None and ref.shape == v.shape and np.allclose(ref, v, rtol=1e-12, atol=0.0):
                    continue
                cols_o.append((f"{nm}_out", nm))
            else:
                cols_o.append((nm, nm))
        # a model-unit problem that states its units (meta["units"]: length_m, speed_mps) leads with SI columns
        # (t_s, h_m, v_mps, a_mps2, ...) and keeps the model columns, with a _model suffix on those converted
        units = self.meta.get("units") if self.time_unit == "model" else None
        si: list[tuple[str, str, str, float]] = []  # (SI header, kind, name, factor)
        if isinstance(units, dict) and {"length_m", "speed_mps"} <= set(units):
            L, U = float(units["length_m"]), float(units["speed_mps"])
            dims = {"h": ("m", L), "v": ("mps", U), "a": ("mps2", U * U / L), "a_prev": ("mps2", U * U / L)}
            si = [
                (f"{nm}_{dims[nm][0]}", kind, nm, dims[nm][1])
                for kind, names in (("x", names_x), ("u", names_u))
                for nm in names
                if nm in dims
            ]
        conv = {nm for _, _, nm, _ in si}
        model = lambda nm: f"{nm}_model" if nm in conv else nm  # noqa: E731
        head = (["t_s"] + [c for c, _, _, _ in si] if si else []) + [f"t_{self.time_unit}"]
        wr.writerow(head + [model(nm) for nm in names_x + names_u] + [c for c, _ in cols_o])
        n = self.t.size
        ctrl = lambda nm, k: self.controls[nm][min(k, self.controls[nm].size - 1)]  # noqa: E731
        for k in range(n):
            row = []
            if si:
                row = [f"{self.t[k] * L / U:.10g}"] + [
                    f"{(self.states[nm][k] if kind == 'x' else ctrl(nm, k)) * f:.12g}" for _, kind, nm, f in si
                ]
            row += [f"{self.t[k]:.10g}"]
            row += [f"{self.states[nm][k]:.12g}" for nm in names_x]
            row += [f"{ctrl(nm, k):.12g}" for nm in names_u]
            row += [f"{self.outputs[nm][k]:.12g}" for _, nm in cols_o]
            wr.writerow(row)
        return buf.getvalue()
