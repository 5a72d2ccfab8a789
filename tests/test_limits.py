"""aev_ocp.limits: the memory estimates refuse oversized OCP / simulation / MPC runs before they start,
with one line that says how much, the limit and which key to change (issue 11 item 6)."""

from __future__ import annotations

import pytest

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
    from aev_ocp.safety.suite import LAW_DT_OUT, run_suite

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
