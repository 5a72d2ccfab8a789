"""Scenario files: a TOML file a user edits, validated into a frozen :class:`Scenario`.

Every field is checked. An unknown key, a wrong type or a value out of range raises
:class:`ScenarioError` (a ValueError) whose message names the file, the key path (e.g.
``vehicle.mass_kg``), the value and what is allowed. Parameter dataclasses keep their own checks:
a :class:`~aev_ocp.params.ParameterError` is caught and re-raised with the file and key path.

Schema (model units unless a key says otherwise; see README.md "Scenario files")::

    name = "table1"                     # optional, defaults to the file stem
    description = "..."                 # optional
    compare = ["proposed", "ovfl"]      # optional: run the whole platoon once per law

    [units]       length_m, speed_mps                       (model guide §1)
    [leader]      kind = "constant" | "paper" | "cycle" | "array"
                  constant: v                               [model speed]
                  paper:    v0, amplitude, forcing_end      (paper eq. acc5; forcing_end [model time])
                  cycle:    cycle = "udds" | "hwfet" | "us06" (SI data, converted with [units])
                  array:    times, speeds, unit = "model" | "si"  (si: [s], [m/s])
                  trace:    file (CSV, relative to the scenario file), time_column ("time"),
                            speed_column ("speed") | position_column, time_unit ("s" | "ms" | "min"),
                            speed_unit ("m/s" | "km/h" | "mph" | "ft/s"), position_unit ("m" | "km" |
                            "ft" | "mi"), max_gap_s (10), filter_column + filter_value (one vehicle's rows);
                            resampled as the cycles are (linear, held after the end)
    [platoon]     followers, law | laws, gap0_first, gap0_others | gap0 | gaps0,
                  speed0 | speed0_factor | speeds0
    [carfollowing] alpha, beta, kappa, eps; a sub-table per law name holds that law's
                  coefficients, e.g. [carfollowing.idm] a_max = 1.0
    [simulation]  t_end [model time], dt_out, rtol, atol

Every model-unit key has an SI twin (:data:`SI_TWINS`), converted with the file's ``[units]``:
simulation.t_end_s, dt_out_s [s]; platoon.gap0_m, gap0_first_m, gap0_others_m, gaps0_m [m],
speed0_mps, speeds0_mps [m/s]; leader.v_mps, v0_mps [m/s], amplitude_mps2 [m/s²], forcing_end_s,
times_s [s], speeds_mps [m/s]. Give one key of a pair, not both.

    [vehicle] [cell] [pack]  fields of VehicleParams, CellParams, PackParams (SI names); [cell] name = "<shipped
                  cell>" (aev_ocp/data/cells/, e.g. "a123_anr26650") or file = "<cell file>" selects a cell file
                  (aev_ocp.cells), its other keys override it; the pack layout stays in [pack]
    [thermal]     fields of ThermalParams: enabled, ambient_K, T0_K, h_Wpm2K, cooling_power_W, T_max_K (the lumped
                  pack temperature, aev_ocp.models.thermal; off by default)
    [limits]      fields of VehicleLimits (SI names): a_min_mps2, a_max_mps2, jerk_max_mps3, lag_s,
                  v_max_mps, enabled; every vehicle's physical limits, enforced by the plant for every
                  controller (default: VehicleLimits(); the paper's scenarios state enabled = false)

Other top-level tables are rejected unless a module registered them with
:func:`register_section`; their validated values land in ``Scenario.extra``.
"""

from __future__ import annotations

import copy
import dataclasses
import errno
import math
import os
import re
import stat
import tomllib
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from .models.carfollowing import LAW_REGISTRY, V_INF, CarFollowingLaw, make_law
from .models.leader import (CYCLES, LENGTH_UNITS, MAX_GAP_S, SPEED_UNITS, TIME_UNITS, ConstantSpeed, LeaderProfile,
                            PaperLeader, SpeedTrace, drive_cycle, read_trace_csv, trace_leader)
from .overrides import SI_TWINS, apply_to_document, parse_assignments
from .overrides import si_twin as si_twin  # re-exported
from .cells import CellFileError, load_cell_file, shipped_cells
from .params import (CarFollowingParams, CellParams, Check, EVParams, PackParams, ParameterError, SimOptions,
                     ThermalParams, Units, VehicleLimits, VehicleParams, field_checks)
from .limits import DEFAULT_MEMORY_LIMIT_GB as DEFAULT_MEMORY_LIMIT_GB  # re-exported: the budget lives in limits
from .limits import BYTES_PER_SAMPLE, estimate_run_bytes, memory_limit_bytes, n_samples, read_regular_file
from .results import check_safe_name

LEADER_KINDS = ("constant", "paper", "cycle", "array", "trace")
SCENARIO_DIR_NAME = "scenarios"  # the repository's folder of scenario files
PACKAGED_DIR_NAME = "scenario_files"  # inside the package: a link to the repository's folder
MAX_FILE_BYTES = 16 * 2**20  # a scenario file is a hand-edited TOML file; a bigger one is a mistake
MIN_SAMPLES = 100  # thinning never leaves fewer output intervals than this
MAX_SAMPLES = 1_000_000  # samples per follower (t_end/dt_out); shipped scenarios need 7 001 ... 70 001


class ScenarioError(ValueError):
    """A scenario file is invalid; the message names the file, the key path and the value."""


class ScenarioWarning(UserWarning):
    """A scenario is valid but questionable (e.g. the leader is faster than any law can follow)."""


_MISSING = object()

def _from_si(units: Units, dim: str) -> Callable[[float], float]:
    return {"time": units.time_from_si, "length": units.length_from_si, "speed": units.speed_from_si,
            "accel": units.accel_from_si}[dim]


def _type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


