"""A report that answers first (issue 10 item 6): report.html's text by hand, battery columns beyond the cell's
current limit are marked, and platoon totals are the sums of the per-follower numbers. The claims summary at the top
of a reproduced report and its figures in report.html are checked on tests/test_report.py's reproduce run (one run
feeds them all)."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.report import OVER_LIMIT_MARK, platoon_totals, scenario_metrics_rows
from aev_ocp.report_html import ReportHTMLError, heading_anchor, markdown_to_html
from aev_ocp.simulate import simulate_platoon


def test_markdown_to_html_by_hand(tmp_path: Path) -> None:
    png = b"\x89PNG\r\n\x1a\nnot really a picture"
    (tmp_path / "a.png").write_bytes(png)
    md = (
        "# Title\n\n## Section: one (x ≤ 2)\n\nText with `a|b`, **bold** and [a link](#section-one-x--2).\n\n"
        "| h1 | h2 |\n|---|---|\n| 1 \\| 2 | <b> |\n\n- item *one*\n- item two\n\n![alt text](a.png)\n"
    )
    html = markdown_to_html(md, tmp_path, "t")
    assert '<h2 id="section-one-x--2">' in html and '<a href="#section-one-x--2">a link</a>' in html
    assert "<td>1 | 2</td><td>&lt;b&gt;</td>" in html and "<code>a|b</code>" in html and "<strong>bold</strong>" in html
    assert "<li>item *one*</li>" in html
    assert '<img alt="alt text" src="a.png">' in html and "base64" not in html  # linked by default
    embedded = markdown_to_html(md, tmp_path, "t", embed=True)  # one self-contained file on request
    assert f'src="data:image/png;base64,{base64.b64encode(png).decode()}"' in embedded
    for embed in (False, True):  # a missing figure is an error either way
        with pytest.raises(ReportHTMLError, match="missing.png"):
            markdown_to_html("![x](missing.png)\n", tmp_path, embed=embed)


def test_heading_anchor() -> None:
    assert heading_anchor("Fig. 5: the platoon (n = 3)") == "fig-5-the-platoon-n--3"
    assert heading_anchor("Theorem 4.1 checked (ω ≤ 2?)") == "theorem-41-checked-ω--2"


def test_over_limit_battery_columns_are_marked_and_totals_are_sums() -> None:
    runs = {
        law.name: simulate_platoon(ConstantSpeed(1.4), [law] * 3, [0.9, 2.2, 2.6], [1.9, 1.5, 1.45], 3.0, dt_out=0.05)
        for law in (Proposed(), OVFL())
    }
    peaks = {k: np.max(np.abs(r.current_A), axis=0) for k, r in runs.items()}
    limit = float(np.median(np.concatenate(list(peaks.values()))))  # some vehicles above, some below
    headers, rows = scenario_metrics_rows(runs, i_max_A=limit, totals=True)
    per_vehicle = [r for r in rows if not r[0].startswith("**")]
    for r in per_vehicle:
        over = peaks[r[0]][int(r[1]) - 1] > limit
        battery = [r[headers.index(h)] for h in ("pack ∫Q [J]", "pack ∫Q_irr [J]", "ΔSOC", "max |I| [A/cell]")]
        assert all((OVER_LIMIT_MARK in c) == over for c in battery)
        assert OVER_LIMIT_MARK not in r[headers.index("ω [model]")]  # ω does not depend on the cell
    q = headers.index("pack ∫Q [J]")
    assert any(OVER_LIMIT_MARK in r[q] for r in per_vehicle) and not all(OVER_LIMIT_MARK in r[q] for r in per_vehicle)
    totals = [r for r in rows if r[0].startswith("**")]
    assert len(totals) == 2
    for k, r in runs.items():
        tot = platoon_totals(r)
        assert tot["heat_pack_J"] == pytest.approx(float(np.sum(r.heat_J[-1])), rel=1e-12)
        assert tot["omega_model"] == pytest.approx(float(np.sum(r.omega[-1])), rel=1e-12)
        assert tot["delta_soc"] == pytest.approx(float(np.sum(r.S[-1] - r.S[0])), rel=1e-9)
        assert tot["max_abs_current_A"] == pytest.approx(float(peaks[k].max()), rel=1e-12)
        ms = r.metrics()
        assert tot["battery_energy_J"] == pytest.approx(sum(m["battery_energy_J"] for m in ms), rel=1e-12)
        km = sum(m["distance_m"] for m in ms) / 1000
        assert tot["battery_energy_kWh_per_100km"] == pytest.approx(tot["battery_energy_J"] / km / 3.6e4, rel=1e-12)


def test_summary_links_with_brackets_in_their_text_render_as_links(tmp_path) -> None:
    """A summary row links to a heading that holds an interval ("t ∈ [0, 70]"): report.html shows a link with
    that text, not the raw Markdown (issue 40: 2 of 9 summary links were raw)."""
    from aev_ocp.report_html import heading_anchor, markdown_to_html
    from aev_ocp.report_sections import Claim, summary_section

    where = "Table 1: the paper's inertial measure ω (platoon of 6, paper leader, t ∈ [0, 70])"
    md = summary_section([Claim("a claim", "holds", "evidence", where)]) + f"\n## {where}\n\ntext\n"
    html = markdown_to_html(md, tmp_path)
    assert f'href="#{heading_anchor(where)}"' in html
    assert "](#" not in html  # no raw Markdown link left
