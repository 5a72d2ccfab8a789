"""Every shipped cell file (aev_ocp/data/cells/*.toml): it loads, every value has a source, and a short drive
with ``[cell] name = ...`` runs on it with a sane pack voltage and coulomb-counted SOC.

Parametrised over :func:`aev_ocp.cells.shipped_cells`, so a cell added to the folder is checked without a new test.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aev_ocp.cells import CELL_KEYS, load_cell_file, shipped_cells
from aev_ocp.life import BLAST_MODELS
from aev_ocp.models import battery
from aev_ocp.scenarios import find_scenario, load_scenario

SHIPPED = sorted(shipped_cells())


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_cell_loads_with_a_source_for_every_value(name: str) -> None:
    cf = load_cell_file(name)
    assert cf.name == name  # the name scenarios use is the file's stem
    assert cf.chemistry in BLAST_MODELS and cf.description
    for key in CELL_KEYS + ("ocv",):
        assert cf.sources[key].strip(), key
    c = cf.cell
    assert c.ocv_soc is not None and c.ocv_V is not None
    # an OCV curve of a Li-ion cell: rising with SOC, inside 2-4.5 V (Prada2013: 0 % SOC is its 2.0 V cut-off)
    assert all(b >= a for a, b in zip(c.ocv_V, c.ocv_V[1:])) and 2.0 <= min(c.ocv_V) and max(c.ocv_V) < 4.5


@pytest.mark.parametrize("name", SHIPPED)
def test_short_drive_on_each_shipped_cell(tmp_path: Path, name: str) -> None:
    """udds_platoon's first 60 model time units on the cell: the pack voltage N_s·V_T stays within the pack's OCV
    range widened by the largest possible polarisation, and S(t) equals coulomb counting of the cell current."""
    base = find_scenario("udds_platoon").read_text()
    p = tmp_path / "s.toml"
    p.write_text(base + f'\n[cell]\nname = "{name}"\nsoc0 = 0.73\n')
    sc = load_scenario(p).replace(t_end=60.0)
    cell, pack = sc.ev.cell, sc.ev.pack
    assert cell.capacity_Ah == load_cell_file(name).cell.capacity_Ah and cell.soc0 == 0.73
    r = sc.run(only="proposed")["proposed"]
    assert r.status == "ok"
    I = np.asarray(r.current_A)
    S = np.asarray(r.S)
    VT = np.asarray(battery.terminal_voltage(S, np.asarray(r.V1), np.asarray(r.V2), I, cell), dtype=float)
    v_pack = pack.n_series * VT
    r_tot = cell.R_s_ohm + cell.R1_ohm + cell.R2_ohm
    i_max = float(np.max(np.abs(I)))
    assert i_max > 0.0
    lo = pack.n_series * (min(cell.ocv_V) - r_tot * i_max)
    hi = pack.n_series * (max(cell.ocv_V) + r_tot * i_max)
    assert lo <= float(v_pack.min()) and float(v_pack.max()) <= hi
    # and the pack sits near N_s·OCV(S0) (S moves little in 60 model time units)
    ocv0 = float(battery.ocv(0.73, cell))
    assert abs(float(np.median(v_pack)) - pack.n_series * ocv0) < pack.n_series * r_tot * i_max + 1e-9
    # coulomb counting, independently of the integrator: S(t) = S0 − ∫ I dt / (3600 Q)
    t_s = np.asarray(r.t) * sc.ev.units.time_s  # model time -> s
    for k in range(S.shape[1]):
        q = np.concatenate([[0.0], np.cumsum(0.5 * (I[1:, k] + I[:-1, k]) * np.diff(t_s))])
        dS = q / (3600.0 * cell.capacity_Ah)
        assert float(np.max(np.abs(dS))) > 1e-4  # the drive moved the SOC
        assert float(np.max(np.abs(S[:, k] - (0.73 - dS)))) <= 2e-3 * float(np.max(np.abs(dS)))