class TableReader:
    """Reads one TOML table with typed, range-checked getters that name the file and key path.

    Section validators registered with :func:`register_section` receive one of these. Call
    :meth:`finish` at the end: it rejects every key that was not read.
    """

    def __init__(self, table: dict[str, Any], path: str, file: str) -> None:
        self.table, self.path, self.file = table, path, file
        self._seen: set[str] = set()

    # -- errors --------------------------------------------------------------------------
    def key_path(self, key: str) -> str:
        """Dotted key path of ``key`` in this table."""
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, value: Any, allowed: str) -> ScenarioError:
        """A ScenarioError naming the file, ``key``'s path, the value and what is allowed."""
        return ScenarioError(f"{self.file}: {self.key_path(key)} = {value!r} is not allowed: {allowed}")

    def has(self, key: str) -> bool:
        """Whether ``key`` is present (marks nothing as read)."""
        return key in self.table

    def _get(self, key: str, default: Any) -> Any:
        self._seen.add(key)
        if key in self.table:
            return self.table[key]
        if default is _MISSING:
            raise ScenarioError(f"{self.file}: {self.key_path(key)} is missing (required)")
        return default

    # -- typed getters -------------------------------------------------------------------
    def number(self, key: str, default: Any = _MISSING, *, gt: float | None = None, ge: float | None = None,
               lt: float | None = None, le: float | None = None) -> float:
        """A finite float (integers accepted) within the given bounds."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        return self.check_number(key, value, gt=gt, ge=ge, lt=lt, le=le)

    def check_number(self, key: str, value: Any, *, gt: float | None = None, ge: float | None = None,
                     lt: float | None = None, le: float | None = None) -> float:
        """Validate one number against bounds; ``key`` is only used in the message."""
        bounds = [f"{op} {b:g}" for op, b in ((">", gt), (">=", ge), ("<", lt), ("<=", le)) if b is not None]
        allowed = "a finite number" + (" " + " and ".join(bounds) if bounds else "")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, value, f"expected {allowed}, got a {_type_name(value)}")
        x = float(value)
        ok = (math.isfinite(x) and (gt is None or x > gt) and (ge is None or x >= ge)
              and (lt is None or x < lt) and (le is None or x <= le))
        if not ok:
            raise self.error(key, value, f"must be {allowed}")
        return x

    def integer(self, key: str, default: Any = _MISSING, *, ge: int | None = None) -> int:
        """An integer (not a boolean, not a float) >= ``ge``."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, value, f"expected an integer, got a {_type_name(value)}")
        if ge is not None and value < ge:
            raise self.error(key, value, f"must be an integer >= {ge}")
        return value

    def string(self, key: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None) -> str:
        """A string, optionally one of ``choices`` (compared in lower case)."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        if not isinstance(value, str):
            raise self.error(key, value, f"expected a string, got a {_type_name(value)}")
        if choices is not None and value.lower() not in choices:
            raise self.error(key, value, f"must be one of {list(choices)}")
        return value.lower() if choices is not None else value

    def declared(self, key: str, check: Check, default: Any = _MISSING) -> Any:
        """A value checked against a dataclass field's declared :class:`~aev_ocp.params.Check` (type and
        range declared once, beside the field); errors name the file, key path, value and range."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        if check.kind == "choice" and isinstance(value, str) and value.lower() in (check.choices or ()):
            value = value.lower()
        problem = check.problem(value)
        if problem is not None:
            raise self.error(key, value, problem)
        return float(value) if check.kind == "number" else value

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        """true or false."""
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, value, f"expected true or false, got a {_type_name(value)}")
        return value

    def numbers(self, key: str, default: Any = _MISSING, *, min_len: int = 1, gt: float | None = None,
                ge: float | None = None) -> list[float]:
        """A non-empty array of finite numbers, each within the bounds."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        if not isinstance(value, list):
            raise self.error(key, value, f"expected an array of numbers, got a {_type_name(value)}")
        if len(value) < min_len:
            raise self.error(key, value, f"needs at least {min_len} value(s)")
        return [self.check_number(f"{key}[{i}]", x, gt=gt, ge=ge) for i, x in enumerate(value)]

    def _twin(self, key: str) -> tuple[str, str]:
        si, dim = SI_TWINS[self.path][key]
        if self.has(key) and self.has(si):
            raise self.error(si, self.table[si], f"give either {self.key_path(key)} [model units] or "
                                                 f"{self.key_path(si)} [SI], not both")
        return si, dim

    def has_quantity(self, key: str) -> bool:
        """Whether the model-unit ``key`` or its SI twin (:data:`SI_TWINS`) is present."""
        return self.has(key) or self.has(SI_TWINS[self.path][key][0])

    def quantity(self, key: str, units: Units, default: Any = _MISSING, *, gt: float | None = None,
                 ge: float | None = None) -> float:
        """The model-unit number ``key`` or its SI twin converted with ``units`` (bounds 0 are the same in
        both); both given is an error naming both keys."""
        si, dim = self._twin(key)
        if self.has(si):
            return float(_from_si(units, dim)(self.number(si, gt=gt, ge=ge)))
        return self.number(key, default, gt=gt, ge=ge)

    def quantities(self, key: str, units: Units, default: Any = _MISSING, *, min_len: int = 1,
                   gt: float | None = None, ge: float | None = None) -> list[float]:
        """An array of model-unit numbers ``key`` or its SI twin converted with ``units``."""
        si, dim = self._twin(key)
        if self.has(si):
            conv = _from_si(units, dim)
            return [float(conv(x)) for x in self.numbers(si, min_len=min_len, gt=gt, ge=ge)]
        return self.numbers(key, default, min_len=min_len, gt=gt, ge=ge)

    def strings(self, key: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None) -> list[str]:
        """A non-empty array of strings, each one of ``choices`` if given (lower case)."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        if not isinstance(value, list) or not value or not all(isinstance(x, str) for x in value):
            raise self.error(key, value, "expected a non-empty array of strings")
        out = [x.lower() for x in value] if choices is not None else list(value)
        for i, x in enumerate(out):
            if choices is not None and x not in choices:
                raise self.error(f"{key}[{i}]", value[i], f"must be one of {list(choices)}")
        return out

    def sub(self, key: str, required: bool = False) -> "TableReader":
        """The sub-table ``key`` as a reader (an empty one if absent and not required)."""
        value = self._get(key, _MISSING if required else {})
        if not isinstance(value, dict):
            raise self.error(key, value, f"expected a table, got a {_type_name(value)}")
        return TableReader(value, self.key_path(key), self.file)

    def unread(self) -> list[str]:
        """Keys present but not read so far."""
        return [k for k in self.table if k not in self._seen]

    def finish(self, allowed_hint: Sequence[str] | None = None) -> None:
        """Reject every key that was not read (unknown keys), listing the known ones."""
        extra = self.unread()
        if extra:
            known = sorted(allowed_hint if allowed_hint is not None else self._seen)
            raise ScenarioError(f"{self.file}: unknown key {self.key_path(extra[0])!r} "
                                f"(= {self.table[extra[0]]!r}); allowed keys here: {known}")


SectionValidator = Callable[[TableReader], Any]
_SECTIONS: dict[str, SectionValidator] = {}
_CORE_TABLES = ("units", "leader", "platoon", "carfollowing", "simulation", "vehicle", "cell", "pack", "limits",
                "thermal")
