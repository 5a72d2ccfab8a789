"""The vehicle tables every scenario form shares (platoon, ring, SUMO): [units], [vehicle], [cell], [pack],
[limits], [thermal] into :class:`~aev_ocp.params.EVParams`, and the head (name, description, vehicle) of a scenario
form with a command of its own."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from ..cells import CellFileError, load_cell_file, shipped_cells
from ..params import (
    CellParams,
    EVParams,
    PackParams,
    ParameterError,
    ThermalParams,
    Units,
    VehicleLimits,
    VehicleParams,
)
from ..results import check_safe_name
from .tables import ScenarioError, TableReader, _params


def _cell(r: TableReader, source: Path | None) -> CellParams:
    """[cell]: ``name`` (a shipped cell, aev_ocp/data/cells/) or ``file`` (a cell file, relative to the scenario),
    then any CellParams field overriding it (e.g. soc0); neither: CellParams() (the A123 defaults)."""
    base = None
    if r.has("name") and r.has("file"):
        raise r.error("file", r.table["file"], "give [cell] name or file, not both")
    for key in ("name", "file"):
        if r.has(key):
            ref = r.string(key)
            try:
                if key == "name" and ref not in shipped_cells():
                    raise CellFileError(f"not a shipped cell; shipped: {', '.join(shipped_cells())}")
                base = load_cell_file(ref, source.parent if (key == "file" and source is not None) else None).cell
            except CellFileError as exc:
                raise r.error(key, ref, str(exc)) from None
    return _params(CellParams, r, base)


def read_ev(top: TableReader, source: Path | None) -> EVParams:
    """The vehicle tables every scenario form shares (platoon, ring, SUMO): [units], [vehicle], [cell] (a shipped
    ``name`` or a ``file``, then field overrides), [pack], [limits], [thermal]; absent tables give the defaults."""
    tables = dict(
        units=_params(Units, top.sub("units")),
        vehicle=_params(VehicleParams, top.sub("vehicle")),
        cell=_cell(top.sub("cell"), source),
        pack=_params(PackParams, top.sub("pack")),
        limits=_params(VehicleLimits, top.sub("limits")),
        thermal=_params(ThermalParams, top.sub("thermal")),
    )
    try:
        return EVParams(**tables)
    except ParameterError as exc:  # a rule between tables (EVParams.__post_init__): name the key it is about
        key = str(exc).split(" = ", 1)[0].split(".")[-1]
        table = next((t for t, v in tables.items() if hasattr(v, key)), None)
        raise ScenarioError(f"{top.file}: {table + '.' + key if table else 'vehicle tables'}: {exc}") from None


def standalone_header(
    doc: dict[str, Any], file: str, source: Path | None, allowed: Any, kind: str
) -> tuple[TableReader, str, str, EVParams]:
    """The head of a scenario form with its own command (``kind``: 'ring', 'sumo'): top-level keys checked against
    ``allowed``, then (reader, name, description, EVParams); the name defaults to the file stem made safe."""
    for key in doc:
        if key not in allowed:
            raise ScenarioError(
                f"{file}: unknown top-level key or table {key!r} in a {kind} scenario; allowed: {sorted(allowed)}"
            )
    top = TableReader(doc, "", file)
    stem = source.stem if source is not None else kind
    name = top.string("name", re.sub(r"[^A-Za-z0-9._+-]", "_", stem).lstrip("._+-")[:100] or kind)
    try:
        check_safe_name(name)
    except ValueError as exc:
        raise top.error("name", name, str(exc).split("is not allowed: ", 1)[-1]) from None
    return top, name, top.string("description", ""), read_ev(top, source)
