"""reproduce on a process pool (issue 40): the same report.md, claims and files as one process, in the declared
order, whichever worker finishes first; a section that fails in a worker fails the run naming it; a section a
worker cannot import (made at run time) runs in this process. The sections here are this module's own functions
(a worker imports them by name: this folder is put on its PYTHONPATH)."""

from __future__ import annotations

import dataclasses
import io
import json
import multiprocessing
import re
import time
from pathlib import Path

import pytest

from aev_ocp import reproduce as rp

NONE = dataclasses.replace(rp.ReproduceConfig.quick(), builtin=("fig3",))  # one cheap built-in section


def slow_section(out_dir, ctx):
    """Ends LAST on a pool (it waits there for the fast section's file, written in the other worker), though it is
    declared first; in this process (one process: the sections run one after another) there is nothing to overtake
    it, so it does not wait (issue 40: was a fixed 1.5 s wait per pool run)."""
    ctx("slow: step 1 of 2")
    if multiprocessing.parent_process() is not None:  # in a pool's worker
        deadline = time.monotonic() + 60.0  # a bound against a hang only
        while not (Path(out_dir) / "fast.json").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
    (Path(out_dir) / "slow.json").write_text(json.dumps({"value_m": 12.375}))
    ctx.record_claim("the slow claim", "holds", "12.375 m", "Slow")
    return "## Slow\n\n12.375 m\n"


def fast_section(out_dir, ctx):
    ctx("fast: step 1 of 1")
    ctx("fast: an extra line (a sub-step)")
    (Path(out_dir) / "fast.json").write_text(json.dumps({"value_s": 0.8125}))
    ctx.record_claim("the fast claim", "fails", "0.8125 s", "Fast")
    return "## Fast\n\n0.8125 s\n"


def failing_section(out_dir, ctx):
    ctx("failing: about to fail")
    raise ValueError("the pool worker computed 7.25 where 3 was expected")


@pytest.fixture()
def registry(monkeypatch):
    saved = dict(rp._REGISTRY)
    rp._REGISTRY.clear()
    # only the sections each test registers
    monkeypatch.setattr(rp, "load_providers", lambda providers=(), log=None: [])
    here = str(Path(__file__).parent)
    monkeypatch.setenv("PYTHONPATH", here + ":" + __import__("os").environ.get("PYTHONPATH", ""))
    yield
    rp._REGISTRY.clear()
    rp._REGISTRY.update(saved)


def _run(out: Path, workers: int) -> tuple[str, str]:
    err = io.StringIO()
    rp.reproduce(out, NONE, registered=True, stream=err, workers=workers)
    text = (out / "report.md").read_text(encoding="utf-8")
    return re.sub(r"utc `[^`]*`", "utc `T`", text), err.getvalue()


def test_a_pool_writes_the_report_of_one_process(tmp_path, registry) -> None:
    rp.register_section("slow", slow_section, steps=2)
    rp.register_section("fast", fast_section, steps=1)
    rp.register_section("made-here", lambda d, ctx: "## Made here\n", steps=1)  # not importable: runs here
    one, _ = _run(tmp_path / "one", 1)
    pool, err = _run(tmp_path / "pool", 2)
    assert pool == one
    assert one.index("## Slow") < one.index("## Fast") < one.index("## Made here")  # the declared order
    for name in ("slow.json", "fast.json"):
        assert (tmp_path / "pool" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()
    # the summary holds both claims, in the declared order (the slow section's first)
    assert one.index("the slow claim") < one.index("the fast claim")
    heads = [int(m.group(1)) for m in re.finditer(r"^\[(\d+)/(\d+)\]", err, re.M)]
    total = {int(m.group(2)) for m in re.finditer(r"^\[(\d+)/(\d+)\]", err, re.M)}
    assert len(total) == 1 and heads == sorted(heads) and heads[-1] == total.pop() and heads.count(heads[-1]) == 1
    assert "fast: an extra line" in err and "made-here" not in err.split("\n")[0]


def test_a_section_failing_in_a_worker_fails_the_run_naming_it(tmp_path, registry) -> None:
    rp.register_section("fast", fast_section)
    rp.register_section("failing", failing_section)
    with pytest.raises(rp.ReportSectionError) as info:
        rp.reproduce(tmp_path, NONE, registered=True, stream=io.StringIO(), workers=2)
    msg = str(info.value)
    assert "'failing'" in msg and "ValueError" in msg and "7.25" in msg and "\n" not in msg
    assert not (tmp_path / "report.md").exists()
