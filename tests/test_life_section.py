"""The "battery life" report section on a reduced configuration: rows, files, the install line without BLAST-Lite."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from aev_ocp import life_section as ls


def test_life_section_reduced(tmp_path: Path) -> None:
    lines: list[str] = []
    md = ls.life_section(tmp_path, lines.append, segment_s=12.0, years=1.0, cycles=("us06",))
    data = json.loads((tmp_path / "battery_life" / "life.json").read_text())
    rows = data["rows"]
    assert {(r["ambient"], r["controller"]) for r in rows} == {
        (a, c) for a in ("hot", "cold") for c in ("mpc", "proposed", "ovfl")
    }
    for r in rows:
        assert r["status"] == "ok" and r["peak_temperature_K"] >= r["ambient_K"] - 1e-9
        assert r["mean_temperature_K"] <= r["peak_temperature_K"]
    assert "## Battery life" in md and (tmp_path / "battery_life" / "life.csv").exists()
    if ls.blast_available():
        hot = {r["controller"]: r["capacity_1y"] for r in rows if r["ambient"] == "hot"}
        cold = {r["controller"]: r["capacity_1y"] for r in rows if r["ambient"] == "cold"}
        assert all(hot[c] < cold[c] < 1.0 for c in hot)  # the hot pack ages faster
    else:
        assert ls.INSTALL_HINT in md


def test_section_without_blast_says_how_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ls, "blast_available", lambda: False)
    md = ls.life_section(tmp_path, lambda m: None, segment_s=6.0, years=1.0, cycles=("us06",))
    assert ls.INSTALL_HINT in md and "capacity_1y" not in (tmp_path / "battery_life" / "life.csv").read_text()


def test_life_claims_say_no_measurable_difference_within_the_resolution() -> None:
    rows = [
        {"cycle": "udds", "ambient": "hot", "controller": c, "capacity_10y": q}
        for c, q in (("proposed", 0.91234), ("ovfl", 0.91241), ("mpc", 0.91302))
    ] + [
        {"cycle": "us06", "ambient": "hot", "controller": c, "capacity_10y": q}
        for c, q in (("proposed", 0.905), ("mpc", 0.9081))
    ]
    lines = ls.life_claims(rows, 10.0)
    assert len(lines) == 2
    assert "UDDS, hot" in lines[0] and "no measurable difference" in lines[0]  # spread 6.8e-4 <= 1e-3
    assert "US06, hot" in lines[1] and "differ by 0.31 %" in lines[1]  # spread 3.1e-3 > 1e-3
    assert ls.life_claims(rows[:1], 10.0) == [] and ls.life_claims(rows, 5.0) == []
