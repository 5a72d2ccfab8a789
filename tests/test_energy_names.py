"""One energy (issue 35): every metric key, table header and CLI line that says "energy" means battery energy
∫P_b dt (``battery_energy_*``, "battery energy [unit]"); the paper's ω is called ω / omega. The old names of ω
(§9's objective 'energy', the traffic formulation's ``energy_weight``) are still read, with a FutureWarning that
names the new one.
"""

from __future__ import annotations

import dataclasses
import re
import warnings

import numpy as np
import pytest

from aev_ocp import load_scenario, replay
from aev_ocp.mpc.cycles import COLUMNS as CYCLE_COLUMNS
from aev_ocp.mpc.report import METRIC_ROWS
from aev_ocp.ocp.eco_trip import EcoTrip
from aev_ocp.ocp.following import objective_name, term_names
from aev_ocp.ocp.formulation import Formulation, formulation_from_dict
from aev_ocp.ocp.traffic import TrafficParams
from aev_ocp.params import ParameterError
from aev_ocp.report import platoon_totals, scenario_metrics_rows
from aev_ocp.ring.cli import COLUMNS as RING_COLUMNS
from aev_ocp.ring.run import human_ring, relative_to, run_ring
from aev_ocp.scenarios import ScenarioError, load_scenario as load_file
from cli_helpers import run_cli

#: Keys with "energy" in them that are not battery energy, and why each may keep the word. Short on purpose.
ALLOWED_ENERGY_KEYS: dict[str, str] = {}

#: "energy" in printed text that is not battery energy: the project's name ("Energy-aware control ...").
ALLOWED_ENERGY_TEXT = re.compile(r"energy-aware", re.IGNORECASE)


def offending_keys(keys: list[str]) -> list[str]:
    """Keys with an 'energy' (any case) not written 'battery_energy' (a prefix such as change_ may come before it),
    and not allowed."""
    return [
        k
        for k in keys
        if k not in ALLOWED_ENERGY_KEYS
        and any(k[: m.start()][-8:] != "battery_" for m in re.finditer("energy", k, re.IGNORECASE))
    ]


def offending_text(text: str) -> list[str]:
    """Lines where 'energy' appears without 'battery' right before it (header cells, summaries)."""
    bad = []
    for line in text.splitlines():
        rest = ALLOWED_ENERGY_TEXT.sub("", line)
        for m in re.finditer(r"energy", rest, re.IGNORECASE):
            if not re.search(r"battery[ _]$", rest[: m.start()], re.IGNORECASE):
                bad.append(line.strip())
                break
    return bad


@pytest.fixture(scope="module")
def short_platoon():
    """Table 1's platoon for 3 model time units (the paper's leader, the constant η)."""
    s = load_scenario("table1").replace(t_end=3.0)
    return s.run()


def test_the_checks_catch_an_energy_that_is_not_battery_energy() -> None:
    """The two rules themselves, on names that must pass and names that must fail."""
    good = ["battery_energy_J", "battery_energy_kWh_per_100km", "omega_J_per_kg", "change_battery_energy_J_per_km"]
    assert offending_keys(good) == []
    bad = ["energy_J_per_km", "omega_energy", "Battery_energy_J", "battery_energy_vs_energy", "ENERGY_J"]
    assert offending_keys(bad) == bad
    assert offending_text("battery energy [kWh/100 km]  battery_energy_J  Energy-aware control") == []
    assert offending_text("energy 145.1 kJ/km\nω [J/kg]  energy [J]") == ["energy 145.1 kJ/km", "ω [J/kg]  energy [J]"]


