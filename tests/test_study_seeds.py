"""A study's seed axis (aev_ocp.study.seeds): the mean, 95 % interval and n over the seeds against hand computations,
the paired difference against SciPy, runs ended by an event left out, and a tiny study run end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aev_ocp.study import parse_study, run_study
from aev_ocp.study.seeds import is_seed_key, seed_differences, seed_keys, seed_summary
from aev_ocp.study.spec import StudyError

stats = pytest.importorskip("scipy.stats")

T975_2 = 4.302652729911275  # t_{0.975} with 2 degrees of freedom (tables)
T975_3 = 3.182446305284263  # t_{0.975} with 3 degrees of freedom


def _row(ctrl: str, seed: int, e: float, gap: float, status: str = "ok", kappa: float = 0.03) -> dict[str, Any]:
    return {
        "scenario": "udds",
        "k": kappa,
        "s": seed,
        "controller": ctrl,
        "vehicle": 1,
        "status": status,
        "e": e,
        "gap": gap,
        "conditioning": "none" if ctrl == "a" else "filter 0.5 s",
    }


def test_seed_keys() -> None:
    assert is_seed_key("sensors.seed") and is_seed_key("ring.noise_seed") and is_seed_key("seed")
    assert not is_seed_key("sensors.seeds") and not is_seed_key("seed.mass_rel") and not is_seed_key("mpc.w_Q")


def test_summary_and_paired_difference_by_hand() -> None:
    ea, eb = [3.17, 3.42, 3.05, 3.31], [3.58, 3.61, 3.49, 3.77]
    ga, gb = [4.1, 3.7, 4.4, 3.9], [6.2, 6.05, 6.4, 6.1]
    rows = [_row("a", s, ea[s], ga[s]) for s in range(4)] + [_row("b", s, eb[s], gb[s]) for s in range(4)]
    rows.append(_row("b", 4, 99.0, 0.1, status="collision"))  # ended by an event: left out, counted as dropped
    rows.append(_row("a", 0, 7.7, 7.7, kappa=0.1))  # another point of the other axis: a group of its own
    summ = {(r["k"], r["controller"]): r for r in seed_summary(rows, ["scenario", "k"], ["s"], ["e", "gap"])}
    b = summ[(0.03, "b")]
    m, sd = sum(eb) / 4, math.sqrt(sum((x - sum(eb) / 4) ** 2 for x in eb) / 3)
    half = T975_3 * sd / 2.0
    assert (b["e_mean"], b["e_lo"], b["e_hi"], b["e_n"]) == pytest.approx((m, m - half, m + half, 4), rel=1e-10)
    assert (b["n_seeds"], b["n_dropped"], b["conditioning"]) == (4, 1, "filter 0.5 s")
    one = summ[(0.1, "a")]  # one seed: its value, no interval
    assert (one["e_mean"], one["e_lo"], one["e_hi"], one["e_n"]) == (7.7, None, None, 1)

    (d,) = seed_differences(rows, ["scenario", "k"], ["s"], ["e", "gap"], [("a", "b")], vehicles=[1])[:1]
    assert d["k"] == 0.03
    diff = np.array(ea) - np.array(eb)
    ci = stats.ttest_rel(ea, eb).confidence_interval(0.95)
    assert (d["e_diff_mean"], d["e_diff_lo"], d["e_diff_hi"]) == pytest.approx((diff.mean(), ci.low, ci.high))
    assert d["e_diff_n"] == 4 and d["e_verdict"] == "better"  # a uses less on every seed
    assert d["e_diff_pct"] == pytest.approx(100 * diff.mean() / np.mean(eb))
    dg = seed_differences(rows, ["scenario", "k"], ["s"], ["min_gap_m"], [("a", "b")])
    assert all(r["min_gap_m_verdict"] is None for r in dg)  # no such column: no values, no verdict


def test_min_gap_larger_is_better_and_tie_when_zero_inside() -> None:
    ga, gb = [4.1, 3.7, 4.4, 3.9], [6.2, 6.05, 6.4, 6.1]
    rows = [{**_row("a", s, 1.0 + 0.1 * s, 0.0), "min_gap_m": ga[s]} for s in range(4)]
    rows += [{**_row("b", s, 1.0 + 0.1 * s + (-1) ** s * 0.05, 0.0), "min_gap_m": gb[s]} for s in range(4)]
    (d,) = seed_differences(rows, ["k"], ["s"], ["min_gap_m", "e"], [("a", "b")])
    assert d["min_gap_m_verdict"] == "worse"  # smaller gaps on every seed: worse for a (larger is better)
    assert d["e_diff_lo"] < 0.0 < d["e_diff_hi"] and d["e_verdict"] == "tie"


def _tiny_study(seeds: list[int], differences: list[list[str]] | None = None) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "name": "tiny_seeds",
        "scenarios": [{"scenario": "mpc_udds_single", "label": "udds", "overrides": {"simulation.t_end_s": 6.0}}],
        "reference": "proposed",
        "overrides": {
            "sensors.noise_scale": 3.0,
            "sensors.delay_s": 0.1,
            "sensors.estimator": "none",
            "sensors.battery_states_observed": True,
        },
        "axes": [{"key": "sensors.seed", "values": seeds}],
        "controllers": {"laws": ["proposed", "ovfl"]},
        "report": {"metrics": ["rms_jerk_mps3", "min_gap_m"]},
    }
    if differences is not None:
        doc["report"]["differences"] = differences
    return doc


def test_tiny_study_over_seeds(tmp_path: Path) -> None:
    study = parse_study(_tiny_study([11, 12, 13]))
    assert seed_keys(study.axes) == ["sensors.seed"]
    out = run_study(study, tmp_path / "s", executor="inprocess")
    rows = [r for r in out.rows if r["vehicle"] == 1]
    seeds = json.loads((tmp_path / "s" / "seeds.json").read_text())
    by = {r["controller"]: r for r in seeds["summary"]}
    for ctrl in ("proposed", "ovfl"):
        x = np.array([r["rms_jerk_mps3"] for r in rows if r["controller"] == ctrl])
        assert len(set(x.tolist())) == 3  # the seeds draw different noise
        half = T975_2 * x.std(ddof=1) / math.sqrt(3)
        got = by[ctrl]
        assert (got["rms_jerk_mps3_mean"], got["rms_jerk_mps3_lo"], got["rms_jerk_mps3_hi"]) == pytest.approx(
            (x.mean(), x.mean() - half, x.mean() + half), rel=1e-10
        )
        assert got["n_seeds"] == 3
        # laws under realistic sensors: a production ACC's conditioning by default (aev_ocp.loop.PRODUCTION_ACC)
        assert got["conditioning"] == "filter 0.5 s, jerk <= 5 m/s^3"
    (d,) = seeds["differences"]
    assert (d["a"], d["b"]) == ("ovfl", "proposed")
    a = [r["rms_jerk_mps3"] for r in sorted(rows, key=lambda r: r["sensors.seed"]) if r["controller"] == "ovfl"]
    b = [r["rms_jerk_mps3"] for r in sorted(rows, key=lambda r: r["sensors.seed"]) if r["controller"] == "proposed"]
    ci = stats.ttest_rel(a, b).confidence_interval(0.95)
    assert (d["rms_jerk_mps3_diff_lo"], d["rms_jerk_mps3_diff_hi"]) == pytest.approx((ci.low, ci.high), rel=1e-9)
    report = (tmp_path / "s" / "report.md").read_text()
    assert "## Over the seeds" in report and "ovfl − proposed" in report


def test_differences_must_name_controllers() -> None:
    with pytest.raises(StudyError, match="report.differences names \\['mpc'\\]"):
        parse_study(_tiny_study([1, 2], [["mpc", "ovfl"]]))
    with pytest.raises(StudyError, match="report.differences"):
        parse_study(_tiny_study([1, 2], [["ovfl", "ovfl"]]))


def test_no_seed_axis_no_seed_file(tmp_path: Path) -> None:
    doc = _tiny_study([1])
    doc["axes"] = [{"key": "sensors.delay_s", "values": [0.1, 0.2]}]
    del doc["overrides"]["sensors.delay_s"]
    study = parse_study(doc)
    assert seed_keys(study.axes) == []
    run_study(study, tmp_path / "s", executor="inprocess", report=False)
    assert not (tmp_path / "s" / "seeds.json").exists()
