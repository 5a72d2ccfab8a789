"""Cells as data: cell files, their validation, and scenarios selecting a cell."""

from __future__ import annotations

import dataclasses
import textwrap
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.cells import CellFileError, load_cell, load_cell_file, shipped_cells
from aev_ocp.models import battery
from aev_ocp.params import CellParams
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario, parse_scenario

DATA = Path(__file__).resolve().parents[1] / "aev_ocp" / "data"

USER_CELL = """
name = "test_nmc"
chemistry = "NMC"
capacity_Ah = { value = 3.17, source = "test" }
R_s_ohm = { value = 0.0231, source = "test" }
R1_ohm = { value = 0.0117, source = "test" }
C1_F = { value = 1730.0, source = "test" }
R2_ohm = { value = 0.0093, source = "test" }
C2_F = { value = 21300.0, source = "test" }
max_current_A = { value = 9.3, source = "test" }
heat_capacity_JpK = { value = 43.7, source = "test" }
surface_area_m2 = { value = 4.2e-3, source = "test" }
activation_energy_Jpmol = { value = 2.9e4, source = "test" }
T_ref_K = { value = 296.15, source = "test" }
[ocv]
soc = [0.0, 0.2, 0.45, 0.7, 1.0]
ocv_V = [3.03, 3.52, 3.68, 3.91, 4.17]
source = "test"
"""


def test_shipped_a123_is_exactly_the_defaults() -> None:
    c, d = load_cell("a123_anr26650"), CellParams()
    for f in dataclasses.fields(CellParams):
        if f.name not in ("ocv_soc", "ocv_V"):
            assert getattr(c, f.name) == getattr(d, f.name), f.name
    rows = np.loadtxt(DATA / "a123_ocv_25C.csv", delimiter=",", skiprows=1)
    assert np.array_equal(np.array(c.ocv_soc), rows[:, 0]) and np.array_equal(np.array(c.ocv_V), rows[:, 1])
    S = np.linspace(0.0, 1.0, 37)
    assert np.array_equal(np.asarray(battery.ocv_function(c)(S)).ravel(), np.asarray(battery.ocv_function()(S)).ravel())
    cf = load_cell_file("a123_anr26650")
    assert cf.chemistry == "LFP" and all(cf.sources.values()) and "ocv" in cf.sources
    assert "a123_anr26650" in shipped_cells()


