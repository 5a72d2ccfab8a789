"""Issue 28, the small leftovers: a signal held back by interrupts.deferred() is raised by its own block however
it ends, folder locks follow a folder that was removed and made again, a second Ctrl-C cannot skip the kill of a
compiler, bad nested keys are echoed shortly, mpc.N is named as typed, and --time-limit stops a run in progress."""

from __future__ import annotations

import fcntl
import os
import shutil
import signal

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp import interrupts


# ----------------------------------------------------------------------------- interrupts.deferred


def test_a_signal_held_back_by_deferred_is_raised_when_its_block_ends_normally():
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                done = "the block ran to its end"  # held back: the handler does not cut the block
        assert done and info.value.__cause__ is None
        with interrupts.deferred():  # raised once: the next block is not interrupted again
            pass


def test_a_signal_held_back_by_deferred_is_raised_when_its_block_fails():
    """The block ends with another exception: the interrupt is raised at the end of that block (the failure as
    its cause), not by the next deferred() block of the same command."""
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                raise OSError(28, "No space left on device")
        assert isinstance(info.value.__cause__, OSError)
        with interrupts.deferred():  # nothing left pending
            pass
        with pytest.raises(interrupts.Interrupted):  # a KeyboardInterrupt of the block itself passes unchanged
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                raise interrupts.Interrupted("SIGINT")
        with interrupts.deferred():
            pass


def test_nested_deferred_blocks_raise_at_the_outermost_end_even_when_the_inner_one_fails():
    with interrupts.handle_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            with interrupts.deferred():
                try:
                    with interrupts.deferred():
                        os.kill(os.getpid(), signal.SIGINT)
                        raise ValueError("inner")
                except ValueError:
                    reached = True  # the inner block does not raise the interrupt: it is still held back
        assert reached and info.value.__cause__ is None


# ----------------------------------------------------------------------------- output-folder locks


def _locked_by_someone(folder) -> bool:
    """Whether another open file description of folder's lock file cannot take the lock (flock treats each
    open() independently, even within one process)."""
    from aev_ocp.results import LOCK

    fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def test_a_folder_removed_and_made_again_is_locked_again(tmp_path):
    from aev_ocp.results import claim_output_dir, output_lock, release_output_locks

    out = tmp_path / "o"
    try:
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])  # held until the command ends
        assert _locked_by_someone(out)
        shutil.rmtree(out)  # a notebook removes the folder and runs again into the same name
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])
        assert _locked_by_someone(out)  # the new folder is locked too (before: the cached path said 'held')
        os.unlink(out / ".aev-ocp.lock")  # only the lock file removed: taken again as well
        with output_lock(out):
            assert _locked_by_someone(out)
        assert _locked_by_someone(out)  # the claim's lock outlives the inner block, as before
        release_output_locks()
        assert not _locked_by_someone(out)
    finally:
        release_output_locks()


# ----------------------------------------------------------------------------- compiler process group


def _group_members(pgid: int) -> set[int]:
    """Live (not zombie) processes of process group ``pgid`` (Linux /proc)."""
    out = set()
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                with open(f"/proc/{p}/stat") as fh:
                    state, _ppid, pgrp = fh.read().rsplit(")", 1)[-1].split()[:3]
            except OSError:
                continue
            if int(pgrp) == pgid and state not in ("Z", "X"):
                out.add(int(p))
    return out


def test_a_second_ctrl_c_during_the_grace_wait_still_kills_the_compiler_group(tmp_path):
    """A tool (and its child) that ignore SIGTERM, as a hung compiler may: the first Ctrl-C sends the group
    SIGTERM and waits TOOL_STOP_GRACE_S; a second Ctrl-C in that wait goes straight to SIGKILL (before: it skipped
    the kill, and the whole group ran on)."""
    import threading
    import time

    from aev_ocp.compiled import TOOL_STOP_GRACE_S, run_tool

    pidf = tmp_path / "tool.pid"
    script = f'trap "" TERM; echo $$ > {pidf}; sleep 30 & wait; wait'

    def ctrl_c_twice() -> None:
        while not pidf.exists() or not pidf.read_text().strip():
            time.sleep(0.02)
        time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)  # interrupts the build: SIGTERM to the group, then the grace wait
        time.sleep(0.4)
        os.kill(os.getpid(), signal.SIGINT)  # in the grace wait

    timer = threading.Thread(target=ctrl_c_twice, daemon=True)
    t0 = time.perf_counter()
    with interrupts.handle_signals():
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            run_tool(["sh", "-c", script], tmp_path, 60.0)
        timer.join()
    assert time.perf_counter() - t0 < TOOL_STOP_GRACE_S + 0.5  # the second Ctrl-C cut the grace wait short
    pgid = int(pidf.read_text())
    deadline = time.monotonic() + 3.0
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = _group_members(pgid)
    if survivors:  # do not leave them running when the test fails
        os.killpg(pgid, signal.SIGKILL)
    assert survivors == set()


