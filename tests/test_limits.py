"""aev_ocp.limits: the memory estimates refuse oversized OCP / simulation / MPC runs before they start,
with one line that says how much, the limit and which key to change (issue 11 item 6)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from cli_helpers import one_error, run_cli
from helpers import SCENARIO, _unblocked_after

from aev_ocp import limits
from aev_ocp.params import ParameterError

pytestmark = pytest.mark.quick  # the whole module runs in the sub-minute subset (pytest -m quick)


@pytest.mark.parametrize("problem", ["prop31", "current-profile", "eco-trip", "oracle"])
@pytest.mark.parametrize("method", ["ms", "collocation"])
def test_defaults_fit_and_absurd_sizes_are_refused(problem, method, monkeypatch) -> None:
    monkeypatch.delenv("AEV_OCP_MAX_MEMORY_GB", raising=False)
    n_default = 700 if problem == "oracle" else 200  # the CLI's defaults (oracle: the canonical scenario)
    assert limits.check_ocp_size(problem, n_default, method) < 3e9
    for N in (10**9, 2**62):
        with pytest.raises(ParameterError) as info:
            limits.check_ocp_size(problem, N, method)
        msg = str(info.value)
        assert "\n" not in msg and f"N = {N}" in msg and "--N" in msg and "GB" in msg, msg


def test_the_budget_and_the_suggested_n_agree(monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.95")
    n_max = limits.max_ocp_intervals("eco-trip", "ms")
    assert n_max == int((0.95e9 - limits.OCP_BASE_BYTES) // limits.OCP_BYTES_PER_INTERVAL[("eco-trip", "ms")])
    limits.check_ocp_size("eco-trip", n_max, "ms")
    with pytest.raises(ParameterError, match=rf"N <= {n_max}\b"):
        limits.check_ocp_size("eco-trip", n_max + 1, "ms", key="--N")
    with pytest.raises(ParameterError, match=r"lower simulation\.t_end"):
        limits.check_ocp_size("oracle", 10**7, "ms", key="simulation.t_end")


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "200"])
def test_bad_n_is_refused(bad) -> None:
    with pytest.raises(ParameterError, match="integer >= 1"):
        limits.check_ocp_size("prop31", bad)


def test_simulation_and_mpc_checks_name_the_arguments(monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "2")
    assert limits.check_simulation_size(5, 70.0, 0.01) < 2e9  # Table 1
    with pytest.raises(ParameterError, match=r"10000000 followers .*raise dt_out"):
        limits.check_simulation_size(10**7, 70.0, 0.01)
    with pytest.raises(ParameterError, match=r"dt_out = 1e-09"):
        limits.check_simulation_size(1, 1e3, 1e-9)
    assert limits.check_mpc_size(40, 5) < 2e9  # mpc_paper_platoon
    with pytest.raises(ParameterError, match=r"MPCSettings\.N to at most \d+"):
        limits.check_mpc_size(10**9)
    assert limits.oracle_intervals(70.0, 0.1) == 700
    with pytest.raises(ParameterError):
        limits.oracle_intervals(float("inf"), 0.1)


def test_read_regular_file_reads_up_to_the_limit_and_refuses_the_rest(tmp_path) -> None:
    """One reader of a bounded regular file for scenario files and saved outputs: the size limit on, inside and
    outside; a folder, a FIFO, a link loop and a missing file refused with the reason (never a hang)."""
    import os

    data = bytes(range(256)) * 3 + b"xyz"  # 771 bytes
    f = tmp_path / "f.bin"
    f.write_bytes(data)
    assert limits.read_regular_file(f, 771) == data  # on the limit
    assert limits.read_regular_file(f, 1000) == data  # inside
    (tmp_path / "link").symlink_to(f)
    assert limits.read_regular_file(tmp_path / "link", 771) == data  # a link to a regular file is fine
    with pytest.raises(limits.FileRefused, match="it is 771 bytes, more than the 770"):
        limits.read_regular_file(f, 770)  # outside, by one byte
    with pytest.raises(limits.FileRefused, match="it is a folder"):
        limits.read_regular_file(tmp_path, 10**6)
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(limits.FileRefused, match="not a regular file"):
        limits.read_regular_file(tmp_path / "fifo", 10**6)
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    with pytest.raises(limits.FileRefused, match="a loop of symbolic links"):
        limits.read_regular_file(tmp_path / "a", 10**6)
    with pytest.raises(limits.FileRefused, match="No such file"):
        limits.read_regular_file(tmp_path / "missing", 10**6)


def test_the_safety_suite_reads_the_memory_budget_before_any_case(monkeypatch, tmp_path) -> None:
    """The suite used to ignore $AEV_OCP_MAX_MEMORY_GB for its closed-loop runs (a layered law or the MPC: nothing
    checked) and to refuse its bare laws' runs deep inside with simulate's advice; now it checks the whole suite
    first: on the limit it runs, a byte below it is refused naming the variable; a bad value is exit 2 and no folder."""
    from aev_ocp.cli import main
    from aev_ocp.safety.cases import CASE_UNITS, suite_cases
    from aev_ocp.safety.run import LAW_DT_OUT, run_suite

    cases = suite_cases(True)[:2]
    t_ends = [float(CASE_UNITS.time_from_si(c.t_end_s)) for c in cases]
    need = sum(limits.estimate_run_bytes(1, t, LAW_DT_OUT) for t in t_ends) * 2  # 2 controllers x 1 actuator
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", repr(need * 0.999 / 1e9))
    with pytest.raises(ParameterError, match=r"safety suite: 2 cases x 2 runs .*AEV_OCP_MAX_MEMORY_GB"):
        run_suite(cases, ["proposed+layer", "ovfl+layer"], actuators=["ideal"], workers=1)
    # with two workers only the two longest runs of each kind are held at once: the same budget is enough
    assert limits.check_suite_size(t_ends, 2, LAW_DT_OUT, False, 1) < need * 0.999
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", repr(need * 1.001 / 1e9))
    out = run_suite(cases, ["proposed+layer", "ovfl+layer"], actuators=["ideal"], workers=1)
    assert len(out.rows) == 4
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "-3")
    monkeypatch.chdir(tmp_path)
    assert main(["safety", "--quick", "--controllers", "proposed", "--out", "o", "--workers", "1"]) == 2
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)


@pytest.mark.parametrize("raw", ["lots", "nan", "-4", "inf", "0", "1e400"])
def test_a_bad_memory_budget_is_refused_not_replaced(monkeypatch: pytest.MonkeyPatch, raw: str) -> None:
    from aev_ocp.limits import memory_limit_bytes

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", raw)
    with pytest.raises(ParameterError, match=r"\$AEV_OCP_MAX_MEMORY_GB = .* is not allowed"):
        memory_limit_bytes()


def test_memory_budget_values(monkeypatch: pytest.MonkeyPatch) -> None:
    from aev_ocp.limits import DEFAULT_MEMORY_LIMIT_GB, memory_limit_bytes

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", " 0.75 ")
    assert memory_limit_bytes() == 0.75e9
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "")
    assert memory_limit_bytes() == DEFAULT_MEMORY_LIMIT_GB * 1e9
    monkeypatch.delenv("AEV_OCP_MAX_MEMORY_GB")
    assert memory_limit_bytes() == DEFAULT_MEMORY_LIMIT_GB * 1e9


def test_bad_memory_budget_is_bad_input_for_commands_and_load(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    import aev_ocp

    f = tmp_path / "u.toml"
    f.write_text(SCENARIO.format(L=12.5, U=7.25))
    out = tmp_path / "o"
    rc, _, err = run_cli(["simulate", str(f), "--out", str(out), "--no-plots"], capsys)
    assert rc == 0
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "lots")
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o2"), "--no-plots"], capsys)
    assert rc == 2 and "$AEV_OCP_MAX_MEMORY_GB = 'lots'" in one_error(err)
    with pytest.raises(ParameterError, match="AEV_OCP_MAX_MEMORY_GB"):  # the caller's setting, not a damaged folder
        aev_ocp.load(out)
    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "0.5")
    assert aev_ocp.load(out).speed.shape[1] == 1


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


@pytest.mark.parametrize(
    "argv, what",
    [
        (["study", "{f}", "--in-process"], "study file"),
        (["ocp", "current-profile", "--grid-file", "{f}", "--out", "{d}/o"], "grid file"),
        (["ocp", "prop31", "--cell", "{f}", "--out", "{d}/o"], "cell file"),
    ],
)
@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_input_files_that_are_no_regular_files_are_refused_unread(tmp_path, capsys, argv, what, kind):
    f = tmp_path / "input.toml"
    if kind == "fifo":
        os.mkfifo(f)
    else:
        f.symlink_to("/dev/zero")
    with _unblocked_after(f, 300.0) as opened_for_writing:  # a FIFO read would wait for a writer
        rc, _, err = run_cli([a.replace("{f}", str(f)).replace("{d}", str(tmp_path)) for a in argv], capsys)
    line = one_error(err)
    assert rc == 2 and what in line and "not a regular file" in line and not opened_for_writing.is_set()


def test_input_file_size_is_checked_before_reading(tmp_path, monkeypatch):
    from aev_ocp import limits
    from aev_ocp.study import StudyError, read_study

    f = tmp_path / "big.toml"
    with f.open("wb") as fh:  # sparse: 20 MB stated, nothing written
        fh.truncate(20 * 2**20)
    reads = []
    monkeypatch.setattr(limits.os, "fdopen", lambda *a, **k: reads.append(a) or open(*a, **k))  # noqa: SIM115
    with pytest.raises(StudyError, match=f"is {20 * 2**20} bytes, more than the {limits.MAX_INPUT_FILE_BYTES}"):
        read_study(f)
    assert reads == []  # refused from its stated size, not read
