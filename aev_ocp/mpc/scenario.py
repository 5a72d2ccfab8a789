"""The ``[mpc]`` table of scenario files, and building a closed loop from a scenario.

Keys (all optional): every :class:`MPCSettings` solver option (N, dt, solver, qp_solver, codegen, tol, max_iter,
rti_iterations, budget, max_step_ms, max_cpu_time_s, predictor, predictor_window, rk4_substeps, verbose); the
formulation's keys, routed into one :class:`aev_ocp.ocp.formulation.Formulation`: ``formulation`` ('traffic', the
default, or 's9'), the traffic formulation's SI parameters (TrafficParams fields), §9's objective, weights w_Q, w_V,
w_r, w_a and bounds h_min, v_min, v_max, a_min, a_max, smoothing_width_W, and the pack temperature in the prediction
(TemperatureTerms: temperature_state, temperature_max_K, temperature_penalty; needs ``[thermal] enabled = true``); plus
``vehicles`` ("all" or an array of 1-based follower numbers on MPC; the others keep the scenario's [platoon] law) and
``follower_predictor`` (forecast of an MPC follower behind another vehicle: "cooperative" behind an MPC vehicle by
default, else "constant-velocity").
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..ocp.following import FollowingBounds, FollowingWeights, TemperatureTerms
from ..ocp.formulation import (
    DEFAULT_FORMULATION,
    Formulation,
    formulation_from_dict,
    formulation_keys,
    renamed_formulation_keys,
)
from ..ocp.traffic import TrafficParams
from ..control import ClosedLoop
from ..params import Check, ParameterError, PowertrainOptions, field_checks
from .policy import MPCVehicle
from .settings import MPCSettings

#: Dataclasses of the formulation whose fields appear flat in the [mpc] table.
_NESTED = {
    "weights": FollowingWeights,
    "bounds": FollowingBounds,
    "smooth": PowertrainOptions,
    "traffic": TrafficParams,
    "temperature": TemperatureTerms,
}
#: The ``follower_predictor`` key: forecasts that make sense behind another vehicle.
FOLLOWER_PREDICTORS = ("cooperative", "constant-velocity", "constant-acceleration")


@dataclass(frozen=True)
class MPCConfig:
    """Validated [mpc] table: solver settings, 0-based MPC vehicle indices (None = all), follower predictor,
    and the formulation (the problem; default the traffic formulation)."""

    settings: MPCSettings
    vehicles: tuple[int, ...] | None = None
    follower_predictor: str | None = None
    formulation: Formulation = DEFAULT_FORMULATION


def mpc_table_keys() -> dict[str, Check | None]:
    """Keys of the [mpc] table (besides vehicles, follower_predictor) -> their declared Check (None: a
    number checked by its dataclass). Derived from MPCSettings and the formulation's dataclasses, never listed by hand."""
    keys: dict[str, Check | None] = {k: c for k, c in field_checks(MPCSettings).items() if c.kind != "instance"}
    fc = field_checks(Formulation)
    keys["formulation"] = Check("choice", choices=("traffic", "s9"))
    keys["objective"] = fc["objective"]
    for cls in _NESTED.values():
        checks = field_checks(cls)
        keys.update({f.name: checks.get(f.name) for f in fields(cls)})
    return keys


def _read(r: Any, key: str, check: Check | None) -> Any:
    """One [mpc] value checked against its declaration (type and range), errors naming file and key."""
    return r.number(key) if check is None else r.declared(key, check)


def validate_mpc_table(r: Any) -> MPCConfig:
    """Validator for ``aev_ocp.scenarios.register_section('mpc', ...)`` (a TableReader)."""
    from ..scenarios.tables import ScenarioError

    keys = mpc_table_keys()
    try:  # old key names (energy_weight, objective = "energy") are read with a FutureWarning naming the new ones
        r.table = renamed_formulation_keys(r.table, f"{r.path}." if r.path else "", f"{r.file}: ")
    except ParameterError as exc:
        raise ScenarioError(str(exc)) from None
    d = {k: _read(r, k, keys[k]) for k in list(r.table) if k in keys}
    vehicles: tuple[int, ...] | None = None
    if r.has("vehicles"):
        val = r.table["vehicles"]
        if val == "all":
            r._get("vehicles", None)
        else:
            if not isinstance(val, list):
                raise r.error("vehicles", val, 'must be "all" or an array of follower numbers (1, 2, …)')
            nums_v = r.numbers("vehicles", ge=1)
            if any(int(x) != x for x in nums_v):
                raise r.error("vehicles", val, 'must be "all" or an array of follower numbers (1, 2, …)')
            if len(set(nums_v)) != len(nums_v):
                raise r.error("vehicles", val, "lists a follower twice")
            vehicles = tuple(sorted({int(x) - 1 for x in nums_v}))
    fp = r.string("follower_predictor", None, choices=list(FOLLOWER_PREDICTORS))
    r.finish(allowed_hint=sorted(keys) + ["follower_predictor", "vehicles"])
    if d.get("formulation", DEFAULT_FORMULATION.kind) != "s9":  # §9-only keys would be silently ignored
        s9_only = {f.name for c in (FollowingWeights, FollowingBounds) for f in fields(c)} | {"objective"}
        bad = [k for k in d if k in s9_only]
        if bad:
            raise r.error(
                bad[0],
                d[bad[0]],
                'applies to the §9 formulation only: set mpc.formulation = "s9", or '
                "use the traffic formulation's SI parameters (standstill_gap_m, time_headway_s, "
                "a_min_mps2, ...; see aev_ocp/ocp/traffic.py)",
            )
    elif d.get("formulation") == "s9":  # and the traffic formulation's keys under §9
        bad = [k for k in d if k in {f.name for f in fields(TrafficParams)}]
        if bad:
            raise r.error(
                bad[0],
                d[bad[0]],
                'applies to the traffic formulation only (aev_ocp/ocp/traffic.py), not to formulation = "s9"',
            )
    fkeys = formulation_keys()
    try:
        settings = MPCSettings.from_dict({k: v for k, v in d.items() if k not in fkeys})
        formulation = formulation_from_dict({k: v for k, v in d.items() if k in fkeys})
    except ParameterError as exc:  # a cross-field rule of a nested dataclass (e.g. v_min < v_max)
        key = next((k for k in d if f".{k} " in str(exc)), None)
        raise ScenarioError(f"{r.file}: {r.key_path(key) if key else r.path}: {exc}") from None
    from ..limits import check_mpc_size

    try:  # one MPC vehicle's NLP within the memory budget, wherever an [mpc] table is read (mpc, mpc-export, study)
        check_mpc_size(settings.N, 1, key=r.key_path("N"))
    except ParameterError as exc:
        raise ScenarioError(f"{r.file}: {exc}") from None
    return MPCConfig(settings, vehicles, fp, formulation)


