"""Helpers shared by the command-line tests: run ``aev-ocp`` in-process, check its one-line errors."""

from __future__ import annotations

import pytest

from aev_ocp.cli import main


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``aev-ocp argv``."""
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def one_error(err: str) -> str:
    """The single ``aev-ocp: error:`` line of stderr (and no traceback)."""
    lines = [ln for ln in err.splitlines() if ln.startswith("aev-ocp: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]
