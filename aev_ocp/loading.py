"""``aev_ocp.load(folder)``: every command's output folder back as the object it was made from.

The manifest's ``kind`` (:data:`aev_ocp.saved.KINDS`) picks the loader: the run kinds (simulate, mpc, ocp) and
studies are read by :mod:`aev_ocp.saved`; ring runs and experiments, the safety suite, the stability analyses and
SUMO fleet runs by their package's ``outputs`` module. Every loaded object has ``.plot()`` returning a matplotlib
Figure where its package draws one (ring, safety, stability, SUMO).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .saved import LoadError, _damaged, read_manifest
from .saved import load as load_run


def load(path: str | Path, run: str | None = None) -> Any:
    """Load what a command saved: ``path`` is its output folder (or the folder's manifest.json).

    Returns, by the manifest's kind: simulate, mpc → :class:`~aev_ocp.results.SimulationResult`; ocp →
    :class:`~aev_ocp.ocp_result.OCPResult`; study → :class:`~aev_ocp.saved.StudyOutput`; ring →
    :class:`~aev_ocp.ring.outputs.RingOutput` (``run=`` a run's label: its RingResult); safety →
    :class:`~aev_ocp.safety.run.SuiteOutput`; stability, ring_stability, mixed_ring_stability →
    :class:`~aev_ocp.stability.outputs.StabilityOutput`; sumo → :class:`~aev_ocp.sumo.run.SumoRun` (``run=`` a
    vehicle's SUMO id: its SimulationResult). ``run`` picks one labelled run of the run kinds (see
    :func:`aev_ocp.saved.load`). Raises :class:`~aev_ocp.saved.LoadError` naming the file (and the manifest field)
    for a path that is not an aev_ocp output, a damaged one or a newer format.
    """
    return _damaged(path, lambda: _load(path, run))


def _load(path: str | Path, run: str | None) -> Any:
    m, folder = read_manifest(path)
    kind = m["kind"]
    if kind == "ring":
        from .ring.outputs import load_ring_output

        out = load_ring_output(m, folder)
        return out if run is None else out.run(run)
    if kind == "safety":
        _no_run(run, kind, folder)
        from .safety.outputs import load_suite_output

        return load_suite_output(m, folder)
    if kind in ("stability", "ring_stability", "mixed_ring_stability"):
        _no_run(run, kind, folder)
        from .stability.outputs import load_stability_output

        return load_stability_output(m, folder)
    if kind == "sumo" and run is None:
        from .sumo.outputs import load_sumo

        return load_sumo(folder)
    return load_run(path, run)


def _no_run(run: str | None, kind: str, folder: Path) -> None:
    if run is not None:
        raise LoadError(f"{folder}: run = {run!r}: a {kind} output has no labelled runs to pick; load it without run")
