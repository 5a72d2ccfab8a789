"""The shared progress helper (ETA, time limit) and the runs that use it stop cleanly at their time limit."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from cli_helpers import one_error, run_cli

from aev_ocp.control import ClosedLoop, ControlSequence
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.params import ParameterError
from aev_ocp.progress import Progress, TimeLimitReached, format_seconds

pytestmark = pytest.mark.quick


class Clock:
    """A settable clock [s]."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_eta_is_the_rate_since_the_first_update():
    """Set-up before the first step (e.g. a solver build) does not enter the ETA: 7 s of set-up, then
    12 steps in 3 s -> 0.25 s per step, 188 steps left -> 47 s."""
    clock, buf = Clock(), io.StringIO()
    p = Progress("run", 200, clock=clock, stream=buf, every_s=5.0)
    clock.t += 7.0
    p.update(0, what="step")
    assert math.isnan(p.eta_s())
    clock.t += 3.0
    p.update(12, what="step")
    assert p.eta_s() == pytest.approx(0.25 * 188)
    assert p.elapsed_s() == pytest.approx(10.0)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("[run] step 0/200 (0 %)")  # the next line is due after 5 s
    clock.t += 5.0
    p.update(32, what="step")
    assert buf.getvalue().splitlines()[-1] == "[run] step 32/200 (16 %), 15 s elapsed, ETA 42 s"  # 8 s/32 steps × 168
    assert p.eta_s() == pytest.approx(8.0 / 32 * 168)


def test_time_limit_raises_after_it_passes_and_children_share_it():
    clock = Clock()
    p = Progress("run", 10, clock=clock, time_limit_s=4.5, stream=io.StringIO())
    clock.t += 4.4
    p.update(3)
    assert p.remaining_s() == pytest.approx(0.1)
    c = p.child("part", 5)
    clock.t += 0.2
    assert p.expired() and c.expired()
    with pytest.raises(TimeLimitReached, match="4.5 s"):
        p.update(4)
    with pytest.raises(TimeLimitReached):
        c.check()
    for bad in (0, -1.0, math.inf, math.nan, True):
        with pytest.raises(ParameterError, match="time limit"):
            Progress("x", time_limit_s=bad)


def test_format_seconds():
    assert [format_seconds(x) for x in (3.25, 42.4, 185.0, 7325.0, math.nan)] == [
        "3.2 s",
        "42 s",
        "3 min 05 s",
        "2 h 02 min",
        "?",
    ]


def test_closed_loop_stops_at_the_time_limit_with_the_prefix_of_the_full_run():
    """A progress that raises TimeLimitReached after step 7 stops the loop there: status 'time_limit'
    (an event of the whole run), and the trajectory is exactly the first 7 steps of the full run."""
    dt = 0.25
    a = tuple(0.3 * math.sin(0.7 * k) for k in range(20))
    loop = ClosedLoop(ConstantSpeed(1.3), [ControlSequence(a, dt, "seq")])
    full = loop.run([2.1], [1.1], 20 * dt)
    steps = []

    def progress(t: float, t_end: float) -> None:
        steps.append(t)
        if len(steps) == 7:
            raise TimeLimitReached("time limit of 1 s reached")

    part = loop.run([2.1], [1.1], 20 * dt, progress=progress)
    assert full.status == "ok" and part.status == "time_limit"
    assert part.events[0].vehicle == -1 and "partial" in part.events[0].message and "whole run" in str(part.events[0])
    assert part.t[-1] == pytest.approx(7 * dt)
    k = part.t.size
    for name in ("gap", "speed", "S", "omega", "heat_J"):
        np.testing.assert_array_equal(getattr(part, name), getattr(full, name)[:k], err_msg=name)
    m = part.metrics()[0]
    assert m["run_status"] == "time_limit" and m["status"] == "ok" and m["duration_model"] == pytest.approx(7 * dt)


def test_study_time_limit_stores_finished_tasks_and_resumes(tmp_path):
    from aev_ocp.study import TimeLimitStop, read_study, run_study
    from aev_ocp.study.cli import _with_sets
    from aev_ocp.study.spec import parse_study

    study = _with_sets("studies/kappa_alpha_table1.toml", {"simulation.t_end": 1.0}, parse_study)
    assert read_study("studies/kappa_alpha_table1.toml").name == study.name
    with pytest.raises(TimeLimitStop, match=r"\d+ of 36 tasks stored"):
        run_study(study, tmp_path, executor="inprocess", report=False, time_limit_s=1e-9, progress_stream=io.StringIO())
    stored = len(list((tmp_path / "points").glob("*.json")))
    assert 1 <= stored < 36
    buf = io.StringIO()
    out = run_study(study, tmp_path, executor="inprocess", report=False, progress_stream=buf)
    assert out.n_tasks == 36 and f"({stored} stored" in buf.getvalue() and "ETA" in buf.getvalue()