def test_metric_keys_and_table_headers_name_battery_energy(short_platoon) -> None:
    """Every metric key a platoon run, its totals, a replay, the MPC, cycle and ring tables use, and every header
    of the simulate table: 'energy' only as battery energy."""
    r = next(iter(short_platoon.values()))
    keys = list(r.metrics()[0]) + list(platoon_totals(r))
    keys += list(replay(([0.0, 4.0, 9.0, 12.0], [0.0, 6.0, 6.0, 0.0])).summary())
    keys += list(METRIC_ROWS) + list(CYCLE_COLUMNS) + list(RING_COLUMNS)
    ring = run_ring(human_ring(230.0, seed=0), 4.0)  # the ring's fleet metrics and their changes against a base
    keys += list(ring.fleet) + ["change_" + k for k in relative_to(ring.fleet, ring.fleet)]
    assert "battery_energy_kWh_per_100km" in keys and "omega_J_per_kg" in keys
    assert offending_keys(keys) == []
    headers, _rows = scenario_metrics_rows(short_platoon)
    assert any("battery energy" in h for h in headers)
    assert offending_text("\n".join(headers)) == []


def test_cli_simulate_and_replay_say_battery_energy(tmp_path, capsys, short_platoon) -> None:
    """What `aev-ocp simulate` and `aev-ocp replay` print: 'energy' only as battery energy."""
    trace = tmp_path / "trace.csv"
    trace.write_text("time_s,speed_mps\n0,0\n4,6\n9,6\n12,0\n", encoding="utf-8")
    code, out, _err = run_cli(["replay", str(trace)], capsys)
    assert code == 0 and "battery energy" in out
    assert offending_text(out) == []
    code, out, _err = run_cli(
        ["simulate", "table1", "--set", "simulation.t_end=3", "--no-plots", "--out", str(tmp_path / "s")], capsys
    )
    assert code == 0 and "battery energy" in out
    assert offending_text(out) == []


def test_the_paper_s_measure_is_named_omega() -> None:
    """§9's first term is named after its objective: 'heat' or 'omega' (never 'energy')."""
    assert term_names("heat") == ("heat", "ovm", "relative", "accel")
    assert term_names("omega") == ("omega", "ovm", "relative", "accel")
    with pytest.raises(ParameterError, match=r"objective = 'battery' is not allowed"):
        objective_name("battery")


def test_old_names_are_read_with_a_warning_naming_the_new_one() -> None:
    """objective = 'energy' -> 'omega' and energy_weight -> omega_weight, each with a FutureWarning naming the
    new name; both names at once: refused, naming both."""
    with pytest.warns(FutureWarning, match=r"objective = 'energy' is deprecated: use 'omega'"):
        f = formulation_from_dict({"formulation": "s9", "objective": "energy"})
    assert f.objective == "omega"
    with pytest.warns(FutureWarning, match=r"Formulation.objective = 'energy' is deprecated: use 'omega'"):
        assert Formulation(kind="s9", objective="energy").objective == "omega"
    with pytest.warns(FutureWarning, match=r"EcoTrip.objective = 'energy' is deprecated: use 'omega'"):
        assert EcoTrip(objective="energy").objective == "omega"
    with pytest.warns(FutureWarning, match=r"energy_weight is deprecated: use omega_weight"):
        f = formulation_from_dict({"energy_weight": 2.5})
    assert f.traffic.omega_weight == 2.5
    with pytest.raises(ParameterError, match=r"energy_weight and omega_weight are both given"):
        formulation_from_dict({"energy_weight": 2.5, "omega_weight": 1.5})
    with pytest.warns(FutureWarning, match=r"TrafficParams.energy_weight is deprecated: use omega_weight"):
        assert TrafficParams(energy_weight=0.25).omega_weight == 0.25
    assert dataclasses.replace(TrafficParams(omega_weight=0.5), heat_weight=3.0).omega_weight == 0.5
    with warnings.catch_warnings():  # the new names: no warning at all
        warnings.simplefilter("error")
        assert formulation_from_dict({"formulation": "s9", "objective": "omega"}).objective == "omega"
        assert formulation_from_dict({"omega_weight": 0.75}).traffic.omega_weight == 0.75


