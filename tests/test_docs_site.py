"""The documentation stands on its own (issue 26): no text refers to a file outside the repository, the site's
pages own their text (nothing is pulled from README.md at build time), and every notebook is listed, stored
without outputs and executed by the build with errors failing it."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
TEXT = {".py", ".md", ".toml", ".yml", ".yaml", ".txt", ".ipynb", ".json", ".c", ".h", ".in", ".csv"}


def _repo_files() -> list[Path]:
    out = [ROOT / "README.md", ROOT / "mkdocs.yml", ROOT / "pyproject.toml", ROOT / "setup.py"]
    for d in ("aev_ocp", "docs", "examples", "scenarios", "studies", "benchmarks", ".ci"):
        out += [
            p
            for p in (ROOT / d).rglob("*")
            if p.is_file() and (p.suffix in TEXT or p.parent.name == ".ci") and "__pycache__" not in p.parts
        ]
    return out


def test_no_text_refers_to_the_problem_card_or_to_files_outside_the_repository() -> None:
    bad = []
    for p in _repo_files():
        text = p.read_text(encoding="utf-8", errors="replace")
        for pat in ("PROBLEM.md", "../shared/", "paper.tex"):
            if pat in text:
                bad.append(f"{p.relative_to(ROOT)}: {pat}")
    assert not bad, bad


def test_section_numbers_name_the_model_page() -> None:
    """'model guide §N' and the site's links point at a section the model page has (§1-§12)."""
    model = (ROOT / "docs" / "guide" / "model.md").read_text(encoding="utf-8")
    have = {int(n) for n in re.findall(r"^## §(\d+) ", model, re.M)}
    assert have == set(range(1, 13))
    slugs = {
        re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower())
        for h in re.findall(r"^## (§\d+ .+)$", model, re.M)
    }
    for p in _repo_files():
        text = p.read_text(encoding="utf-8", errors="replace")
        for n in re.findall(r"model guide §(\d+)", text):
            assert int(n) in have, f"{p.relative_to(ROOT)}: model guide §{n}"
        for anchor in re.findall(r"model\.md#([\w-]+)", text):
            assert anchor in slugs, f"{p.relative_to(ROOT)}: model.md#{anchor}"


def test_the_site_owns_its_pages_and_executes_every_notebook() -> None:
    cfg = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    assert "hooks:" not in cfg and not (ROOT / "docs" / "hooks").exists()
    pages = sorted(
        p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*") if p.suffix in (".md", ".ipynb")
    )
    for page in pages:
        assert f": {page}" in cfg or f"- {page}" in cfg, f"{page} is not in the site's nav"
        if page.endswith(".md"):
            assert "<!-- readme:" not in (ROOT / "docs" / page).read_text(encoding="utf-8"), page
    notebooks = [p for p in pages if p.endswith(".ipynb")]
    assert len(notebooks) >= 3
    plugin = cfg.split("- mkdocs-jupyter:", 1)[1].split("\n  - ", 1)[0]
    assert re.search(r"^\s+execute: true$", plugin, re.M) and re.search(r"^\s+allow_errors: false$", plugin, re.M)
    # no output cache: mkdocs-jupyter's cache (keyed by the notebook's text) would show stored outputs unexecuted
    assert re.search(r"^\s+cache: false$", plugin, re.M)
    assert not (ROOT / ".cache").exists() or ".cache/" in (ROOT / ".gitignore").read_text(encoding="utf-8")
    for nb in notebooks:  # stored without outputs: what the site shows is what the build computed
        cells = json.loads((ROOT / "docs" / nb).read_text(encoding="utf-8"))["cells"]
        code = [c for c in cells if c["cell_type"] == "code"]
        assert code and all(not c.get("outputs") and c.get("execution_count") is None for c in code), nb
    toml = (ROOT / "pyproject.toml").read_text(encoding="utf-8")  # the docs extra brings what the build needs
    docs_extra = toml.split("\ndocs = [", 1)[1].split("\n[", 1)[0].split("]\n", 1)[0]
    for pkg in ("mkdocs", "mkdocstrings[python]", "mkdocs-jupyter", "nbformat", "ipykernel", "pandas"):
        assert f'"{pkg}>=' in docs_extra, pkg
    assert "mkdocs build --strict" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")


# Both builds of the scratch site in one process (issue 40: a second interpreter importing mkdocs, its plugins and
# nbconvert cost 1-3 s of CPU): mkdocs' own command line (``mkdocs build --strict -q``, click's standalone mode, whose
# SystemExit code is the command's exit status, and an exception out of it status 1 with its traceback, as the
# interpreter gives) on the broken notebook, then on the fixed one; each notebook is
# executed by a kernel of its own, as in a build of its own.
_TWO_BUILDS = """
import json, shutil, sys, traceback
from pathlib import Path

from mkdocs.__main__ import cli

def build(source):
    nb = {
        "cells": [{"cell_type": "code", "metadata": {}, "source": source, "outputs": [], "execution_count": None}],
        "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
        "nbformat": 4,
        "nbformat_minor": 5,
    }
    Path("docs/nb.ipynb").write_text(json.dumps(nb), encoding="utf-8")
    shutil.rmtree("site", ignore_errors=True)
    try:
        cli.main(["build", "--strict", "-q"], prog_name="mkdocs")
    except SystemExit as stop:
        return stop.code if isinstance(stop.code, int) else 1
    except Exception:  # what the interpreter does with an exception out of the command: its traceback, status 1
        traceback.print_exc()
        return 1
    return 0

for name, source in zip(("bad", "good"), sys.argv[1:3]):
    code = build(source)
    sys.stderr.flush()
    print(f"@@ build {name} exit {code}", flush=True)
    print(f"@@ build {name} exit {code}", file=sys.stderr, flush=True)
"""


