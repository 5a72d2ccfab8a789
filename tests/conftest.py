"""What the whole suite shares: the order files are handed to pytest-xdist's workers in (the heaviest first).

Tests that compile C use the compile cache of the environment (``$AEV_OCP_CACHE``, else the user's), except those
that count or break compilations (a cache of their own in ``tmp_path``): libraries are keyed by a hash of their
source, compiler and flags, so a cached library is the one the test's code generates, and a warm cache compiles
nothing.

The README's test command distributes whole files (``-n auto --dist loadfile``): a file's module-scoped results are
computed once, on one worker. Files are collected heaviest first, so the long ones start at once and the short ones
fill the end of the run on both workers. A file's weight is its measured seconds in the previous run (kept in
pytest's cache, ``.pytest_cache``, by the controller at the end of a run), else its seconds in the recorded run
``tests/data/file_seconds.json`` (``python benchmarks/bench_suite.py --record``), else an estimate from its tests:
5 s per test marked ``slow`` (each over about 5 s of one core) plus 0.1 s per other test. The weights only order
the files: a stale one costs time, never a result.
"""

from __future__ import annotations

import gc
import json
import os
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterator

import pytest

#: pytest cache key of {file: seconds of its setup, call and teardown} from the previous run
DURATIONS_KEY = "aev_ocp/file_seconds"
SLOW_TEST_S = 5.0  # the weight of a test marked slow: over about 5 s of one core (pyproject.toml's marker)
OTHER_TEST_S = 0.1  # the weight of any other test (most take well under a second)
RECORDED = Path(__file__).resolve().parent / "data" / "file_seconds.json"
WEIGHTS_INPUT = "aev_ocp_file_weights"  # key of the weights in an xdist worker's start-up input
_WEIGHTS = pytest.StashKey[dict[str, float]]()

# One BLAS thread per process (unless the environment says otherwise): the command runs one pytest worker per core and
# tests start more processes (study pools, Dask workers, the CLI), which inherit this; OpenBLAS's own threads on top
# oversubscribe the cores and spin while they wait (issue 40: the mixed-ring stability command's eigenvalues took 2.5 s
# of CPU with OpenBLAS's default threads on this two-core machine, 0.6 s with one). Set before NumPy is imported here.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def _recorded() -> dict[str, float]:
    try:
        table = json.loads(RECORDED.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return table if isinstance(table, dict) else {}


def pytest_configure(config: pytest.Config) -> None:
    # with --dist loadfile, keep the collection order below (xdist would otherwise sort files by their number of tests)
    if getattr(config.option, "dist", "no") == "loadfile" and hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False
    # the weights are read once, by the controller, and handed to every worker (all must collect the same order, even
    # if another run in this folder rewrites the cache meanwhile)
    workerinput = getattr(config, "workerinput", None)
    if workerinput is not None:
        config.stash[_WEIGHTS] = dict(workerinput.get(WEIGHTS_INPUT, {}))
    else:
        cache = getattr(config, "cache", None)
        last = cache.get(DURATIONS_KEY, {}) if cache is not None else {}
        config.stash[_WEIGHTS] = {**_recorded(), **(last if isinstance(last, dict) else {})}


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node: Any) -> None:
    """pytest-xdist (on the controller): the file weights go to each worker with its start-up input."""
    node.workerinput[WEIGHTS_INPUT] = node.config.stash.get(_WEIGHTS, {})


def _file_of(item: pytest.Item) -> str:
    return item.nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """Files heaviest first (stable: a file's tests keep their order and stay together)."""
    known = config.stash.get(_WEIGHTS, {})
    estimate: dict[str, float] = defaultdict(float)
    for item in items:
        estimate[_file_of(item)] += SLOW_TEST_S if item.get_closest_marker("slow") else OTHER_TEST_S
    first = {f: k for k, f in enumerate(dict.fromkeys(_file_of(i) for i in items))}

    def weight(f: str) -> float:
        w = known.get(f)
        return float(w) if isinstance(w, (int, float)) else estimate[f]

    items.sort(key=lambda i: (-weight(_file_of(i)), first[_file_of(i)]))


@pytest.fixture(autouse=True)
def _no_shared_mpc_problems_across_a_monkeypatch(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test that asks for ``monkeypatch`` may change the models' code: the MPC problems this process keeps
    (Formulation.mpc_problem, built once per equal inputs) are forgotten before it and after it."""
    import inspect

    fn = getattr(request, "function", None)
    patches = fn is not None and "monkeypatch" in inspect.signature(fn).parameters
    if patches:
        from aev_ocp.ocp.formulation import clear_mpc_problems

        clear_mpc_problems()
    yield
    if patches:
        clear_mpc_problems()


@pytest.fixture
def figures_at_test_dpi(monkeypatch: pytest.MonkeyPatch) -> None:
    """The package's figures drawn at tests/helpers.py's TEST_DPI for one test (a test that checks that a figure is
    written and shown, not how it looks: ``pytestmark = pytest.mark.usefixtures("figures_at_test_dpi")``)."""
    import aev_ocp.plots
    from helpers import TEST_DPI

    monkeypatch.setattr(aev_ocp.plots, "DPI", TEST_DPI)


@pytest.fixture(scope="module")
def module_figures_at_test_dpi() -> Iterator[None]:
    """:func:`figures_at_test_dpi` for a whole module (``pytestmark = pytest.mark.usefixtures(...)``), also for a
    module-scoped fixture's figures and for a hypothesis test (which refuses function-scoped fixtures)."""
    import aev_ocp.plots
    from helpers import TEST_DPI

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(aev_ocp.plots, "DPI", TEST_DPI)
        yield


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    # on the controller (or a run without xdist): every phase's report of every test arrives here
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return
    _SECONDS[report.nodeid.split("::", 1)[0]] += report.duration


_SECONDS: dict[str, float] = defaultdict(float)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Keep each file's seconds for the next run's order (from a run that passed; files it did not run keep their
    earlier weight)."""
    if os.environ.get("PYTEST_XDIST_WORKER") or getattr(session.config, "cache", None) is None or not _SECONDS:
        return
    if exitstatus != 0:
        return
    old = session.config.cache.get(DURATIONS_KEY, {})
    merged = {**(old if isinstance(old, dict) else {}), **{f: round(s, 2) for f, s in _SECONDS.items()}}
    session.config.cache.set(DURATIONS_KEY, merged)


def pytest_collection_finish(session: pytest.Session) -> None:
    # what collection leaves alive (the modules, their functions, pytest's items: ~250 000 objects per worker) lives
    # to the end of the run: moved out of the cyclic garbage collector's reach, its full collections scan only what
    # the tests create (issue 40: they took ~3.5 s of each worker's CPU, rescanning the same objects)
    gc.freeze()