_CORE_KEYS = ("name", "description", "compare")
# Modules that register extra sections on import; imported on demand the first time their table
# appears (the loader's registry: it imports no section's code itself).
SECTION_PROVIDERS: dict[str, str] = {"mpc": "aev_ocp.mpc.scenario", "ring": "aev_ocp.ring.scenario",
                                     "mismatch": "aev_ocp.estimation.scenario", "sensors": "aev_ocp.estimation.scenario"}
#: Registered sections that describe a whole run of their own (no [leader], [platoon], [simulation]; their own
#: loader) -> the command that runs such a file. The platoon loader refuses them with that pointer, and
#: :func:`shipped_scenarios` lists them only when asked.
STANDALONE_SECTIONS: dict[str, str] = {"ring": "aev-ocp ring"}


def register_section(name: str, validator: SectionValidator) -> None:
    """Allow a top-level table ``[name]`` in scenario files.

    ``validator(reader)`` receives a :class:`TableReader` over the table, reads and checks its keys
    (raising through ``reader.error(...)``; ``reader.finish()`` rejects unknown keys) and returns the
    validated value, stored as ``Scenario.extra[name]``. It is called only when the table is present.
    """
    if name in _CORE_TABLES or name in _CORE_KEYS:
        raise ValueError(f"register_section: {name!r} is a core scenario key")
    _SECTIONS[name] = validator


def registered_sections() -> list[str]:
    """Names of the registered extra sections."""
    return sorted(_SECTIONS)


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Model units unless a name says otherwise.

    laws: one car-following law per follower; gaps0[i], speeds0[i]: h_i(0), v_i(0) of follower i+1;
    t_end, dt_out [model time]; compare: law names to run side by side (each for the whole platoon);
    cf: the car-following coefficients; law_overrides: per-law extra coefficients; extra: validated
    registered sections.
    """

    name: str
    description: str
    units: Units
    leader: LeaderProfile
    laws: tuple[CarFollowingLaw, ...]
    gaps0: tuple[float, ...]
    speeds0: tuple[float, ...]
    t_end: float
    ev: EVParams
    dt_out: float = 0.01
    rtol: float = 1e-10
    atol: float = 1e-10
    compare: tuple[str, ...] = ()
    cf: CarFollowingParams = field(default_factory=CarFollowingParams)
    law_overrides: dict[str, dict[str, float]] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None
    document: dict[str, Any] | None = field(default=None, compare=False, repr=False)  # the TOML as parsed

    @property
    def file_label(self) -> str:
        """How messages name this scenario: its file, else its name."""
        return str(self.source) if self.source is not None else self.name

    @property
    def n_followers(self) -> int:
        """Number of followers."""
        return len(self.laws)

    def law(self, name: str) -> CarFollowingLaw:
        """The law ``name`` with this scenario's coefficients."""
        return make_law(name, self.cf, **self.law_overrides.get(name.lower(), {}))

    def runs(self) -> list[tuple[str, tuple[CarFollowingLaw, ...]]]:
        """(label, laws per follower) for each run: one per ``compare`` entry, else the platoon as given."""
        if self.compare:
            return [(c, (self.law(c),) * self.n_followers) for c in self.compare]
        names = sorted({law.name for law in self.laws})
        return [("+".join(names), self.laws)]

    def simulate_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for :func:`aev_ocp.simulate.simulate_platoon` (besides leader and laws)."""
        return {"gaps0": list(self.gaps0), "speeds0": list(self.speeds0), "t_end": self.t_end,
                "ev": self.ev, "dt_out": self.dt_out, "rtol": self.rtol, "atol": self.atol}

    def run(self, progress: Callable[[str, float, float], None] | None = None, *, only: str | None = None,
            **overrides: Any) -> dict[str, Any]:
        """Simulate every run of :meth:`runs` (``only``: just the run of that label); returns {label: SimulationResult}.

        progress(label, t, t_end) is called as each run advances [model time]; ``overrides`` replace
        keyword arguments of :func:`aev_ocp.simulate.simulate_platoon` (e.g. rtol, dt_out, t_end).
        """
        from .simulate import simulate_platoon

        base = {**self.simulate_kwargs(), **overrides}
        check_run_size(self.n_followers, float(base["t_end"]), float(base["dt_out"]),
                       str(self.source or self.name))
        out: dict[str, Any] = {}
        runs = self.runs()
        if only is not None and only not in dict(runs):
            raise ScenarioError(f"{self.file_label}: no run {only!r}; runs: {[lab for lab, _ in runs]}")
        for label, laws in runs:
            if only is not None and label != only:
                continue
            kwargs = dict(base)
            cb = (lambda t, te, _l=label: progress(_l, t, te)) if progress is not None else None
            out[label] = simulate_platoon(self.leader, list(laws), progress=cb, **kwargs)
        return out

    def with_overrides(self, overrides: dict[str, Any]) -> "Scenario":
        """A copy with dotted-path overrides ({"carfollowing.kappa": 0.05, "mpc.w_Q": 2}) applied to the
        scenario's TOML document and validated exactly like the file (see :mod:`aev_ocp.overrides`)."""
        return apply_to_scenario(self, overrides)

    def replace(self, **changes: Any) -> "Scenario":
        """A copy with some fields changed (e.g. ``replace(t_end=5.0)`` for a quick run); every change takes
        effect or raises ScenarioError.

        Fields that a file key states (name, description, compare, units, cf, law_overrides, t_end,
        dt_out, rtol, atol) go through :meth:`with_overrides` when the scenario has its document, so
        whatever is derived from them (the laws from cf, the leader and ev from units, …) is rebuilt
        and validated. Object fields (leader, laws, gaps0, speeds0, ev, extra, source) are set as given
        and checked for consistency; the copy then has no document (no file describes it; ``source`` alone
        keeps it).
        """
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)} - {"document"})
        if unknown:
            raise ScenarioError(f"{self.file_label}: replace(): unknown field(s) {unknown}; fields are "
                                f"{[f.name for f in dataclasses.fields(self) if f.name != 'document']}")
        changes.pop("document", None)
        keyed = {k: changes.pop(k) for k in list(changes) if k in _REPLACE_KEYS}
        out = self
        if keyed:
            if self.document is not None:
                out = self.with_overrides(_replace_overrides(keyed))
            else:
                out = _replace_without_document(self, keyed)
        if changes:
            stale = set(changes) - {"source"}  # no file key states these objects: the document no longer applies
            drop_document: dict[str, Any] = {"document": None} if stale else {}
            fixed = dataclasses.replace(out, **changes, **drop_document)
            if "units" not in keyed and "ev" in changes and changes["ev"].units != fixed.units:
                raise ScenarioError(f"{self.file_label}: replace(ev=...): ev.units ({changes['ev'].units}) differ "
                                    f"from the scenario's units ({fixed.units}); pass units= too")
            if "laws" in changes and fixed.compare:
                raise ScenarioError(f"{self.file_label}: replace(laws=...) would be ignored: the scenario sets "
                                    f"compare = {list(fixed.compare)}, so every run uses those laws; "
                                    "pass compare=() too")
            n = len(fixed.laws)
            if len(fixed.gaps0) != n or len(fixed.speeds0) != n:
                raise ScenarioError(f"{self.file_label}: replace(): {n} laws but {len(fixed.gaps0)} gaps0 and "
                                    f"{len(fixed.speeds0)} speeds0; give one of each per follower")
            out = fixed
        return out


