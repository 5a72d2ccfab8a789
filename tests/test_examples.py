"""The runnable examples (issue 10 item 8): each runs as a script (``__main__``) in its quick mode, and what it
writes or prints is checked against the physics it claims to show (not only its exit code). They run in this
process (issue 40: a subprocess importing NumPy, CasADi, matplotlib and aev_ocp cost 1.5 s of CPU each); own_law.py's
law, registered by name, is unregistered after it."""

from __future__ import annotations

import json
import re
import runpy
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def run_example_here(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any, *args: str) -> str:
    """``python examples/<name> --quick *args`` in this process (runpy, as ``__main__``, in ``tmp_path``): its stdout;
    an error in the example raises here."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", [str(EXAMPLES / name), "--quick", *args])
    capsys.readouterr()
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    return capsys.readouterr().out


def _png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_own_law(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    from aev_ocp.models.carfollowing import LAW_REGISTRY

    before = dict(LAW_REGISTRY)
    try:
        run_example_here("own_law.py", tmp_path, monkeypatch, capsys, "--out", str(tmp_path / "o"))
        assert set(LAW_REGISTRY) - set(before) == {"gentle_ovfl"}  # scenario files can name it
    finally:  # the law the example registers does not outlive the test
        LAW_REGISTRY.clear()
        LAW_REGISTRY.update(before)
    d = json.loads((tmp_path / "o" / "own_law.json").read_text())
    assert set(d) == {"gentle_ovfl", "ovfl", "proposed"} and all(v["status"] == "ok" for v in d.values())
    cap = 0.1 * 17.0**2 / 15.0  # a_cap [model] × U²/L [m/s²]
    assert d["gentle_ovfl"]["max_abs_accel_mps2"] <= cap * (1 + 1e-9) < d["ovfl"]["max_abs_accel_mps2"]
    assert all(v["omega_J_per_kg"] > 0 and v["heat_pack_J"] > 0 and v["min_gap_m"] > 0 for v in d.values())
    assert _png(tmp_path / "o" / "own_law_space_time.png")


def test_mpc_drive_cycle(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    out = run_example_here("mpc_drive_cycle.py", tmp_path, monkeypatch, capsys, "--out", str(tmp_path / "m"))
    d = json.loads((tmp_path / "m" / "mpc_drive_cycle.json").read_text())
    m = d["metrics"]
    assert set(m) == {"mpc", "proposed", "ovfl"} and all(v["status"] == "ok" for v in m.values())
    assert m["mpc"]["fallbacks"] == 0 and m["mpc"]["solve_ms_median"] > 0
    assert m["mpc"]["min_gap_m"] >= 0.2 * 20.0 - 1e-6  # h_min [model] × L [m]: the MPC keeps its bound
    assert d["t_end_s"] == pytest.approx(8.0 * 20.0 / 22.0)
    assert _png(tmp_path / "m" / "overlay.png") and "mpc" in out


def test_wq_pareto(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    run_example_here("wq_pareto.py", tmp_path, monkeypatch, capsys, "--out", str(tmp_path / "w"))
    rows = json.loads((tmp_path / "w" / "wq_pareto.json").read_text())
    mpc = sorted((r for r in rows if r["w_Q"] is not None), key=lambda r: r["w_Q"])
    assert [r["w_Q"] for r in mpc] == [0.3, 1.0, 3.0] and {r["controller"] for r in rows} >= {"proposed", "ovfl"}
    heat = [r["heat_pack_J"] for r in mpc]
    assert heat == sorted(heat, reverse=True)  # a larger heat weight never buys more heat
    assert heat[0] > heat[-1] * (1 + 1e-3)  # ... and w_Q really acts (a front of one point is a bug)
    for r in mpc:  # the 'pareto' flag is exactly non-domination, checked by hand
        dominated = any(
            o is not r
            and o["heat_pack_J"] <= r["heat_pack_J"]
            and o["rms_rel_speed_model"] <= r["rms_rel_speed_model"]
            and (o["heat_pack_J"], o["rms_rel_speed_model"]) != (r["heat_pack_J"], r["rms_rel_speed_model"])
            for o in mpc
        )
        assert r["pareto"] == (not dominated)
    assert _png(tmp_path / "w" / "wq_pareto.png")


def test_custom_mpc_term(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    """The baseline labelled '§9' runs model guide §9's problem (states h, v, V1, V2, S; no traffic a_prev, energy
    epigraph or slack; the 'mpc' problem, §9's 0.2 floor and v_max = 2), and the '+ headway' run is §9 plus
    headway: a user problem whose every derived item follows it (its own name, §9's bounds, the §9 family's cold
    start), not the traffic formulation's (the MPC's default: problem mpc_traffic, h_min 2 m = 0.2, v_max 9)."""
    out = run_example_here("custom_mpc_term.py", tmp_path, monkeypatch, capsys)
    runs = {
        m.group(1).strip(): m.groupdict()
        for m in re.finditer(
            r"^\s*(.+?): status ok, min \(h - T_h v\) over the second half = (?P<margin>[-\d.]+) \(h_min = (?P<h_min>[-\d.e]+), "
            r"v_max = (?P<v_max>[-\d.e]+)\).*controller (?P<ctrl>\S+), problem (?P<problem>\S+) \(formulation (?P<kind>\w+), "
            r"family (?P<family>\w+)\)",
            out,
            re.M,
        )
    }
    assert set(runs) == {"mpc (§9)", "mpc (§9) + headway"}, out
    base, hw = runs["mpc (§9)"], runs["mpc (§9) + headway"]
    assert (base["ctrl"], base["problem"], base["kind"], base["family"]) == ("mpc(w_Q=1)", "mpc", "s9", "s9")
    assert (hw["ctrl"], hw["problem"], hw["kind"], hw["family"]) == ("mpc(mpc_headway)", "mpc_headway", "problem", "s9")
    for r in (base, hw):  # §9's bounds (the traffic formulation's v_max would be 45 m/s = 9 model)
        assert float(r["h_min"]) == 0.2 and float(r["v_max"]) == 2.0
    assert float(hw["margin"]) >= 0.2 - 2e-3 > float(base["margin"])  # the added constraint is active
