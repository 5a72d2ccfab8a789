"""Cells as data: a cell parameter file (TOML) → :class:`~aev_ocp.params.CellParams`.

A cell file holds one cell's 2-RC values, OCV curve, capacity, current limit and thermal properties, every
number with its unit in the key and its source beside it::

    name = "a123_anr26650"            # the name scenarios use: [cell] name = "a123_anr26650"
    chemistry = "LFP"                 # LFP, NMC or NCA (picks the battery-life model, aev_ocp.life)
    description = "..."
    capacity_Ah = { value = 2.3, source = "A123 ANR26650M1-B datasheet" }
    R_s_ohm = { value = 0.010, source = "..." }
    ...                               # any CellParams field but soc0 (the scenario's initial state)
    [ocv]                             # the OCV curve: a CSV beside the file (columns soc, ocv_V) ...
    file = "a123_ocv_25C.csv"
    source = "..."
    # ... or inline: soc = [0.0, ..., 1.0]  ocv_V = [..]
    [rc_table]                        # optional: R_s, R1, C1, R2, C2 over SOC and T (CellParams.rc_table)
    source = "..."
    soc = [0.1, ..., 0.9]             # columns
    T_K = [283.15, 298.15, 313.15]    # rows
    R_s_ohm = [[...], [...], [...]]   # one row per T_K, one value per soc; likewise R1_ohm, C1_F, R2_ohm, C2_F
    [identification]                  # optional: how the values were identified (parameter set, script, residual)

Shipped cells live in ``aev_ocp/data/cells/``; :func:`load_cell` takes a shipped name or a path. Every key is
checked against the CellParams declaration; errors are one line naming the file and the key.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from .limits import read_input_file
from .params import RC_TABLE_KEYS, CellParams, ParameterError, RCTable, check_ocv_table, echo, field_checks

CHEMISTRIES = ("LFP", "NMC", "NCA")
#: CellParams fields a cell file may set (soc0 is the scenario's initial state, the OCV comes from [ocv]).
CELL_KEYS = tuple(
    f.name for f in dataclasses.fields(CellParams) if f.name not in ("soc0", "ocv_soc", "ocv_V", "rc_table")
)


class CellFileError(ParameterError):
    """A cell file is invalid; the message names the file and the key."""


@dataclass(frozen=True)
class CellFile:
    """A loaded cell file: the cell, its name, chemistry, description, the source of every value and the path."""

    cell: CellParams
    name: str
    chemistry: str
    description: str
    sources: dict[str, str]
    path: str
    identification: dict[str, Any] = dataclasses.field(default_factory=dict)


def cell_dir() -> Path:
    """The folder of the shipped cell files."""
    return Path(str(resources.files("aev_ocp") / "data" / "cells"))


def shipped_cells() -> dict[str, Path]:
    """{name: path} of the shipped cell files."""
    return {p.stem: p for p in sorted(cell_dir().glob("*.toml"))}


def _read_csv(path: Path, file: str) -> tuple[list[float], list[float]]:
    try:
        text = read_input_file(path, "OCV table", CellFileError, label=f"{file}: ocv.file = {str(path)!r}")
        rows = list(csv.DictReader(io.StringIO(text.decode("utf-8"), newline="")))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise CellFileError(f"{file}: ocv.file = {str(path)!r} is not a UTF-8 CSV table: {exc}") from None
    except OSError as exc:
        raise CellFileError(f"{file}: ocv.file = {str(path)!r} cannot be read: {exc.strerror or exc}") from None
    try:
        return [float(r["soc"]) for r in rows], [float(r["ocv_V"]) for r in rows]
    except (KeyError, TypeError, ValueError):
        raise CellFileError(
            f"{file}: ocv.file = {str(path)!r} is not allowed: needs numeric columns soc, ocv_V"
        ) from None


def parse_cell(doc: dict[str, Any], file: str = "<cell>", base_dir: Path | None = None) -> CellFile:
    """Validate a parsed cell document (``file`` names it in messages; ``base_dir`` resolves ``ocv.file``)."""
    allowed = ("name", "chemistry", "description", "ocv", "rc_table", "identification") + CELL_KEYS
    for key in doc:
        if key not in allowed:
            raise CellFileError(f"{file}: unknown key {key!r}; allowed: {sorted(allowed)}")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise CellFileError(f"{file}: name = {echo(name)} is not allowed: a non-empty string is required")
    chem = doc.get("chemistry")
    if chem not in CHEMISTRIES:
        raise CellFileError(f"{file}: chemistry = {echo(chem)} is not allowed: one of {CHEMISTRIES}")
    checks = field_checks(CellParams)
    values: dict[str, Any] = {}
    sources: dict[str, str] = {}
    for key in CELL_KEYS:
        if key not in doc:
            raise CellFileError(f'{file}: {key} is missing (required, as {{ value = ..., source = "..." }})')
        entry = doc[key]
        if not isinstance(entry, dict) or set(entry) - {"value", "source"} or "source" not in entry:
            raise CellFileError(
                f"{file}: {key} = {entry!r:.60} is not allowed: must be {{ value = ..., "
                'source = "..." }} (value may be left out only where None is allowed)'
            )
        if not isinstance(entry["source"], str) or not entry["source"].strip():
            raise CellFileError(f"{file}: {key}.source is not allowed: a non-empty string is required")
        value = entry.get("value")
        problem = checks[key].problem(value)
        if problem is not None:
            raise CellFileError(f"{file}: {key}.value = {echo(value)} is not allowed: {problem}")
        values[key] = float(value) if isinstance(value, int) and not isinstance(value, bool) else value
        sources[key] = entry["source"]
    ocv = doc.get("ocv")
    if not isinstance(ocv, dict):
        raise CellFileError(f'{file}: [ocv] is missing (required: file = "x.csv" or soc = [...], ocv_V = [...])')
    extra = set(ocv) - {"file", "soc", "ocv_V", "source"}
    if extra:
        raise CellFileError(f"{file}: unknown key ocv.{sorted(extra)[0]}; allowed: file, soc, ocv_V, source")
    if not isinstance(ocv.get("source"), str) or not ocv["source"].strip():
        raise CellFileError(f"{file}: ocv.source is missing (required: where the curve comes from)")
    soc: Any
    volts: Any
    if "file" in ocv:
        if "soc" in ocv or "ocv_V" in ocv:
            raise CellFileError(f"{file}: ocv: give file or soc/ocv_V, not both")
        p = Path(str(ocv["file"]))
        soc, volts = _read_csv(p if p.is_absolute() else (base_dir or Path.cwd()) / p, file)
    else:
        soc, volts = ocv.get("soc"), ocv.get("ocv_V")
        if (
            not isinstance(soc, list)
            or not isinstance(volts, list)
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in soc + volts)
        ):
            raise CellFileError(f"{file}: ocv.soc and ocv.ocv_V must be arrays of numbers")
    table = _rc_table(doc.get("rc_table"), file)
    ident = doc.get("identification", {})
    if not isinstance(ident, dict):
        raise CellFileError(f"{file}: identification is not allowed: must be a table ([identification])")
    try:
        check_ocv_table(soc, volts, "ocv")
        cell = CellParams(
            **values, ocv_soc=tuple(float(x) for x in soc), ocv_V=tuple(float(x) for x in volts), rc_table=table
        )
    except ParameterError as exc:
        raise CellFileError(f"{file}: {exc}") from None
    sources["ocv"] = ocv["source"]
    if table is not None:
        sources["rc_table"] = doc["rc_table"]["source"]
    return CellFile(cell, name, chem, str(doc.get("description", "")), sources, file, dict(ident))


def _rc_table(tab: Any, file: str) -> RCTable | None:
    """The [rc_table] of a cell file as an RCTable (None when absent); CellFileError naming the key otherwise."""
    if tab is None:
        return None
    if not isinstance(tab, dict):
        raise CellFileError(f"{file}: rc_table is not allowed: must be a table ([rc_table])")
    keys = ("source", "soc", "T_K", "soc_ref") + RC_TABLE_KEYS
    for key in tab:
        if key not in keys:
            raise CellFileError(f"{file}: unknown key rc_table.{key}; allowed: {', '.join(keys)}")
    for key in ("source", "soc", "T_K") + RC_TABLE_KEYS:
        if key not in tab:
            raise CellFileError(f"{file}: rc_table.{key} is missing (required)")
    if not isinstance(tab["source"], str) or not tab["source"].strip():
        raise CellFileError(f"{file}: rc_table.source is not allowed: a non-empty string is required")
    for key in ("soc", "T_K") + RC_TABLE_KEYS:
        rows = tab[key] if key in ("soc", "T_K") else [x for r in tab[key] if isinstance(r, list) for x in r]
        if not isinstance(tab[key], list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in rows):
            raise CellFileError(f"{file}: rc_table.{key} is not allowed: must be an array of numbers (rows: T_K)")
    try:
        return RCTable(**{k: v for k, v in tab.items() if k != "source"})
    except ParameterError as exc:
        raise CellFileError(f"{file}: rc_table: {str(exc).removeprefix('RCTable.')}") from None


def find_cell(name_or_path: str | Path) -> Path:
    """The path of a shipped cell name or of a cell file; CellFileError listing the shipped names otherwise."""
    shipped = shipped_cells()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.exists():  # a FIFO, device or folder: never opened (a FIFO would hang the read)
        raise CellFileError(f"cell {str(name_or_path)!r}: cannot read the cell file (it is not a regular file)")
    raise CellFileError(f"cell {str(name_or_path)!r} is neither a shipped cell ({', '.join(shipped)}) nor a file")


def load_cell_file(name_or_path: str | Path, base_dir: Path | None = None) -> CellFile:
    """Load a shipped cell by name or a cell file by path (relative paths: to ``base_dir``, else the cwd)."""
    p = Path(name_or_path)
    if base_dir is not None and not p.is_absolute() and str(name_or_path) not in shipped_cells():
        p = base_dir / p
    path = find_cell(p if p.is_file() else name_or_path)
    try:
        doc = tomllib.loads(read_input_file(path, "cell file", CellFileError).decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise CellFileError(f"{path}: not valid UTF-8 TOML: {exc}") from None
    return parse_cell(doc, str(path), path.parent)


def load_cell(name_or_path: str | Path) -> CellParams:
    """The CellParams of a shipped cell name (e.g. 'a123_anr26650') or a cell file path."""
    return load_cell_file(name_or_path).cell