def test_reproduce_counter_has_a_fixed_denominator_and_reaches_n_only_at_the_end() -> None:
    """aev_ocp.reproduce.Progress: N never moves; a line beyond its section's declared steps repeats k (a
    sub-step), a section that reports fewer moves k past its skipped steps; k never exceeds N - 1 before the
    final line, which alone shows N/N. Times come from a fake clock (never the wall)."""
    from aev_ocp.reproduce import Progress as ReproduceProgress

    buf = io.StringIO()
    ticks = iter(float(x) for x in range(100))
    p = ReproduceProgress(2 + 3 + 4 + 1 + 1, stream=buf, clock=lambda: next(ticks) * 1.5)
    for steps, lines in ((2, 4), (3, 1), (4, 4), (1, 1)):  # reports more, fewer, exactly, the writing step
        p.begin(steps)
        for _ in range(lines):
            p("x")
        p.end()
    p.done("done: report.md, report.html")
    lines = buf.getvalue().splitlines()
    heads = [line.split("]")[0] + "]" for line in lines]
    assert heads == [
        "[1/11]",
        "[2/11]",
        "[2/11]",
        "[2/11]",
        "[3/11]",
        "[6/11]",
        "[7/11]",
        "[8/11]",
        "[9/11]",
        "[10/11]",
        "[11/11]",
    ]
    assert lines[-1].startswith("[11/11] done: report.md, report.html (") and lines[-1].endswith(" s)")
    assert lines[0].endswith("(1.5 s)")  # the fake clock: 1.5 s per tick after the start


def test_reproduce_counter_never_shows_n_before_done() -> None:
    """A run whose sections report far more lines than declared (OCP-D's iterations) stays below N."""
    from aev_ocp.reproduce import Progress as ReproduceProgress

    buf = io.StringIO()
    p = ReproduceProgress(3, stream=buf, clock=lambda: 0.0)
    p.begin(2)
    for _ in range(7):
        p("iteration")
    p.end()
    assert all(not line.startswith("[3/3]") for line in buf.getvalue().splitlines())
    p.done("done")
    assert buf.getvalue().splitlines()[-1].startswith("[3/3] done")


def test_reproduce_final_line_names_both_reports_and_the_verdict() -> None:
    from aev_ocp.report_sections import Claim
    from aev_ocp.reproduce import verdict

    claims = [Claim("a", "holds", "", "x"), Claim("b", "fails", "", "y"), Claim("c", "partly", "", "z")]
    assert verdict(claims) == "1 of 3 paper claims hold, 1 fail or disagree: b"
    assert verdict([]) == "no paper claim checked"


LONG_TASK_STUDY = """
name = "long_task"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.t_end" = 3000.0
"simulation.dt_out" = 0.5
"platoon.followers" = 2
[[axes]]
key = "platoon.gap0_first"
values = [0.35]
[controllers]
laws = ["ovfl"]
[[controllers.mpc]]
label = "m"
"""


