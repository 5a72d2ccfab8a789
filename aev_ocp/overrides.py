"""Dotted-path overrides of a scenario, validated exactly like the file.

An override is ``key.path = value`` (``carfollowing.kappa=0.05``, ``mpc.w_Q=2``, ``leader.cycle="udds"``,
``units.length_m=15``). It is applied to the scenario's raw TOML document (kept on the
:class:`~aev_ocp.scenarios.Scenario` by the loader), and the edited document is re-parsed by
:func:`aev_ocp.scenarios.parse_scenario`: every override meets the same checks, with the same
messages naming file, key path, value and what is allowed, as the file itself.

Precedence, one rule for every command: **command line over study file over scenario file**. A ``--set``
replaces the file's value; in a study it is applied over the study's ``[overrides]`` and a scenario's own
``overrides`` (noted in one line) and refused when an axis sweeps the key or a controller sets it
(:func:`aev_ocp.study.spec.parse_study`); an option and a ``--set`` of the same key are refused.

Rules beyond plain assignment:

- A model-unit key and its SI twin (``simulation.t_end`` / ``simulation.t_end_s``,
  :data:`SI_TWINS`) exclude each other: setting one removes the other.
- A value that is not a finite number (``nan``, ``inf``) or holds a line break is refused.

- Keys that exclude each other are swapped, not added: setting ``platoon.speed0`` removes
  ``speed0_factor``/``speeds0`` (likewise ``gaps0`` against ``gap0_first``/``gap0_others`` and
  ``law`` against ``laws``), so an override replaces the file's choice.
- Setting ``leader.kind`` to another kind clears the file's ``[leader]`` keys (they belong to the old
  kind); give the new kind's keys as overrides too (``leader.kind="cycle"``, ``leader.cycle="udds"``).
- In Python, the value ``None`` removes the key (the loader's default applies), e.g.
  ``{"compare": None}`` runs the platoon as declared.
- An override the scenario would ignore is an error: ``platoon.law``/``platoon.laws`` while
  ``compare`` is set (every run then uses the ``compare`` laws).

Command lines call :func:`aev_ocp.scenarios.load_with_sets` (or :func:`parse_assignments` on their
``--set KEY=VALUE`` arguments, then :func:`aev_ocp.scenarios.apply_to_scenario` / ``Scenario.with_overrides``).
This module works on TOML documents only and knows nothing of :class:`~aev_ocp.scenarios.Scenario`.
"""

from __future__ import annotations

import copy
import math
import tomllib
from typing import Any, Iterable, Mapping

from .errors import AevOcpError
from .params import echo

#: SI twins of the model-unit keys: {table: {model key: (SI key, dimension)}}. A file, a study or a
#: ``--set`` may give either key of a pair (not both); the SI value is converted with the scenario's
#: ``[units]`` (dimension: "time" [s], "length" [m], "speed" [m/s], "accel" [m/s²]).
SI_TWINS: dict[str, dict[str, tuple[str, str]]] = {
    "simulation": {"t_end": ("t_end_s", "time"), "dt_out": ("dt_out_s", "time")},
    "platoon": {
        "gap0": ("gap0_m", "length"),
        "gap0_first": ("gap0_first_m", "length"),
        "gap0_others": ("gap0_others_m", "length"),
        "gaps0": ("gaps0_m", "length"),
        "speed0": ("speed0_mps", "speed"),
        "speeds0": ("speeds0_mps", "speed"),
    },
    "leader": {
        "v": ("v_mps", "speed"),
        "v0": ("v0_mps", "speed"),
        "amplitude": ("amplitude_mps2", "accel"),
        "forcing_end": ("forcing_end_s", "time"),
        "times": ("times_s", "time"),
        "speeds": ("speeds_mps", "speed"),
    },
}


def si_twin(key: str) -> str | None:
    """The other key of an SI/model pair (``"simulation.t_end"`` <-> ``"simulation.t_end_s"``), else None."""
    table, _, leaf = key.rpartition(".")
    for model, (si, _dim) in SI_TWINS.get(table, {}).items():
        if leaf == model:
            return f"{table}.{si}"
        if leaf == si:
            return f"{table}.{model}"
    return None


#: Keys of one table that exclude each other: setting one removes the others. A model-unit key and its
#: SI twin (:data:`SI_TWINS`, e.g. simulation.t_end and simulation.t_end_s) always do.
_WHOLE_GAPS = ("gaps0", "gaps0_m", "gap0", "gap0_m")
EXCLUSIVE: dict[str, tuple[tuple[str, ...], ...]] = {
    "platoon": (
        ("speed0", "speed0_mps", "speed0_factor", "speeds0", "speeds0_mps"),
        _WHOLE_GAPS + ("gap0_first", "gap0_first_m"),
        _WHOLE_GAPS + ("gap0_others", "gap0_others_m"),
        ("law", "laws"),
    ),
}


