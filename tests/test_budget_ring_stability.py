"""``aev-ocp ring`` and ``aev-ocp stability`` keep the memory budget ($AEV_OCP_MAX_MEMORY_GB) as simulate, mpc and
study do: a bad value is bad input (exit 2, one line naming the variable) before anything is written, and a ring or
a measured platoon too large for the budget is refused before it runs, with the keys that change it."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from aev_ocp.cli import main
from aev_ocp.limits import RING_BYTES_PER_SAMPLE, check_ring_size, estimate_run_bytes, ring_samples
from aev_ocp.params import ParameterError

BUDGET = "AEV_OCP_MAX_MEMORY_GB"


def _one_line(capsys: pytest.CaptureFixture) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_ring_estimate_bounds_a_real_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """The estimate counts the samples the simulator really keeps and bounds its peak memory (tracemalloc) from
    above, within a factor 2."""
    from aev_ocp.ring.run import human_ring, run_ring
    from aev_ocp.ring.simulate import RingOptions

    monkeypatch.delenv(BUDGET, raising=False)
    opts = RingOptions(dt_out_s=0.05)
    run_ring(human_ring(230.0, 22), 0.5, options=opts)  # the compiled ring loaded before measuring
    ring = human_ring(9.5 * 31, 31)
    tracemalloc.start()
    try:
        ex = run_ring(ring, 45.0, options=opts)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert ex.result.t_s.size == ring_samples(45.0, 0.05) == 901
    need = check_ring_size(31, 45.0, 0.05)
    assert need == RING_BYTES_PER_SAMPLE * 31 * 901
    assert 0.5 * need < peak <= need, (peak, need)


def test_ring_budget_on_and_past_the_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    need = RING_BYTES_PER_SAMPLE * 37 * 401  # 37 vehicles, 401 samples: 4.4511 MB
    monkeypatch.setenv(BUDGET, repr(need / 1e9))  # exactly the need: fits
    assert check_ring_size(37, 100.0, 0.25) == need
    monkeypatch.setenv(BUDGET, repr(need * (1 - 1e-6) / 1e9))
    with pytest.raises(ParameterError, match=r"37 vehicles x 401 samples .*at most 36 vehicles \(n_vehicles\)"):
        check_ring_size(37, 100.0, 0.25)


def test_ring_scenario_too_large_is_refused_when_read(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    from aev_ocp.ring.scenario import load_ring_scenario
    from aev_ocp.scenarios import ScenarioError

    f = tmp_path / "big.toml"
    f.write_text("[ring]\nlength_m = 420.0\nvehicles = 37\nt_end_s = 100.0\ndt_out_s = 0.25\n", encoding="utf-8")
    monkeypatch.setenv(BUDGET, "0.0045")  # 4.5 MB: the 4.45 MB run fits
    assert load_ring_scenario(f).spec.vehicles == 37
    monkeypatch.setenv(BUDGET, "0.0044")
    with pytest.raises(ScenarioError, match=r"big\.toml: ring: 37 vehicles .*ring\.t_end_s = 100 s, ring\.dt_out_s"):
        load_ring_scenario(f)
    rc = main(["ring", str(f), "--out", str(tmp_path / "o"), "--no-plots"])
    err = _one_line(capsys)
    assert rc == 2 and "big.toml: ring: 37 vehicles" in err and "(ring.vehicles)" in err
    assert not (tmp_path / "o").exists()


def test_ring_simulator_checks_the_budget_before_it_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    from aev_ocp.ring.run import human_ring
    from aev_ocp.ring.simulate import simulate_ring

    monkeypatch.setenv(BUDGET, "0.0061")  # 6.1 MB: 22 cars x 1201 samples (7.9 MB) do not fit
    with pytest.raises(ParameterError, match=r"22 vehicles x 1201 samples \(t_end_s = 600 s.*at most 16 vehicles"):
        simulate_ring(human_ring(), 600.0)


@pytest.mark.parametrize("raw", ["lots", "nan", "-4", "inf"])
@pytest.mark.parametrize(
    "argv",
    [
        ["ring", "sugiyama", "--t-end-s", "2.5"],
        ["stability", "--law", "proposed", "--linear-only"],
        ["stability", "--law", "ovfl", "--ring", "30", "--spacing-m", "12.5"],
    ],
)
def test_bad_budget_is_bad_input(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path, raw: str, argv: list[str]
) -> None:
    monkeypatch.setenv(BUDGET, raw)
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    assert f"$AEV_OCP_MAX_MEMORY_GB = {raw!r} is not allowed" in _one_line(capsys)
    assert not (tmp_path / "o").exists()


def test_ring_cli_too_large_for_the_budget_is_refused_before_it_runs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    monkeypatch.setenv(BUDGET, "0.0061")
    assert main(["ring", "stern", "--t-end-s", "600", "--out", str(tmp_path / "o")]) == 2
    err = _one_line(capsys)
    assert "22 vehicles x 1201 samples (--t-end-s = 600 s" in err and "lower --t-end-s" in err
    assert not (tmp_path / "o").exists()
    f = tmp_path / "big.toml"
    f.write_text("[ring]\nlength_m = 420.0\nvehicles = 37\nt_end_s = 10.0\ndt_out_s = 0.25\n", encoding="utf-8")
    monkeypatch.setenv(BUDGET, "0.0044")  # the file's 10 s fit; --t-end-s 100 does not
    assert main(["ring", str(f), "--t-end-s", "100", "--out", str(tmp_path / "o")]) == 2
    err = _one_line(capsys)
    assert "37 vehicles x 401 samples (--t-end-s = 100 s, ring.dt_out_s = 0.25 s)" in err and "(ring.vehicles)" in err
    assert not (tmp_path / "o").exists()


def test_stability_measured_platoon_too_large_is_refused_before_it_runs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    """The measured runs' horizon grows with the platoon: the largest platoon that fits, found independently
    here by walking up from one follower, is the one the message offers."""
    import aev_ocp.stability.run as api
    from aev_ocp.models.carfollowing import make_law
    from aev_ocp.params import CarFollowingParams
    from aev_ocp.stability.linear import analyse
    from aev_ocp.stability.cli import _DURATION, _OMEGA, _V_STAR
    from aev_ocp.stability.measure import MEASURE_DT_OUT, default_t_end

    monkeypatch.setenv(BUDGET, "0.35")
    monkeypatch.setattr(api, "measure", lambda *a, **k: pytest.fail("a measured run started"))
    assert main(["stability", "--law", "proposed", "--followers", "700", "--out", str(tmp_path / "o")]) == 2
    err = _one_line(capsys)
    lin = analyse(make_law("proposed", CarFollowingParams()), _V_STAR)  # the CLI's defaults: v*, a pulse
    need = lambda n: estimate_run_bytes(n, default_t_end(lin, n, "pulse", _OMEGA, _DURATION), MEASURE_DT_OUT)  # noqa: E731
    k = 1
    while need(k + 1) <= 0.35e9:
        k += 1
    assert 50 < k < 700 and need(700) > 0.35e9
    assert "--followers 700: the measured runs need about" in err and f"use at most {k} followers" in err, (k, err)
    assert "--linear-only" in err
    assert not (tmp_path / "o").exists()  # refused before the output folder is claimed
