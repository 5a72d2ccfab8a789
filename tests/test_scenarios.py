"""Scenario files: every shipped file loads, and each class of invalid input gives a ScenarioError
whose message names the file, the key path and the offending value."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest
from cli_helpers import one_error, run_cli
from helpers import _BIG_STR, _BIG_TABLE, SCENARIO, SMALL
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.models.carfollowing import OVFL, V_INF, Proposed
from aev_ocp.models.leader import PaperLeader, SpeedTrace
from aev_ocp.params import ParameterError, Units
from aev_ocp.scenarios import (
    ScenarioError,
    ScenarioWarning,
    TableReader,
    find_scenario,
    load_scenario,
    register_section,
    shipped_scenarios,
)

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)

BASE = """
name = "t"
compare = ["proposed", "ovfl"]
[units]
length_m = 10.0
speed_mps = 5.0
[leader]
kind = "paper"
[platoon]
followers = 3
law = "proposed"
gap0_first = 0.3
gap0_others = 3.5
speed0_factor = 1.1
[carfollowing]
kappa = 0.03
[vehicle]
mass_kg = 1752.0
efficiency = 0.8
[simulation]
t_end = 5.0
"""

SHIPPED = ["fig1a", "fig1b", "table1", "udds_platoon", "hwfet_platoon", "us06_platoon"]


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def edit(old: str, new: str) -> str:
    assert old in BASE, old
    return BASE.replace(old, new)


def expect_error(tmp_path: Path, text: str, *fragments: str) -> str:
    p = write(tmp_path, text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(p)
    msg = str(info.value)
    assert str(p) in msg, msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    assert "\n" not in msg
    return msg


def test_base_loads(tmp_path: Path) -> None:
    s = load_scenario(write(tmp_path, BASE))
    assert s.n_followers == 3
    assert s.gaps0 == (0.3, 3.5, 3.5)
    assert s.speeds0 == pytest.approx((1.87, 1.87, 1.87))
    assert isinstance(s.leader, PaperLeader)
    assert all(isinstance(law, Proposed) for law in s.laws)
    assert [label for label, _ in s.runs()] == ["proposed", "ovfl"]
    assert isinstance(s.runs()[1][1][0], OVFL)
    assert s.ev.vehicle.mass_kg == 1752.0 and s.t_end == 5.0


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_load(name: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)  # shipped leaders stay below V∞
        s = load_scenario(find_scenario(name))
    assert s.name == name
    assert s.compare == ("proposed", "ovfl")
    assert s.leader.max_speed(s.t_end) < V_INF
    assert all(g > 0 for g in s.gaps0) and all(v >= 0 for v in s.speeds0)


def test_shipped_list_is_complete() -> None:
    assert set(SHIPPED) <= set(shipped_scenarios())


def test_table1_matches_paper_setup() -> None:
    s = load_scenario("table1")
    assert s.n_followers == 5 and s.t_end == 70.0
    assert s.gaps0 == (0.3, 3.5, 3.5, 3.5, 3.5)
    assert s.speeds0 == pytest.approx((1.1 * 1.7,) * 5)
    assert s.ev.vehicle.efficiency == 0.8
    assert (s.cf.alpha, s.cf.beta, s.cf.kappa) == (2.0, 3.0, 0.03)


def test_unknown_top_level_key(tmp_path: Path) -> None:
    expect_error(tmp_path, BASE + "\n[mystery]\nx = 1\n", "'mystery'", "allowed")


def test_unknown_nested_key(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("mass_kg = 1752.0", "mass_kg = 1752.0\nmas_kg = 3.0"), "vehicle.mas_kg", "3.0")


def test_unknown_platoon_key(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("followers = 3", "followers = 3\ncolour = 'red'"), "platoon.colour", "'red'")


def test_wrong_type(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("mass_kg = 1752.0", 'mass_kg = "heavy"'), "vehicle.mass_kg", "'heavy'", "number")


def test_wrong_type_integer(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("followers = 3", "followers = 2.5"), "platoon.followers", "2.5", "integer")


def test_negative_mass(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("mass_kg = 1752.0", "mass_kg = -5.0"), "vehicle.mass_kg", "-5.0", "> 0")


def test_negative_kappa(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("kappa = 0.03", "kappa = -0.1"), "carfollowing.kappa", "-0.1", ">= 0")


@pytest.mark.parametrize(
    "old,new,key,value",
    [
        ("gap0_first = 0.3", "gap0_first = 0.0", "platoon.gap0_first", "0.0"),
        ("gap0_others = 3.5", "gap0_others = -1.0", "platoon.gap0_others", "-1.0"),
    ],
)
def test_gap_not_positive(tmp_path: Path, old: str, new: str, key: str, value: str) -> None:
    expect_error(tmp_path, edit(old, new), key, value, "> 0")


@pytest.mark.parametrize("eta", ["0.0", "1.2"])
def test_efficiency_out_of_range(tmp_path: Path, eta: str) -> None:
    expect_error(tmp_path, edit("efficiency = 0.8", f"efficiency = {eta}"), "vehicle.efficiency", eta, "(0, 1]")


def test_negative_speed_and_t_end(tmp_path: Path) -> None:
    expect_error(tmp_path, edit("speed0_factor = 1.1", "speed0 = -0.5"), "platoon.speed0", "-0.5")
    expect_error(tmp_path, edit("t_end = 5.0", "t_end = 0.0"), "simulation.t_end", "0.0")


def test_unknown_law(tmp_path: Path) -> None:
    expect_error(tmp_path, edit('law = "proposed"', 'law = "warp"'), "platoon.law", "'warp'", "proposed")


def test_unknown_law_in_compare(tmp_path: Path) -> None:
    expect_error(
        tmp_path, edit('compare = ["proposed", "ovfl"]', 'compare = ["ovfl", "bogus"]'), "compare[1]", "'bogus'"
    )


def test_unknown_cycle(tmp_path: Path) -> None:
    expect_error(tmp_path, edit('kind = "paper"', 'kind = "cycle"\ncycle = "nedc"'), "leader.cycle", "'nedc'", "udds")


def test_unknown_leader_kind(tmp_path: Path) -> None:
    expect_error(tmp_path, edit('kind = "paper"', 'kind = "teleport"'), "leader.kind", "'teleport'", "constant")


def test_per_vehicle_list_length(tmp_path: Path) -> None:
    text = edit("gap0_first = 0.3\ngap0_others = 3.5", "gaps0 = [0.3, 1.0]")
    expect_error(tmp_path, text, "platoon.gaps0", "3 values")


def test_file_not_found(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(ScenarioError, match="nope.toml"):
        load_scenario(missing)


def test_malformed_toml(tmp_path: Path) -> None:
    expect_error(tmp_path, BASE + "\n[units\n", "not valid TOML")


def test_parameter_error_is_rewrapped_with_key_path(tmp_path: Path) -> None:
    expect_error(tmp_path, BASE + "\n[cell]\nsoc0 = 1.5\n", "cell.soc0", "1.5", "[0, 1]")


def test_speed_warning_fires(tmp_path: Path) -> None:
    fast = edit('kind = "paper"', 'kind = "constant"\nv = 2.5').replace("speed0_factor = 1.1", "speed0 = 1.0")
    with pytest.warns(ScenarioWarning, match="V∞"):
        load_scenario(write(tmp_path, fast))


def test_array_leader_si_and_model(tmp_path: Path) -> None:
    arr = edit('kind = "paper"', 'kind = "array"\ntimes = [0, 10, 20]\nspeeds = [0, 8, 8]\nunit = "si"')
    s = load_scenario(write(tmp_path, arr))
    assert isinstance(s.leader, SpeedTrace)
    assert s.leader.times == (0.0, 5.0, 10.0) and s.leader.speeds == (0.0, 1.6, 1.6)  # T = 2 s, U = 5 m/s
    bad = edit('kind = "paper"', 'kind = "array"\ntimes = [0, 2, 1]\nspeeds = [0, 1, 1]')
    expect_error(tmp_path, bad, "leader.times", "increase")


def test_per_vehicle_laws_and_overrides(tmp_path: Path) -> None:
    text = edit('law = "proposed"', 'laws = ["proposed", "ovfl", "idm"]') + "\n[carfollowing.idm]\nv0_mps = 19.5\n"
    s = load_scenario(write(tmp_path, text.replace('compare = ["proposed", "ovfl"]\n', "")))
    assert [law.name for law in s.laws] == ["proposed", "ovfl", "idm"]
    assert s.laws[2].v0_mps == 19.5 and s.laws[2].model_units == s.units  # Treiber's SI IDM, run in [units]
    assert len(s.runs()) == 1
    bad = edit('law = "proposed"', 'law = "idm"') + "\n[carfollowing.idm]\nspeed_of_light = 3.0\n"
    expect_error(tmp_path, bad, "carfollowing.idm", "speed_of_light")


def test_many_followers(tmp_path: Path) -> None:
    s = load_scenario(write(tmp_path, edit("followers = 3", "followers = 1200")))
    assert s.n_followers == 1200 and len(s.gaps0) == 1200


def test_registered_section(tmp_path: Path) -> None:
    def validate(r: TableReader) -> dict[str, float]:
        out = {"horizon": r.integer("horizon", 40, ge=1), "w_q": r.number("w_q", 1.0, ge=0)}
        r.finish()
        return out

    register_section("testsection", validate)
    s = load_scenario(write(tmp_path, BASE + "\n[testsection]\nhorizon = 20\n"))
    assert s.extra["testsection"] == {"horizon": 20, "w_q": 1.0}
    expect_error(tmp_path, BASE + "\n[testsection]\nw_q = -1\n", "testsection.w_q", "-1")
    expect_error(tmp_path, BASE + "\n[testsection]\nbogus = 1\n", "testsection.bogus")


def test_mpc_table_loads_without_importing_the_mpc_package_first() -> None:
    """A fresh interpreter that only imports the scenario loader can read a scenario with [mpc]."""
    import subprocess
    import sys

    code = (
        "from aev_ocp.scenarios import load_scenario; s = load_scenario('mpc_paper_single'); "
        "print(type(s.extra['mpc']).__name__)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "MPCConfig"


def test_the_split_loader_keeps_every_public_name_importable_from_aev_ocp_scenarios() -> None:
    """aev_ocp.scenarios is a package of one module per job; every name it lists (and the ones other scenario forms
    import) comes from aev_ocp.scenarios, and each class and function is defined in one of its modules or below."""
    import types

    import aev_ocp.scenarios as scn

    names = set(scn.__all__)
    assert {
        "Scenario",
        "ScenarioError",
        "TableReader",
        "load_scenario",
        "parse_scenario",
        "find_scenario",
        "register_section",
        "read_scenario_doc",
        "standalone_header",
        "load_with_sets",
        "check_run_size",
        "thinned_dt_out",
        "shipped_scenarios",
        "_params",
    } <= names
    for name in names:
        obj = getattr(scn, name)
        if isinstance(obj, (type, types.FunctionType)):
            assert obj.__module__.startswith("aev_ocp."), (name, obj.__module__)
    assert scn.Scenario.__module__ == "aev_ocp.scenarios.platoon"
    assert scn.TableReader.__module__ == "aev_ocp.scenarios.tables"


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)
BOM = b"\xef\xbb\xbf"


def test_a_byte_order_mark_is_read_like_the_same_file_without_it(tmp_path: Path) -> None:
    """Scenario, study and grid files saved with a UTF-8 BOM (Notepad) load exactly as without it (before: 'not
    valid TOML: Invalid statement (at line 1, column 1)', exit 2)."""
    from aev_ocp.scenarios import load_scenario
    from aev_ocp.study.spec import read_study

    plain, marked = tmp_path / "plain.toml", tmp_path / "marked.toml"
    plain.write_text(SMALL, encoding="utf-8")
    marked.write_bytes(BOM + SMALL.replace("\n", "\r\n").encode("utf-8"))
    a, b = load_scenario(plain).run()["proposed"], load_scenario(marked).run()["proposed"]
    assert float(abs(a.gap - b.gap).max()) == 0.0 and float(abs(a.speed - b.speed).max()) == 0.0
    study = 'name = "st"\nscenarios = ["plain.toml"]\n[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.013, 0.047]\n'
    study += '[controllers]\nlaws = ["proposed"]\n'
    (tmp_path / "st.toml").write_bytes(BOM + study.encode("utf-8"))
    assert len(read_study(tmp_path / "st.toml").points) == 2


def test_a_grid_file_with_a_byte_order_mark_is_read(tmp_path: Path) -> None:
    from aev_ocp.limits import read_input_file

    f = tmp_path / "g.json"
    f.write_bytes(BOM + b'{"E_req": [1500.0], "t_f": [45.0]}')
    assert read_input_file(f, "grid file", ValueError) == b'{"E_req": [1500.0], "t_f": [45.0]}'
    f.write_bytes(b"\xef\xbb" + b"{}")  # a broken mark is not a mark: left for the parser to refuse
    assert read_input_file(f, "grid file", ValueError) == b"\xef\xbb{}"


# ----------------------------------------------------------------------------- from the issue-28 small leftovers (test_reliability_minors.py)


def _bad_scenario(tmp_path, extra: str):
    from pathlib import Path

    import aev_ocp

    base = (Path(aev_ocp.__file__).parent / "scenario_files" / "fig1a.toml").read_text()
    f = tmp_path / "bad.toml"
    f.write_text(base + extra)
    return f


def test_echo_is_repr_when_short_and_at_most_60_characters_otherwise():
    from aev_ocp.params import ECHO_CHARS, echo

    assert ECHO_CHARS == 60
    for v in (0.35, "udds", [1, 2.5, "a"], {"a": {"b": [1, 2]}}, (3,), None, True, -7):
        assert echo(v) == repr(v)
    long = {f"k{i}": i for i in range(2000)}
    assert echo(long) == repr(long)[:59] + "…"
    assert echo(_BIG_STR) == repr(_BIG_STR)[:59] + "…"
    deep: list = []
    for _ in range(100_000):  # repr() of this raises RecursionError
        deep = [deep]
    assert echo(deep) == "[" * 59 + "…"
    assert echo(-(10**5000)) == "-" + "9" * 58 + "…"  # repr() refuses integers of > 4300 digits


@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=90),
        lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=8), inner, max_size=8),
        max_leaves=20,
    )
)
@settings(max_examples=60, deadline=None)
def test_echo_never_exceeds_the_limit_and_keeps_short_values_whole(value):
    from aev_ocp.params import echo

    text = echo(value)
    assert len(text) <= 60
    full = repr(value)
    if len(full) <= 60:
        assert text == full
    else:
        assert text.endswith("…") and len(text) == 60