#: Scenario fields that a file key states: replace() routes them through with_overrides.
_REPLACE_KEYS = ("name", "description", "compare", "units", "cf", "law_overrides", "t_end", "dt_out", "rtol", "atol")


def _replace_overrides(keyed: dict[str, Any]) -> dict[str, Any]:
    """replace() arguments of the file-keyed fields as dotted-path overrides."""
    ov: dict[str, Any] = {}
    simple = {"name": "name", "description": "description", "t_end": "simulation.t_end",
              "dt_out": "simulation.dt_out", "rtol": "simulation.rtol", "atol": "simulation.atol"}
    for k, v in keyed.items():
        if k in simple:
            ov[simple[k]] = v
        elif k == "compare":
            ov["compare"] = list(v) or None  # None removes the key: no compare
        elif k in ("units", "cf"):
            table = "units" if k == "units" else "carfollowing"
            ov.update({f"{table}.{f.name}": getattr(v, f.name) for f in dataclasses.fields(v)})
        elif k == "law_overrides":
            for law, coeffs in v.items():
                ov.update({f"carfollowing.{law}.{c}": x for c, x in coeffs.items()})
    return ov


def _replace_without_document(sc: "Scenario", keyed: dict[str, Any]) -> "Scenario":
    """replace() of file-keyed fields on a scenario built in Python: rebuild what derives from them."""
    out = dataclasses.replace(sc, **keyed)
    if "cf" in keyed or "law_overrides" in keyed:
        try:
            laws = tuple(make_law(law.name, out.cf, **out.law_overrides.get(law.name, {})) for law in out.laws)
        except (KeyError, TypeError, ParameterError) as exc:
            raise ScenarioError(f"{sc.file_label}: replace(): cannot rebuild the laws: {exc}") from None
        out = dataclasses.replace(out, laws=laws)
    if "units" in keyed:
        if not isinstance(out.leader, (ConstantSpeed, PaperLeader)):
            raise ScenarioError(f"{sc.file_label}: replace(units=...): the leader ({type(out.leader).__name__}) "
                                "was converted with the old units and this scenario has no document to rebuild "
                                "it from; pass leader= too, or load the scenario from a file")
        out = dataclasses.replace(out, ev=dataclasses.replace(out.ev, units=out.units))
    return out


# ----------------------------------------------------------------------------- size of a run
def _round_up(x: float) -> float:
    """The smallest number of 3 significant digits >= x (x > 0)."""
    step = 10.0 ** (math.floor(math.log10(x)) - 2)
    y = math.ceil(x / step - 1e-9) * step
    return float(f"{y:.3g}") if float(f"{y:.3g}") >= x else y


def _gb(x: float) -> str:
    return f"{x / 1e9:.3g} GB"