# ----------------------------------------------------------------------------- short echoes of bad values

_BIG_STR = "q" * 10_000
_BIG_TABLE = "{" + ", ".join(f"k{i} = {i}" for i in range(2000)) + "}"


def test_echo_is_repr_when_short_and_at_most_60_characters_otherwise():
    from aev_ocp.params import ECHO_CHARS, echo

    assert ECHO_CHARS == 60
    for v in (0.35, "udds", [1, 2.5, "a"], {"a": {"b": [1, 2]}}, (3,), None, True, -7):
        assert echo(v) == repr(v)
    long = {f"k{i}": i for i in range(2000)}
    assert echo(long) == repr(long)[:59] + "…"
    assert echo(_BIG_STR) == repr(_BIG_STR)[:59] + "…"
    deep: list = []
    for _ in range(100_000):  # repr() of this raises RecursionError
        deep = [deep]
    assert echo(deep) == "[" * 59 + "…"
    assert echo(-(10**5000)) == "-" + "9" * 58 + "…"  # repr() refuses integers of > 4300 digits


@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=90),
        lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=8), inner, max_size=8),
        max_leaves=20,
    )
)
@settings(max_examples=60, deadline=None)
def test_echo_never_exceeds_the_limit_and_keeps_short_values_whole(value):
    from aev_ocp.params import echo

    text = echo(value)
    assert len(text) <= 60
    full = repr(value)
    if len(full) <= 60:
        assert text == full
    else:
        assert text.endswith("…") and len(text) == 60


def _bad_scenario(tmp_path, extra: str):
    from pathlib import Path

    import aev_ocp

    base = (Path(aev_ocp.__file__).parent / "scenario_files" / "fig1a.toml").read_text()
    f = tmp_path / "bad.toml"
    f.write_text(base + extra)
    return f


@pytest.mark.parametrize(
    "extra, path, shown",
    [
        (f'\n[carfollowing.proposed]\nzz = "{_BIG_STR}"\n', "carfollowing.proposed.zz", "'qqq"),
        (f"\n[carfollowing.proposed]\nzz = {_BIG_TABLE}\n", "carfollowing.proposed.zz", "{'k0': 0, 'k1': 1"),
        (f"\n[carfollowing.ovm.deep]\nzz = {_BIG_TABLE}\n", "carfollowing.ovm.deep", "{'zz': {'k0': 0"),
        (f"\n[thermal.a.b]\nzz = {_BIG_TABLE}\n", "thermal.a", "{'b': {'zz': {'k0'"),
    ],
)
def test_a_bad_key_deep_in_a_scenario_names_its_path_and_echoes_a_short_value(tmp_path, capsys, extra, path, shown):
    from cli_helpers import one_error, run_cli

    f = _bad_scenario(tmp_path, extra)
    rc, _, err = run_cli(["simulate", str(f), "--out", str(tmp_path / "o")], capsys)
    line = one_error(err)
    assert rc == 2 and f"{path}" in line and shown in line and "…" in line
    assert len(line) < len(str(f)) + 400  # the value is echoed in <= 60 characters, not 10 000
    assert not (tmp_path / "o").exists()


def test_a_bad_study_value_and_a_long_set_value_are_echoed_shortly(tmp_path, capsys, monkeypatch):
    from pathlib import Path

    from cli_helpers import one_error, run_cli

    repo = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(repo)
    text = (repo / "studies" / "kappa_alpha_table1.toml").read_text()
    cases = [
        (text + f"\n[report.a.b]\nzz = {_BIG_TABLE}\n", [], "report.a"),
        (text.replace("values = [1.0, 1.5, 2.0, 3.0]", f'values = [1.0, "{_BIG_STR}"]'), [], "carfollowing.alpha"),
        (text.replace('name = "kappa_alpha_table1"', f'name = "{_BIG_STR}"'), [], "name = 'qqq"),
        (text, ["--set", f"carfollowing.kappa={_BIG_STR}"], "--set carfollowing.kappa = 'qqq"),
        (text, ["--set", f"carfollowing.beta.x={_BIG_STR}"], "override carfollowing.beta.x = 'qqq"),
    ]
    for i, (body, extra, word) in enumerate(cases):
        f = tmp_path / f"s{i}.toml"
        f.write_text(body)
        rc, _, err = run_cli(["study", str(f), *extra, "--out", str(tmp_path / f"o{i}")], capsys)
        line = one_error(err)
        assert rc == 2 and word in line and "…" in line and len(line) < len(str(f)) + 600, (i, line[:300])
        assert not (tmp_path / f"o{i}").exists()


