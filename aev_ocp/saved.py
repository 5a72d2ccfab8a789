"""Saving every run so that it loads back: ``manifest.json`` + ``trajectories.npz`` in the output folder.

Format (``format = "aev_ocp-output"``, ``format_version`` 2; version 1 files load as well):

- ``trajectories.npz``: every array of every run, keyed ``<run label>/<field>`` (SimulationResult:
  ``t``, ``gap``, ``speed`` …; OCPResult: ``t``, ``states/<name>``, ``controls/<name>``,
  ``outputs/<name>`` and its scalars ``objective`` …). NumPy's own format (no pickle, compressed): float64 kept
  bit for bit, NaN and inf included. Since version 2 a float64 array of at least :data:`PACK_MIN_SIZE` numbers is
  stored packed (the manifest's ``packed`` names it, with its shape): its bit patterns as int64, differenced along
  the first (time) axis with wrap-around, split into 8 byte planes (a uint8 array of shape (8, size)); smooth
  trajectories then compress about twice as well, and :func:`unpack_array` restores them bit for bit (so
  the reproduction's output fell from 79 MB to under 60 MB). Version 1 wrote every array as is (``numpy.load`` reads it). A run saved with ``max_samples``
  (reproduce's long drive-cycle runs, kept for their figures) holds every k-th sample and the last; its
  manifest record says ``stored_samples`` of ``samples``, and its ``metrics`` are those of the whole run.
- ``manifest.json``: ``kind`` (:data:`KINDS`), ``primary`` (the run :func:`load` returns),
  per run its type, controllers, events, parameters, solver statistics, meta and metrics as saved;
  ``settings`` (the scenario's TOML document and the command's options) and ``provenance``
  (:mod:`aev_ocp.provenance`); the SHA-256 of the arrays file, checked on load; for the kinds whose numbers
  are a JSON document (ring, safety, stability …) ``document`` (its file name beside the manifest) and
  ``document_sha256``, checked on load as well.

This module reads the run kinds (simulate, mpc, ocp, sumo's vehicles) and studies; :func:`aev_ocp.load`
(:mod:`aev_ocp.loading`) reads every kind, handing the others to their package's ``outputs`` module.

The arrays file is written first and the manifest last, both atomically: a folder with a manifest
always has the arrays it names (a rerun that is interrupted in between is caught by the SHA-256).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import AevOcpError
from .limits import FileRefused, memory_limit_bytes, read_regular_file
from .params import (
    UNLIMITED,
    CellParams,
    EVParams,
    PackParams,
    ThermalParams,
    Units,
    VehicleLimits,
    VehicleParams,
    as_dict,
)
from .results import (
    SIM_ARRAYS,
    Event,
    FieldsRepr,
    SimulationResult,
    atomic_path,
    require_pandas,
    to_jsonable,
    write_json,
)

FORMAT = "aev_ocp-output"
FORMAT_VERSION = 2  # 2: float64 arrays packed (PACK_ENCODING); 1: every array as is
PACK_ENCODING = "int64-delta-byteplanes"  # the one packing :func:`pack_array` writes
PACK_MIN_SIZE = 256  # our choice: smaller arrays (scalars, parameters) stay plain
MANIFEST = "manifest.json"
ARRAYS = "trajectories.npz"
#: Every kind of output a command writes; :mod:`aev_ocp.loading` maps each to the object it loads as.
KINDS = (
    "simulate",
    "mpc",
    "ocp",
    "study",
    "sumo",
    "ring",
    "safety",
    "stability",
    "ring_stability",
    "mixed_ring_stability",
)
DOCUMENT_KINDS = ("ring", "safety", "stability", "ring_stability", "mixed_ring_stability")  # see aev_ocp.loading
OCP_SCALARS = ("objective", "objective_exact", "max_violation", "wall_time_s", "solver_time_s")
#: Samples per run that reproduce stores of its long drive-cycle runs (scenarios/, mpc_cycles/), which it keeps for
#: their figures: our choice, more points than a figure has pixels across (udds_platoon: 31 101 samples -> 3 889;
#: the output folder 132 -> under 60 MB); their metrics are computed from every sample.
FIGURE_MAX_SAMPLES = 4000
OUTPUT_FILES = (MANIFEST, ARRAYS)  # what :func:`save_output` writes (for claim_output_dir)


class LoadError(AevOcpError, ValueError):
    """A path is not a loadable aev_ocp output (or a newer format); the message says which and why."""


# ----------------------------------------------------------------------------- saving
def _own_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """A result's meta without the record :func:`load` adds (a loaded result saved again stays flat)."""
    return {k: v for k, v in meta.items() if k != "output"}


