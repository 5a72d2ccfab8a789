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


def crash_toml(law: str, gap0_first: float, speed0: float, t_end: float, limits: bool = True) -> str:
    """A scenario whose one follower (``law``, initial gap and speed [model units]) drives into a leader standing
    still (v = 0) until t_end [model time]; ``limits`` False: the paper's unlimited vehicle."""
    return (
        f'name = "crash"\n[leader]\nkind = "constant"\nv = 0.0\n[platoon]\nfollowers = 1\nlaw = "{law}"\n'
        f"gap0_first = {gap0_first}\nspeed0 = {speed0}\n[simulation]\nt_end = {t_end}\n"
        + ("" if limits else "[limits]\nenabled = false\n")
    )