# ----------------------------------------------------------------------------- mpc.N named as typed


def _refuse_too_large_horizons(tmp_path, capsys) -> None:
    from cli_helpers import one_error, run_cli

    for argv, n_max in (
        (["mpc", "mpc_paper_single", "--set", "mpc.N=1501"], 1500),
        (["mpc-export", "mpc_paper_single", "--set", "mpc.N=2000000"], 1500),
        (["mpc", "mpc_paper_platoon", "--set", "mpc.N=301"], 300),
    ):
        rc, _, err = run_cli([*argv, "--out", str(tmp_path / "o")], capsys)
        line = one_error(err)
        assert rc == 2 and f"{argv[-1].replace('=', ' = ')} is not allowed" in line, line
        assert f"lower mpc.N to at most {n_max}" in line and "MPCSettings" not in line, line
        assert not (tmp_path / "o").exists()  # nothing written


def test_a_too_large_mpc_horizon_names_mpc_N_and_the_limit_before_anything_is_built(tmp_path, capsys, monkeypatch):
    """Budget 1.5 GB at 1 MB per interval (limits.MPC_BYTES_PER_INTERVAL): 1500 intervals for one MPC vehicle,
    300 each for the five of mpc_paper_platoon; the message names mpc.N (what --set and [mpc] take), never
    the Python field MPCSettings.N, and the platoon is refused before its first NLP is compiled."""
    import aev_ocp.mpc.export
    import aev_ocp.mpc.report
    from aev_ocp.limits import MPC_BYTES_PER_INTERVAL
    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.mpc.scenario import check_mpc_setup
    from aev_ocp.scenarios import ScenarioError, load_scenario

    monkeypatch.setenv("AEV_OCP_MAX_MEMORY_GB", "1.5")
    assert MPC_BYTES_PER_INTERVAL == 1_000_000

    def built(*a: object, **k: object) -> None:  # "before anything is built": no controller, no run, no export
        raise AssertionError("an MPC was built")

    with monkeypatch.context() as m:
        for owner, name in (
            (MPCController, "__init__"),
            (aev_ocp.mpc.report, "run_comparison"),
            (aev_ocp.mpc.export, "export_mpc"),
        ):
            m.setattr(owner, name, built)
        _refuse_too_large_horizons(tmp_path, capsys)
    platoon = load_scenario("mpc_paper_platoon")
    for N, ok in ((299, True), (300, True), (301, False)):  # the five vehicles' budget: on, inside, outside
        sc = platoon.with_overrides({"mpc.N": N})
        if ok:
            check_mpc_setup(sc)
        else:
            with pytest.raises(ScenarioError, match=r"mpc\.N = 301 is not allowed: 5 MPC vehicles .*at most 300"):
                check_mpc_setup(sc)


# ----------------------------------------------------------------------------- --time-limit inside a run

_LONG = ["--set", "platoon.followers=15", "--set", "simulation.dt_out=50"]  # 2 s per compiled run at t_end 40 000


def test_simulate_time_limit_stops_a_compiled_run_in_progress(tmp_path, capsys, monkeypatch):
    """One compiled run of ~2 s (15 followers over 40 000 model time units, 2 runs) and --time-limit 0.5: the
    cascade is cancelled through its flag at the limit (the C call returns its 'stopped' code 2, and it is the
    only call: the second run never starts), the command says so (exit 1, as for runs not started) and writes no
    result file (before: the limit was looked at between runs only)."""
    import aev_ocp.simulate as simulate
    from cli_helpers import one_error, run_cli

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


# ----------------------------------------------------------------------------- study validation cost

_GRID = """
name = "grid"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.dt_out" = 0.05
"simulation.t_end" = 35.0
[[axes]]
key = "carfollowing.kappa"
values = [0.004, 0.011, 0.027, 0.045, 0.083, 0.12]
[[axes]]
key = "carfollowing.alpha"
values = [1.3, 1.7, 2.2, 2.6, 3.1]
[controllers]
laws = ["proposed", "ovfl"]
"""


