"""A platoon scenario: the validated, frozen :class:`Scenario` and how a parsed TOML document becomes one
(:func:`parse_scenario`: the top-level keys, [simulation], then the tables each module of this package reads), or
an edited copy of one (:meth:`Scenario.replace`, :func:`apply_to_scenario`)."""

from __future__ import annotations

import copy
import dataclasses
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from ..models.carfollowing import LAW_REGISTRY, V_INF, CarFollowingLaw, make_law
from ..models.leader import ConstantSpeed, LeaderProfile, PaperLeader, SpeedTrace
from ..overrides import SI_TWINS, apply_to_document
from ..params import CarFollowingParams, EVParams, ParameterError, SimOptions, Units, field_checks
from ..results import check_safe_name
from .followers import _carfollowing, _platoon
from .leader import _leader, trace_read_s
from .providers import _check_top_level
from .sections import _SECTIONS, STANDALONE_SECTIONS
from .size import check_run_size, thinned_dt_out
from .tables import ScenarioError, ScenarioWarning, TableReader, read_declared
from .vehicle import read_ev


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
        return {
            "gaps0": list(self.gaps0),
            "speeds0": list(self.speeds0),
            "t_end": self.t_end,
            "ev": self.ev,
            "dt_out": self.dt_out,
            "rtol": self.rtol,
            "atol": self.atol,
        }

    def run(
        self, progress: Callable[[str, float, float], None] | None = None, *, only: str | None = None, **overrides: Any
    ) -> dict[str, Any]:
        """Simulate every run of :meth:`runs` (``only``: just the run of that label); returns {label: SimulationResult}.

        progress(label, t, t_end) is called as each run advances [model time]; ``overrides`` replace
        keyword arguments of :func:`aev_ocp.simulate.simulate_platoon` (e.g. rtol, dt_out, t_end).
        """
        from ..simulate import simulate_platoon

        base = {**self.simulate_kwargs(), **overrides}
        check_trace_horizon(self, float(base["t_end"]))
        check_run_size(self.n_followers, float(base["t_end"]), float(base["dt_out"]), str(self.source or self.name))
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
            raise ScenarioError(
                f"{self.file_label}: replace(): unknown field(s) {unknown}; fields are "
                f"{[f.name for f in dataclasses.fields(self) if f.name != 'document']}"
            )
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
                raise ScenarioError(
                    f"{self.file_label}: replace(ev=...): ev.units ({changes['ev'].units}) differ "
                    f"from the scenario's units ({fixed.units}); pass units= too"
                )
            if "laws" in changes and fixed.compare:
                raise ScenarioError(
                    f"{self.file_label}: replace(laws=...) would be ignored: the scenario sets "
                    f"compare = {list(fixed.compare)}, so every run uses those laws; "
                    "pass compare=() too"
                )
            n = len(fixed.laws)
            if len(fixed.gaps0) != n or len(fixed.speeds0) != n:
                raise ScenarioError(
                    f"{self.file_label}: replace(): {n} laws but {len(fixed.gaps0)} gaps0 and "
                    f"{len(fixed.speeds0)} speeds0; give one of each per follower"
                )
            out = fixed
        return out


#: Scenario fields that a file key states: replace() routes them through with_overrides.
_REPLACE_KEYS = ("name", "description", "compare", "units", "cf", "law_overrides", "t_end", "dt_out", "rtol", "atol")


def _replace_overrides(keyed: dict[str, Any]) -> dict[str, Any]:
    """replace() arguments of the file-keyed fields as dotted-path overrides."""
    ov: dict[str, Any] = {}
    simple = {
        "name": "name",
        "description": "description",
        "t_end": "simulation.t_end",
        "dt_out": "simulation.dt_out",
        "rtol": "simulation.rtol",
        "atol": "simulation.atol",
    }
    for k, v in keyed.items():
        if k in simple:
            ov[simple[k]] = v
        elif k == "compare":
            ov["compare"] = list(v) or None  # None removes the key: no compare
        elif k in ("units", "cf"):
            table = "units" if k == "units" else "carfollowing"
            ov.update(
                {f"{table}.{f.name}": getattr(v, f.name) for f in dataclasses.fields(v) if f.name != "model_units"}
            )
        elif k == "law_overrides":
            for law, coeffs in v.items():
                ov.update({f"carfollowing.{law}.{c}": x for c, x in coeffs.items()})
    return ov