def stored_samples(n: int, max_samples: int | None) -> np.ndarray | None:
    """Indices of the samples kept of ``n`` when at most about ``max_samples`` are stored: every k-th from the first
    (k = ceil(n / max_samples)) and always the last; None: all (``max_samples`` None or n ≤ max_samples)."""
    if max_samples is None or n <= max_samples:
        return None
    idx = np.arange(0, n, math.ceil(n / max_samples))
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def _sim_record(
    label: str, r: SimulationResult, arrays: dict[str, np.ndarray], max_samples: int | None = None
) -> dict[str, Any]:
    n = np.asarray(r.t).shape[0]
    keep = stored_samples(n, max_samples)

    def put(name: str, v: Any) -> None:
        a = np.asarray(v)
        arrays[f"{label}/{name}"] = a[keep] if keep is not None and a.ndim and a.shape[0] == n else a

    for name in SIM_ARRAYS:
        put(name, getattr(r, name))
    if r.temperature_K is not None:  # the pack temperature [K] of a run with the thermal model
        put("temperature_K", r.temperature_K)
    if r.battery_energy_J is not None:  # ∫P_b [J] of a plant that integrates it (SUMO)
        put("battery_energy_J", r.battery_energy_J)
    thinned = {} if keep is None else {"stored_samples": int(keep.size), "samples": int(n)}
    return {
        **thinned,
        "type": "SimulationResult",
        "status": r.status,
        "controllers": list(r.controllers),
        "events": [vars(e) for e in r.events],
        "violations": [vars(e) for e in r.violations],
        "ev": as_dict(r.ev),
        "jerk_sampled": bool(r.jerk_sampled),
        "solver_stats": r.solver_stats,
        "meta": _own_meta(r.meta),
        "metrics": r.metrics(),
    }


def _ocp_record(label: str, r: Any, arrays: dict[str, np.ndarray]) -> dict[str, Any]:
    arrays[f"{label}/t"] = np.asarray(r.t, float)
    for group in ("states", "controls", "outputs"):
        for name, v in getattr(r, group).items():
            arrays[f"{label}/{group}/{name}"] = np.asarray(v, float)
    if r.t_colloc is not None:
        arrays[f"{label}/t_colloc"] = np.asarray(r.t_colloc, float)
    for name in OCP_SCALARS:
        arrays[f"{label}/{name}"] = np.asarray(float(getattr(r, name)))
    return {
        "type": "OCPResult",
        "problem": r.problem,
        "method": r.method,
        "N": r.N,
        "time_unit": r.time_unit,
        "objective_name": r.objective_name,
        "status": r.status,
        "success": r.success,
        "message": r.message,
        "solver_status": r.solver_status,
        "iterations": r.iterations,
        "warnings": list(r.warnings),
        "states": list(r.states),
        "controls": list(r.controls),
        "outputs": list(r.outputs),
        "meta": _own_meta(r.meta),
        "metrics": r.stats(),
    }


def pack_array(a: np.ndarray) -> np.ndarray:
    """A float64 array as its byte planes (uint8, shape (8, a.size)): its bit patterns as int64, differenced along
    axis 0 (wrapping), the axes moved so that each column's samples are consecutive. Exact: see
    :func:`unpack_array`."""
    iv = np.ascontiguousarray(a, dtype="<f8").view("<i8")
    d = iv.copy()
    d[1:] -= iv[:-1]  # int64 arithmetic wraps: exact both ways
    return np.ascontiguousarray(np.moveaxis(d, 0, -1)).view(np.uint8).reshape(-1, 8).T.copy()


