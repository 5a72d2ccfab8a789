"""Build hook: record the commit being built in ``aev_ocp/_build_info.json`` (inside the built package only).

``pip install .`` from a clone then knows its commit (``aev_ocp.provenance.git_commit``), which an
installed copy cannot ask git for. Without git or a ``.git`` folder nothing is recorded and the build
goes on. Everything else is in pyproject.toml.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


def _git(*args: str) -> str | None:
    try:
        p = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def build_info() -> dict[str, str | None]:
    """The commit of the tree being built (``+dirty`` when tracked files differ from it), or None."""
    if not (ROOT / ".git").exists():
        return {"git_commit": None}
    head = _git("rev-parse", "HEAD")
    if not head:
        return {"git_commit": None}
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return {"git_commit": head + ("+dirty" if dirty else "")}


class BuildPyWithInfo(build_py):
    """build_py, then ``_build_info.json`` beside the built package's modules."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):  # an editable install asks git at run time
            return
        target = Path(self.build_lib) / "aev_ocp" / "_build_info.json"
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(json.dumps(build_info()) + "\n", encoding="utf-8")
        except OSError:
            pass  # provenance then records git_commit = null, as before


setup(cmdclass={"build_py": BuildPyWithInfo})
