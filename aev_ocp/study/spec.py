"""Study files: base scenarios, axes over dotted scenario keys, controllers, report options.

A study is a TOML file (see README.md "Studies")::

    name = "kappa_alpha_table1"          # optional (default: the file stem)
    description = "..."
    scenarios = ["table1"]               # shipped names or paths relative to the study file, or inline
                                         # tables { scenario = "udds_platoon", label = "udds",
                                         #          overrides = { "simulation.t_end" = 680.0 } }
    reference = "ovfl"                   # controller for comparability and % change (default: first)

    [overrides]                          # dotted keys applied to every point
    "simulation.dt_out" = 0.05

    [[axes]]                             # grid axis: one key, a list of values
    key = "carfollowing.kappa"
    values = [0.0, 0.03, 0.1]

    [[axes]]                             # zipped axis: several keys, one list per key, same lengths
    keys = ["mpc.w_Q", "mpc.w_a"]
    values = [[0.5, 2.0], [0.1, 0.2]]

    [[axes]]                             # seeded random axis: n joint samples, uniform or log-uniform
    keys = ["carfollowing.kappa"]
    random = { n = 20, seed = 1, low = [0.0], high = [0.5], log = false }

    [controllers]
    laws = ["proposed", "ovfl"]          # closed-form laws: every follower on that law
    ocpd = false                         # OCP-D lower bound (single follower only)
    [[controllers.mpc]]                  # one entry per MPC set-up: label and any [mpc] key
    label = "mpc"
    solver = "rti"

    [report]
    vehicle = 1                          # follower in figures (an array: change tables for each)
    metrics = ["battery_energy_kWh_per_100km", "heat_pack_J_per_km", "omega_model"]  # battery energy first
    pareto = [["heat_pack_J_per_km", "rms_rel_speed_model"]]
    pareto_by = ["leader.cycle"]         # a front per value of these keys (and per base scenario)
    change_metric = "omega_model"        # % change vs the reference, tabulated over the first two axes
    differences = [["mpc", "ovfl"]]      # with a seed axis: paired a − b over the seeds (default: each vs reference)

An axis whose keys are all seeds (``sensors.seed``, ``mismatch.seed``, ``ring.seed``, ...) is a *seed axis*: the
study then also reports every [report] metric over the seeds, mean, 95 % interval and n, and the paired differences
between controllers with a better/worse/tie verdict (:mod:`aev_ocp.study.seeds`; ``seeds.json``, report.md).

Points are the Cartesian product of the axes (and of ``scenarios``). Every point and every
controller is validated (the scenario loader's checks) before anything runs; an error names the
study file, the axis and the key.

The parts live in :mod:`.model` (axes, controllers, points, tasks), :mod:`.tables` (the file's tables),
:mod:`.points` (each point validated by the scenario loader) and :mod:`.tasks` (hashing); this module reads a
study file into a :class:`Study` and re-exports those names.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..limits import check_study_size
from ..params import ParameterError, echo
from ..progress import Progress
from ..results import check_safe_name
from ..scenarios import ScenarioError, TableReader, load_scenario
from .model import Axis, Controller, Point, StudyError, Task
from .points import (
    _point_document,
    _validate_controllers,
    controller_document,
    parse_scenario_quiet,
    parse_scenario_warnings,
)
from .tables import _axis, _base, _bases, _controllers, _report, check_report
from .tasks import canonical_json, make_task

__all__ = [
    "PRECEDENCE",
    "Axis",
    "Controller",
    "Point",
    "Study",
    "StudyError",
    "Task",
    "canonical_json",
    "controller_document",
    "make_task",
    "parse_scenario_quiet",
    "parse_scenario_warnings",
    "parse_study",
    "read_study",
]


@dataclass
class Study:
    """A validated study: points × controllers, ready to run (see :func:`aev_ocp.study.run_study`)."""

    name: str
    description: str
    file: str
    axes: list[Axis]
    controllers: list[Controller]
    reference: str
    points: list[Point]
    bases: list[str]
    report: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # the scenario loader's warnings, once each
    _tasks: list[Task] | None = field(default=None, repr=False)

    def tasks(self) -> list[Task]:
        """Every point × controller as a task (tasks with equal specifications share one hash)."""
        if self._tasks is None:
            own_cost = any(c.kind == "ocpd" for c in self.controllers)  # OCP-D's bound check needs the MPC's cost
            self._tasks = [
                make_task(p, c, own_cost=own_cost and c.kind == "mpc") for p in self.points for c in self.controllers
            ]
        return list(self._tasks)

    @property
    def axis_keys(self) -> list[str]:
        """Axis keys in order, with 'scenario' first when the study has several base scenarios."""
        keys = [k for a in self.axes for k in a.keys]
        return (["scenario"] if len(self.bases) > 1 else []) + keys


def read_study(path: str | Path, sets: dict[str, Any] | None = None) -> Study:
    """Read, expand and validate a study file (every point and controller; nothing runs).

    sets: command-line overrides ``{dotted key: value}`` (``--set``), the last layer (see :func:`parse_study`)."""
    file = str(path)
    from ..limits import read_input_file

    data = read_input_file(path, "study file", StudyError, label=file)  # a FIFO or /dev/zero: refused, unread
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
        why = exc if isinstance(exc, tomllib.TOMLDecodeError) else type(exc).__name__
        raise StudyError(f"{file}: not valid UTF-8 TOML: {why}") from None
    return parse_study(doc, file, Path(path), sets=sets)


PRECEDENCE = (
    "command line (--set) over study file (per-scenario overrides over [overrides]) over scenario file; "
    "a --set on a key that the study sweeps (an axis) or sets per controller is refused"
)


def parse_study(
    doc: dict[str, Any], file: str = "<study>", path: Path | None = None, sets: dict[str, Any] | None = None
) -> Study:
    """Validate a parsed study document (see the module docstring).

    Layers, later over earlier (:data:`PRECEDENCE`): the base scenario file, the study's ``[overrides]``, a
    base's own ``overrides``, then ``sets`` (the command line's ``--set``), then the point's axis values. A
    ``set`` that an axis or a ``[[controllers.mpc]]`` entry would replace is refused (StudyError); one that
    replaces a study-file override is applied and noted in ``Study.warnings``."""
    try:
        return _parse_study(doc, file, path, dict(sets or {}))
    except ScenarioError as exc:  # raised by a TableReader over the study file itself
        if isinstance(exc, StudyError):
            raise
        raise StudyError(str(exc)) from None
    except ParameterError as exc:  # the size check (aev_ocp.limits.check_study_size), before any point is built
        raise StudyError(str(exc)) from None


def _family(key: str) -> set[str]:
    """``key`` and every key that setting it would replace (its SI twin, keys of its exclusive group)."""
    from ..overrides import _exclusive_groups

    table, _, leaf = key.rpartition(".")
    out = {key}
    for group in _exclusive_groups(table):
        if leaf in group:
            out.update(f"{table}.{k}" if table else k for k in group)
    return out


def _refuse_swept(file: str, what: str, key: str, value: Any, axes: list[Axis], fix: str) -> None:
    """StudyError if an axis sweeps ``key`` (or a key that setting it replaces): the value ``what`` gives for it
    would be dropped at every point."""
    fam = _family(key)
    for i, a in enumerate(axes):
        hit = next((k for k in a.keys if k in fam), None)
        if hit is not None:
            raise StudyError(
                f"{file}: {what} {key} = {echo(value)} would be ignored: axes[{i}] sweeps {hit} at every point; {fix}"
            )


def _check_overrides(file: str, axes: list[Axis], layers: list[tuple[str, dict[str, Any]]]) -> None:
    """Refuse a study-file override that an axis replaces at every point (it would be dropped without a word)."""
    for where, ov in layers:
        for key, value in ov.items():
            _refuse_swept(file, where, key, value, axes, f"remove it from {where} or from the axes")


def _check_sets(
    file: str,
    sets: dict[str, Any],
    axes: list[Axis],
    controllers: list[Controller],
    layers: list[tuple[str, dict[str, Any]]],
) -> list[str]:
    """Refuse a --set that an axis or a controller would replace; note the study-file overrides it replaces."""
    notes: list[str] = []
    for key, value in sets.items():
        _refuse_swept(file, "--set", key, value, axes, "change the axis values in the study file instead")
        fam = _family(key)
        for c in controllers:
            hit = next((f"mpc.{k}" for k, _ in c.settings if f"mpc.{k}" in fam), None)
            if hit is not None:
                raise StudyError(
                    f"{file}: --set {key} = {echo(value)} would be ignored: controller {c.label!r} sets "
                    f"{hit}; change [[controllers.mpc]] in the study file instead"
                )
        for where, ov in layers:
            for k in sorted(fam & set(ov)):
                notes.append(
                    f"{file}: --set {key} = {echo(value)} replaces {where} {k} = {echo(ov[k])} (the command line "
                    f"is applied over the study file)"
                )
    return notes


def _parse_study(doc: dict[str, Any], file: str, path: Path | None, sets: dict[str, Any]) -> Study:
    top = TableReader(doc, "", file)
    name = top.string("name", path.stem if path is not None else "study")
    try:
        check_safe_name(name, "name")  # it names the output folder results/study/<name>
    except ValueError as exc:
        raise StudyError(f"{file}: {exc}") from None
    description = top.string("description", "")
    bases, base_overrides = _bases(top)
    common = top.sub("overrides")
    overrides = dict(common.table)
    common._seen.update(overrides)
    raw_axes = top.table.get("axes", [])
    top._get("axes", None)
    if not isinstance(raw_axes, list) or not all(isinstance(a, dict) for a in raw_axes):
        raise top.error("axes", raw_axes, "expected [[axes]] tables")
    axes = [_axis(TableReader(a, f"axes[{i}]", file), i) for i, a in enumerate(raw_axes)]
    seen: dict[str, int] = {}
    for i, a in enumerate(axes):
        for k in a.keys:
            if k in seen:
                raise StudyError(f"{file}: axes[{i}]: key {k} is already swept by axes[{seen[k]}]")
            seen[k] = i
    controllers = _controllers(top.sub("controllers", required=True))
    labels = [c.label for c in controllers]
    reference = top.string("reference", labels[0])
    if reference not in labels:
        raise top.error("reference", reference, f"must be one of the controllers {labels}")
    report = _report(top.sub("report"), file)
    unknown = sorted({x for pair in report["differences"] for x in pair} - set(labels))
    if unknown:
        raise StudyError(f"{file}: report.differences names {unknown}, not controllers of the study {labels}")
    check_report(file, report, axes)  # a metric name that is no column: before the points are validated
    top.finish()

    docs: dict[str, tuple[dict[str, Any], str]] = {}
    for b in bases:
        try:
            sc = load_scenario(_base(base_overrides[b][0], path))
        except ScenarioError as exc:
            raise StudyError(f"{file}: scenarios: {exc}") from None
        assert sc.document is not None
        d = dict(sc.document)
        d.setdefault("name", sc.name)
        docs[b] = (d, sc.file_label)

    points: list[Point] = []
    layers = [("[overrides]", overrides)] + [(f"scenario {b!r} overrides", base_overrides[b][1]) for b in bases]
    found_warnings: list[str] = _check_sets(file, sets, axes, controllers, layers)
    _check_overrides(file, axes, layers)
    n_points = len(bases) * math.prod(len(a.rows) for a in axes)
    sizes = " x ".join([f"{len(bases)} scenarios"] * (len(bases) > 1) + [f"{len(a.rows)} ({a.label})" for a in axes])
    check_study_size(n_points, len(controllers), f"{file}: axes {sizes or '(none)'}")
    combos = list(itertools.product(*[a.rows for a in axes])) if axes else [()]
    prog = Progress(f"study {name}", n_points, unit="points", every_s=2.0)
    prog._last = prog.clock()  # a line only once validation has taken 2 s (a 100 x 100 grid takes ~4 s)
    memo: dict[int, dict[str, Any]] = {}  # each base document with the overrides and --set applied, once
    followers: set[int] = set()  # the points' follower counts: a [report] vehicle must be in one of them
    for b in bases:
        base_doc, base_file = docs[b]
        for combo in combos:
            prog.update(len(points), what="validating")
            values = {k: v for a, row in zip(axes, combo) for k, v in zip(a.keys, row)}
            pdoc = _point_document(
                file,
                base_doc,
                base_file,
                {**overrides, **base_overrides[b][1]},
                values,
                axes,
                b,
                len(points),
                found_warnings,
                sets,
                memo,
                followers,
            )
            points.append(Point(len(points), b, values, pdoc, base_file))
    check_report(file, report, axes, followers)
    study = Study(name, description, file, axes, controllers, reference, points, bases, report, found_warnings)
    _validate_controllers(file, controllers, points, axes)
    return study