def check_trace_horizon(sc: "Scenario", t_end: float) -> None:
    """ScenarioError if ``sc``'s trace leader was read only for a shorter horizon than ``t_end`` [model time]: the
    run would see the last speed read held instead of the recording (reload or with_overrides re-reads it)."""
    limit = getattr(sc.leader, "read_for_t_end", None)
    if limit is not None and t_end > limit * (1.0 + 1e-12):
        raise ScenarioError(
            f"{sc.file_label}: t_end = {t_end:g} model time ({sc.units.time_to_si(t_end):g} s): the trace leader's "
            f"file was read only as far as a run of {limit:g} model time ({sc.units.time_to_si(limit):g} s) needs; "
            "set simulation.t_end_s with with_overrides() or in the file, so the recording is read that far"
        )


def _replace_without_document(sc: "Scenario", keyed: dict[str, Any]) -> "Scenario":
    """replace() of file-keyed fields on a scenario built in Python: rebuild what derives from them."""
    if "t_end" in keyed:
        check_trace_horizon(sc, float(keyed["t_end"]))
    out = dataclasses.replace(sc, **keyed)
    out = dataclasses.replace(out, cf=dataclasses.replace(out.cf, model_units=out.units))  # laws in the units
    if "cf" in keyed or "law_overrides" in keyed or "units" in keyed:
        try:
            laws = tuple(make_law(law.name, out.cf, **out.law_overrides.get(law.name, {})) for law in out.laws)
        except (KeyError, TypeError, ParameterError) as exc:
            raise ScenarioError(f"{sc.file_label}: replace(): cannot rebuild the laws: {exc}") from None
        out = dataclasses.replace(out, laws=laws)
    if "units" in keyed:
        if not isinstance(out.leader, (ConstantSpeed, PaperLeader)):
            raise ScenarioError(
                f"{sc.file_label}: replace(units=...): the leader ({type(out.leader).__name__}) "
                "was converted with the old units and this scenario has no document to rebuild "
                "it from; pass leader= too, or load the scenario from a file"
            )
        out = dataclasses.replace(out, ev=dataclasses.replace(out.ev, units=out.units))
    return out


def parse_scenario(doc: dict[str, Any], file: str = "<scenario>", *, source: Path | None = None) -> Scenario:
    """Validate a parsed TOML document (``file`` names it in messages) into a :class:`Scenario`."""
    for key, command in STANDALONE_SECTIONS.items():
        if key in doc:
            raise ScenarioError(
                f"{file}: a {key} scenario (it has a [{key}] table), not a platoon: run it with '{command} {file}'"
            )
    _check_top_level(doc, file)
    top = TableReader(doc, "", file)
    name = _scenario_name(top, source)
    description = top.string("description", "")
    compare = tuple(top.strings("compare", [], choices=sorted(LAW_REGISTRY)))
    dups = sorted({c for c in compare if compare.count(c) > 1})
    if dups:
        raise top.error("compare", doc["compare"], f"names {dups[0]!r} twice; each law runs once")

    ev = read_ev(top, source)
    units = ev.units
    t_end, opts = _simulation(top.sub("simulation", required=True), units)

    cf, overrides = _carfollowing(top.sub("carfollowing"))
    cf = dataclasses.replace(cf, model_units=units)  # the laws run in the scenario's model units, same SI behaviour
    read_s = trace_read_s(doc, t_end, units)
    leader = _leader(top.sub("leader", required=True), units, source, read_s)
    if isinstance(leader, SpeedTrace) and units.time_to_si(leader.times[-1]) >= read_s:
        leader = dataclasses.replace(leader, read_for_t_end=t_end)  # the recording was read only this far
    sized: dict[str, float] = {}

    def size(n: int) -> None:
        sized["dt_out"] = thinned_dt_out(n, t_end, opts.dt_out, file)

    laws, gaps, speeds = _platoon(top.sub("platoon", required=True), leader, cf, overrides, compare, size, units)
    _warn_unused_overrides(overrides, compare, laws, file)
    extra = _registered_sections(doc, top, file)
    top.finish()

    scenario = Scenario(
        name=name,
        description=description,
        units=units,
        leader=leader,
        laws=laws,
        gaps0=tuple(gaps),
        speeds0=tuple(speeds),
        t_end=t_end,
        ev=ev,
        dt_out=sized.get("dt_out", opts.dt_out),
        rtol=opts.rtol,
        atol=opts.atol,
        compare=compare,
        cf=cf,
        law_overrides=overrides,
        extra=extra,
        source=source,
        document=copy.deepcopy(doc),
    )
    check_leader_speed(scenario, file)
    return scenario


