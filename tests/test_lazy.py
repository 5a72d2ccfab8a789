"""aev_ocp.lazy.lazy_exports: a package's names are imported on first use and then behave as eager re-exports did,
checked on a planted package (so nothing of aev_ocp is cached) and on the real ``aev_ocp.stability.measure``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

PLANTED = {
    "lzpkg/__init__.py": (
        "from aev_ocp.lazy import lazy_exports\n"
        '_EXPORTS = {"f": "fmod", "measure": "measure", "sub": "sub", "Units": "aev_ocp.params", "ghost": "fmod"}\n'
        "__all__ = list(_EXPORTS)\n"
        "__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)\n"
    ),
    "lzpkg/fmod.py": "def f():\n    return 7\n",
    "lzpkg/measure.py": "def measure():\n    return 11\n",
    "lzpkg/sub.py": "X = 3\n",
}


def run_planted(tmp_path: Path, code: str) -> str:
    for rel, text in PLANTED.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text, encoding="utf-8")
    root = Path(__file__).resolve().parents[1]
    env_path = f"{tmp_path}{':'}{root}"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env={"PYTHONPATH": env_path}
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_names_load_on_first_use_and_stay(tmp_path: Path) -> None:
    out = run_planted(
        tmp_path,
        "import sys, lzpkg\n"
        "print(sorted(m for m in sys.modules if m.startswith('lzpkg')))\n"
        "print(lzpkg.f(), lzpkg.sub.X, lzpkg.Units.__module__, 'lzpkg.fmod' in sys.modules)\n"
        "print('f' in vars(lzpkg), 'ghost' in dir(lzpkg))\n",
    )
    assert out.splitlines() == ["['lzpkg']", "7 3 aev_ocp.params True", "True True"]


def test_a_function_named_as_its_module_stays_the_function(tmp_path: Path) -> None:
    """``measure`` of ``measure.py``: still the function after the submodule is imported (the import system sets
    the package's attribute to the submodule then), as ``from .measure import measure`` kept it."""
    out = run_planted(
        tmp_path,
        "import lzpkg.measure\nimport lzpkg\nprint(lzpkg.measure())\nfrom lzpkg import measure\nprint(measure())\n",
    )
    assert out.splitlines() == ["11", "11"]


def test_an_unknown_or_undefined_name_is_an_attribute_error(tmp_path: Path) -> None:
    out = run_planted(
        tmp_path,
        "import lzpkg\n"
        "for n in ('nothing', 'ghost'):\n"
        "    try:\n        getattr(lzpkg, n)\n    except AttributeError as e:\n        print(e)\n",
    )
    assert out.splitlines() == [
        "module 'lzpkg' has no attribute 'nothing'",
        "module 'lzpkg': 'ghost' is not defined in lzpkg.fmod",
    ]


@pytest.mark.parametrize("first", ["import aev_ocp.stability.run", "import aev_ocp.stability.measure"])
def test_stability_measure_is_the_function(first: str) -> None:
    code = f"{first}\nfrom aev_ocp.stability import measure\nprint(callable(measure), type(measure).__name__)"
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root)
    assert out.stdout.split() == ["True", "function"]