def unpack_array(planes: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The float64 array of ``shape`` that :func:`pack_array` turned into ``planes``, bit for bit."""
    moved = (*shape[1:], shape[0])
    if planes.dtype != np.uint8 or planes.shape != (8, math.prod(shape)):
        raise ValueError(f"packed array of shape {planes.shape} ({planes.dtype}) does not hold {shape} float64")
    d = np.ascontiguousarray(planes.T).view("<i8").reshape(moved)
    return np.cumsum(np.moveaxis(d, -1, 0), axis=0, dtype="<i8").view("<f8")


def _packable(a: np.ndarray) -> bool:
    return a.dtype == np.float64 and a.ndim >= 1 and a.size >= PACK_MIN_SIZE


def save_output(
    out: str | Path,
    kind: str,
    runs: Mapping[str, Any],
    *,
    primary: str | None = None,
    settings: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
    document: str | Path | None = None,
    arrays: Mapping[str, np.ndarray] | None = None,
    max_samples: int | None = None,
) -> list[Path]:
    """Write ``trajectories.npz`` (if any run or array) and ``manifest.json`` into ``out``; returns the paths.

    runs: {label: SimulationResult or OCPResult}; primary: the label :func:`load` returns by default
    (default the first); settings: what produced the runs (scenario document, options); extra: more
    JSON-ready manifest entries (e.g. a study's table file); document: a JSON file already written into ``out``
    that holds the output's numbers (the manifest names it with its SHA-256, :func:`read_document` checks it);
    arrays: more arrays for ``trajectories.npz`` ({key: array}, keys not starting with a run label + '/');
    max_samples: store about this many samples of a longer simulation run (:func:`stored_samples`: evenly spaced,
    the first and the last; for figures), its manifest record saying ``stored_samples`` of ``samples`` (its
    metrics are those of every sample); None: all."""
    if kind not in KINDS:
        raise ValueError(f"save_output: kind {kind!r} is not one of {KINDS}")
    from .ocp_result import OCPResult

    out = Path(out)
    arrays = dict(arrays or {})
    records: dict[str, Any] = {}
    for label, r in runs.items():
        if "/" in label:
            raise ValueError(f"save_output: run label {label!r} must not contain '/'")
        if isinstance(r, SimulationResult):
            records[label] = _sim_record(label, r, arrays, max_samples)
        elif isinstance(r, OCPResult):
            records[label] = _ocp_record(label, r, arrays)
        else:
            raise TypeError(f"save_output: run {label!r} is a {type(r).__name__}, not a SimulationResult or OCPResult")
    files: list[Path] = []
    manifest: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "primary": primary if primary is not None else next(iter(records), None),
        "arrays": None,
        "arrays_sha256": None,
        "runs": records,
        "settings": dict(settings or {}),
    }
    if arrays:
        packed = {k: list(np.shape(v)) for k, v in arrays.items() if _packable(np.asarray(v))}
        stored = {k: pack_array(np.asarray(v)) if k in packed else v for k, v in arrays.items()}
        if packed:
            manifest.update(packed=packed, packed_encoding=PACK_ENCODING)
        buf = io.BytesIO()
        # no allow_pickle keyword: NumPy < 2.2 would store it as an array (the stubs of newer NumPy see the
        # **arrays as that keyword)
        np.savez_compressed(buf, **stored)  # type: ignore[arg-type]
        data = buf.getvalue()
        with atomic_path(out / ARRAYS) as tmp:
            tmp.write_bytes(data)
        files.append(out / ARRAYS)
        manifest.update(arrays=ARRAYS, arrays_sha256=hashlib.sha256(data).hexdigest())
    if document is not None:
        doc = out / Path(document).name
        manifest.update(document=doc.name, document_sha256=hashlib.sha256(doc.read_bytes()).hexdigest())
    manifest.update(dict(extra or {}))
    files.append(write_json(out / MANIFEST, manifest))
    return files


def read_document(m: dict[str, Any], folder: Path) -> Any:
    """The JSON document an output's manifest names (``document``), checked against its ``document_sha256``;
    LoadError naming the file and the field otherwise."""
    name = m.get("document")
    if not isinstance(name, str) or not name:
        raise LoadError(
            f"{folder / MANIFEST}: field 'document' = {name!r:.80} is not the name of the output's JSON file"
        )
    f = folder / Path(name).name  # never outside the folder
    if not f.exists():
        raise LoadError(f"{f}: missing (field 'document' of {folder / MANIFEST} names it); rerun the command")
    data = read_regular(f, int(memory_limit_bytes()) // 4, "document")
    if hashlib.sha256(data).hexdigest() != m.get("document_sha256"):
        raise LoadError(
            f"{f}: its SHA-256 differs from field 'document_sha256' of {MANIFEST}: another run's file or an edited "
            "one; rerun the command"
        )
    try:
        return json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise LoadError(f"{f}: cannot read it as JSON ({type(exc).__name__})") from None


def read_arrays(m: dict[str, Any], folder: Path) -> dict[str, np.ndarray]:
    """Every array of an output (``trajectories.npz``, checked against ``arrays_sha256``; {} without one)."""
    return _arrays(m, folder)


def sim_record(
    label: str, r: SimulationResult, arrays: dict[str, np.ndarray], max_samples: int | None = None
) -> dict[str, Any]:
    """The manifest record of one SimulationResult (its arrays added to ``arrays`` under ``label/``; at most about
    ``max_samples`` samples stored, :func:`stored_samples`; None: every sample)."""
    return _sim_record(label, r, arrays, max_samples)


def sim_result(label: str, rec: dict[str, Any], arrays: dict[str, np.ndarray]) -> SimulationResult:
    """The SimulationResult of a record :func:`sim_record` wrote (ValueError/KeyError if damaged)."""
    return _sim_result(label, rec, arrays)


# ----------------------------------------------------------------------------- loading
def read_manifest(path: str | Path) -> tuple[dict[str, Any], Path]:
    """The manifest of an output (its folder or the manifest file) and the folder; LoadError otherwise."""
    p = Path(path)
    if p.is_dir():
        folder, file = p, p / MANIFEST
    else:
        folder, file = p.parent, p
    if not file.exists():
        hint = (
            " (written by aev-ocp before outputs became loadable? rerun the command)"
            if folder.is_dir() and (folder / "aev-ocp-run.json").is_file()
            else ""
        )
        raise LoadError(f"{path}: not an aev_ocp output: no {MANIFEST} found{hint}")
    text = read_regular(file, MAX_MANIFEST_BYTES, "manifest")
    try:
        m = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise LoadError(f"{file}: not an aev_ocp output: cannot read it as JSON ({type(exc).__name__})") from None
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise LoadError(
            f"{file}: not an aev_ocp output (format is {m.get('format') if isinstance(m, dict) else None!r}, "
            f"expected {FORMAT!r})"
        )
    ver = m.get("format_version")
    if not isinstance(ver, int) or isinstance(ver, bool) or ver < 1:
        raise LoadError(f"{file}: format_version = {ver!r} is not a known version of {FORMAT}")
    if ver > FORMAT_VERSION:
        raise LoadError(
            f"{file}: format_version {ver} is newer than this aev_ocp reads ({FORMAT_VERSION}); "
            "upgrade aev_ocp to load it"
        )
    if m.get("kind") not in KINDS:
        raise LoadError(f"{file}: kind = {m.get('kind')!r} is not one of {KINDS}")
    return m, folder


def _arrays(m: dict[str, Any], folder: Path) -> dict[str, np.ndarray]:
    name = m.get("arrays")
    if not name:
        return {}
    f = folder / Path(str(name)).name  # never outside the folder
    limit = int(memory_limit_bytes())
    data = read_regular(f, limit, "arrays file")
    if hashlib.sha256(data).hexdigest() != m.get("arrays_sha256"):
        raise LoadError(
            f"{f}: its SHA-256 differs from the one in {MANIFEST}: the arrays belong to another run "
            "(an interrupted rerun?); rerun the command"
        )
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:  # sizes from the zip directory, before inflating anything
            total = sum(i.file_size for i in zf.infolist())
        if total > limit:
            raise LoadError(
                f"{f}: its arrays would take {total / 1e9:.3g} GB once unpacked, more than the limit of "
                f"{limit / 1e9:.3g} GB ($AEV_OCP_MAX_MEMORY_GB); not loaded"
            )
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
    except LoadError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, NotImplementedError, RuntimeError) as exc:
        raise LoadError(f"{f}: not a readable NumPy .npz file ({type(exc).__name__}: {exc})") from None
    packed = m.get("packed") or {}
    if packed and m.get("packed_encoding") != PACK_ENCODING:
        raise LoadError(
            f"{f}: {MANIFEST} field packed_encoding = {m.get('packed_encoding')!r} is not {PACK_ENCODING!r}"
        )
    if not isinstance(packed, dict):
        raise LoadError(f"{f}: {MANIFEST} field packed is not a mapping of array names to shapes")
    for k, shape in packed.items():
        try:
            out[k] = unpack_array(out[k], tuple(int(n) for n in shape))
        except (KeyError, TypeError, ValueError) as exc:
            raise LoadError(f"{f}: packed array {k!r} (manifest field packed): {type(exc).__name__}: {exc}") from None
    return out


MAX_MANIFEST_BYTES = 200_000_000  # a manifest is JSON metadata (kB to a few MB for a study); larger is not one of ours


def read_regular(f: Path, max_bytes: int, what: str) -> bytes:
    """The bytes of ``f`` if it is a regular file (a symlink to one is fine) of at most ``max_bytes``, checked
    BEFORE reading (:func:`aev_ocp.limits.read_regular_file`); LoadError otherwise."""
    try:
        return read_regular_file(f, max_bytes)
    except FileRefused as exc:
        raise LoadError(f"{f}: the output's {what} was not read ({exc})") from None


def _nan(x: Any) -> float:
    return math.nan if x is None else float(x)


def _sim_result(label: str, rec: dict[str, Any], arrays: dict[str, np.ndarray]) -> SimulationResult:
    ev = rec["ev"]
    # a run saved before the vehicle limits existed ran without any (UNLIMITED)
    limits = VehicleLimits(**ev["limits"]) if "limits" in ev else UNLIMITED
    cell: dict[str, Any] = {
        k: tuple(v) if k in ("ocv_soc", "ocv_V") and v is not None else v for k, v in ev["cell"].items()
    }
    evp = EVParams(
        units=Units(**ev["units"]),
        vehicle=VehicleParams(**ev["vehicle"]),
        cell=CellParams(**cell),
        pack=PackParams(**ev["pack"]),
        limits=limits,
        thermal=ThermalParams(**ev["thermal"]) if "thermal" in ev else ThermalParams(),
    )

    def event(e: dict[str, Any]) -> Event:
        return Event(
            e["kind"],
            _nan(e["time"]),
            int(e["vehicle"]),
            e["message"],
            None if e.get("time_s") is None else float(e["time_s"]),
            None if e.get("impact_speed_mps") is None else float(e["impact_speed_mps"]),
        )

    _check_sim_arrays(label, arrays)
    stats = rec["solver_stats"] or []
    if not isinstance(stats, list) or not all(s is None or isinstance(s, dict) for s in stats):
        raise ValueError(f"solver_stats = {str(stats)[:60]!r} is not a list of per-vehicle tables")
    ctrls, n_veh = rec["controllers"], arrays[f"{label}/gap"].shape[1]
    if not isinstance(ctrls, list) or len(ctrls) != n_veh or not all(isinstance(c, str) for c in ctrls):
        raise ValueError(
            f"controllers = {str(ctrls)[:60]!r} is not a list of {n_veh} controller names, one per vehicle"
        )
    return SimulationResult(
        **{n: arrays[f"{label}/{n}"] for n in SIM_ARRAYS},
        controllers=list(rec["controllers"]),
        ev=evp,
        events=[event(e) for e in rec["events"]],
        jerk_sampled=bool(rec["jerk_sampled"]),
        solver_stats=list(stats),
        meta=dict(rec["meta"] or {}),
        violations=[event(e) for e in rec.get("violations") or []],
        temperature_K=arrays.get(f"{label}/temperature_K"),
        battery_energy_J=arrays.get(f"{label}/battery_energy_J"),
    )


def _check_sim_arrays(label: str, arrays: dict[str, np.ndarray]) -> None:
    """ValueError unless run ``label``'s arrays have the shapes a SimulationResult has: numbers, t of n >= 1
    samples, the leader's (n,), every per-vehicle array (n, vehicles) like gap (a damaged or edited file whose
    SHA-256 was updated would otherwise load as a run with silently wrong numbers)."""
    t, gap = arrays[f"{label}/t"], arrays[f"{label}/gap"]
    n = t.shape[0] if t.ndim == 1 else -1
    want = {"t": (n,), "leader_speed": (n,), "leader_position": (n,), "temperature_K": gap.shape}
    for name in (*SIM_ARRAYS, "temperature_K", "battery_energy_J"):
        a = arrays.get(f"{label}/{name}")
        if a is None and name in ("temperature_K", "battery_energy_J"):
            continue
        shape = want.get(name, gap.shape)
        if a is None or a.dtype.kind not in "fiub" or a.shape != shape or n < 1 or gap.ndim != 2 or gap.shape[0] != n:
            got = "missing" if a is None else f"{a.dtype} {a.shape}"
            raise ValueError(
                f"array {name!r} is {got}; expected numbers of shape {shape} (t has {n} samples, gap {gap.shape})"
            )


def _ocp_result(label: str, rec: dict[str, Any], arrays: dict[str, np.ndarray]) -> Any:
    from .ocp_result import OCPResult

    group = {g: {n: arrays[f"{label}/{g}/{n}"] for n in rec[g]} for g in ("states", "controls", "outputs")}
    scal = {n: float(arrays[f"{label}/{n}"]) for n in OCP_SCALARS}
    return OCPResult(
        problem=rec["problem"],
        method=rec["method"],
        N=int(rec["N"]),
        t=arrays[f"{label}/t"],
        time_unit=rec["time_unit"],
        states=group["states"],
        controls=group["controls"],
        outputs=group["outputs"],
        objective_name=rec["objective_name"],
        status=rec["status"],
        success=bool(rec["success"]),
        message=rec["message"],
        solver_status=rec["solver_status"],
        iterations=int(rec["iterations"]),
        t_colloc=arrays.get(f"{label}/t_colloc"),
        meta=dict(rec["meta"] or {}),
        warnings=list(rec["warnings"]),
        objective=scal["objective"],
        objective_exact=scal["objective_exact"],
        max_violation=scal["max_violation"],
        wall_time_s=scal["wall_time_s"],
        solver_time_s=scal["solver_time_s"],
    )


def _build(label: str, m: dict[str, Any], arrays: dict[str, np.ndarray], folder: Path) -> Any:
    rec = m["runs"][label]
    try:
        obj = (_sim_result if rec["type"] == "SimulationResult" else _ocp_result)(label, rec, arrays)
    except (KeyError, TypeError, ValueError) as exc:
        raise LoadError(
            f"{folder / MANIFEST}: run {label!r} is incomplete or damaged ({type(exc).__name__}: {exc})"
        ) from None
    obj.meta["output"] = {
        "path": str(folder),
        "kind": m["kind"],
        "label": label,
        "runs": list(m["runs"]),
        "settings": m.get("settings", {}),
        "provenance": m.get("provenance"),
        "saved_metrics": rec.get("metrics"),
    }
    return obj


def _damaged(path: str | Path, fn: Any) -> Any:
    """``fn()``, with anything a damaged folder can raise (a wrong type deep in the manifest, a missing array,
    a RecursionError, a MemoryError) turned into one :class:`LoadError` naming ``path``. A path that is no path
    at all is a LoadError saying so; a bad $AEV_OCP_MAX_MEMORY_GB is the caller's ParameterError, not damage."""
    if not isinstance(path, (str, os.PathLike)):
        raise LoadError(
            f"path = {path!r:.80}: expected an output folder (a str or pathlib.Path), got {type(path).__name__}"
        )
    memory_limit_bytes()
    try:
        return fn()
    except LoadError:
        raise
    except (
        KeyError,
        TypeError,
        ValueError,
        AttributeError,
        IndexError,
        RecursionError,
        MemoryError,
        OverflowError,
        OSError,
        UnicodeError,
        zipfile.BadZipFile,
        EOFError,
    ) as exc:
        raise LoadError(
            f"{path}: not a loadable aev_ocp output: it is damaged ({type(exc).__name__}: {str(exc)[:200]})"
        ) from None


def load_all(path: str | Path) -> dict[str, Any]:
    """Every run of an output folder: {label: SimulationResult or OCPResult} (a study: {} – use :func:`load`)."""
    return _damaged(path, lambda: _load_all(path))


def _load_all(path: str | Path) -> dict[str, Any]:
    m, folder = read_manifest(path)
    arrays = _arrays(m, folder)
    return {label: _build(label, m, arrays, folder) for label in m.get("runs", {})}


def load(path: str | Path, run: str | None = None) -> Any:
    """Load what a command saved: ``path`` is its output folder (or the folder's manifest.json).

    Returns the run's result object: a :class:`~aev_ocp.results.SimulationResult` (``simulate``,
    ``mpc``), an :class:`~aev_ocp.ocp_result.OCPResult` (``ocp``) or a
    :class:`~aev_ocp.study.StudyOutput` (``study``: the table rows). ``run`` picks one labelled run of
    the folder (``"mpc"``, ``"proposed"``, ``"ocp-d"``, ``"heat"`` …); default the command's main run
    (simulate: the first law; mpc: the MPC; ocp: the main solve). The object's
    ``meta["output"]`` holds the folder, the run labels, the settings, the provenance and the metrics
    as saved; :meth:`SimulationResult.metrics` recomputes them from the loaded trajectories.
    Raises :class:`LoadError` for a path that is not an aev_ocp output, a damaged one or a newer format; the
    files are checked before they are read (regular files only, sizes within $AEV_OCP_MAX_MEMORY_GB).
    """
    return _damaged(path, lambda: _load(path, run))


def _load(path: str | Path, run: str | None) -> Any:
    m, folder = read_manifest(path)
    if m["kind"] == "study":
        return load_study_output(m, folder)
    if m["kind"] in DOCUMENT_KINDS:
        raise LoadError(f"{folder}: kind = {m['kind']!r} is read by aev_ocp.load (aev_ocp.loading), not saved.load")
    runs = m.get("runs") or {}
    label = run if run is not None else m.get("primary")
    if label is None or label not in runs:  # (JSON keys are strings: a None label was never in runs)
        raise LoadError(f"{folder}: no run {label!r} in this output; its runs are {list(runs)}")
    return _build(label, m, _arrays(m, folder), folder)


def settings_of(scenario: Any, **options: Any) -> dict[str, Any]:
    """The ``settings`` entry of a manifest: the scenario (name, file, TOML document) and the options."""
    out: dict[str, Any] = {"options": to_jsonable(options)}
    if scenario is not None:
        out.update(
            scenario=scenario.name, source=str(scenario.source) if scenario.source else None, document=scenario.document
        )
    return out


# ----------------------------------------------------------------------------- studies
TRAJECTORIES = "trajectories"  # sub-folder of a study's output: one loadable folder per task hash


@dataclass(repr=False)  # the short repr of FieldsRepr, not the dataclass's field dump
class StudyOutput(FieldsRepr):
    """What :func:`aev_ocp.study.run_study` produced (or :func:`aev_ocp.load` read back): folder, rows (one per point ×
    controller × vehicle, see :mod:`aev_ocp.study.table`), files written, counts; meta: the manifest's
    settings (the study file's document and path) and provenance, and ``output`` when loaded."""

    folder: Path
    rows: list[dict[str, Any]]
    files: list[Path]
    n_tasks: int
    n_failed: int
    meta: dict[str, Any] = field(default_factory=dict)

    def metrics(self) -> list[dict[str, Any]]:
        """The table rows (every §10 metric per point × controller × vehicle)."""
        return self.rows

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        ctrls = sorted({str(r.get("controller")) for r in self.rows})
        points = {r.get("point") for r in self.rows}
        return (
            f"StudyOutput: {len(points)} points × {len(ctrls)} controllers ({', '.join(ctrls)}), "
            f"{self.n_failed} of {self.n_tasks} tasks failed",
            [("folder", str(self.folder)), ("rows", len(self.rows)), ("files", len(self.files))],
        )

    def to_dataframe(self) -> Any:
        """The table rows as a pandas DataFrame. Needs pandas (``pip install 'aev_ocp[pandas]'``)."""
        return require_pandas("StudyOutput.to_dataframe()").DataFrame(self.rows)

    def plot(self, metric: str = "battery_energy_kWh_per_100km", axis: str | None = None, vehicle: int = 1) -> Any:
        """``metric`` (a table column, unit in its name) of follower ``vehicle`` against ``axis`` (default the
        study's first axis key, else the point index), one line per controller
        (:func:`aev_ocp.plots.plot_study_rows`): a matplotlib Figure."""
        from .plots import plot_study_rows

        if axis is None:
            axes = (self.meta.get("settings") or {}).get("axes") or []
            keys = [k for a in axes if isinstance(a, dict) for k in (a.get("keys") or [])]
            axis = keys[0] if keys else "point"
        return plot_study_rows(self.rows, metric, axis, vehicle, title=f"{self.folder.name}: {metric}")

    def trajectory(self, point: int, controller: str) -> Any:
        """The SimulationResult of one point under one controller, saved by ``run_study(...,
        trajectories=True)`` (``aev-ocp study --trajectories``); LoadError if it was not saved."""
        keys = {r["task_hash"] for r in self.rows if r["point"] == point and r["controller"] == controller}
        if not keys:
            raise LoadError(f"{self.folder}: no row for point {point} and controller {controller!r}")
        path = self.folder / TRAJECTORIES / keys.pop()
        if not path.is_dir():
            raise LoadError(
                f"{self.folder}: no trajectories saved for point {point}, controller {controller!r}; "
                "rerun the study with --trajectories (trajectories=True)"
            )
        return load(path)


def load_study_output(manifest: dict[str, Any], folder: Path) -> StudyOutput:
    """The :class:`StudyOutput` of a study folder from its manifest (used by :func:`aev_ocp.load`)."""
    table = folder / Path(str(manifest.get("table") or "table.jsonl")).name
    if not table.exists():
        raise LoadError(f"{folder}: the study's table {table.name} is missing")
    data = read_regular(table, int(memory_limit_bytes()) // 4, "table")  # a FIFO or device is refused, unread
    want = manifest.get("table_sha256")  # absent in folders written before it was recorded
    if want is not None and hashlib.sha256(data).hexdigest() != want:
        raise LoadError(
            f"{table}: not the table this study wrote (its SHA-256 differs from the manifest's table_sha256): "
            "another study's table or an edited one; rerun the study to rebuild it"
        )
    rows = [json.loads(line) for line in data.decode("utf-8").splitlines() if line.strip()]  # as load_table reads it
    if not all(isinstance(r, dict) for r in rows):
        raise LoadError(f"{table}: a line of the study's table is not a row (a JSON object); the table is damaged")
    files = sorted(p for p in folder.iterdir() if p.is_file())
    meta = {
        "settings": manifest.get("settings", {}),
        "output": {
            "path": str(folder),
            "kind": "study",
            "settings": manifest.get("settings", {}),
            "provenance": manifest.get("provenance"),
        },
    }
    return StudyOutput(folder, rows, files, int(manifest.get("n_tasks", 0)), int(manifest.get("n_failed", 0)), meta)