@pytest.mark.parametrize(
    "extra, path, shown",
    [
        (f'\n[carfollowing.proposed]\nzz = "{_BIG_STR}"\n', "carfollowing.proposed.zz", "'qqq"),
        (f"\n[carfollowing.proposed]\nzz = {_BIG_TABLE}\n", "carfollowing.proposed.zz", "{'k0': 0, 'k1': 1"),
        (f"\n[carfollowing.ovm.deep]\nzz = {_BIG_TABLE}\n", "carfollowing.ovm.deep", "{'zz': {'k0': 0"),
        (f"\n[thermal.a.b]\nzz = {_BIG_TABLE}\n", "thermal.a", "{'b': {'zz': {'k0'"),
    ],
)
def test_a_bad_key_deep_in_a_scenario_names_its_path_and_echoes_a_short_value(tmp_path, capsys, extra, path, shown):
    from cli_helpers import one_error, run_cli

    f = _bad_scenario(tmp_path, extra)
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o")], capsys)
    line = one_error(err)
    assert rc == 2 and f"{path}" in line and shown in line and "…" in line
    assert len(line) < len(str(f)) + 400  # the value is echoed in <= 60 characters, not 10 000
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 1.7e308, exclude_min=True), st.floats(0, 1.7e308, exclude_min=True))
def test_units_either_refused_or_every_derived_unit_finite(L: float, U: float) -> None:
    """Property: for any finite positive L, U, Units either raises ParameterError or its time, acceleration and
    energy units are finite and positive, and equal the closed forms L/U, U²/L, U² (no OverflowError later)."""
    try:
        u = Units(L, U)
    except ParameterError as exc:
        assert "speed_mps" in str(exc) and "not a finite positive number" in str(exc)
        return
    for value in (u.time_s, u.accel_mps2, u.energy_per_mass_to_si(1.0)):
        assert math.isfinite(value) and value > 0
    assert u.time_s == L / U and u.accel_mps2 == U**2 / L


@pytest.mark.parametrize("L, U", [(10.0, 1e308), (1e-300, 1e10), (1e300, 1e-10), (1e-170, 1e-170)])
def test_units_overflowing_a_derived_unit_are_refused(L: float, U: float) -> None:
    with pytest.raises(ParameterError, match="Units.speed_mps .* not a finite positive number"):
        Units(L, U)


def test_scenario_units_overflow_is_bad_input_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    f = tmp_path / "u.toml"
    f.write_text(SCENARIO.format(L=10.0, U=1e308))
    with pytest.raises(ScenarioError, match=r"u\.toml: units\.speed_mps"):
        load_scenario(f)
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o"), "--no-plots"], capsys)
    assert rc == 2 and "units.speed_mps" in one_error(err) and "internal error" not in err
    f.write_text(SCENARIO.format(L=12.5, U=7.25))  # everyday units still load, with the closed-form time unit
    assert load_scenario(f).units.time_s == 12.5 / 7.25
