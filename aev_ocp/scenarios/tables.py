"""Reading one TOML table of a scenario file: :class:`TableReader`'s typed, range-checked getters, the errors they
raise (:class:`ScenarioError`, :class:`ScenarioWarning`) and parameter dataclasses built from a table with the
types and ranges the dataclass declares (:func:`read_declared`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Sequence

from ..errors import AevOcpError, AevOcpWarning
from ..overrides import SI_TWINS
from ..params import Check, ParameterError, Units, echo, field_checks


class ScenarioError(AevOcpError, ValueError):
    """A scenario file is invalid; the message names the file, the key path and the value."""


class ScenarioWarning(AevOcpWarning, UserWarning):
    """A scenario is valid but questionable (e.g. the leader is faster than any law can follow)."""


_MISSING = object()


def _from_si(units: Units, dim: str) -> Callable[[float], float]:
    return {
        "time": units.time_from_si,
        "length": units.length_from_si,
        "speed": units.speed_from_si,
        "accel": units.accel_from_si,
    }[dim]


def _type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array", dict: "table"}.get(
        type(value), type(value).__name__
    )


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
        return ScenarioError(f"{self.file}: {self.key_path(key)} = {echo(value)} is not allowed: {allowed}")

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
    def number(
        self,
        key: str,
        default: Any = _MISSING,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> float:
        """A finite float (integers accepted) within the given bounds."""
        value = self._get(key, default)
        if value is default and key not in self.table:
            return value
        return self.check_number(key, value, gt=gt, ge=ge, lt=lt, le=le)

    def check_number(
        self,
        key: str,
        value: Any,
        *,
        gt: float | None = None,
        ge: float | None = None,
        lt: float | None = None,
        le: float | None = None,
    ) -> float:
        """Validate one number against bounds; ``key`` is only used in the message."""
        bounds = [f"{op} {b:g}" for op, b in ((">", gt), (">=", ge), ("<", lt), ("<=", le)) if b is not None]
        allowed = "a finite number" + (" " + " and ".join(bounds) if bounds else "")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, value, f"expected {allowed}, got a {_type_name(value)}")
        x = float(value)
        ok = (
            math.isfinite(x)
            and (gt is None or x > gt)
            and (ge is None or x >= ge)
            and (lt is None or x < lt)
            and (le is None or x <= le)
        )
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

    def numbers(
        self, key: str, default: Any = _MISSING, *, min_len: int = 1, gt: float | None = None, ge: float | None = None
    ) -> list[float]:
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
            raise self.error(
                si,
                self.table[si],
                f"give either {self.key_path(key)} [model units] or {self.key_path(si)} [SI], not both",
            )
        return si, dim

    def has_quantity(self, key: str) -> bool:
        """Whether the model-unit ``key`` or its SI twin (:data:`SI_TWINS`) is present."""
        return self.has(key) or self.has(SI_TWINS[self.path][key][0])

    def quantity(
        self, key: str, units: Units, default: Any = _MISSING, *, gt: float | None = None, ge: float | None = None
    ) -> float:
        """The model-unit number ``key`` or its SI twin converted with ``units`` (bounds 0 are the same in
        both); both given is an error naming both keys."""
        si, dim = self._twin(key)
        if self.has(si):
            return float(_from_si(units, dim)(self.number(si, gt=gt, ge=ge)))
        return self.number(key, default, gt=gt, ge=ge)

    def quantities(
        self,
        key: str,
        units: Units,
        default: Any = _MISSING,
        *,
        min_len: int = 1,
        gt: float | None = None,
        ge: float | None = None,
    ) -> list[float]:
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
            known_set = set(allowed_hint if allowed_hint is not None else self._seen)
            for model, (si, _dim) in SI_TWINS.get(self.path, {}).items():  # a read key's SI/model twin is allowed too
                if model in known_set or si in known_set:
                    known_set |= {model, si}
            known = sorted(known_set)
            raise ScenarioError(
                f"{self.file}: unknown key {self.key_path(extra[0])!r} "
                f"(= {echo(self.table[extra[0]])}); allowed keys here: {known}"
            )


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
