"""reproduce on a cheap configuration writes every file; table1.json has the required keys and
shapes; sections can be registered; the report states the comparison with the paper."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from aev_ocp import reproduce as rp
from aev_ocp.report import PAPER_TABLE1, percent_change, table1_disagreements


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("reproduce")
    stream = io.StringIO()
    rp.register_section("extra-test", lambda d, progress: (progress("extra"), "## Extra section\n")[1])
    try:
        rp.reproduce(out, rp.ReproduceConfig.quick(), registered=True, stream=stream)
    finally:
        rp._REGISTRY.pop("extra-test", None)
    return out, stream.getvalue()


def test_reproduce_writes_all_files(quick_report: tuple[Path, str]) -> None:
    out, _ = quick_report
    for name in (
        "fig1_phase_plane.png",
        "fig2_phase_plane_vs_ovfl.png",
        "fig3_leader.png",
        "fig5_platoon.png",
        "table1.csv",
        "table1.md",
        "table1.json",
        "tolerance_study.json",
        "report.md",
    ):
        path = out / name
        assert path.stat().st_size > 0, name
        if name.endswith(".png"):
            assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob(".*")), "temporary files left behind"


def test_table1_json_keys_and_shapes(quick_report: tuple[Path, str]) -> None:
    data = json.loads((quick_report[0] / "table1.json").read_text())
    for key in ("proposed_omega", "ovfl_omega", "percent_change", "paper_proposed_omega", "paper_ovfl_omega"):
        assert len(data[key]) == 5 and all(isinstance(x, float) for x in data[key]), key
    assert data["paper_proposed_omega"] == list(PAPER_TABLE1["proposed"])
    assert data["percent_change"] == pytest.approx(percent_change(data["proposed_omega"], data["ovfl_omega"]))
    for key in ("pack_heat_J", "delta_soc"):
        assert set(data[key]) == {"proposed", "ovfl"} and all(len(v) == 5 for v in data[key].values())
    assert all(x < 0 for x in data["delta_soc"]["proposed"])  # the platoon drains the pack


def test_report_text_and_progress(quick_report: tuple[Path, str]) -> None:
    out, log = quick_report
    text = (out / "report.md").read_text()
    for fragment in (
        "Table 1",
        "1.827",
        "Tolerance study",
        "disagree",
        "## Extra section",
        "fig5_platoon.png",
        "udds_platoon",
        "Reduced configuration",
    ):
        assert fragment in text, fragment
    lines = [line for line in log.splitlines() if line.startswith("[")]
    assert lines and lines[0].startswith("[1/") and "extra" in log


def test_disagreement_statements_are_computed() -> None:
    same = {
        "proposed_omega": list(PAPER_TABLE1["proposed"]),
        "ovfl_omega": list(PAPER_TABLE1["ovfl"]),
        "paper_proposed_omega": list(PAPER_TABLE1["proposed"]),
        "paper_ovfl_omega": list(PAPER_TABLE1["ovfl"]),
        "paper_percent_change": [-1.56, -2.67, -3.47, -2.21, -1.66],
    }
    same["percent_change"] = percent_change(same["proposed_omega"], same["ovfl_omega"])
    notes = " ".join(table1_disagreements(same))
    assert "agrees" in notes and "HIGHER" not in notes
    worse = dict(same, proposed_omega=[2.0] * 5)
    worse["percent_change"] = percent_change(worse["proposed_omega"], worse["ovfl_omega"])
    notes = " ".join(table1_disagreements(worse))
    assert "differs" in notes and "HIGHER ω" in notes


def test_failing_provider_adds_no_section() -> None:
    log: list[str] = []
    assert rp.load_providers(("aev_ocp.no_such_module",), log=log.append) == []
    assert log and "skipped" in log[0]


def test_every_section_run_loads_back_with_the_numbers_of_the_report(quick_report: tuple[Path, str]) -> None:
    """The runs reproduce made are saved outputs: aev_ocp.load reads each folder, and the loaded runs give the
    numbers the report's own files state (issue 26)."""
    import re

    import aev_ocp

    out, _ = quick_report
    t1 = json.loads((out / "table1.json").read_text())
    runs = aev_ocp.load_all(out / "table1")
    assert set(runs) == {"proposed", "ovfl"}
    for law in ("proposed", "ovfl"):  # ω [model] per follower, recomputed from the loaded trajectories
        assert [m["omega_model"] for m in runs[law].metrics()] == pytest.approx(t1[f"{law}_omega"], rel=1e-12)
    for name in ("fig1a", "fig1b"):
        assert aev_ocp.load(out / name).status == "ok"
    udds = json.loads((out / "scenarios" / "udds_platoon" / "metrics.json").read_text())
    for label, r in aev_ocp.load_all(out / "scenarios" / "udds_platoon").items():
        assert [m["heat_pack_J"] for m in r.metrics()] == pytest.approx(
            [m["heat_pack_J"] for m in udds["runs"][label]["metrics"]], rel=1e-12
        )
    mpc = aev_ocp.load(out / "mpc")  # the example: aev_ocp.load("results/mpc")
    res = json.loads((out / "mpc" / "results.json").read_text())
    assert mpc.meta["output"]["label"] == "mpc" and mpc.status == res["status"]
    assert mpc.metrics()[0]["omega_J_per_kg"] == pytest.approx(res["metrics"]["mpc"][0]["omega_J_per_kg"], rel=1e-12)
    cyc = [p.parent for p in (out / "mpc_cycles").glob("*/manifest.json")]
    assert len(cyc) >= 2
    for folder in cyc:
        labels = set(aev_ocp.load_all(folder))
        assert any(lab.startswith("mpc+") for lab in labels) and "proposed" in labels
    text = (out / "report.md").read_text()
    assert "aev_ocp.load" in text
    # every figure of the MPC and drive-cycle sections is in the report and embedded in report.html
    shown = set(re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text))
    for png in [*(out / "mpc").glob("*.png"), *(out / "mpc_cycles").glob("*/overlay.png")]:
        assert png.relative_to(out).as_posix() in shown, png
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == len(shown)


def test_the_counter_counts_every_line(quick_report: tuple[Path, str]) -> None:
    _, log = quick_report
    heads = [tuple(map(int, ln[1 : ln.index("]")].split("/"))) for ln in log.splitlines() if ln.startswith("[")]
    ks = [k for k, _ in heads]
    assert ks[0] == 1 and all(b - a in (0, 1) for a, b in zip(ks, ks[1:]))  # one by one (a section's extra lines
    # repeat its step number), no jump, never back
    assert len({n for _, n in heads}) == 1  # one denominator from the first line to the last
    assert heads[-1][0] == heads[-1][1] and ks.count(heads[-1][1]) == 1  # N/N once, on the final line


def test_report_html_shows_every_figure_of_the_folder(quick_report: tuple[Path, str]) -> None:
    from aev_ocp.report_html import unshown_figures

    out, _ = quick_report
    text = (out / "report.md").read_text()
    assert unshown_figures(text, out) == []  # a figure a section writes and the report forgets
    html = (out / "report.html").read_text()
    assert html.count("<img ") >= len(list(out.glob("*.png")))