def check_run_size(n_followers: int, t_end: float, dt_out: float, file: str = "<scenario>") -> float:
    """Raise ScenarioError (naming the key to change) if a run needs more than :func:`memory_limit_bytes`.
    Returns the estimate [bytes]."""
    need, limit = estimate_run_bytes(n_followers, t_end, dt_out), memory_limit_bytes()
    if need <= limit:
        return need
    per_vehicle = BYTES_PER_SAMPLE * n_samples(t_end, dt_out)
    max_followers = int(limit // per_vehicle)
    k_max = limit / (BYTES_PER_SAMPLE * n_followers)
    if k_max - 1 < MIN_SAMPLES or max_followers < 1 and t_end / SimOptions().chunk > k_max:
        fix = (f"lower platoon.followers to at most {max_followers}" if max_followers >= 1
               else "lower simulation.t_end")
    else:
        fix = (f"raise simulation.dt_out to at least {_round_up(t_end / (k_max - 1)):.3g}"
               + (" or lower platoon.followers" if n_followers > 1 else " or lower simulation.t_end"))
    raise ScenarioError(f"{file}: the run needs about {_gb(need)} ({n_followers} followers x "
                        f"{n_samples(t_end, dt_out):.3g} samples, simulation.t_end = {t_end:g}, simulation.dt_out = "
                        f"{dt_out:g}), more than the limit of {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB): {fix}")


def thinned_dt_out(n_followers: int, t_end: float, dt_out: float, file: str = "<scenario>") -> float:
    """dt_out, raised (with a ScenarioWarning) just enough that the run fits the memory budget when at
    least MIN_SAMPLES output intervals remain; otherwise :func:`check_run_size` refuses the run."""
    chunk = SimOptions().chunk
    if n_samples(t_end, dt_out) > MAX_SAMPLES:  # not a large platoon but an absurd grid: refuse, never thin
        if t_end / chunk + 1 > MAX_SAMPLES:
            raise ScenarioError(f"{file}: simulation.t_end = {t_end:g} is not allowed: the integrator samples "
                                f"at least every {chunk:g} time units, {t_end / chunk:.3g} samples per follower, "
                                f"more than {MAX_SAMPLES}; lower simulation.t_end to at most {MAX_SAMPLES * chunk:g}")
        raise ScenarioError(f"{file}: simulation.dt_out = {dt_out:g} is not allowed: {n_samples(t_end, dt_out):.3g} "
                            f"samples per follower over simulation.t_end = {t_end:g}, more than {MAX_SAMPLES}; raise "
                            f"simulation.dt_out to at least {_round_up(t_end / (MAX_SAMPLES - 2)):.3g}")
    limit = memory_limit_bytes()
    if estimate_run_bytes(n_followers, t_end, dt_out) <= limit:
        return dt_out
    k_max = limit / (BYTES_PER_SAMPLE * n_followers) - 2
    new = _round_up(t_end / math.floor(k_max)) if k_max >= MIN_SAMPLES else dt_out
    if k_max >= MIN_SAMPLES and new < SimOptions().chunk and estimate_run_bytes(n_followers, t_end, new) <= limit:
        warnings.warn(ScenarioWarning(
            f"{file}: simulation.dt_out raised from {dt_out:g} to {new:g} so that {n_followers} followers over "
            f"t_end = {t_end:g} fit in {_gb(limit)} ($AEV_OCP_MAX_MEMORY_GB; {_gb(estimate_run_bytes(n_followers, t_end, dt_out))} "
            f"were needed); ω, ∫Q and the RMS metrics are integrated by the solver and do not depend on dt_out, "
            f"min gap and min speed are taken from the coarser samples"), stacklevel=3)
        return new
    check_run_size(n_followers, t_end, dt_out, file)
    return dt_out  # pragma: no cover - check_run_size raised


# ----------------------------------------------------------------------------- sections
def read_declared(cls: type, reader: TableReader, keys: Sequence[str] | None = None) -> dict[str, Any]:
    """The keys of ``reader``'s table that are fields of dataclass ``cls`` (or ``keys``), each checked against
    the type and range the dataclass declares (:func:`aev_ocp.params.field_checks`): a range is written
    once, beside the field, and the TOML table derives from it. Undeclared fields are read as numbers."""
    checks = field_checks(cls)
    names = list(keys) if keys is not None else [f.name for f in dataclasses.fields(cls)]
    out: dict[str, Any] = {}
    for key in names:
        if reader.has(key):
            check = checks.get(key)
            out[key] = reader.declared(key, check) if check is not None else reader.number(key)
    return out


def _rewrap(reader: TableReader, exc: ParameterError, keys: Sequence[str]) -> ScenarioError:
    """A ParameterError of a dataclass's cross-field rule, with the file and the key path."""
    field_name = next((k for k in keys if f".{k} " in str(exc)), None)
    where = reader.key_path(field_name) if field_name else reader.path
    return ScenarioError(f"{reader.file}: {where}: {exc}")


def _params(cls: type, reader: TableReader, base: Any = None) -> Any:
    """Build a parameter dataclass from a table: types and ranges come from the dataclass's declarations."""
    names = [f.name for f in dataclasses.fields(cls)]
    defaults = base if base is not None else cls()
    kwargs = read_declared(cls, reader)
    reader.finish(allowed_hint=names)
    try:
        return dataclasses.replace(defaults, **kwargs)
    except ParameterError as exc:
        raise _rewrap(reader, exc, list(kwargs)) from None


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
    return EVParams(units=_params(Units, top.sub("units")), vehicle=_params(VehicleParams, top.sub("vehicle")),
                    cell=_cell(top.sub("cell"), source), pack=_params(PackParams, top.sub("pack")),
                    limits=_params(VehicleLimits, top.sub("limits")), thermal=_params(ThermalParams, top.sub("thermal")))


def standalone_header(doc: dict[str, Any], file: str, source: Path | None, allowed: Any,
                      kind: str) -> tuple[TableReader, str, str, EVParams]:
    """The head of a scenario form with its own command (``kind``: 'ring', 'sumo'): top-level keys checked against
    ``allowed``, then (reader, name, description, EVParams); the name defaults to the file stem made safe."""
    for key in doc:
        if key not in allowed:
            raise ScenarioError(f"{file}: unknown top-level key or table {key!r} in a {kind} scenario; allowed: "
                                f"{sorted(allowed)}")
    top = TableReader(doc, "", file)
    stem = source.stem if source is not None else kind
    name = top.string("name", re.sub(r"[^A-Za-z0-9._+-]", "_", stem).lstrip("._+-")[:100] or kind)
    try:
        check_safe_name(name)
    except ValueError as exc:
        raise top.error("name", name, str(exc).split("is not allowed: ", 1)[-1]) from None
    return top, name, top.string("description", ""), read_ev(top, source)


def _trace(r: TableReader, units: Units, source: Path | None, t_max_s: float | None = None) -> LeaderProfile:
    """[leader] kind = "trace": a recorded trajectory in a CSV file, relative to the scenario file."""
    file = r.string("file")
    path = Path(file)
    if not path.is_absolute():
        path = (source.parent if source is not None else Path.cwd()) / path
    if not path.is_file():
        raise r.error("file", file, f"not a regular file ({path}: a FIFO, device or folder)" if path.exists() else
                      f"no such file ({path}); a relative path starts at the scenario file's folder")
    speed, position = r.string("speed_column", None), r.string("position_column", None)
    if speed is not None and position is not None:
        raise r.error("position_column", position, "give speed_column or position_column, not both")
    if speed is None and position is None:
        speed = "speed"
    kw: dict[str, Any] = {"time_column": r.string("time_column", "time"), "speed_column": speed,
                          "position_column": position,
                          "time_unit": r.string("time_unit", "s", choices=tuple(TIME_UNITS)),
                          "speed_unit": r.string("speed_unit", "m/s", choices=tuple(SPEED_UNITS)),
                          "position_unit": r.string("position_unit", "m", choices=tuple(LENGTH_UNITS)),
                          "max_gap_s": r.number("max_gap_s", MAX_GAP_S, gt=0)}
    if r.has("filter_column") != r.has("filter_value"):
        missing = "filter_value" if r.has("filter_column") else "filter_column"
        raise r.error(missing, None, "filter_column and filter_value go together (the rows of one vehicle)")
    if r.has("filter_column"):
        kw["filter_column"] = r.string("filter_column")
        value = r._get("filter_value", None)
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise r.error("filter_value", value, "expected a string or a number")
        kw["filter_value"] = value
    try:
        t, v = read_trace_csv(path, label=file, t_max_s=t_max_s, **kw)
    except ParameterError as exc:
        raise ScenarioError(f"{r.file}: {r.key_path('file')}: {exc}") from None
    return trace_leader(t, v, units, "trace")


def trace_read_s(doc: dict[str, Any], t_end: float, units: Units) -> float:
    """How much of a trace leader's file a run reads [s]: twice (the horizon t_end [model time] + the MPC's look-ahead
    N·dt of the [mpc] table, at least MPCSettings' default): a 10^7-row recording is not read to its end for a
    2 s run, and an MPC forecast or a longer horizon set in Python still finds the recorded speeds."""
    from .mpc.settings import MPCSettings

    d = MPCSettings()
    mpc: dict[str, Any] = doc["mpc"] if isinstance(doc.get("mpc"), dict) else {}
    n, dt = mpc.get("N", d.N), mpc.get("dt", d.dt)
    ok = all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0 for x in (n, dt))
    look = max(float(n) * float(dt) if ok else 0.0, d.N * d.dt)
    return 2.0 * units.time_to_si(t_end + look)


