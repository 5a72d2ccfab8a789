"""reproduce on a cheap configuration writes every file; table1.json has the required keys and
shapes; sections can be registered; the report states the comparison with the paper."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from cli_helpers import run_cli
from helpers import SMALL, TEST_DPI
from study_helpers import TINY_STUDY as STUDY
from study_helpers import write_tiny_study as _study

from aev_ocp import plots
from aev_ocp import reproduce as rp
from aev_ocp.report import PAPER_TABLE1, percent_change, table1_disagreements
from aev_ocp.report_html import heading_anchor

# the study reports' figures at TEST_DPI (aev_ocp.plots.DPI): these tests check that each figure is written and shown,
# not its resolution (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("module_figures_at_test_dpi")


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("reproduce")
    stream = io.StringIO()
    rp.register_section("extra-test", lambda d, progress: (progress("extra"), "## Extra section\n")[1])
    try:
        with pytest.MonkeyPatch.context() as mp:
            # the figures at TEST_DPI, was 120: the tests check that each PNG is written and shown, not its
            # resolution (issue 40: 3.7 s of the run's 31 s of CPU)
            mp.setattr(plots, "DPI", TEST_DPI)
            rp.reproduce(out, rp.ReproduceConfig.quick(), registered=True, stream=stream)
    finally:
        rp._REGISTRY.pop("extra-test", None)
    return out, stream.getvalue()


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
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


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_table1_json_keys_and_shapes(quick_report: tuple[Path, str]) -> None:
    data = json.loads((quick_report[0] / "table1.json").read_text())
    for key in ("proposed_omega", "ovfl_omega", "percent_change", "paper_proposed_omega", "paper_ovfl_omega"):
        assert len(data[key]) == 5 and all(isinstance(x, float) for x in data[key]), key
    assert data["paper_proposed_omega"] == list(PAPER_TABLE1["proposed"])
    assert data["percent_change"] == pytest.approx(percent_change(data["proposed_omega"], data["ovfl_omega"]))
    for key in ("pack_heat_J", "delta_soc"):
        assert set(data[key]) == {"proposed", "ovfl"} and all(len(v) == 5 for v in data[key].values())
    assert all(x < 0 for x in data["delta_soc"]["proposed"])  # the platoon drains the pack


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
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


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_every_section_run_loads_back_with_the_numbers_of_the_report(quick_report: tuple[Path, str]) -> None:
    """The runs reproduce made are saved outputs: aev_ocp.load reads each folder, and the loaded runs give the
    numbers the report's own files state (issue 26)."""
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
    # every figure of the MPC and drive-cycle sections is in the report and shown (linked) in report.html
    shown = set(re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text))
    for png in [*(out / "mpc").glob("*.png"), *(out / "mpc_cycles").glob("*/overlay.png")]:
        assert png.relative_to(out).as_posix() in shown, png
    html = (out / "report.html").read_text()
    assert set(re.findall(r'<img alt="[^"]*" src="([^"]+)"', html)) == shown and "data:image" not in html
    assert all((out / f).is_file() for f in shown)


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_the_counter_counts_every_line(quick_report: tuple[Path, str]) -> None:
    _, log = quick_report
    heads = [tuple(map(int, ln[1 : ln.index("]")].split("/"))) for ln in log.splitlines() if ln.startswith("[")]
    ks = [k for k, _ in heads]
    assert ks[0] == 1 and all(b - a in (0, 1) for a, b in zip(ks, ks[1:]))  # one by one (a section's extra lines
    # repeat its step number), no jump, never back
    assert len({n for _, n in heads}) == 1  # one denominator from the first line to the last
    assert heads[-1][0] == heads[-1][1] and ks.count(heads[-1][1]) == 1  # N/N once, on the final line


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_report_html_shows_every_figure_of_the_folder(quick_report: tuple[Path, str]) -> None:
    from aev_ocp.report_html import unshown_figures

    out, _ = quick_report
    text = (out / "report.md").read_text()
    assert unshown_figures(text, out) == []  # a figure a section writes and the report forgets
    html = (out / "report.html").read_text()
    assert html.count("<img ") >= len(list(out.glob("*.png")))


# ----------------------------------------------------------------------------- the summary and report.html (issue 10 item 6)
# (on this file's reproduce run: every section's claims and figures; test_report_summary.py ran a reproduce of its own)
@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_summary_comes_first_and_every_link_reaches_a_heading(quick_report: tuple[Path, str]) -> None:
    out, _ = quick_report
    md = (out / "report.md").read_text()
    heads = [ln for ln in md.splitlines() if ln.startswith("## ")]
    assert heads[0] == "## Summary: the paper's claims and what the computations say"
    anchors = {heading_anchor(h[3:]) for h in heads}
    summary = md.split("## Summary", 1)[1].split("\n## ", 1)[0]
    links = re.findall(r"\]\(#([^)]+)\)", summary)
    rows = [ln for ln in summary.splitlines() if ln.startswith("| ") and "**" in ln]
    assert len(rows) == len(links) >= 4  # Fig. 1/2, Table 1 (two), Fig. 5 (two), the sections' claims
    assert set(links) <= anchors
    assert any("**fails**" in r and "Table 1: the proposed law has a lower ω" in r for r in rows)
    html = (out / "report.html").read_text()
    for a in links:  # the same links work in report.html
        assert f'id="{a}"' in html


