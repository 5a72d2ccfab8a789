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
    metrics = ["omega_model", "heat_pack_J_per_km"]
    pareto = [["heat_pack_J_per_km", "rms_rel_speed_model"]]
    pareto_by = ["leader.cycle"]         # a front per value of these keys (and per base scenario)
    change_metric = "omega_model"        # % change vs the reference, tabulated over the first two axes

Points are the Cartesian product of the axes (and of ``scenarios``). Every point and every
controller is validated (the scenario loader's checks) before anything runs; an error names the
study file, the axis and the key.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from contextlib import contextmanager
from typing import Any, Iterator

import numpy as np

from .._version import __version__
from ..models.carfollowing import LAW_REGISTRY
from ..overrides import OverrideError, apply_to_document, check_key
from ..limits import check_study_size
from ..params import ParameterError
from ..progress import Progress
from ..results import check_safe_name
from ..scenarios import Scenario, ScenarioError, TableReader, find_scenario, load_scenario, parse_scenario


class StudyError(ValueError):
    """A study file is invalid; the message names the study file, the axis and the key."""


@dataclass(frozen=True)
class Axis:
    """One axis: keys (dotted scenario paths) and rows of values (one value per key per row)."""

    keys: tuple[str, ...]
    rows: tuple[tuple[Any, ...], ...]
    kind: str  # "grid" | "zip" | "random"
    seed: int | None = None

    @property
    def label(self) -> str:
        """The axis as messages name it."""
        return ", ".join(self.keys)


@dataclass(frozen=True)
class Controller:
    """A controller to compare: kind 'law' (name = law), 'mpc' (settings = [mpc] keys) or 'ocpd'."""

    label: str
    kind: str
    name: str = ""
    settings: tuple[tuple[str, Any], ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready description (part of every task's hash)."""
        return {"label": self.label, "kind": self.kind, "name": self.name, "settings": dict(self.settings)}


@dataclass(frozen=True)
class Point:
    """One point of the study: index, base scenario name, axis values {key: value}, the overridden document."""

    index: int
    base: str
    values: dict[str, Any]
    document: dict[str, Any]
    file: str


@dataclass(frozen=True)
class Task:
    """A point run by one controller: the unit of work (picklable, hash-keyed)."""

    point: int
    controller: str
    spec: dict[str, Any]
    key: str


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
            self._tasks = [make_task(p, c, own_cost=own_cost and c.kind == "mpc") for p in self.points
                           for c in self.controllers]
        return list(self._tasks)

    @property
    def axis_keys(self) -> list[str]:
        """Axis keys in order, with 'scenario' first when the study has several base scenarios."""
        keys = [k for a in self.axes for k in a.keys]
        return (["scenario"] if len(self.bases) > 1 else []) + keys


# ----------------------------------------------------------------------------- hashing
def canonical_json(obj: Any) -> str:
    """Deterministic JSON (sorted keys, exact float repr) used for hashing."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True, default=str)


def _law_fingerprint(doc: dict[str, Any], law: str) -> dict[str, Any]:
    """The law's coefficients as the (validated) document sets them: only what the law reads."""
    from ..models.carfollowing import make_law
    from ..params import CarFollowingParams

    table = doc.get("carfollowing") or {}
    names = {f.name for f in dataclasses.fields(CarFollowingParams)}
    cf = CarFollowingParams(**{k: float(v) for k, v in table.items() if k in names})
    own = {k.lower(): v for k, v in table.items() if k not in names and isinstance(v, dict)}
    obj = make_law(law, cf, **own.get(law, {}))
    return {"law": law, "coefficients": {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}}


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
    identity.update({"controller": {"kind": c.kind, "name": c.name, "settings": dict(c.settings)},
                     "version": __version__})
    if own_cost:  # (only then in the hash: other tasks keep theirs)
        identity["own_cost"] = True
    trace = _trace_file(p.document, p.file)
    if trace is not None:  # a recorded leader: its data, not only its file name, decides the result
        identity["leader_trace_sha256"] = hashlib.sha256(trace.read_bytes()).hexdigest() if trace.is_file() else None
    key = hashlib.sha256(canonical_json(identity).encode()).hexdigest()
    spec = {"document": p.document, "file": p.file, "controller": c.as_dict(), "key": key, "own_cost": own_cost}
    return Task(p.index, c.label, spec, key)


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


# ----------------------------------------------------------------------------- reading
def _axis(r: TableReader, i: int) -> Axis:
    where = f"axes[{i}]"
    if r.has("key") == r.has("keys"):
        raise StudyError(f"{r.file}: {where}: give either key (one dotted key) or keys (an array), not both or neither")
    keys = [r.string("key")] if r.has("key") else r.strings("keys")
    for k in keys:
        try:
            check_key(k)
        except OverrideError as exc:
            raise StudyError(f"{r.file}: {where}: {exc}") from None
    if len(set(keys)) != len(keys):
        raise r.error("keys", keys, "keys must be distinct")
    if r.has("values") == r.has("random"):
        raise StudyError(f"{r.file}: {where} ({', '.join(keys)}): give either values or random = {{n, seed, low, high}}")
    if r.has("values"):
        vals = r.table["values"]
        r._get("values", None)
        if not isinstance(vals, list) or not vals:
            raise r.error("values", vals, "expected a non-empty array")
        rows: tuple[tuple[Any, ...], ...]
        if len(keys) == 1 and r.has("key"):
            rows = tuple((v,) for v in vals)
            kind = "grid"
        else:
            if len(vals) != len(keys) or not all(isinstance(v, list) for v in vals):
                raise r.error("values", vals, f"expected {len(keys)} arrays, one per key of {keys}")
            lengths = {len(v) for v in vals}
            if len(lengths) != 1 or 0 in lengths:
                raise r.error("values", vals, "the arrays of a zipped axis must have the same, non-zero length")
            rows = tuple(zip(*vals))
            kind = "zip"
        r.finish()
        return Axis(tuple(keys), rows, kind)
    rnd = r.sub("random", required=True)
    n = rnd.integer("n", ge=1)
    check_study_size(n, 1, f"{r.file}: {where} ({', '.join(keys)}): random.n = {n}")  # before drawing n samples
    seed = rnd.integer("seed", ge=0)
    log = rnd.boolean("log", False)
    lows = _bounds(rnd, "low", len(keys))
    highs = _bounds(rnd, "high", len(keys))
    for j, (lo, hi) in enumerate(zip(lows, highs)):
        if not hi > lo or (log and lo <= 0):
            raise rnd.error("high", highs, f"needs high > low{' > 0 (log)' if log else ''} for {keys[j]}")
    rnd.finish()
    r.finish()
    rng = np.random.default_rng(seed)
    u = rng.random((n, len(keys)))
    lo_a, hi_a = np.array(lows), np.array(highs)
    x = np.exp(np.log(lo_a) + u * (np.log(hi_a) - np.log(lo_a))) if log else lo_a + u * (hi_a - lo_a)
    return Axis(tuple(keys), tuple(tuple(float(v) for v in row) for row in x), "random", seed)


def _bounds(r: TableReader, key: str, n: int) -> list[float]:
    if isinstance(r.table.get(key), list):
        vals = r.numbers(key)
        if len(vals) != n:
            raise r.error(key, vals, f"needs {n} values, one per key")
        return vals
    return [r.number(key)] * n


def _controllers(r: TableReader) -> list[Controller]:
    out: list[Controller] = []
    for name in r.strings("laws", [], choices=sorted(LAW_REGISTRY)):
        out.append(Controller(name, "law", name))
    mpcs = r.table.get("mpc", [])
    r._get("mpc", None)
    if isinstance(mpcs, dict):
        mpcs = [mpcs]
    if not isinstance(mpcs, list) or not all(isinstance(m, dict) for m in mpcs):
        raise r.error("mpc", mpcs, "expected [[controllers.mpc]] tables")
    for j, m in enumerate(mpcs):
        m = dict(m)
        label = m.pop("label", "mpc" if len(mpcs) == 1 else f"mpc{j + 1}")
        if not isinstance(label, str) or not label:
            raise StudyError(f"{r.file}: controllers.mpc[{j}].label = {label!r} is not allowed: expected a string")
        out.append(Controller(label, "mpc", "mpc", tuple(sorted(m.items()))))
    if r.boolean("ocpd", False):
        out.append(Controller("ocp-d", "ocpd", "ocpd"))
    r.finish()
    labels = [c.label for c in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise StudyError(f"{r.file}: controllers: labels {dup} are used twice; give each [[controllers.mpc]] a label")
    if not out:
        raise StudyError(f"{r.file}: controllers: none given (laws = [...], [[controllers.mpc]] or ocpd = true)")
    return out


def _report(r: TableReader, file: str) -> dict[str, Any]:
    veh = r.table.get("vehicle", 1)
    r._get("vehicle", None)
    vehicles = veh if isinstance(veh, list) else [veh]
    if not vehicles or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in vehicles):
        raise r.error("vehicle", veh, "expected a follower number (1, 2, ...) or an array of them")
    rep: dict[str, Any] = {"vehicle": vehicles[0], "vehicles": vehicles,
                           "metrics": r.strings("metrics", ["omega_model", "heat_pack_J_per_km"]),
                           "change_metric": r.string("change_metric", "omega_model")}
    pareto = r.table.get("pareto", [])
    r._get("pareto", None)
    if not isinstance(pareto, list) or not all(isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p)
                                               for p in pareto):
        raise r.error("pareto", pareto, "expected an array of [metric_x, metric_y] pairs (both minimised)")
    rep["pareto"] = [tuple(p) for p in pareto]
    rep["pareto_by"] = r.strings("pareto_by", [])
    r.finish()
    return rep


def _bases(top: TableReader) -> tuple[list[str], dict[str, tuple[str, dict[str, Any]]]]:
    """``scenarios``: names/paths, or inline tables {scenario, label, overrides} (overrides for that base only).
    Returns the labels and {label: (scenario, overrides)}."""
    raw = top.table.get("scenarios")
    top._get("scenarios", None)
    if not isinstance(raw, list) or not raw:
        raise top.error("scenarios", raw, "expected a non-empty array of scenario names/paths or "
                                          "{ scenario = ..., label = ..., overrides = { ... } } tables")
    labels: list[str] = []
    out: dict[str, tuple[str, dict[str, Any]]] = {}
    for j, item in enumerate(raw):
        if isinstance(item, str):
            label, scen, ov = Path(item).stem, item, {}
        elif isinstance(item, dict):
            r = TableReader(item, f"scenarios[{j}]", top.file)
            scen = r.string("scenario")
            label = r.string("label", Path(scen).stem)
            ov_r = r.sub("overrides")
            ov = dict(ov_r.table)
            ov_r._seen.update(ov)
            r.finish()
        else:
            raise top.error(f"scenarios[{j}]", item, "expected a scenario name/path or an inline table")
        if label in out:
            raise top.error(f"scenarios[{j}]", item, f"label {label!r} is used twice; give each a distinct label")
        labels.append(label)
        out[label] = (scen, ov)
    return labels, out


def _base(name: str, study_path: Path | None) -> Path:
    p = Path(name)
    if study_path is not None and not p.is_absolute():
        cand = study_path.parent / p
        if cand.is_file():
            return cand
    return find_scenario(name)


def read_study(path: str | Path, sets: dict[str, Any] | None = None) -> Study:
    """Read, expand and validate a study file (every point and controller; nothing runs).

    sets: command-line overrides ``{dotted key: value}`` (``--set``), the last layer (see :func:`parse_study`)."""
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise StudyError(f"{file}: cannot read the study file ({exc.strerror or exc})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(f"{file}: not valid TOML: {exc}") from None
    return parse_study(doc, file, Path(path), sets=sets)


PRECEDENCE = ("command line (--set) over study file (per-scenario overrides over [overrides]) over scenario file; "
              "a --set on a key that the study sweeps (an axis) or sets per controller is refused")


def parse_study(doc: dict[str, Any], file: str = "<study>", path: Path | None = None,
                sets: dict[str, Any] | None = None) -> Study:
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


def _check_sets(file: str, sets: dict[str, Any], axes: list[Axis], controllers: list[Controller],
                layers: list[tuple[str, dict[str, Any]]]) -> list[str]:
    """Refuse a --set that an axis or a controller would replace; note the study-file overrides it replaces."""
    notes: list[str] = []
    for key, value in sets.items():
        fam = _family(key)
        for i, a in enumerate(axes):
            hit = next((k for k in a.keys if k in fam), None)
            if hit is not None:
                raise StudyError(f"{file}: --set {key} = {value!r} would be ignored: axes[{i}] sweeps {hit} at every "
                                 f"point; change the axis values in the study file instead")
        for c in controllers:
            hit = next((f"mpc.{k}" for k, _ in c.settings if f"mpc.{k}" in fam), None)
            if hit is not None:
                raise StudyError(f"{file}: --set {key} = {value!r} would be ignored: controller {c.label!r} sets "
                                 f"{hit}; change [[controllers.mpc]] in the study file instead")
        for where, ov in layers:
            for k in sorted(fam & set(ov)):
                notes.append(f"{file}: --set {key} = {value!r} replaces {where} {k} = {ov[k]!r} (the command line "
                             f"is applied over the study file)")
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
    n_points = len(bases) * math.prod(len(a.rows) for a in axes)
    sizes = " x ".join([f"{len(bases)} scenarios"] * (len(bases) > 1) + [f"{len(a.rows)} ({a.label})" for a in axes])
    check_study_size(n_points, len(controllers), f"{file}: axes {sizes or '(none)'}")
    combos = list(itertools.product(*[a.rows for a in axes])) if axes else [()]
    prog = Progress(f"study {name}", n_points, unit="points", every_s=2.0)
    prog._last = prog.clock()  # a line only once validation has taken 2 s (a 100 x 100 grid takes ~10 s)
    for b in bases:
        base_doc, base_file = docs[b]
        for combo in combos:
            prog.update(len(points), what="validating")
            values = {k: v for a, row in zip(axes, combo) for k, v in zip(a.keys, row)}
            pdoc = _point_document(file, base_doc, base_file, {**overrides, **base_overrides[b][1]}, values, axes, b,
                                   len(points), found_warnings, sets)
            points.append(Point(len(points), b, values, pdoc, base_file))
    study = Study(name, description, file, axes, controllers, reference, points, bases, report, found_warnings)
    _validate_controllers(study)
    return study


def _describe(values: dict[str, Any]) -> str:
    return ", ".join(f"{k} = {v!r}" for k, v in values.items()) or "no axis values"


def _culprit(message: str, values: dict[str, Any], axes: list[Axis]) -> str:
    """The axis (and key) an error message is about: the longest axis key it mentions."""
    hits = sorted((k for k in values if k in message), key=len, reverse=True)
    if hits:
        axis = next(a for a in axes if hits[0] in a.keys)
        return f"axis {axis.label}, key {hits[0]}"
    return "overrides/base scenario" if not values else f"axes {', '.join(values)}"


def _point_document(file: str, base_doc: dict[str, Any], base_file: str, overrides: dict[str, Any],
                    values: dict[str, Any], axes: list[Axis], base: str, index: int,
                    sink: list[str], sets: dict[str, Any] | None = None) -> dict[str, Any]:
    """The point's document, validated by the scenario loader; errors name study file, axis, key.
    Layers: study overrides, then ``sets`` (--set), then the axis values (see :func:`parse_study`)."""
    sets = sets or {}
    try:
        pdoc = base_doc
        for layer in (overrides, sets, values):
            if layer:
                pdoc = apply_to_document(pdoc, layer, base_file)
        _, found = parse_scenario_warnings(pdoc, base_file)
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


def _validate_controllers(study: Study) -> None:
    """Each MPC controller's settings on each distinct point document; OCP-D needs one follower."""
    for c in study.controllers:
        if c.kind == "law":
            continue
        for p in study.points:
            try:
                sc = parse_scenario_quiet(controller_document(p.document, c, p.file), p.file)
            except (ScenarioError, OverrideError, ParameterError) as exc:
                msg = str(exc)
                where = (f"controller {c.label}" if any(f"mpc.{k}" in msg or k in msg for k, _ in c.settings)
                         else _culprit(msg, p.values, study.axes))
                raise StudyError(f"{study.file}: {where} (point {p.index}: {_describe(p.values)}): {msg}") from None
            if c.kind == "ocpd" and sc.n_followers != 1:
                raise StudyError(f"{study.file}: controllers.ocpd: OCP-D needs a single follower; scenario {p.base} "
                                 f"has {sc.n_followers} (point {p.index})")


def controller_document(doc: dict[str, Any], c: Controller, file: str) -> dict[str, Any]:
    """The point's document with the controller's [mpc] keys applied (laws: unchanged)."""
    if c.kind == "law" or not c.settings:
        return doc
    return apply_to_document(doc, {f"mpc.{k}": v for k, v in c.settings}, file)