def _leader(r: TableReader, units: Units, source: Path | None = None, t_max_s: float | None = None) -> LeaderProfile:
    kind = r.string("kind", choices=LEADER_KINDS)
    leader: LeaderProfile
    if kind == "trace":
        leader = _trace(r, units, source, t_max_s)
        r.finish()
        return leader
    try:
        if kind == "constant":
            leader = ConstantSpeed(r.quantity("v", units, ge=0))  # or v_mps [m/s]
        elif kind == "paper":
            d = PaperLeader()
            leader = PaperLeader(v0=r.quantity("v0", units, d.v0, ge=0),
                                 amplitude=r.quantity("amplitude", units, d.amplitude),
                                 t_end=r.quantity("forcing_end", units, d.t_end, gt=0))
        elif kind == "cycle":
            leader = drive_cycle(r.string("cycle", choices=CYCLES), units)
        else:
            twins = [SI_TWINS["leader"][k][0] for k in ("times", "speeds") if r.has(SI_TWINS["leader"][k][0])]
            if twins and r.has("unit"):
                raise r.error("unit", r.table["unit"], f"applies to leader.times/leader.speeds; {twins[0]} is in SI "
                                                       "already: remove leader.unit or use the model keys")
            unit = r.string("unit", "model", choices=("model", "si"))
            # unit = "si": times [s], speeds [m/s] (converted below); times_s / speeds_mps: converted here
            times = r.quantities("times", units, min_len=2)
            speeds = r.quantities("speeds", units, min_len=2, ge=0)
            if len(times) != len(speeds):
                raise r.error("speeds", speeds, f"needs one value per entry of leader.times ({len(times)})")
            if times[0] != 0 or any(b <= a for a, b in zip(times, times[1:])):
                raise r.error("times", times, "must start at 0 and increase strictly")
            leader = (SpeedTrace.from_si(times, speeds, units, label="array") if unit == "si"
                      else SpeedTrace(tuple(times), tuple(speeds), label="array"))
    except ParameterError as exc:
        raise ScenarioError(f"{r.file}: {r.path}: {exc}") from None
    r.finish()
    return leader


def _carfollowing(r: TableReader) -> tuple[CarFollowingParams, dict[str, dict[str, float]]]:
    coeffs = {f.name for f in dataclasses.fields(CarFollowingParams)}
    cf_table = {k: v for k, v in r.table.items() if k in coeffs}
    cf = _params(CarFollowingParams, TableReader(cf_table, r.path, r.file))
    r._seen.update(cf_table)
    overrides: dict[str, dict[str, float]] = {}
    for key, value in r.table.items():
        if key in coeffs:
            continue
        if key.lower() not in LAW_REGISTRY:
            raise r.error(key, value, f"unknown key: allowed are {sorted(coeffs)} or a sub-table named after "
                                      f"a law, one of {sorted(LAW_REGISTRY)}")
        sub = r.sub(key, required=True)
        ov = {k: sub.number(k) for k in list(sub.table)}
        try:
            make_law(key, cf, **ov)
        except (TypeError, ParameterError) as exc:
            raise ScenarioError(f"{r.file}: {sub.path}: invalid coefficients for law {key!r}: {exc}") from None
        overrides[key.lower()] = ov
    return cf, overrides


def _per_vehicle(r: TableReader, n: int, list_key: str, values: list[float] | None) -> list[float] | None:
    if values is not None and len(values) != n:
        raise r.error(list_key, values, f"needs exactly {n} values, one per follower (platoon.followers = {n})")
    return values


def _platoon(r: TableReader, leader: LeaderProfile, cf: CarFollowingParams,
             overrides: dict[str, dict[str, float]], compare: tuple[str, ...] = (),
             size: Callable[[int], None] | None = None, units: Units | None = None
             ) -> tuple[tuple[CarFollowingLaw, ...], list[float], list[float]]:
    laws_known = sorted(LAW_REGISTRY)
    if r.has("laws") and r.has("law"):
        raise r.error("laws", r.table["laws"], "give either platoon.law (all followers) or platoon.laws, not both")
    if r.has("laws"):
        names = r.strings("laws", choices=laws_known)
        n = r.integer("followers", len(names), ge=1)
        if len(names) != n:
            raise r.error("laws", names, f"needs exactly {n} names, one per follower")
        if size is not None:
            size(n)
        if compare:  # a mixed platoon never runs when compare is set: say so instead of ignoring it
            raise r.error("laws", r.table["laws"], f"cannot be combined with compare = {list(compare)}, which runs "
                                                   "the whole platoon once per compared law; remove one of them")
    else:
        n = r.integer("followers", ge=1)
        law_name = r.string("law", "proposed", choices=laws_known)
        if compare and r.has("law") and law_name not in compare:
            raise r.error("law", r.table["law"], f"is never run: compare = {list(compare)} runs the whole platoon "
                                                 f"once per compared law; add {law_name!r} to compare, or remove compare")
        if size is not None:
            size(n)  # refuse an oversized platoon before building anything of its size
        names = [law_name] * n
    laws = tuple(make_law(nm, cf, **overrides.get(nm, {})) for nm in names)

    # initial gaps (each key or its SI twin, e.g. gap0_first or gap0_first_m [m])
    u = units if units is not None else Units()
    tw = SI_TWINS["platoon"]
    for g in ("gap0", "gaps0", "gap0_first", "gap0_others"):
        r._twin(g)  # a key and its SI twin together: an error naming both
    whole = [k for k in ("gap0", "gap0_m", "gaps0", "gaps0_m") if r.has(k)]
    part = [k for k in ("gap0_first", "gap0_first_m", "gap0_others", "gap0_others_m") if r.has(k)]
    if len(whole) > 1 or (whole and part):
        other = (whole[1:] + part)[0]
        raise r.error(other, r.table[other], f"give one of platoon.gap0 (every follower), platoon.gaps0 (one per "
                                             f"follower) or gap0_first/gap0_others (each also in m as *_m); "
                                             f"{r.key_path(whole[0])} is given too")
    if r.has_quantity("gaps0"):
        gaps = _per_vehicle(r, n, tw["gaps0"][0] if r.has(tw["gaps0"][0]) else "gaps0",
                            r.quantities("gaps0", u, gt=0))
    elif r.has_quantity("gap0"):
        gaps = [r.quantity("gap0", u, gt=0)] * n
    else:
        if not part:
            raise ScenarioError(f"{r.file}: {r.path}: the initial gaps are missing: give gap0_first (model length) "
                                "or gap0_first_m [m] (and optionally gap0_others / gap0_others_m), gap0 / gap0_m "
                                "(every follower) or gaps0 / gaps0_m (one per follower)")
        first = r.quantity("gap0_first", u, gt=0)
        others = r.quantity("gap0_others", u, first, gt=0)
        gaps = [first] + [others] * (n - 1)

    # initial speeds (speed0 / speeds0 or their SI twins speed0_mps / speeds0_mps [m/s])
    r._twin("speed0"), r._twin("speeds0")  # a key and its SI twin together: an error naming both
    given = [k for k in ("speed0", "speed0_mps", "speed0_factor", "speeds0", "speeds0_mps") if r.has(k)]
    if len(given) != 1:
        raise ScenarioError(f"{r.file}: {r.path}: give exactly one of speed0 (model speed) or speed0_mps [m/s], "
                            f"speed0_factor (× the leader's initial speed) or speeds0 / speeds0_mps (one per "
                            f"follower); got {given or 'none'}")
    if given[0].startswith("speeds0"):
        speeds = _per_vehicle(r, n, given[0], r.quantities("speeds0", u, ge=0))
    elif given[0].startswith("speed0") and given[0] != "speed0_factor":
        speeds = [r.quantity("speed0", u, ge=0)] * n
    else:
        v_l0 = float(leader.speed_np(0.0)[0])
        speeds = [r.number("speed0_factor", ge=0) * v_l0] * n
    r.finish()
    assert gaps is not None and speeds is not None
    return laws, gaps, speeds


