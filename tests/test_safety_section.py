"""The safety section of ``aev-ocp reproduce``: a representative subset of the suite (stated in its text;
``aev-ocp safety`` runs every case), and every figure it writes is shown in report.html."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import pytest

from aev_ocp.report_html import unshown_figures, write_report_html
from aev_ocp.report_sections import ReproduceConfig, SectionContext
from aev_ocp.safety import section
from aev_ocp.safety.cases import FAMILIES, KMH, REPRODUCE, reproduce_cases, suite_cases


def test_reproduce_subset_is_representative() -> None:
    sub, every = reproduce_cases(), {c.name: c for c in suite_cases()}
    assert len(sub) == len(REPRODUCE) < len(every)  # every name is a suite case (a typo would drop one silently)
    assert all(c == every[c.name] for c in sub)  # full length, not the quick 3 s
    assert {c.family for c in sub} == set(FAMILIES)
    ccrs = {round(c.v_ego_mps / KMH) for c in sub if c.family == "CCRs"}
    assert {100, 120, 130} <= ccrs and min(ccrs) <= 80  # every motorway CCRs, and an NCAP speed
    for fam in ("CCRm", "CCRb", "lane-end", "cut-in"):  # every family up to motorway speed
        assert max(c.v_ego_mps for c in sub if c.family == fam) >= 100 * KMH - 1e-9, fam
    assert any(c.family == "cut-in" and c.a_lead_mps2 < -8.0 for c in sub)  # a lead braking harder than a_min


def test_unshown_figures_over_a_fake_report_folder(tmp_path: Path) -> None:
    for name in ("a.png", "b.svg", "c.PNG", "data.csv", "report.md"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "d.png").write_bytes(b"x")  # not in the folder's top level: not the report's
    md = "# R\n\nText ![one](a.png) and a [link](b.svg), not a figure.\n"
    assert unshown_figures(md, tmp_path) == ["b.svg", "c.PNG"]
    assert unshown_figures(md + "![two](b.svg)\n![three](c.PNG)\n", tmp_path) == []


def test_section_states_the_subset_and_shows_every_figure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the section as reproduce runs it (full configuration), on a small suite: one short case per family, one law
    short = {}
    for c in suite_cases():
        short.setdefault(c.family, dataclasses.replace(c, t_end_s=1.5))
    monkeypatch.setattr(section, "reproduce_cases", lambda: list(short.values()))
    monkeypatch.setattr(
        section, "run_suite", functools.partial(section.run_suite, controllers=("proposed",), actuators=("ideal",))
    )
    lines: list[str] = []
    ctx = SectionContext(lines.append, ReproduceConfig())
    assert ctx.config.is_full
    md = section.safety_section(tmp_path, ctx)
    n_all = len(suite_cases())
    assert f"**Representative subset**: {len(FAMILIES)} of the suite's {n_all} cases" in md
    assert f"`aev-ocp safety` runs all {n_all} cases" in md and lines == ["safety suite (representative subset)"]
    figures = sorted(p.name for p in tmp_path.glob("*.png"))
    assert len(figures) == len(FAMILIES)  # one per family
    assert unshown_figures(md, tmp_path) == []
    html = write_report_html(md, tmp_path, tmp_path / "report.html").read_text()
    assert html.count('<img alt="Safety suite, ') == len(FAMILIES)