def _exclusive_groups(table: str) -> tuple[tuple[str, ...], ...]:
    twins = tuple((model, si) for model, (si, _dim) in SI_TWINS.get(table, {}).items())
    return EXCLUSIVE.get(table, ()) + twins


class OverrideError(AevOcpError, ValueError):
    """An override is malformed (syntax, path) or would be ignored by the scenario.

    A subclass of ValueError; the scenario loader's ScenarioError is raised for invalid values."""


def parse_value(text: str) -> Any:
    """A TOML value (``0.05``, ``2``, ``true``, ``"udds"``, ``[1, 2]``); anything else is a bare string.

    A line break is refused (TOML would read the rest as further keys and drop them), and so is a
    number that is not finite (``nan``, ``inf``): no scenario key takes one."""
    if "\n" in text or "\r" in text:
        raise OverrideError(f"override value {echo(text)} holds a line break; give one value per --set")
    text = text.strip()
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except (ValueError, RecursionError) as exc:  # an integer of > 4300 digits, arrays nested thousands deep
        why = "arrays nested too deeply" if isinstance(exc, RecursionError) else "a number of too many digits"
        raise OverrideError(f"override value {echo(text)} is not a value any scenario key takes ({why})") from None
    if not _all_finite(value):
        raise OverrideError(f"override value {echo(text)} is not a finite number")
    return value


def _all_finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, list):
        return all(_all_finite(v) for v in value)
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    return True


def parse_assignment(item: str) -> tuple[str, Any]:
    """``"key.path=value"`` -> (``"key.path"``, value parsed by :func:`parse_value`)."""
    if "=" not in item:
        raise OverrideError(f"override {item!r} is not KEY.PATH=VALUE (e.g. carfollowing.kappa=0.05)")
    key, _, raw = item.partition("=")
    check_key(key.strip(" \t"))  # a line break in the key is refused, not stripped
    key = key.strip()
    if not raw.strip():
        raise OverrideError(f"override {item!r} has no value after '='")
    try:
        return key, parse_value(raw)
    except OverrideError as exc:
        raise OverrideError(f"--set {key}: {exc}") from None


def parse_assignments(items: Iterable[str] | None) -> dict[str, Any]:
    """Every ``--set KEY=VALUE`` of a command line as an ordered dict (a later key wins)."""
    out: dict[str, Any] = {}
    for item in items or ():
        k, v = parse_assignment(item)
        out[k] = v
    return out


def check_key(key: str) -> list[str]:
    """Split a dotted key path, rejecting empty parts and keys that are not strings; returns the parts."""
    if not isinstance(key, str):
        raise OverrideError(
            f"override key {key!r} ({type(key).__name__}) is not a dotted key path string (e.g. 'carfollowing.kappa')"
        )
    parts = key.split(".")
    if not key or any(not p.strip() for p in parts) or any(c in key for c in "\r\n"):
        raise OverrideError(f"override key {key!r} is not a dotted key path (e.g. carfollowing.kappa)")
    return [p.strip() for p in parts]


def apply_to_document(doc: Mapping[str, Any], overrides: Mapping[str, Any], file: str = "<scenario>") -> dict[str, Any]:
    """A deep copy of the TOML document ``doc`` with every override set (missing tables are created).

    Raises :class:`OverrideError` naming ``file`` and the key when a path runs through a value that
    is not a table, or when the scenario would ignore the override (see the module docstring)."""
    out = copy.deepcopy(dict(doc))
    items = list(overrides.items())
    # a kind change clears the old kind's keys before the new ones are set
    kind = dict(items).get("leader.kind")
    if kind is not None and isinstance(out.get("leader"), dict) and out["leader"].get("kind") != kind:
        out["leader"] = {}
    for key, value in items:
        parts = check_key(key)
        node: Any = out
        for depth, part in enumerate(parts[:-1]):
            nxt = node.get(part)
            if nxt is None:
                nxt = node[part] = {}
            if not isinstance(nxt, dict):
                where = ".".join(parts[: depth + 1])
                raise OverrideError(
                    f"{file}: override {key} = {echo(value)}: {where} is a value ({echo(nxt)}), not a table"
                )
            node = nxt
        leaf = parts[-1]
        table = ".".join(parts[:-1])
        for group in _exclusive_groups(table):
            if leaf in group:
                for other in group:
                    if other != leaf and f"{table}.{other}" not in overrides:
                        node.pop(other, None)
        if value is None:  # Python API: None removes the key (the file's default applies)
            node.pop(leaf, None)
        else:
            node[leaf] = copy.deepcopy(value)
    ignored = [k for k in overrides if k in ("platoon.law", "platoon.laws")]
    if ignored and out.get("compare"):
        raise OverrideError(
            f"{file}: override {ignored[0]} = {echo(overrides[ignored[0]])} would be ignored: the "
            f"scenario sets compare = {echo(out['compare'])}, so every run uses those laws; "
            f"override 'compare' instead (e.g. compare=[\"ovfl\"])"
        )
    return out