def _write(tmp_path: Path, text: str, name: str = "c.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_user_cell_file_and_its_ocv(tmp_path: Path) -> None:
    c = load_cell(_write(tmp_path, USER_CELL))
    assert (c.capacity_Ah, c.R_s_ohm, c.C2_F, c.activation_energy_Jpmol) == (3.17, 0.0231, 21300.0, 2.9e4)
    # the B-spline interpolates its nodes; between them it is the cell's curve, not the A123's
    for s, v in zip(c.ocv_soc, c.ocv_V):
        assert float(battery.ocv(s, c)) == pytest.approx(v, abs=1e-12)
    assert abs(float(battery.ocv(0.45, c)) - float(battery.ocv(0.45))) > 0.3
    # the piecewise form of the MPC agrees with the B-spline for this cell too
    import casadi as ca

    S = ca.SX.sym("S")
    f = ca.Function("f", [S], [battery.ocv_piecewise(S, c)])
    for s in (0.05, 0.33, 0.81):
        assert float(f(s)) == pytest.approx(float(battery.ocv(s, c)), abs=1e-12)


def test_scenario_selects_cell_by_name_and_file(tmp_path: Path) -> None:
    base = find_scenario("udds_platoon").read_text()
    cell_path = _write(tmp_path, USER_CELL, "my_cell.toml")
    by_file = load_scenario(_write(tmp_path, base + '\n[cell]\nfile = "my_cell.toml"\nsoc0 = 0.63\n', "s1.toml"))
    assert by_file.ev.cell.R_s_ohm == 0.0231 and by_file.ev.cell.soc0 == 0.63
    assert by_file.ev.pack == load_scenario(find_scenario("udds_platoon")).ev.pack  # the layout stays the scenario's
    by_name = load_scenario(_write(tmp_path, base + '\n[cell]\nname = "a123_anr26650"\n', "s2.toml"))
    assert by_name.ev.cell.capacity_Ah == 2.3 and cell_path.exists()


@pytest.mark.parametrize(
    "edit, where",
    [
        (('R1_ohm = { value = 0.0117, source = "test" }', "R1_ohm = 0.0117"), "R1_ohm"),
        (("R1_ohm = { value = 0.0117,", "R1_ohm = { value = -0.0117,"), "R1_ohm.value"),
        (('C1_F = { value = 1730.0, source = "test" }', 'C1_F = { value = 1730.0, source = "" }'), "C1_F.source"),
        (('chemistry = "NMC"', 'chemistry = "LMO"'), "chemistry"),
        (('name = "test_nmc"', 'name = "test_nmc"\nwidth_m = 0.02'), "width_m"),
        (("0.45, 0.7", "0.75, 0.7"), "ocv_soc"),
        (("soc = [0.0,", "soc = [0.1,"), "ocv_soc"),
        (('4.17]\nsource = "test"', "4.17]"), "ocv.source"),
        (('T_ref_K = { value = 296.15, source = "test" }\n', ""), "T_ref_K is missing"),
    ],
)
def test_bad_cell_files_one_line_errors(tmp_path: Path, edit: tuple[str, str], where: str) -> None:
    assert edit[0] in USER_CELL
    p = _write(tmp_path, USER_CELL.replace(*edit))
    with pytest.raises(CellFileError) as exc:
        load_cell(p)
    msg = str(exc.value)
    assert "\n" not in msg and str(p) in msg and where in msg


def test_scenario_cell_errors(tmp_path: Path) -> None:
    base = find_scenario("udds_platoon").read_text()
    with pytest.raises(ScenarioError, match=r"cell\.name = 'lg_m99'.*shipped"):
        load_scenario(_write(tmp_path, base + '\n[cell]\nname = "lg_m99"\n'))
    with pytest.raises(ScenarioError, match=r"cell\.file = 'nope.toml'"):
        load_scenario(_write(tmp_path, base + '\n[cell]\nfile = "nope.toml"\n'))
    with pytest.raises(ScenarioError, match="not both"):
        load_scenario(_write(tmp_path, base + '\n[cell]\nname = "a123_anr26650"\nfile = "x.toml"\n'))
    with pytest.raises(ScenarioError, match=r"thermal\.h_Wpm2K"):
        parse_scenario({**__import__("tomllib").loads(base), "thermal": {"h_Wpm2K": -3.0}}, "s.toml")


def test_prop31_battery_numbers_are_parameters(tmp_path: Path) -> None:
    """OCP-A's S(0), initial polarisation and cell are arguments: the relaxing case's unconstrained optimum
    equals the independent LQ solution for a user cell, another S(0) and another V(0); bad values are one line."""
    from aev_ocp.ocp.prop31 import run_prop31
    from aev_ocp.params import ParameterError

    cell = load_cell(_write(tmp_path, USER_CELL))
    out = run_prop31(N=40, cell=cell, refine=False, soc0=0.37, v_relax_V=(0.013, 0.041))
    e = out["relaxing"]
    assert e["V0"] == [0.013, 0.041] and e["result"].states["S"][0] == pytest.approx(0.37)
    assert e["objective_J"] == pytest.approx(e["lq_exact_discrete_J"], rel=1e-4)
    W0 = 0.5 * cell.C1_F * 0.013**2 + 0.5 * cell.C2_F * 0.041**2
    assert e["stored_rc_energy_W0_J"] == pytest.approx(W0, rel=1e-12)
    with pytest.raises(ParameterError, match="soc0"):
        run_prop31(N=10, refine=False, soc0=1.3)
    with pytest.raises(ParameterError, match="v_relax_V"):
        run_prop31(N=10, refine=False, v_relax_V=(0.0, 0.0))
