"""Saving and loading ring runs (``aev-ocp ring``: the experiments and a ring scenario file's runs; manifest kind
``ring``).

The folder holds ``ring.json`` (the fleet metrics of every run, SI, and the experiment's settings),
``trajectories.npz`` (per run ``runNNN/``: the :class:`~aev_ocp.results.SimulationResult` arrays as
:mod:`aev_ocp.saved` writes them, plus ``distance`` and ``energy_J``) and ``manifest.json`` (per run its label,
the ring's geometry, which vehicles are human, the controllers' names and the initial state). A loaded run is a
:class:`~aev_ocp.ring.simulate.RingResult` whose vehicles are :class:`SavedVehicle` records (their names; a loaded
ring is read, not run again).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..results import FieldsRepr, fmt_value, write_json
from ..saved import (
    LoadError,
    MANIFEST,
    read_arrays,
    read_document,
    save_output,
    sim_record,
    sim_result,
    stored_samples,
)
from .run import RingExperiment
from .simulate import RingInitial, RingResult, RingRoad

RING_FILE = "ring.json"
FILES = (RING_FILE, MANIFEST, "trajectories.npz")


@dataclass(frozen=True)
class SavedVehicle:
    """A vehicle of a loaded ring: the name of the controller it had (the Controller protocol's shape, so the
    ring holds it; calling it is an error: a loaded run is read, not run again)."""

    name: str
    dt: float = float("nan")

    def reset(self) -> None:
        """Nothing to forget."""

    def command(self, obs: Any) -> Any:
        """Refused: a loaded ring's controllers are names only."""
        raise LoadError(f"vehicle {self.name!r} of a loaded ring is a saved record; rerun the command to simulate")

    def describe(self) -> dict[str, Any]:
        """The controller's name."""
        return {"name": self.name, "saved": True}


@dataclass(repr=False)
class RingOutput(FieldsRepr):
    """What ``aev-ocp ring`` wrote, loaded back: the ring.json document (settings and fleet metrics), the runs
    (label, :class:`RingResult`, fleet metrics as saved) and the folder."""

    folder: Path
    document: dict[str, Any]
    runs: list[RingExperiment] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def run(self, label: str) -> RingResult:
        """The RingResult of the run labelled ``label``; LoadError listing the labels otherwise."""
        for r in self.runs:
            if r.label == label:
                return r.result
        raise LoadError(f"{self.folder}: no run {label!r} in this output; its runs are {[r.label for r in self.runs]}")

    def plot(self, t_from_s: float = 0.0) -> Any:
        """The space-time diagrams of every run side by side (:func:`aev_ocp.ring.plots.space_time_panels`):
        a matplotlib Figure."""
        from .plots import space_time_panels

        if not self.runs:
            raise ValueError(f"RingOutput.plot: {self.folder} holds no run trajectories to draw")
        return space_time_panels([(r.label, r.result) for r in self.runs], t_from_s=t_from_s)

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        return (
            f"RingOutput: {self.document.get('experiment')}, {len(self.runs)} runs",
            [
                (r.label, f"status {r.fleet.get('status')}, speed std {fmt_value(r.fleet.get('speed_std_mps'))} m/s")
                for r in self.runs
            ],
        )


def _ring_record(
    i: int, run: RingExperiment, arrays: dict[str, np.ndarray], max_samples: int | None = None
) -> dict[str, Any]:
    res, ring = run.result, run.result.ring
    key = f"run{i:03d}"
    rec = sim_record(key, res.sim, arrays, max_samples)
    keep = stored_samples(np.asarray(res.sim.t).shape[0], max_samples)  # the same samples as the run's arrays
    for name, v in (("distance", res.distance), ("energy_J", res.energy_J)):
        a = np.asarray(v, float)
        arrays[f"{key}/{name}"] = a if keep is None else a[keep]
    return {
        "key": key,
        "label": run.label,
        "fleet": run.fleet,
        "sim": rec,
        "ring": {
            "length_m": ring.length_m,
            "vehicle_length_m": ring.vehicle_length_m,
            "human": [ring.is_human(i) for i in range(ring.n)],
            "vehicles": [str(getattr(v, "name", type(v).__name__)) for v in ring.vehicles],
            "noise_mps2": ring.noise_mps2,
            "noise_dt_s": ring.noise_dt_s,
            "seed": ring.seed,
        },
        "initial": {
            "positions_m": list(res.initial.positions_m),
            "speeds_mps": list(res.initial.speeds_mps),
            "soc0": res.initial.soc0,
            "perturbation": res.initial.perturbation,
        },
        "wall_s": res.wall_s,
        "stats": res.stats,
    }