def test_a_scenario_file_with_the_old_key_loads_and_names_the_new_one(tmp_path) -> None:
    """A shipped MPC scenario file with [mpc] energy_weight = 3.5: loads, omega_weight = 3.5, and the warning names
    the file and mpc.omega_weight; with both keys: a ScenarioError naming both."""
    text = load_scenario("mpc_udds_single").source.read_text(encoding="utf-8")
    assert "\n[mpc]" in text
    p = tmp_path / "old_key.toml"
    p.write_text(text.replace("\n[mpc]", "\n[mpc]\nenergy_weight = 3.5\n#", 1), encoding="utf-8")
    with pytest.warns(FutureWarning, match=r"old_key\.toml: mpc\.energy_weight is deprecated: use mpc\.omega_weight"):
        s = load_file(p)
    assert s.extra["mpc"].formulation.traffic.omega_weight == 3.5
    p.write_text(text.replace("\n[mpc]", "\n[mpc]\nenergy_weight = 3.5\nomega_weight = 1.0\n#", 1), encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"energy_weight and .*omega_weight are both given"):
        load_file(p)


def test_same_run_same_numbers_under_the_old_and_new_objective_names() -> None:
    """The alias is only a name: the §9 problem built from 'energy' is the one built from 'omega'."""
    with pytest.warns(FutureWarning):
        old = Formulation(kind="s9", objective="energy")
    new = Formulation(kind="s9", objective="omega")
    assert dataclasses.astuple(old.weights) == dataclasses.astuple(new.weights) and old == new
    from aev_ocp.params import EVParams

    a = old.builder(EVParams(), 0.1).build()
    b = new.builder(EVParams(), 0.1).build()
    assert a.control_names == b.control_names == ["a", "omega_rate"]
    x, u, w = [1.1, 0.9, 1e-3, 2e-3, 0.6], [0.3, 0.35], [1.0, 0.9]
    p = [1.0, 1.0, 1.0, 0.1]
    assert np.array_equal(np.asarray(a.stage(x, u, w, p)), np.asarray(b.stage(x, u, w, p)))


def _pct(x: float, digits: int) -> str:
    """A percentage as the guide prints it: minus sign U+2212, no plus sign."""
    return f"{x:.{digits}f}".replace("-", "−")


def test_the_powertrain_change_the_docs_quote_is_the_benchmarks() -> None:
    """The guide's 'What changed with the validated powertrain' and the MPC page's table quote what
    benchmarks/bench_mpc_powertrain.py (and its --ring) measured: the JSON it records in tests/data/ (--record)."""
    import json
    from pathlib import Path

    root = Path(__file__).parents[1]
    guide = (root / "docs" / "guide" / "powertrain.md").read_text(encoding="utf-8")
    mpc_page = (root / "docs" / "guide" / "mpc.md").read_text(encoding="utf-8")
    rows = json.loads((root / "tests" / "data" / "bench_mpc_powertrain.json").read_text(encoding="utf-8"))["rows"]
    key = "battery_energy_kWh_per_100km"
    by = {(r["cycle"], r["powertrain"]): r for r in rows}
    for cyc in ("udds", "hwfet", "us06"):
        c, m = by[(cyc, "constant")], by[(cyc, "map")]
        assert c["comparable"] and m["comparable"]
        line = next(x for x in guide.splitlines() if x.startswith(f"| MPC vs the proposed law, {cyc.upper()}"))
        want = f"| {_pct(c[f'mpc_vs_proposed_{key}_pct'], 2)} % | {_pct(m[f'mpc_vs_proposed_{key}_pct'], 2)} % |"
        assert line.endswith(want), (line, want)
        for r, pt in ((c, "η = 0.8"), (m, "map")):
            head = f"| {cyc.upper()} | {pt} | {r[f'mpc_{key}']:.3f} / {r[f'proposed_{key}']:.3f} / {r[f'ovfl_{key}']:.3f} |"
            assert head in mpc_page, head
    ring = json.loads((root / "tests" / "data" / "bench_mpc_powertrain_ring.json").read_text(encoding="utf-8"))["rows"]
    fs = {r["powertrain"]: r["change_battery_energy_pct"] for r in ring if "followerstopper" in r["run"].lower()}
    line = next(x for x in guide.splitlines() if x.startswith("| one FollowerStopper AEV"))
    assert line.endswith(f"| {_pct(fs['constant'], 0)} % | {_pct(fs['map'], 0)} % |"), (line, fs)
