"""The command line: simulate writes its files; bad input and failed runs give one-line errors
with exit codes 2 and 1, without a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from aev_ocp.cli import EXIT_BAD_INPUT, EXIT_FAILED_RUN
from cli_helpers import crash_toml, one_error, run_cli

SMALL = """
name = "small"
compare = ["proposed", "ovfl"]
[leader]
kind = "paper"
[platoon]
followers = 2
gap0_first = 0.3
gap0_others = 3.5
speed0_factor = 1.1
[simulation]
t_end = 3.0
dt_out = 0.05
"""

CRASH = crash_toml("ovm", 0.1, 1.9, 5.0)  # a collision at the first seconds


def test_simulate_writes_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "small.toml"
    scen.write_text(SMALL)
    out = tmp_path / "out"
    rc, stdout, err = run_cli(["simulate", str(scen), "--out", str(out)], capsys)
    assert rc == 0, err
    for name in ("proposed.csv", "ovfl.csv", "proposed.png", "ovfl.png", "metrics.json", "metrics.md"):
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "metrics.json").read_text())
    assert set(data["runs"]) == {"proposed", "ovfl"}
    m = data["runs"]["proposed"]["metrics"]
    assert len(m) == 2 and {"omega_model", "heat_pack_J", "delta_soc", "min_gap_m"} <= set(m[0])
    header = (out / "proposed.csv").read_text().splitlines()[0]
    assert header.startswith("t_s,vehicle,controller,leader_speed_mps,gap_m,speed_mps")
    # no temporary files left behind (.aev-ocp.lock: the folder's lock, held while a run writes into it)
    assert "proposed" in stdout and [p.name for p in out.glob(".*")] == [".aev-ocp.lock"]


@pytest.mark.quick
def test_bad_scenario_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "bad.toml"
    scen.write_text(SMALL.replace("followers = 2", "followers = 2\nmass_kg = -1"))
    rc, _, err = run_cli(["simulate", str(scen), "--out", str(tmp_path / "o")], capsys)
    assert rc == EXIT_BAD_INPUT
    one_error(err)
    assert "platoon.mass_kg" in err and str(scen) in err


@pytest.mark.quick
def test_missing_file_and_bad_arguments_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = run_cli(["simulate", str(tmp_path / "missing.toml")], capsys)
    assert rc == EXIT_BAD_INPUT
    one_error(err)
    rc, _, err = run_cli(["frobnicate"], capsys)
    assert rc == EXIT_BAD_INPUT
    one_error(err)


@pytest.mark.quick
def test_failed_run_still_writes_and_exits_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "crash.toml"
    scen.write_text(CRASH)
    out = tmp_path / "crash"
    rc, _, err = run_cli(["simulate", str(scen), "--out", str(out), "--no-plots"], capsys)
    assert rc == EXIT_FAILED_RUN
    one_error(err)
    assert "collision" in err
    summary = json.loads((out / "metrics.json").read_text())
    assert summary["runs"]["ovm"]["status"] == "collision"
    assert (out / "ovm.csv").exists()


def test_console_script_subprocess(tmp_path: Path) -> None:
    scen = tmp_path / "bad.toml"
    scen.write_text("[leader\n")
    proc = subprocess.run(
        [sys.executable, "-m", "aev_ocp.cli", "simulate", str(scen)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == EXIT_BAD_INPUT
    assert proc.stderr.strip().count("\n") == 0 and proc.stderr.startswith("aev-ocp: error:")
    assert "not valid TOML" in proc.stderr