@pytest.mark.parametrize("executor", ["--workers", "--dask-local"])
def test_study_time_limit_holds_while_one_long_task_computes(tmp_path, capsys, monkeypatch, executor):
    """--time-limit with one worker (process pool or local Dask cluster) that computes the fast OVFL task first, then
    an MPC task that runs for minutes (3000 s of model time): the command, run in this process on a clock that
    passes the limit the moment the OVFL result is recorded, stops at the limit while the worker computes the MPC
    task (the study must look at the limit while it waits, not only when a result arrives): exit 1 with the
    time-limit line, exactly the OVFL task stored, no temporary file, and the worker processes gone. (issue 40: was
    the command in a subprocess on the real clock, waiting out 5 and 6 s limits kept well after the OVFL result
    under load; the study's time limit on the real clock: test_study_time_limit_stores_finished_tasks_and_resumes
    and test_study_pool.py's test_time_limit_passing_as_the_last_task_ends_is_not_a_stop.)"""
    if executor == "--dask-local":
        pytest.importorskip("dask.distributed")
    from test_study_pool import _descendants

    from aev_ocp.study import runner

    class LimitPassesAfterFirstResult(runner.Progress):
        """The real clock, pushed a day ahead once a result has been recorded (after that update's own check)."""

        passed = False

        def __init__(self, *a, **kw) -> None:  # noqa: ANN002, ANN003
            import time

            super().__init__(*a, clock=lambda: time.perf_counter() + (86400.0 if self.passed else 0.0), **kw)

        def update(self, done, *a, **kw) -> None:  # noqa: ANN001, ANN002, ANN003
            super().update(done, *a, **kw)
            self.passed = self.passed or done >= 1

    monkeypatch.setattr(runner, "Progress", LimitPassesAfterFirstResult)
    f = tmp_path / "s.toml"
    f.write_text(LONG_TASK_STUDY)
    out = tmp_path / "o"
    me = __import__("os").getpid()
    kids = _descendants(me)
    rc, _, err = run_cli(
        ["study", str(f), "--out", str(out), executor, "1", "--no-report", "--time-limit", "600"], capsys
    )
    assert rc == 1 and "stopped by --time-limit 600 s" in err, err[-800:]
    stored = list((out / "points").glob("*.json"))
    assert len(stored) == 1 and json.loads(stored[0].read_text())["controller"] == "ovfl", stored
    assert not [q for q in out.rglob("*") if ".tmp" in q.name]
    assert _descendants(me) - kids == set()  # the worker processes (the pool's; the cluster's scheduler, worker) gone


# ----------------------------------------------------------------------------- from the issue-28 small leftovers (test_reliability_minors.py)
_LONG = ["--set", "platoon.followers=15", "--set", "simulation.dt_out=50"]  # 2 s per compiled run at t_end 40 000


def test_simulate_time_limit_stops_a_compiled_run_in_progress(tmp_path, capsys, monkeypatch):
    """One compiled run of ~2 s (15 followers over 40 000 model time units, 2 runs) and --time-limit 0.5: the
    cascade is cancelled through its flag at the limit (the C call returns its 'stopped' code 2, and it is the
    only call: the second run never starts), the command says so (exit 1, as for runs not started) and writes no
    result file (before: the limit was looked at between runs only)."""
    import aev_ocp.simulate as simulate

    warm = ["simulate", "table1", *_LONG, "--set", "simulation.t_end=100", "--no-plots"]
    assert run_cli([*warm, "--out", str(tmp_path / "warm")], capsys)[0] == 0  # the cascade's library compiled
    codes: list[int] = []
    real = simulate._interruptible_call

    def recorded(fn, args, cancel):  # the C call's own return code
        def c_run(*a):
            codes.append(int(fn(*a)))
            return codes[-1]

        return real(c_run, args, cancel)

    monkeypatch.setattr(simulate, "_interruptible_call", recorded)
    out = tmp_path / "o"
    rc, _, err = run_cli(
        ["simulate", "table1", *_LONG, "--set", "simulation.t_end=40000", "--no-plots", "--time-limit", "0.5"]
        + ["--out", str(out)],
        capsys,
    )
    assert rc == 1 and codes == [2], (rc, codes)  # stopped inside the one C call it started
    assert "--time-limit 0.5 s passed before the first run finished; nothing written" in one_error(err)
    assert not [p.name for p in out.iterdir() if not p.name.startswith((".aev-ocp", "aev-ocp-run"))]


def test_the_python_integrator_checks_the_time_limit_between_chunks():
    """The CVODES path (no C compiler) checks the same deadline between its chunks (5 model time units): with a
    clock that moves 0.1 s a reading, a 0.5 s limit stops the run after a few chunks of its 8000."""
    from aev_ocp.progress import Progress, TimeLimitReached, check_deadline, time_limited
    from aev_ocp.scenarios import load_scenario
    from aev_ocp.simulate import simulate_platoon

    sc = load_scenario("table1")
    kw = {**sc.simulate_kwargs(), "t_end": 40000.0, "dt_out": 5.0}  # ~90 s with CVODES on a quiet machine
    readings: list[float] = []

    def clock() -> float:
        readings.append(0.1 * len(readings))
        return readings[-1]

    with pytest.raises(TimeLimitReached), time_limited(Progress("", time_limit_s=0.5, clock=clock)):
        simulate_platoon(sc.leader, list(sc.runs()[0][1]), method="cvodes", **kw)
    assert 6 <= len(readings) <= 12, len(readings)  # stopped at the limit's reading, not at the run's end
    check_deadline()  # outside the block the limit no longer applies
    with time_limited(Progress("", time_limit_s=30.0)):
        check_deadline()  # inside the limit: nothing raised
