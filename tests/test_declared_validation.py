"""Validation declared once (issue 7 item 6): each option/parameter dataclass states its fields' types and
ranges beside the fields; the Python API and the TOML tables ([mpc], [simulation], ...) read the same
declarations, so a range changed in one place changes both, with messages naming file, key, value, range."""

from __future__ import annotations

import dataclasses
import tomllib

import pytest

from aev_ocp.mpc.scenario import closed_loop_from_scenario, mpc_table_keys
from aev_ocp.mpc.settings import MPCSettings
from aev_ocp.ocp.following import TemperatureTerms
from aev_ocp.ocp.formulation import Formulation
from aev_ocp.ocp.traffic import TrafficParams
from aev_ocp.params import (
    ATOL_RANGE,
    RTOL_RANGE,
    CarFollowingParams,
    CellParams,
    PackParams,
    ParameterError,
    PowertrainOptions,
    SimOptions,
    ThermalParams,
    Units,
    VehicleParams,
    field_checks,
)
from aev_ocp.scenarios import ScenarioError, find_scenario, parse_scenario

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)

DATACLASSES = (
    Units,
    CarFollowingParams,
    VehicleParams,
    CellParams,
    PackParams,
    PowertrainOptions,
    SimOptions,
    MPCSettings,
    ThermalParams,
)


@pytest.mark.parametrize("cls", DATACLASSES)
def test_every_field_declares_its_check(cls) -> None:
    """No field is left to a hand-written check: every field carries a declaration."""
    assert set(field_checks(cls)) == {f.name for f in dataclasses.fields(cls)}


#: Fields whose edge values need another field moved out of the way (a rule between fields): {cls: {field: kwargs}}.
#: ThermalParams: T_max_K must exceed ambient_K.
COMPANIONS: dict[type, dict[str, dict[str, float]]] = {
    ThermalParams: {"T_max_K": {"ambient_K": 1e-9}, "ambient_K": {"T_max_K": 1000.0}}
}


@pytest.mark.parametrize("cls", DATACLASSES)
def test_declared_bounds_are_enforced_at_the_edges(cls) -> None:
    """For every numeric bound: a value just inside is accepted, the bound itself (open) or just outside
    (closed) is rejected with a message naming class, field and value."""
    tried = 0
    for name, c in field_checks(cls).items():
        if c.kind not in ("number", "integer"):
            continue
        step = 1 if c.kind == "integer" else None
        for bound, inside_sign, strict in ((c.gt, +1, True), (c.ge, +1, False), (c.lt, -1, True), (c.le, -1, False)):
            if bound is None:
                continue
            d = step or max(abs(bound), 1.0) * 1e-6
            inside = bound if not strict else bound + inside_sign * d
            outside = bound if strict else bound - inside_sign * d
            if c.kind == "integer":
                inside, outside = int(inside), int(outside)
            other = COMPANIONS.get(cls, {}).get(name, {})
            cls(**{name: inside}, **other)
            with pytest.raises(ParameterError, match=rf"^{cls.__name__}\.{name} = "):
                cls(**{name: outside}, **other)
            tried += 1
    if cls not in (MPCSettings,):
        assert tried > 0


def test_tolerances_outside_what_the_integrators_honour_are_refused() -> None:
    """Issue 11 item 3: rtol = atol = 1e-30 used to pass and crash the compiled cascade."""
    assert RTOL_RANGE == (1e-14, 1e-2) and ATOL_RANGE == (1e-16, 1.0)
    for kw in ({"rtol": 1e-30}, {"atol": 1e-30}, {"rtol": 0.5}, {"atol": 2.0}, {"rtol": float("nan")}):
        with pytest.raises(ParameterError, match=next(iter(kw))):
            SimOptions(**kw)
    SimOptions(rtol=1e-14, atol=1e-16)


def test_wrong_types_name_the_type() -> None:
    with pytest.raises(ParameterError, match=r"PackParams\.n_series = 2\.0 .*got a float"):
        PackParams(n_series=2.0)
    with pytest.raises(ParameterError, match=r"VehicleParams\.efficiency = 'x' .*got a string"):
        VehicleParams(efficiency="x")
    with pytest.raises(ParameterError, match=r"Formulation\.weights = .*FollowingWeights"):
        Formulation("s9", weights={"w_Q": 1.0})


def _mpc_doc(**mpc):
    doc = tomllib.loads(find_scenario("mpc_paper_single").read_text())
    doc["mpc"].update(mpc)
    return doc


def test_mpc_table_keys_derive_from_the_dataclasses() -> None:
    keys = set(mpc_table_keys())
    own = {f.name for f in dataclasses.fields(MPCSettings)}  # solver options, then the formulation's keys
    assert (
        own
        | {
            "formulation",
            "objective",
            "w_Q",
            "w_V",
            "w_r",
            "w_a",
            "h_min",
            "v_min",
            "v_max",
            "a_min",
            "a_max",
            "smoothing_width_W",
        }
        | {f.name for f in dataclasses.fields(TrafficParams)}
        | {f.name for f in dataclasses.fields(TemperatureTerms)}
        == keys
    )