def save_ring_output(
    out: str | Path, runs: Sequence[RingExperiment], document: dict[str, Any], max_samples: int | None = None
) -> list[Path]:
    """Write ring.json (``document`` with every run's label and fleet metrics under ``runs``), the runs'
    trajectories and the manifest into ``out``; returns the paths (ring.json first). ``max_samples``: store at
    most about that many samples of each run (every k-th and the last; the manifest's run record says so), for
    figures; the fleet metrics in ring.json are the run's own, from every sample. None: every sample."""
    out = Path(out)
    doc = dict(document)
    doc["runs"] = [{"label": r.label, **r.fleet} for r in runs]
    files = [write_json(out / RING_FILE, doc)]
    arrays: dict[str, np.ndarray] = {}
    records = [_ring_record(i, r, arrays, max_samples) for i, r in enumerate(runs)]
    files += save_output(out, "ring", {}, document=RING_FILE, arrays=arrays, extra={"ring_runs": records})
    return files


def _loaded_run(rec: dict[str, Any], arrays: dict[str, np.ndarray]) -> RingExperiment:
    key = rec["key"]
    sim = sim_result(key, rec["sim"], arrays)
    g = rec["ring"]
    ring = RingRoad(
        float(g["length_m"]),
        tuple(SavedVehicle(str(n)) for n in g["vehicles"]),
        vehicle_length_m=float(g["vehicle_length_m"]),
        ev=sim.ev,
        human=tuple(bool(h) for h in g["human"]),
        noise_mps2=float(g["noise_mps2"]),
        noise_dt_s=float(g["noise_dt_s"]),
        seed=int(g["seed"]),
    )
    ini = rec["initial"]
    initial = RingInitial(
        tuple(float(x) for x in ini["positions_m"]),
        tuple(float(x) for x in ini["speeds_mps"]),
        None if ini["soc0"] is None else float(ini["soc0"]),
        str(ini["perturbation"]),
    )
    distance, energy = arrays[f"{key}/distance"], arrays[f"{key}/energy_J"]
    if distance.shape != sim.gap.shape or energy.shape != sim.gap.shape:
        raise ValueError(f"run {key}: distance {distance.shape} and energy_J {energy.shape} must be {sim.gap.shape}")
    res = RingResult(ring, initial, sim, distance, energy, float(rec["wall_s"]), dict(rec["stats"] or {}))
    return RingExperiment(str(rec["label"]), res, dict(rec["fleet"]))


def load_ring_output(m: dict[str, Any], folder: Path) -> RingOutput:
    """The :class:`RingOutput` of a ring folder from its manifest (used by :func:`aev_ocp.load`)."""
    doc = read_document(m, folder)
    records = m.get("ring_runs")
    if not isinstance(records, list):
        raise LoadError(f"{folder / MANIFEST}: field 'ring_runs' = {str(records)[:60]!r} is not a list of runs")
    arrays = read_arrays(m, folder)
    runs = []
    for k, rec in enumerate(records):
        try:
            runs.append(_loaded_run(rec, arrays))
        except (KeyError, TypeError, ValueError) as exc:
            raise LoadError(
                f"{folder / MANIFEST}: field 'ring_runs' entry {k} is incomplete or damaged ({type(exc).__name__}: "
                f"{str(exc)[:200]})"
            ) from None
    meta = {"output": {"path": str(folder), "kind": "ring", "provenance": m.get("provenance")}}
    return RingOutput(folder, doc, runs, meta)