@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_html_links_every_figure_of_the_report(quick_report: tuple[Path, str]) -> None:
    out, log = quick_report
    md = (out / "report.md").read_text()
    html = (out / "report.html").read_text()
    figs = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    imgs = re.findall(r'<img alt="[^"]*" src="([^"]+)"', html)
    assert imgs == figs and len(figs) >= 5 and "data:" not in html  # linked in order, none embedded (issue 40)
    for f in imgs:  # each link resolves from the HTML's own folder to a PNG
        assert (out / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "report.html").stat().st_size < 200_000  # the text alone, not 7 MB of base64
    assert html.count("<table>") == md.count("\n|---")
    # the progress counter reaches N/N
    last = [ln for ln in log.splitlines() if ln.startswith("[")][-1]
    m = re.match(r"\[(\d+)/(\d+)\]", last)
    assert m is not None and m.group(1) == m.group(2)


# ----------------------------------------------------------------------------- the string-stability section (§6, Fig. 5)
# (its checks were tests/test_stability.py's, on a run of the section of its own: the section takes no configuration,
# so reproduce's run is the same computation)
@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_string_stability_section_answers_fig5(quick_report: tuple[Path, str]) -> None:
    out, log = quick_report
    text = (out / "report.md").read_text()
    assert "\n## String stability" in text
    md = "## String stability" + text.split("\n## String stability", 1)[1].split("\n## ", 1)[0]  # the section's text
    assert sum(ln.startswith("[") and "] string-stability: " in ln for ln in log.splitlines()) == 3  # its 3 steps
    doc = json.loads((out / "string_stability.json").read_text())
    assert doc["linear"]["string_stable"] and doc["linear"]["criterion"] == pytest.approx(1.7767, abs=1e-4)
    assert doc["linear_agreement_up_to"] is not None and doc["linear_agreement_up_to"] < 1e-3
    assert "C = 1.7767 ≥ 0" in md and "Fig. 5's 0.88 → 1.19" in md
    # SI twins beside the paper's model-unit columns (L = 10 m, U = 5 m/s): v* = 1.7 -> 8.5 m/s, h* = 2.9416 -> 29.42 m
    assert "| v* [m/s] | h* [m] | v* (model) | h* (model) |" in md
    assert "| proposed (paper) | 8.5 | 29.42 | 1.7 | 2.9416 |" in md
    assert "| A [m/s] | A (model) |" in md and "\n| 0.0005 | 0.0001 | " in md
    assert doc["v_star_mps"] == pytest.approx(5.0 * doc["v_star"])
    assert doc["units"] == {"length_m": 10.0, "speed_mps": 5.0}
    assert (out / "string_stability.png").read_bytes()[:4] == b"\x89PNG"
    assert doc["fig5_origin"]["proposed"]["paper"][1] > doc["fig5_origin"]["proposed"]["paper"][0]
    eq = doc["fig5_origin"]["proposed"]["equilibrium"]
    assert all(b < a for a, b in zip(eq[:-1], eq[1:]))  # from equilibrium the peaks decrease


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)


@pytest.mark.parametrize(
    ("vehicle", "outcome"),
    [
        ("[2, 7]", "report.vehicle = 7"),
        ("9", "report.vehicle = 9"),
        ("[1, 2]", None),
        ("3", "scenario(s) ['s'] have no follower 3"),
    ],
)
def test_report_vehicle_without_rows_is_refused_or_warns(tmp_path: Path, vehicle: str, outcome: str | None) -> None:
    """[report] vehicle = [99] on a 1-follower platoon wrote a report of nothing ('0 of 0') without a word: a
    follower no scenario has is refused before any task runs; one that only some scenarios lack is a warning."""
    import warnings

    from aev_ocp.study import StudyError, run_study

    (tmp_path / "s.toml").write_text(SMALL, encoding="utf-8")  # 2 followers
    (tmp_path / "st.toml").write_text(
        'name = "st"\nscenarios = ["s.toml", { scenario = "s.toml", label = "s3", overrides = '
        '{ "platoon.followers" = 3 } }]\n[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.013, 0.047]\n'
        f'[controllers]\nlaws = ["proposed"]\n[report]\nvehicle = {vehicle}\n',
        encoding="utf-8",
    )
    if outcome is not None and outcome.startswith("report.vehicle"):
        with pytest.raises(StudyError, match=rf"{outcome} is not allowed: must be a follower 1-3 .*have 2, 3 follower"):
            run_study(tmp_path / "st.toml", tmp_path / "o", executor="inprocess")
        assert not (tmp_path / "o").exists()
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run_study(tmp_path / "st.toml", tmp_path / "o", executor="inprocess")
    said = [str(w.message) for w in caught if "[report] vehicle" in str(w.message)]
    assert len(said) == (outcome is not None), said
    if outcome is not None:
        assert outcome in said[0], said


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