def test_a_broken_notebook_fails_the_strict_build(tmp_path) -> None:
    """The site's mkdocs-jupyter settings on a scratch site whose one notebook raises: ``mkdocs build --strict``
    exits non-zero naming the error (so CI fails on a broken notebook); the same notebook fixed builds."""
    import subprocess
    import sys

    pytest.importorskip("mkdocs_jupyter")
    pytest.importorskip("ipykernel")
    cfg = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    plugin = cfg.split("- mkdocs-jupyter:", 1)[1].split("\n  - ", 1)[0]
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.md").write_text("# scratch\n", encoding="utf-8")
    (tmp_path / "mkdocs.yml").write_text(
        "site_name: scratch\nnav:\n  - Home: index.md\n  - NB: nb.ipynb\nplugins:\n  - mkdocs-jupyter:" + plugin + "\n",
        encoding="utf-8",
    )
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            _TWO_BUILDS,
            "x = 3.25\nraise ValueError('planted notebook error')",
            "x = 3.25\nprint(x * 2)",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    bad_out, rest_out = p.stdout.split("@@ build bad exit ", 1)
    bad_err, rest_err = p.stderr.split("@@ build bad exit ", 1)
    bad_code, rest_out = rest_out.split("\n", 1)
    good_err = rest_err.split("\n", 1)[1]
    assert int(bad_code) != 0 and "planted notebook error" in bad_out + bad_err
    assert rest_out.strip() == "@@ build good exit 0", good_err[-2000:]
    assert "6.5" in (tmp_path / "site" / "nb" / "index.html").read_text(encoding="utf-8")
    assert not (tmp_path / ".cache").exists()  # nothing cached for the next build to reuse


def test_the_reproduce_timing_the_docs_quote_is_the_benchmarks() -> None:
    """README and the set-up page quote reproduce's CPU time and compilations as measured by
    benchmarks/bench_reproduce.py (a stale '4.5 minutes' was quoted after the run had grown to 8.5)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    assert "benchmarks/bench_reproduce.py" in readme and "bench_reproduce.py" in index
    cpu = re.search(r"used (\d+) s of CPU", readme)
    assert cpu is not None and f"used {cpu.group(1)} s of CPU" in index
    run = json.loads((ROOT / "benchmarks" / "bench_reproduce.json").read_text())["run"]
    assert not run["quick"] and not run["full"]  # the default reproduction is what the docs quote
    for doc in (" ".join(readme.split()), " ".join(index.split())):  # the recorded benchmark's numbers
        assert f"used {run['cpu_s']:.0f} s of CPU and {run['wall_s']:.0f} s of wall time" in doc
        assert f"{sum(run['compilations'].values())} compil" in doc and f"{run['output_MB']:.0f} MB" in doc
    assert "4.5 minutes" not in readme + index
    assert (ROOT / "benchmarks" / "bench_reproduce.py").is_file()


def test_the_suite_timing_the_readme_quotes_is_the_benchmarks() -> None:
    """README quotes the test command's wall and CPU time and counts as recorded by benchmarks/bench_suite.py."""
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    doc = json.loads((ROOT / "benchmarks" / "bench_suite.json").read_text())
    run = doc["quoted"]
    same = ("dist", "bytecode")  # the quoted run's configuration: xdist mode, bytecode cached (Python's default) or not
    mode = [r for r in doc["runs"] if all(r[k] == run[k] for k in same)]
    assert all(r["returncode"] == 0 and not r["failures"] for r in mode)
    walls = sorted(r["wall_s"] for r in mode)
    assert run["wall_s"] == walls[(len(walls) - 1) // 2]  # the median run, not the fastest
    median = next(m for m in doc["medians"] if all(m[k] == run[k] for k in same))
    assert median["repeats"] == len(mode) >= 3  # a median of at least three runs
    assert f"median of {median['repeats']} runs" in readme
    assert f"{min(walls):.0f}-{max(walls):.0f} s" in readme  # and their spread
    quoted = (
        f"took {run['wall_s']:.0f} s of wall and {run['cpu_s']:.0f} s of CPU on this two-core machine "
        f"(load {run['load_1min_before']:.1f} before it; {run['counts']['passed']} passed,"
    )
    assert quoted in readme
    assert "benchmarks/bench_suite.json" in readme
