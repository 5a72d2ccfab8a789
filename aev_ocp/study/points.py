"""A study point's scenario document, validated by the scenario loader (warnings collected once, the leader's
speed check memoised across points), and the document a controller runs; errors name the study file, the axis and
the key."""

from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import Any, Iterator

from ..overrides import OverrideError, apply_to_document
from ..params import ParameterError, echo
from ..scenarios import Scenario, ScenarioError, parse_scenario
from .model import Axis, Controller, Point, StudyError
from .tasks import _source


_LEADER_CHECKS: dict[Any, tuple[float, list[Warning]]] = {}


@contextmanager
def _memoised_leader_check() -> Iterator[None]:
    """parse_scenario checks the leader's top speed by sampling it (tens of ms); study points share a few
    leaders, so the check is computed once per (leader, t_end, units) in this process and its warnings
    replayed. Everything else of parse_scenario runs as usual."""
    from ..scenarios import platoon as scn  # the module whose parse_scenario calls check_leader_speed

    orig = scn.check_leader_speed

    def check(scenario: Scenario, file: str = "<scenario>") -> float:
        key = (scenario.leader, scenario.t_end, scenario.units, file)
        try:
            hash(key)
        except TypeError:
            return orig(scenario, file)
        if key not in _LEADER_CHECKS:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                v = orig(scenario, file)
            _LEADER_CHECKS[key] = (v, [w.message for w in caught if isinstance(w.message, Warning)])
        v, msgs = _LEADER_CHECKS[key]
        for m in msgs:
            warnings.warn(m, stacklevel=3)
        return v

    scn.check_leader_speed = check
    try:
        yield
    finally:
        scn.check_leader_speed = orig


def parse_scenario_quiet(doc: dict[str, Any], file: str) -> Scenario:
    """parse_scenario without warnings (they are collected once, at validation)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with _memoised_leader_check():
            return parse_scenario(doc, file, source=_source(file))


def parse_scenario_warnings(doc: dict[str, Any], file: str) -> tuple[Scenario, list[str]]:
    """parse_scenario, returning its warnings' messages."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with _memoised_leader_check():
            sc = parse_scenario(doc, file, source=_source(file))
    return sc, [str(w.message) for w in caught]


def _describe(values: dict[str, Any]) -> str:
    return ", ".join(f"{k} = {echo(v)}" for k, v in values.items()) or "no axis values"


def _culprit(message: str, values: dict[str, Any], axes: list[Axis]) -> str:
    """The axis (and key) an error message is about: the longest axis key it mentions."""
    hits = sorted((k for k in values if k in message), key=len, reverse=True)
    if hits:
        axis = next(a for a in axes if hits[0] in a.keys)
        return f"axis {axis.label}, key {hits[0]}"
    return "overrides/base scenario" if not values else f"axes {', '.join(values)}"


def _point_document(
    file: str,
    base_doc: dict[str, Any],
    base_file: str,
    overrides: dict[str, Any],
    values: dict[str, Any],
    axes: list[Axis],
    base: str,
    index: int,
    sink: list[str],
    sets: dict[str, Any] | None = None,
    memo: dict[int, dict[str, Any]] | None = None,
    followers: set[int] | None = None,
) -> dict[str, Any]:
    """The point's document, validated by the scenario loader; errors name study file, axis, key.
    Layers: study overrides, then ``sets`` (--set), then the axis values (see :func:`parse_study`).
    ``memo`` keeps the base document with the first two layers applied (the same at every point of a base
    scenario), so a point copies and edits its document once, for its axis values. ``followers`` collects the
    points' follower counts."""
    sets = sets or {}
    try:
        pdoc = memo.get(id(base_doc)) if memo is not None else None
        if pdoc is None:
            pdoc = base_doc
            for layer in (overrides, sets):
                if layer:
                    pdoc = apply_to_document(pdoc, layer, base_file)
            if memo is not None:
                memo[id(base_doc)] = pdoc
        if values:
            pdoc = apply_to_document(pdoc, values, base_file)
        sc, found = parse_scenario_warnings(pdoc, base_file)
        if followers is not None:
            followers.add(sc.n_followers)
        for w in found:
            if w not in sink:
                sink.append(w)
    except (ScenarioError, OverrideError, ParameterError) as exc:
        msg = str(exc)
        if any(k in msg for k in values):
            where = _culprit(msg, values, axes)
        elif any(k in msg for k in sets):
            where = "--set " + max((k for k in sets if k in msg), key=len)
        elif any(k in msg for k in overrides):
            where = "overrides, key " + max((k for k in overrides if k in msg), key=len)
        else:
            where = _culprit(msg, values, axes)
        raise StudyError(f"{file}: {where} (point {index}, scenario {base}: {_describe(values)}): {msg}") from None
    return pdoc


def _validate_controllers(file: str, controllers: list[Controller], points: list[Point], axes: list[Axis]) -> None:
    """Each MPC controller's settings on each point document of study file ``file``; OCP-D needs one follower."""
    for c in controllers:
        if c.kind == "law":
            continue
        for p in points:
            try:
                sc = parse_scenario_quiet(controller_document(p.document, c, p.file), p.file)
            except (ScenarioError, OverrideError, ParameterError) as exc:
                msg = str(exc)
                where = (
                    f"controller {c.label}"
                    if any(f"mpc.{k}" in msg or k in msg for k, _ in c.settings)
                    else _culprit(msg, p.values, axes)
                )
                raise StudyError(f"{file}: {where} (point {p.index}: {_describe(p.values)}): {msg}") from None
            if c.kind == "ocpd" and sc.n_followers != 1:
                raise StudyError(
                    f"{file}: controllers.ocpd: OCP-D needs a single follower; scenario {p.base} "
                    f"has {sc.n_followers} (point {p.index})"
                )


def controller_document(doc: dict[str, Any], c: Controller, file: str) -> dict[str, Any]:
    """The point's document with the controller's [mpc] keys applied (laws: unchanged)."""
    if c.kind == "law" or not c.settings:
        return doc
    return apply_to_document(doc, {f"mpc.{k}": v for k, v in c.settings}, file)