def test_study_points_are_validated_without_sampling_the_leader_or_copying_the_base_per_layer(tmp_path, monkeypatch):
    """A 6 x 5 grid: every point's document is what applying the [overrides], the --set and the axis values
    to the base scenario in turn gives (computed here independently), yet the leader is sampled once (not
    once per point: a CasADi Function each) and the overrides and --set are applied once per base scenario."""
    from aev_ocp.models.leader import LeaderProfile
    from aev_ocp.scenarios import load_scenario
    from aev_ocp.study import points as points_mod
    from aev_ocp.study import read_study

    f = tmp_path / "grid.toml"
    f.write_text(_GRID)
    sampled, applied = [], []
    real_speed_np, real_apply = LeaderProfile.speed_np, points_mod.apply_to_document

    def speed_np(self, t):  # noqa: ANN001, ANN202
        sampled.append(np.size(t))
        return real_speed_np(self, t)

    def apply(doc, layer, file="<scenario>"):  # noqa: ANN001, ANN202
        applied.append(dict(layer))
        return real_apply(doc, layer, file)

    monkeypatch.setattr(LeaderProfile, "speed_np", speed_np)
    monkeypatch.setattr(points_mod, "apply_to_document", apply)
    sets = {"platoon.followers": 3}
    study = read_study(f, sets=sets)
    assert len(study.points) == 30
    assert sampled.count(1) <= 1  # v_l(0) for speed0_factor: once for the equal leaders of all points
    assert len(applied) == 2 + 30  # [overrides] and --set once, then each point's axis values
    base = dict(load_scenario("table1").document)
    base.setdefault("name", "table1")
    over = {"simulation.dt_out": 0.05, "simulation.t_end": 35.0}
    for p in study.points:
        want = real_apply(real_apply(real_apply(base, over), sets), p.values)
        assert p.document == want


def test_a_study_override_of_a_swept_key_is_refused_not_dropped(tmp_path, capsys):
    """[overrides] (or a base scenario's own overrides) setting a key an axis sweeps, or its SI twin, was
    dropped at every point without a word, whatever its value (a 2000-entry table ran the study)."""
    from cli_helpers import one_error, run_cli

    cases = [
        ('"carfollowing.kappa" = 0.5', "[overrides] carfollowing.kappa = 0.5 would be ignored: axes[0] sweeps"),
        (f'"carfollowing.alpha" = {_BIG_TABLE}', "[overrides] carfollowing.alpha = {'k0': 0, 'k1': 1,"),
    ]
    for i, (line, word) in enumerate(cases):
        f = tmp_path / f"g{i}.toml"
        f.write_text(_GRID.replace('"simulation.t_end" = 35.0', f'"simulation.t_end" = 35.0\n{line}'))
        rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / f"o{i}")], capsys)
        assert rc == 2 and word in one_error(err), err
        assert not (tmp_path / f"o{i}").exists()
    inline = _GRID.replace(
        'scenarios = ["table1"]',
        'scenarios = [{ scenario = "table1", label = "t1", overrides = { "carfollowing.kappa" = 0.2 } }]',
    )
    f = tmp_path / "inline.toml"
    f.write_text(inline)
    rc, _, err = run_cli(["study", str(f), "--out", str(tmp_path / "o_inline")], capsys)
    assert rc == 2 and "scenario 't1' overrides carfollowing.kappa = 0.2 would be ignored" in one_error(err)


# ----------------------------------------------------------------------------- a stopped pool at exit


def test_a_stopped_pool_has_closed_its_manager_thread_before_the_process_exits():
    """study --time-limit with a pool: after _stop_pool the pool's manager thread has finished closing its
    wake-up pipe; before, the interpreter's exit hook could write to it while the thread closed it ('OSError:
    [Errno 9] Bad file descriptor' traceback after the stop message, 2 runs in 16 of the probe's try)."""
    import multiprocessing as mp
    import time
    from concurrent.futures import ProcessPoolExecutor

    from aev_ocp.study.runner import _stop_pool

    ex = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
    futures = [ex.submit(time.sleep, 30.0) for _ in range(3)]
    deadline = time.monotonic() + 20.0
    while not futures[0].running() and time.monotonic() < deadline:
        time.sleep(0.02)
    manager = ex._executor_manager_thread
    wakeup = ex._executor_manager_thread_wakeup
    assert manager is not None and manager.is_alive()
    _stop_pool(ex)
    assert not manager.is_alive() and wakeup._closed
    assert all(f.done() for f in futures)


def test_a_worker_stopped_halfway_through_sending_its_result_does_not_hang_the_exit():
    """A worker stopped (SIGTERM) while it wrote its result leaves half a message in the result pipe: the pool's
    manager thread then waited for the rest for ever, and the process's exit with it (1 study --time-limit run
    in 16 hung after its stop message). Half a message is written here as such a worker would leave it."""
    import multiprocessing as mp
    import struct
    import time
    from concurrent.futures import ProcessPoolExecutor

    from aev_ocp.study.runner import _stop_pool

    ex = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
    futures = [ex.submit(time.sleep, 600.0) for _ in range(2)]
    manager = ex._executor_manager_thread
    os.write(ex._result_queue._writer.fileno(), struct.pack("!i", 4000) + b"\x80\x04" + b"x" * 500)
    t0 = time.monotonic()
    _stop_pool(ex)
    # not hung, not waiting for the tasks: a bound far below their 600 s, far above any load's delay
    assert not manager.is_alive() and time.monotonic() - t0 < 120.0
    assert all(f.done() for f in futures)
