"""Small usability defects of issue 40: the allowed keys an unknown --set key lists, the scenarios the
``scenarios`` command lists, stale files and a dead pid left in an output folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from aev_ocp.results import LOCK, MARKER, claim_output_dir, release_output_locks
from aev_ocp.scenarios import ScenarioError, load_with_sets

ROOT = Path(__file__).parents[2]


def test_unknown_simulation_key_lists_the_si_twins_and_tolerances() -> None:
    with pytest.raises(ScenarioError) as err:
        load_with_sets("table1", ["simulation.t_end_sec=60"])
    msg = str(err.value)
    assert "simulation.t_end_sec" in msg
    allowed = msg.split("allowed keys here: ", 1)[1]
    for key in ("'t_end'", "'t_end_s'", "'dt_out'", "'dt_out_s'", "'rtol'", "'atol'"):
        assert key in allowed, (key, allowed)


def test_scenarios_command_lists_platoon_ring_and_sumo_files() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "aev_ocp.cli", "scenarios"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    names = {line.split()[0] for line in out.stdout.splitlines() if line.strip()}
    assert {"table1", "ring_stern", "ring_sugiyama", "sumo_ring", "sumo_merge"} <= names
    ring = next(line for line in out.stdout.splitlines() if line.startswith("ring_stern "))
    assert ring.endswith("(aev-ocp ring ring_stern)") and "Stern et al. 2018" in ring


def test_rerun_into_its_own_folder_removes_the_previous_runs_files_and_leaves_no_pid(tmp_path) -> None:
    out = tmp_path / "run"
    claim_output_dir(out, "simulate", "table1", None, ["a.png"])
    (out / "old_law.png").write_bytes(b"png")  # a figure only the first run made
    (out / "notes.txt").write_text("kept")  # not an output file type: not touched
    (out / "sub").mkdir()
    (out / "sub" / "x.png").write_bytes(b"png")  # below the top level: not touched
    release_output_locks()
    assert (out / LOCK).read_text() == ""  # no pid of a finished run
    claim_output_dir(out, "simulate", "table1", None, ["a.png"])
    try:
        assert not (out / "old_law.png").exists()
        assert (out / "notes.txt").read_text() == "kept" and (out / "sub" / "x.png").exists()
        assert (out / MARKER).is_file()
        assert (out / LOCK).read_text().strip() == str(os.getpid())  # held now: names this process
    finally:
        release_output_locks()


def test_another_runs_folder_is_still_refused_and_untouched(tmp_path) -> None:
    from aev_ocp.results import OutputError

    out = tmp_path / "run"
    claim_output_dir(out, "simulate", "table1", None, ["a.png"])
    (out / "fig.png").write_bytes(b"png")
    release_output_locks()
    with pytest.raises(OutputError):
        claim_output_dir(out, "simulate", "fig1a", None, ["a.png"])
    assert (out / "fig.png").exists()
    release_output_locks()


def test_ring_table_headers_are_whole_and_aligned_with_their_cells() -> None:
    from aev_ocp.ring.cli import COLUMNS, _header, _row

    fleet = {k: 12345.678901 for k in COLUMNS} | {"status": "ok", "vehicles_stopped": 3}
    head, row = _header(), _row("stern: human", fleet)
    for k in COLUMNS:
        assert f" {k}" in head, k  # the full key, its unit suffix included
    assert len(head) == len(row)  # each cell right-aligned under its header
    ends = [head.index(k) + len(k) for k in COLUMNS]
    assert all(row[e - 1] != " " for e in ends)


def test_the_mpc_table_lists_every_model_metric_with_its_si_twin_beside_it() -> None:
    from aev_ocp.metrics import SI_METRICS
    from aev_ocp.mpc.report import METRIC_ROWS

    for model, (si, _dim) in SI_METRICS.items():
        if model in METRIC_ROWS:
            assert METRIC_ROWS.index(si) == METRIC_ROWS.index(model) + 1, (model, si)
    assert {"rms_jerk_mps3", "rms_rel_speed_mps", "min_speed_mps"} <= set(METRIC_ROWS)
