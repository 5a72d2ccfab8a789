"""A study's unit of work: one point under one controller as a :class:`~aev_ocp.study.model.Task`, keyed by the
hash of its full normalised specification (what a rerun finds in the store)."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

from .._version import __version__
from .model import Controller, Point, Task


def canonical_json(obj: Any) -> str:
    """Deterministic JSON (sorted keys, exact float repr) used for hashing."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True, default=str)


def _law_fingerprint(doc: dict[str, Any], law: str) -> dict[str, Any]:
    """The law's coefficients as the (validated) document sets them: only what the law reads."""
    from ..models.carfollowing import make_law
    from ..params import CarFollowingParams

    table = doc.get("carfollowing") or {}
    names = {f.name for f in dataclasses.fields(CarFollowingParams)} - {"model_units"}
    cf = CarFollowingParams(**dict[str, Any]({k: float(v) for k, v in table.items() if k in names}))
    own = {k.lower(): v for k, v in table.items() if k not in names and isinstance(v, dict)}
    obj = make_law(law, cf, **own.get(law, {}))
    fields = [f.name for f in dataclasses.fields(obj) if f.name != "model_units"]
    return {"law": law, "coefficients": {k: getattr(obj, k) for k in fields}}


def make_task(p: Point, c: Controller, own_cost: bool = False) -> Task:
    """The task of point ``p`` under controller ``c`` and its hash; ``own_cost``: an MPC task also reports its
    formulation's own cost of follower 1 (``<cost_key>``; the OCP-D bound check of :func:`build_rows`).

    The hash covers the full normalised specification: the scenario document (without what cannot
    change this run: name, description, compare, and for a closed-form law the [mpc] table and the
    other laws' coefficients), the controller and the package version."""
    doc = copy.deepcopy(p.document)
    for k in ("name", "description", "compare"):
        doc.pop(k, None)
    if c.kind == "law":
        doc.pop("mpc", None)
        doc.pop("carfollowing", None)
        platoon = doc.get("platoon", {})
        n = platoon.get("followers", len(platoon.get("laws") or ()))  # laws = [...] may set the count
        doc["platoon"] = {**{k: v for k, v in platoon.items() if k not in ("law", "laws")}, "followers": n}
        identity: dict[str, Any] = {"document": doc, "law": _law_fingerprint(p.document, c.name)}
    else:
        identity = {"document": doc}
    identity.update(
        {"controller": {"kind": c.kind, "name": c.name, "settings": dict(c.settings)}, "version": __version__}
    )
    if own_cost:  # (only then in the hash: other tasks keep theirs)
        identity["own_cost"] = True
    trace = _trace_file(p.document, p.file)
    if trace is not None:  # a recorded leader: its data, not only its file name, decides the result
        identity["leader_trace_sha256"] = hashlib.sha256(trace.read_bytes()).hexdigest() if trace.is_file() else None
    key = hashlib.sha256(canonical_json(identity).encode()).hexdigest()
    spec = {"document": p.document, "file": p.file, "controller": c.as_dict(), "key": key, "own_cost": own_cost}
    return Task(p.index, c.label, spec, key)


def _source(file: str) -> Path | None:
    """The scenario file (relative paths inside it, e.g. a trace leader's CSV, start at its folder)."""
    p = Path(file)
    return p if p.is_file() else None


def _trace_file(doc: dict[str, Any], file: str) -> Path | None:
    """The CSV of a ``[leader] kind = "trace"`` leader, resolved like the scenario loader does; else None."""
    lead = doc.get("leader")
    if not isinstance(lead, dict) or lead.get("kind") != "trace" or not isinstance(lead.get("file"), str):
        return None
    f = Path(lead["file"])
    src = _source(file)
    return f if f.is_absolute() else (src.parent if src is not None else Path.cwd()) / f