def test_unknown_report_metrics_are_refused_and_absent_ones_named_in_a_warning(tmp_path, capsys):
    """A name that is no column a study can have is bad input before anything runs (issue 28 rest); a column
    this study's controllers do not produce (an MPC's solve time in a study of laws) is the report's warning."""
    f = _study(
        tmp_path,
        text=STUDY + '[report]\nmetrics = ["omega_model", "omgea_model"]\npareto = [["heat_pack_J", "frob"]]\n',
    )
    rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / "o"), "--in-process"], capsys)
    assert rc == 2 and "report.metrics names 'omgea_model'" in err and "did you mean omega_model" in err
    assert not (tmp_path / "o").exists()
    f = _study(
        tmp_path,
        text=STUDY + '[report]\nmetrics = ["omega_model", "solve_ms_median"]\npareto = [["heat_pack_J", "nfev"]]\n',
    )
    rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / "o"), "--in-process"], capsys)
    warn = [ln for ln in err.splitlines() if "not columns of the table" in ln]
    assert rc == 0 and len(warn) == 1 and "'solve_ms_median'" in warn[0] and "nfev" not in warn[0]


# ----------------------------------------------------------------------------- the ring section (Sugiyama, Stern)
# (its checks were tests/test_ring.py's test_ring_report_section, on a quick run of the section of its own: reproduce's
# quick run computes the same section with the same configuration, so they read that run)
@pytest.mark.slow  # needs the module's reproduce run (quick_report: over a minute of one core)
def test_ring_section_runs_sugiyama_and_stern_and_its_runs_load_back(quick_report: tuple[Path, str]) -> None:
    import aev_ocp
    from aev_ocp.reproduce import SECTION_PROVIDERS
    from aev_ocp.report_sections import load_providers
    from aev_ocp.ring.outputs import RingOutput
    from aev_ocp.ring.run import fleet_metrics, human_ring, run_ring
    from aev_ocp.ring_section import QUICK_T_END_S

    out, log = quick_report
    assert "aev_ocp.ring_section" in SECTION_PROVIDERS and "aev_ocp.ring_section" in load_providers(SECTION_PROVIDERS)
    text = (out / "report.md").read_text()
    head = "\n## Ring roads"
    assert head in text
    md = head[1:] + text.split(head, 1)[1].split("\n## ", 1)[0]  # the section's text
    assert sum(ln.startswith("[") and "] ring: " in ln for ln in log.splitlines()) == 3  # its 3 steps
    assert "### Sugiyama" in md and "### Stern" in md and "ring_space_time.png" in md
    assert (out / "ring_space_time.png").read_bytes()[:4] == b"\x89PNG"
    assert not (out / "ring.json").exists()  # one home: the section's folder
    doc = json.loads((out / "ring" / "ring.json").read_text())
    stern = [r for r in doc["runs"] if not r["label"].startswith("sugiyama")]
    assert [r["label"] for r in doc["runs"][:2]] == ["sugiyama 230 m", "sugiyama 600 m"]
    jam, calm = doc["sugiyama"]
    for s in (jam, calm):  # the linear theory's growth rate and the measured one
        assert s["measured"]["measured_per_s"] == pytest.approx(s["predicted_growth_per_s"], rel=0.05)
    assert jam["predicted_growth_per_s"] > 0 > calm["predicted_growth_per_s"]
    labels = [r["label"] for r in stern]
    assert labels == ["all human", "followerstopper", "pi-saturation", "proposed", "ovfl", "mpc"]
    # the all-human row is the experiments' ring, run independently of the scenario file
    ref = run_ring(human_ring(230.0, seed=0), QUICK_T_END_S).fleet
    for k in ("speed_std_mps", "battery_energy_J_per_km", "heat_pack_J_per_km", "braking_events"):
        assert stern[0][k] == pytest.approx(ref[k], rel=1e-9)
    assert all(r["collisions"] == 0 for r in stern)
    assert stern[-1]["fallbacks"] == 0 and stern[-1]["call_ms_median"] > 0
    # the runs load back (manifest kind 'ring' in the section's folder 'ring'): the same fleet metrics as its
    # ring.json, and the trajectories recompute them (fleet_metrics of the loaded RingResult, an independent pass)
    loaded = aev_ocp.load(out / "ring")
    assert isinstance(loaded, RingOutput) and 'aev_ocp.load("ring")' in md
    assert [r.label for r in loaded.runs] == ["sugiyama 230 m", "sugiyama 600 m"] + labels
    assert loaded.document["sugiyama"] == doc["sugiyama"]
    for r, saved in zip(loaded.runs[2:], stern, strict=True):
        assert {"label": r.label, **r.fleet} == saved
    stern_mpc = loaded.run("mpc")
    t_from = float(stern[-1]["window_s"][0])
    again = fleet_metrics(stern_mpc, t_from_s=t_from)
    for k in ("speed_std_mps", "heat_pack_J_per_km", "braking_events"):
        assert again[k] == pytest.approx(stern[-1][k], rel=1e-12)