def _load_provider(key: str) -> None:
    """Import the package that registers section ``key`` (if one is known and it is not registered)."""
    mod = SECTION_PROVIDERS.get(key)
    if mod is not None and key not in _SECTIONS:
        import importlib

        importlib.import_module(mod)


def _check_top_level(doc: dict[str, Any], file: str) -> None:
    for key in doc:
        _load_provider(key)
    for key, value in doc.items():
        if key in _CORE_KEYS:
            continue
        if key in _CORE_TABLES or key in _SECTIONS:
            if not isinstance(value, dict):
                raise ScenarioError(f"{file}: {key} = {value!r} is not allowed: expected a table [{key}], "
                                    f"got a {_type_name(value)}")
            continue
        raise ScenarioError(f"{file}: unknown top-level key or table {key!r}; allowed: "
                            f"{sorted(_CORE_KEYS + _CORE_TABLES + tuple(_SECTIONS))}")


def parse_scenario(doc: dict[str, Any], file: str = "<scenario>", *, source: Path | None = None) -> Scenario:
    """Validate a parsed TOML document (``file`` names it in messages) into a :class:`Scenario`."""
    for key, command in STANDALONE_SECTIONS.items():
        if key in doc:
            raise ScenarioError(f"{file}: a {key} scenario (it has a [{key}] table), not a platoon: run it with "
                                f"'{command} {file}'")
    _check_top_level(doc, file)
    top = TableReader(doc, "", file)
    if top.has("name"):
        name = top.string("name")
        try:
            check_safe_name(name)
        except ValueError as exc:
            raise top.error("name", name, str(exc).split("is not allowed: ", 1)[-1]) from None
    else:  # the file stem, made safe (it names the default output folder results/<name>/)
        stem = source.stem if source is not None else "scenario"
        name = re.sub(r"[^A-Za-z0-9._+-]", "_", stem).lstrip("._+-")[:100] or "scenario"
    description = top.string("description", "")
    compare = tuple(top.strings("compare", [], choices=sorted(LAW_REGISTRY)))
    dups = sorted({c for c in compare if compare.count(c) > 1})
    if dups:
        raise top.error("compare", doc["compare"], f"names {dups[0]!r} twice; each law runs once")

    ev = read_ev(top, source)
    units = ev.units

    sim = top.sub("simulation", required=True)
    t_end = sim.quantity("t_end", units, gt=0)  # or t_end_s [s]
    # dt_out, rtol, atol: types, ranges and defaults are SimOptions's (rtol/atol: what the integrators honour)
    dt_si = sim.has(SI_TWINS["simulation"]["dt_out"][0])
    declared = read_declared(SimOptions, sim, ("rtol", "atol") if dt_si else ("dt_out", "rtol", "atol"))
    if dt_si:
        declared["dt_out"] = sim.quantity("dt_out", units, gt=0)  # dt_out_s [s]
    opts = dataclasses.replace(SimOptions(), **declared)
    dt_out, rtol, atol = opts.dt_out, opts.rtol, opts.atol
    if dt_out > t_end:
        raise sim.error("dt_out_s" if dt_si else "dt_out", sim.table["dt_out_s" if dt_si else "dt_out"],
                        f"must be <= the horizon (simulation.t_end = {t_end:g} model time = "
                        f"{units.time_to_si(t_end):g} s)")
    sim.finish()

    cf, overrides = _carfollowing(top.sub("carfollowing"))
    leader = _leader(top.sub("leader", required=True), units, source, trace_read_s(doc, t_end, units))
    sized: dict[str, float] = {}

    def size(n: int) -> None:
        sized["dt_out"] = thinned_dt_out(n, t_end, dt_out, file)

    laws, gaps, speeds = _platoon(top.sub("platoon", required=True), leader, cf, overrides, compare, size, units)
    dt_out = sized.get("dt_out", dt_out)
    used = set(compare) | {law.name for law in laws} | {"proposed"}  # proposed: the MPC's fallback law
    for law_name in overrides:
        if law_name not in used:
            warnings.warn(ScenarioWarning(
                f"{file}: carfollowing.{law_name} sets coefficients of law {law_name!r}, which no run uses "
                f"(runs: {sorted(set(compare) or {law.name for law in laws})})"), stacklevel=2)

    extra: dict[str, Any] = {}
    for sec, validator in _SECTIONS.items():
        if sec in doc:
            reader = top.sub(sec)
            try:
                extra[sec] = validator(reader)
            except ScenarioError:
                raise
            except (ValueError, TypeError) as exc:
                raise ScenarioError(f"{file}: [{sec}]: {exc}") from None
            reader.finish()
    top.finish()

    scenario = Scenario(name=name, description=description, units=units, leader=leader, laws=laws,
                        gaps0=tuple(gaps), speeds0=tuple(speeds), t_end=t_end, ev=ev, dt_out=dt_out,
                        rtol=rtol, atol=atol, compare=compare, cf=cf, law_overrides=overrides, extra=extra,
                        source=source, document=copy.deepcopy(doc))
    check_leader_speed(scenario, file)
    return scenario