def _scenario_name(top: TableReader, source: Path | None) -> str:
    """The scenario's ``name`` (a safe name: it names the output folder), else its file's stem made safe."""
    if top.has("name"):
        name = top.string("name")
        try:
            check_safe_name(name)
        except ValueError as exc:
            raise top.error("name", name, str(exc).split("is not allowed: ", 1)[-1]) from None
        return name
    stem = source.stem if source is not None else "scenario"  # (it names the default output folder results/<name>/)
    return re.sub(r"[^A-Za-z0-9._+-]", "_", stem).lstrip("._+-")[:100] or "scenario"


def _simulation(sim: TableReader, units: Units) -> tuple[float, SimOptions]:
    """``[simulation]``: the horizon t_end [model time] and the SimOptions (dt_out at most t_end)."""
    t_end = sim.quantity("t_end", units, gt=0)  # or t_end_s [s]
    # dt_out, rtol, atol: types, ranges and defaults are SimOptions's (rtol/atol: what the integrators honour)
    dt_si = sim.has(SI_TWINS["simulation"]["dt_out"][0])
    declared = read_declared(SimOptions, sim, ("rtol", "atol") if dt_si else ("dt_out", "rtol", "atol"))
    if dt_si:
        declared["dt_out"] = sim.quantity("dt_out", units, gt=field_checks(SimOptions)["dt_out"].gt)  # dt_out_s [s]
    opts = dataclasses.replace(SimOptions(), **declared)
    if opts.dt_out > t_end:
        raise sim.error(
            "dt_out_s" if dt_si else "dt_out",
            sim.table["dt_out_s" if dt_si else "dt_out"],
            f"must be <= the horizon (simulation.t_end = {t_end:g} model time = {units.time_to_si(t_end):g} s)",
        )
    sim.finish()
    return t_end, opts


def _warn_unused_overrides(
    overrides: dict[str, dict[str, float]], compare: tuple[str, ...], laws: tuple[CarFollowingLaw, ...], file: str
) -> None:
    """A ScenarioWarning for each [carfollowing.<law>] table whose law no run uses."""
    used = set(compare) | {law.name for law in laws} | {"proposed"}  # proposed: the MPC's fallback law
    for law_name in overrides:
        if law_name not in used:
            warnings.warn(
                ScenarioWarning(
                    f"{file}: carfollowing.{law_name} sets coefficients of law {law_name!r}, which no run uses "
                    f"(runs: {sorted(set(compare) or {law.name for law in laws})})"
                ),
                stacklevel=3,
            )


def _registered_sections(doc: dict[str, Any], top: TableReader, file: str) -> dict[str, Any]:
    """The registered sections the document has, each validated by its module's validator."""
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
    return extra


def check_leader_speed(scenario: Scenario, file: str = "<scenario>") -> float:
    """Warn (ScenarioWarning) if the leader's top speed reaches V∞ = 1 + tanh 2; returns that top speed."""
    v_max = scenario.leader.max_speed(scenario.t_end)
    u = scenario.units
    v_top = V_INF * scenario.cf.v_scale_mps  # the OV laws' top speed [m/s]: V∞ times their speed scale
    if u.speed_to_si(v_max) >= v_top:
        warnings.warn(
            ScenarioWarning(
                f"{file}: the leader reaches {v_max:.4g} model speed ({u.speed_to_si(v_max):.4g} m/s), at or above "
                f"V∞ = 1 + tanh 2 = {V_INF:.4f} times the laws' speed scale ({v_top:.4g} m/s with "
                f"carfollowing.v_scale_mps = {scenario.cf.v_scale_mps:g}): no optimal-velocity law can keep up; "
                f"raise carfollowing.v_scale_mps above {u.speed_to_si(v_max) / V_INF:.4g}"
            ),
            stacklevel=3,
        )
    return v_max


def apply_to_scenario(scenario: Scenario, overrides: Mapping[str, Any]) -> Scenario:
    """``scenario`` with ``overrides`` applied to its TOML document and re-validated (see :mod:`aev_ocp.overrides`).

    The scenario must come from a document (a file, or :func:`aev_ocp.scenarios.parse_scenario`)."""
    if scenario.document is None:
        raise ScenarioError(
            f"{scenario.name}: overrides need the scenario's TOML document; this scenario was "
            "built in Python or changed with replace(leader=..., laws=..., ...), which no "
            "document describes"
        )
    file = scenario.file_label
    doc = apply_to_document(scenario.document, overrides, file)
    return parse_scenario(doc, file, source=scenario.source)
