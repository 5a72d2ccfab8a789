"""Reading a scenario file: its text (a regular UTF-8 file of a stated size), its TOML document (for every
scenario form), and the platoon :class:`~aev_ocp.scenarios.platoon.Scenario` it describes, with ``--set``
overrides applied (:func:`load_with_sets`)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Iterable

from ..limits import FileRefused, read_regular_file, strip_bom
from ..overrides import parse_assignments
from .platoon import Scenario, apply_to_scenario, parse_scenario
from .shipped import find_scenario
from .tables import ScenarioError

MAX_FILE_BYTES = 16 * 2**20  # a scenario file is a hand-edited TOML file; a bigger one is a mistake


def read_scenario_text(p: Path, file: str) -> str:
    """The text of scenario file ``p`` (``file`` names it in messages): a regular file of at most
    MAX_FILE_BYTES, UTF-8; anything else is a ScenarioError."""
    try:
        data = strip_bom(read_regular_file(p, MAX_FILE_BYTES))  # a byte-order mark (Windows editors) is fine
    except FileRefused as exc:
        raise ScenarioError(f"{file}: cannot read the scenario file ({exc})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ScenarioError(
            f"{file}: not a text file in UTF-8 (byte 0x{data[exc.start]:02x} at line {line}); "
            "scenario files are UTF-8 TOML"
        ) from None


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


def load_with_sets(path: str, sets: Iterable[str] | None) -> Scenario:
    """``load_scenario(path)`` with every ``--set KEY=VALUE`` applied and validated like the file.

    The one call a command needs for its ``--set`` flags (``action="append"``); raises ScenarioError
    (invalid value, unknown key) or OverrideError (malformed or ignored override), both ValueErrors
    whose message names the file and the key."""
    scenario = load_scenario(path)
    overrides = parse_assignments(sets)
    return apply_to_scenario(scenario, overrides) if overrides else scenario