def check_leader_speed(scenario: Scenario, file: str = "<scenario>") -> float:
    """Warn (ScenarioWarning) if the leader's top speed reaches V∞ = 1 + tanh 2; returns that top speed."""
    v_max = scenario.leader.max_speed(scenario.t_end)
    if v_max >= V_INF:
        u = scenario.units
        warnings.warn(ScenarioWarning(
            f"{file}: the leader reaches {v_max:.4g} model speed ({u.speed_to_si(v_max):.4g} m/s), at or above "
            f"V∞ = 1 + tanh 2 = {V_INF:.4f} ({u.speed_to_si(V_INF):.4g} m/s with units.speed_mps = "
            f"{u.speed_mps:g}): no optimal-velocity law can keep up; raise units.speed_mps above "
            f"{u.speed_to_si(v_max) / V_INF:.4g}"), stacklevel=3)
    return v_max


def read_scenario_text(p: Path, file: str) -> str:
    """The text of scenario file ``p`` (``file`` names it in messages): a regular file of at most
    MAX_FILE_BYTES, UTF-8; anything else is a ScenarioError."""
    data = read_regular_file(p, "scenario file", ScenarioError, MAX_FILE_BYTES, label=file)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ScenarioError(f"{file}: not a text file in UTF-8 (byte 0x{data[exc.start]:02x} at line {line}); "
                            "scenario files are UTF-8 TOML") from None


def read_scenario_doc(p: Path, file: str) -> dict[str, Any]:
    """The TOML document of scenario file ``p`` (``file`` names it in messages), for every scenario form: the file
    checked and read by :func:`read_scenario_text`, then parsed; bad TOML or too deep nesting is a ScenarioError."""
    text = read_scenario_text(p, file)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{file}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{file}: not valid TOML for a scenario: arrays or tables nested too deeply") from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (a path, or the name of a shipped scenario, see :func:`find_scenario`)."""
    p = find_scenario(path)
    file = str(path)
    doc = read_scenario_doc(p, file)
    try:
        return parse_scenario(doc, file, source=p)
    except RecursionError:
        raise ScenarioError(f"{file}: arrays or tables nested too deeply for a scenario") from None


# ----------------------------------------------------------------------------- finding files
def packaged_scenario_dir() -> Path | None:
    """The scenario files installed with the package (``aev_ocp/scenario_files``), if present."""
    try:
        d = resources.files("aev_ocp") / PACKAGED_DIR_NAME
        path = Path(str(d))
    except (ModuleNotFoundError, TypeError):
        return None
    return path if path.is_dir() else None


def scenario_dirs() -> list[Path]:
    """Where shipped scenarios are looked for, in order: ./scenarios, then the packaged copy."""
    out = [Path.cwd() / SCENARIO_DIR_NAME]
    pkg = packaged_scenario_dir()
    if pkg is not None:
        out.append(pkg)
    return out


def shipped_scenarios(kind: str = "platoon") -> dict[str, Path]:
    """Shipped scenario names -> files (the first folder of :func:`scenario_dirs` that has each name) of one
    ``kind``: "platoon" (the default), a key of :data:`STANDALONE_SECTIONS` ("ring"), or "all"."""
    found: dict[str, Path] = {}
    for d in scenario_dirs():
        if d.is_dir():
            for f in sorted(d.glob("*.toml")):
                found.setdefault(f.stem, f)
    if kind != "all":
        found = {k: f for k, f in found.items() if _file_kind(f) == kind}
    return dict(sorted(found.items()))


def _file_kind(path: Path) -> str:
    """'platoon', or the standalone section a scenario file has (an unreadable file counts as a platoon: the
    platoon loader then reports what is wrong with it)."""
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return "platoon"
    return next((k for k in STANDALONE_SECTIONS if isinstance(doc.get(k), dict)), "platoon")


def find_scenario(name_or_path: str | Path) -> Path:
    """Resolve a scenario: an existing path, else a shipped scenario name (with or without .toml).

    A path that exists but is not a readable file (a folder, a loop of symbolic links, a device) is
    reported as such, not as a missing scenario."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"scenario must be a path or a scenario name (str), got {type(name_or_path).__name__}")
    p = Path(name_or_path)
    try:
        st = p.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ScenarioError(f"{name_or_path}: cannot read the scenario file (a loop of symbolic links)") from None
        st = None
    if st is not None:
        if stat.S_ISREG(st.st_mode):
            return p
        kind = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise ScenarioError(f"{name_or_path}: cannot read the scenario file (it is {kind})")
    stem = p.name[:-5] if p.name.endswith(".toml") else p.name
    if p.parent == Path(".") or str(p.parent) == SCENARIO_DIR_NAME:
        for d in scenario_dirs():
            cand = d / f"{stem}.toml"
            if cand.is_file():
                return cand
    known = ", ".join(shipped_scenarios()) or "none found"
    raise ScenarioError(f"{name_or_path}: no such scenario file (shipped scenarios: {known})")


def iter_shipped() -> Iterator[tuple[str, Path]]:
    """(name, path) of every shipped scenario."""
    yield from shipped_scenarios().items()


# ----------------------------------------------------------------------------- overrides of a scenario
def apply_to_scenario(scenario: Scenario, overrides: Mapping[str, Any]) -> Scenario:
    """``scenario`` with ``overrides`` applied to its TOML document and re-validated (see :mod:`aev_ocp.overrides`).

    The scenario must come from a document (a file, or :func:`aev_ocp.scenarios.parse_scenario`)."""
    if scenario.document is None:
        raise ScenarioError(f"{scenario.name}: overrides need the scenario's TOML document; this scenario was "
                            "built in Python or changed with replace(leader=..., laws=..., ...), which no "
                            "document describes")
    file = scenario.file_label
    doc = apply_to_document(scenario.document, overrides, file)
    return parse_scenario(doc, file, source=scenario.source)


def load_with_sets(path: str, sets: Iterable[str] | None) -> Scenario:
    """``load_scenario(path)`` with every ``--set KEY=VALUE`` applied and validated like the file.

    The one call a command needs for its ``--set`` flags (``action="append"``); raises ScenarioError
    (invalid value, unknown key) or OverrideError (malformed or ignored override), both ValueErrors
    whose message names the file and the key."""
    scenario = load_scenario(path)
    overrides = parse_assignments(sets)
    return apply_to_scenario(scenario, overrides) if overrides else scenario