@pytest.mark.parametrize(
    "key, value, fragments",
    [
        ("N", 0, ["mpc.N = 0", "an integer >= 1"]),
        ("N", 2.5, ["mpc.N = 2.5", "got a float"]),
        ("predictor_window", 1, ["mpc.predictor_window = 1", ">= 2"]),
        ("dt", -0.1, ["mpc.dt = -0.1", "> 0"]),
        ("solver", "warp", ["mpc.solver = 'warp'", "rti"]),
        ("codegen", "yes", ["mpc.codegen = 'yes'", "true or false"]),
        ("max_cpu_time_s", float("inf"), ["mpc.max_cpu_time_s = inf", "finite"]),
        ("w_Q", -2.0, ["mpc.w_Q", "-2.0", ">= 0"]),
        ("v_min", 2.5, ["mpc.v_min", "2.5", "v_max"]),
        ("smoothing_width_W", 0.0, ["mpc.smoothing_width_W = 0.0", "> 0"]),
    ],
)
def test_mpc_table_messages_name_file_key_value_and_range(key, value, fragments) -> None:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(_mpc_doc(**{key: value}), "my.toml")
    msg = str(info.value)
    assert msg.startswith("my.toml: ") and "\n" not in msg
    for f in fragments:
        assert f in msg, msg


def test_mpc_table_accepts_valid_values_and_upper_case_choices() -> None:
    cfg = parse_scenario(
        _mpc_doc(N=17, solver="SQP", qp_solver="HPIPM", w_a=0.25, smoothing_width_W=150), "ok.toml"
    ).extra["mpc"]
    s, f = cfg.settings, cfg.formulation
    assert (s.N, s.solver, f.weights.w_a, f.smooth.smoothing_width_W, f.kind) == (17, "sqp", 0.25, 150.0, "s9")


@pytest.mark.parametrize(
    "mpc, fragments",
    [
        ({"vehicles": [7]}, ["mpc.vehicles = [7]", "platoon.followers = 1"]),
        ({"h_min": 0.45}, ["mpc.h_min = 0.45", "initial gap", "infeasible"]),
        ({"v_max": 1.5}, ["initial speed of follower 1", "1.87", "infeasible"]),
        ({"h_min": 0.3}, ["mpc.h_min = 0.3", "at or above the initial gap"]),
    ],
)
def test_mpc_setup_errors_name_the_file(mpc, fragments) -> None:
    """Issue 11 minor: [mpc] vehicles = [7] did not name the file; h_min above h(0) ran on the fallback."""
    src = find_scenario("mpc_paper_single")
    sc = parse_scenario(_mpc_doc(**mpc), str(src), source=src)
    with pytest.raises(ScenarioError) as info:
        closed_loop_from_scenario(sc)
    msg = str(info.value)
    assert msg.startswith(str(src)) and "\n" not in msg
    for f in fragments:
        assert f in msg, msg


SMALL_DOC = {
    "leader": {"kind": "constant", "v": 1.0},
    "platoon": {"followers": 1, "gap0_first": 1.0, "speed0": 1.0},
    "simulation": {"t_end": 1.0},
}


@pytest.mark.parametrize(
    "table, cls",
    [
        ("simulation", SimOptions),
        ("vehicle", VehicleParams),
        ("cell", CellParams),
        ("units", Units),
        ("pack", PackParams),
        ("carfollowing", CarFollowingParams),
    ],
)
def test_toml_tables_derive_their_ranges_from_the_dataclass(table, cls) -> None:
    """Every declared bound of the dataclass is the TOML table's bound, with the same words in the message."""
    checked = 0
    for name, c in field_checks(cls).items():
        if table == "simulation" and name not in ("dt_out", "rtol", "atol"):
            continue
        for bound, sign, strict in ((c.gt, -1, True), (c.ge, -1, False), (c.lt, +1, True), (c.le, +1, False)):
            if bound is None:
                continue
            outside = (
                bound if strict else (bound + sign if c.kind == "integer" else bound + sign * max(abs(bound), 1) * 1e-3)
            )
            doc = {k: dict(v) for k, v in SMALL_DOC.items()}
            doc.setdefault(table, {})[name] = outside
            with pytest.raises(ScenarioError) as info:
                parse_scenario(doc, "d.toml")
            msg = str(info.value)
            assert msg.startswith(f"d.toml: {table}.{name} = ") and c.allowed() in msg, msg
            checked += 1
    assert checked >= 2


def test_argument_helpers_for_the_python_api() -> None:
    """Helpers the simulator and closed loop use for their arguments (issue 11 minor: AttributeError for a
    wrong type, 'integration failed' for soc0 = nan)."""
    from aev_ocp.models.leader import LeaderProfile, PaperLeader
    from aev_ocp.params import EVParams, check_argument, check_declared

    assert check_declared(CellParams, "soc0", 0.35, "simulate") == 0.35
    for bad in (float("nan"), 1.5, -0.1, "0.5"):
        with pytest.raises(ParameterError, match=r"^simulate: soc0 = .* is not allowed: .*\[0, 1\]"):
            check_declared(CellParams, "soc0", bad, "simulate")
    leader = PaperLeader()
    assert check_argument("simulate_platoon", "leader", leader, LeaderProfile) is leader
    with pytest.raises(TypeError, match=r"^simulate_platoon: leader must be LeaderProfile, got str 'paper'$"):
        check_argument("simulate_platoon", "leader", "paper", LeaderProfile)
    with pytest.raises(TypeError, match=r"ev must be EVParams or None, got dict"):
        check_argument("simulate_platoon", "ev", {}, (EVParams, type(None)))