def register() -> None:
    """Register the [mpc] table with the scenario loader."""
    from ..scenarios.sections import register_section

    register_section("mpc", validate_mpc_table)


def check_mpc_setup(
    scenario: Any,
    config: MPCConfig | None = None,
    settings: MPCSettings | None = None,
    formulation: Formulation | None = None,
) -> None:
    """Refuse an MPC setup that cannot run, before anything is built: MPC vehicles that do not exist, or an
    MPC vehicle whose initial gap is at or below h_min or whose initial speed is outside [v_min, v_max]
    (every NLP would be infeasible and every step would run on the fallback). ScenarioError naming the file."""
    from ..scenarios.tables import ScenarioError

    cfg = config or scenario.extra.get("mpc") or MPCConfig(MPCSettings())
    f = formulation or cfg.formulation
    file = str(scenario.source) if getattr(scenario, "source", None) is not None else scenario.name
    n = scenario.n_followers
    on = list(range(n)) if cfg.vehicles is None else list(cfg.vehicles)
    missing = [i + 1 for i in on if i >= n]
    if missing:
        raise ScenarioError(
            f"{file}: mpc.vehicles = {[i + 1 for i in on]} is not allowed: follower(s) {missing} "
            f"do not exist (platoon.followers = {n})"
        )
    from ..limits import check_mpc_size

    try:  # every MPC vehicle's NLP together within the memory budget, before the first one is built
        check_mpc_size((settings or cfg.settings).N, len(on), key="mpc.N")
    except ParameterError as exc:
        raise ScenarioError(f"{file}: {exc}") from None
    if f.temperature.temperature_state and not scenario.ev.thermal.enabled:
        raise ScenarioError(
            f"{file}: mpc.temperature_state = true is not allowed: the prediction's temperature is "
            "measured on the plant's thermal model, which is off (set [thermal] enabled = true)"
        )
    b = f.bounds_model(scenario.ev)
    for i in on:
        h0, v0 = scenario.gaps0[i], scenario.speeds0[i]
        if f.kind == "s9" and b.h_min is not None and b.h_min >= h0:  # the traffic formulation's floor is soft
            raise ScenarioError(
                f"{file}: mpc.h_min = {b.h_min:g} is not allowed: it is at or above the initial gap "
                f"of follower {i + 1} ({h0:g}), so the MPC problem is infeasible from the first step"
            )
        if b.v_min is not None and b.v_max is not None and not b.v_min <= v0 <= b.v_max:
            raise ScenarioError(
                f"{file}: mpc.v_min/v_max (traffic: 0, v_max_mps) = [{b.v_min:g}, {b.v_max:g}] is not allowed: the initial "
                f"speed of follower {i + 1} ({v0:g}) lies outside, so the MPC problem is infeasible"
            )


def closed_loop_from_scenario(
    scenario: Any,
    config: MPCConfig | None = None,
    settings: MPCSettings | None = None,
    formulation: Formulation | None = None,
) -> ClosedLoop:
    """A :class:`ClosedLoop` for a scenario: MPC on the configured followers (the config's formulation, unless
    ``formulation`` is given), the scenario's laws on the others, the proposed law with the scenario's α, β, κ
    as the fallback."""
    cfg = config or scenario.extra.get("mpc") or MPCConfig(MPCSettings())
    s = settings or cfg.settings
    f = formulation or cfg.formulation
    n = scenario.n_followers
    on = set(range(n)) if cfg.vehicles is None else set(cfg.vehicles)
    check_mpc_setup(scenario, cfg, s, f)
    ctrls: list[Any] = []
    for i in range(n):
        if i not in on:
            ctrls.append(scenario.laws[i])
        elif i == 0:
            ctrls.append(MPCVehicle(s, formulation=f))
        else:
            p = cfg.follower_predictor or ("cooperative" if (i - 1) in on else "constant-velocity")
            if p == "cooperative" and (i - 1) not in on:
                p = "constant-velocity"
            ctrls.append(MPCVehicle(s, predictor=p, formulation=f))
    from ..estimation.scenario import realism_kwargs  # [mismatch], [sensors]: plant ≠ model, measurements

    return ClosedLoop(
        scenario.leader,
        ctrls,
        scenario.ev,
        fallback_law=scenario.law("proposed"),
        rtol=scenario.rtol,
        atol=scenario.atol,
        law_dt=s.dt,
        **realism_kwargs(scenario),
    )


register()  # the scenario loader imports this module when a file has an [mpc] table
