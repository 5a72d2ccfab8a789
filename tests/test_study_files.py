"""A study folder's files: load() returns the table this study wrote (never another study's put in its place), and a
figure interrupted while it is written leaves no temporary behind."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from study_helpers import TINY_AXIS, TINY_STUDY, write_tiny_study

import aev_ocp
from aev_ocp.saved import LoadError
from aev_ocp.study import read_study, run_study


def _run(tmp_path: Path, name: str, values: str) -> Path:
    f = write_tiny_study(
        tmp_path, name, TINY_STUDY.replace(TINY_AXIS, f'key = "carfollowing.kappa"\nvalues = {values}')
    )
    out = tmp_path / name
    run_study(read_study(f), out, executor="inprocess", report=False)
    return out


def test_load_refuses_another_studys_table(tmp_path: Path) -> None:
    a = _run(tmp_path, "sa", "[0.03, 0.07]")
    b = _run(tmp_path, "sb", "[0.11]")
    rows = aev_ocp.load(a).rows
    assert {r["carfollowing.kappa"] for r in rows} == {0.03, 0.07}
    shutil.copy(b / "table.jsonl", a / "table.jsonl")  # b's table in a's folder
    with pytest.raises(LoadError, match=r"table.jsonl: not the table this study wrote .*table_sha256"):
        aev_ocp.load(a)
    assert aev_ocp.load(b).rows[0]["carfollowing.kappa"] == 0.11  # its own table loads


def test_an_interrupted_figure_leaves_no_temporary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.figure

    from aev_ocp.study.report import _save

    fig = matplotlib.figure.Figure()
    fig.add_subplot().plot([0.0, 1.3], [2.1, 0.4])

    def half_written(self: object, fname: object, **kw: object) -> None:
        Path(str(fname)).write_bytes(b"\x89PNG half")  # a part written, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", half_written)
    with pytest.raises(KeyboardInterrupt):
        _save(fig, tmp_path / "fig_omega_vs_kappa.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
