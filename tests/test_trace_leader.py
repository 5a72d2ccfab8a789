"""[leader] kind = "trace": a recorded trajectory from a CSV file, validated, resampled as the cycles are."""

from __future__ import annotations

import os
import tomllib
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import one_error, run_cli
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.models.leader import SpeedTrace, load_cycle_si, read_trace_csv
from aev_ocp.params import ParameterError
from aev_ocp.scenarios import ScenarioError, find_scenario, load_scenario

pytestmark = pytest.mark.quick


def _scenario(tmp_path, leader: str, name: str = "s.toml") -> str:
    """The shipped udds_platoon scenario with its [leader] table replaced, written beside the CSVs."""
    text = find_scenario("udds_platoon").read_text(encoding="utf-8")
    doc = tomllib.loads(text)
    head, _, rest = text.partition("[leader]")
    tail = rest[rest.index("\n[") :] if "\n[" in rest else ""
    p = tmp_path / name
    p.write_text(head + "[leader]\n" + leader + "\n" + tail, encoding="utf-8")
    assert doc["leader"]["kind"] == "cycle"
    return str(p)


def _write(path, header: str, rows) -> None:
    path.write_text(header + "\n" + "".join(",".join(repr(float(x)) for x in r) + "\n" for r in rows), encoding="utf-8")


def _grid(sc) -> np.ndarray:
    return np.linspace(0.0, sc.leader.times[-1] + 3.7, 4001)


def test_udds_trace_in_kmh_and_ms_is_the_cycle(tmp_path):
    """A CSV written from the UDDS data (km/h and ms, starting at t = 5 s) gives the same leader as
    kind = "cycle" to round-off, at every time; an m/s file equals the km/h file."""
    t, v = load_cycle_si("udds")
    _write(tmp_path / "kmh.csv", "t_ms,v_kmh", zip(1000 * t + 5000.0, 3.6 * v))
    _write(tmp_path / "ms.csv", "time,speed", zip(t, v))
    ref = load_scenario(find_scenario("udds_platoon"))
    kmh = load_scenario(
        _scenario(
            tmp_path,
            'kind = "trace"\nfile = "kmh.csv"\ntime_column = "t_ms"\n'
            'speed_column = "v_kmh"\ntime_unit = "ms"\nspeed_unit = "km/h"',
        )
    )
    ms = load_scenario(_scenario(tmp_path, 'kind = "trace"\nfile = "ms.csv"', "m.toml"))
    tt = _grid(ref)
    v_ref = ref.leader.speed_np(tt)
    np.testing.assert_allclose(kmh.leader.speed_np(tt), v_ref, rtol=1e-13, atol=1e-14)
    np.testing.assert_array_equal(ms.leader.speed_np(tt), v_ref)  # same numbers: bit for bit
    np.testing.assert_allclose(kmh.leader.position(tt), ref.leader.position(tt), rtol=1e-12, atol=1e-10)


def test_position_trace_recovers_a_quadratic_motion(tmp_path):
    """x(t) = x0 + 3.3 t + 0.45 t² in feet on an uneven grid: np.gradient (2nd order) is exact for a
    quadratic, so the speeds are v = (3.3 + 0.9 t)·0.3048 m/s at the samples."""
    rng = np.random.default_rng(7)
    t = np.cumsum(np.r_[0.0, rng.uniform(0.05, 0.2, 80)])
    x_ft = 123.4 + 3.3 * t + 0.45 * t**2
    _write(tmp_path / "pos.csv", "frame_time,Local_Y", zip(t + 2.5, x_ft))
    ts, vs = read_trace_csv(
        tmp_path / "pos.csv", time_column="frame_time", position_column="Local_Y", position_unit="ft"
    )
    np.testing.assert_allclose(ts, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(vs, (3.3 + 0.9 * t) * 0.3048, rtol=1e-9)


def test_filter_keeps_one_vehicle(tmp_path):
    rows = [(7, 0.0, 4.1), (9, 0.0, 30.0), (7, 0.1, 4.3), (9, 0.1, 31.0), (7, 0.2, 4.6)]
    (tmp_path / "many.csv").write_text("Vehicle_ID,time,speed\n" + "".join(f"{a},{b},{c}\n" for a, b, c in rows))
    t, v = read_trace_csv(tmp_path / "many.csv", filter_column="Vehicle_ID", filter_value=7, speed_column="speed")
    np.testing.assert_allclose(v, [4.1, 4.3, 4.6])
    np.testing.assert_allclose(t, [0.0, 0.1, 0.2])


@pytest.mark.parametrize(
    "body, words",
    [
        ("time,speed\n0,1.5\n1,2.5\n1,3.5\n", ["row 4", "'time'", "increase"]),
        ("time,speed\n0,1.5\n1,nan\n2,3.5\n", ["row 3", "'speed'", "finite"]),
        ("time,speed\n0,1.5\n1,-2.5\n2,3.5\n", ["row 3", "negative"]),
        ("time,speed\n0,1.5\n1,2.5\n31,3.5\n", ["rows 3-4", "gap", "max_gap_s"]),
        ("time,speed\n0,1.5\n1,abc\n", ["row 3", "'abc'"]),
        ("time,velocity\n0,1.5\n1,2.5\n", ["speed_column", "'speed'", "velocity"]),
        ("time,speed\n0,1.5\n", ["at least 2"]),
    ],
)
def test_bad_trace_names_the_row_and_field(tmp_path, body, words):
    (tmp_path / "bad.csv").write_text(body)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(_scenario(tmp_path, 'kind = "trace"\nfile = "bad.csv"'))
    msg = str(exc.value)
    assert "leader.file" in msg and "bad.csv" in msg
    for w in words:
        assert w in msg, msg


def test_max_gap_is_settable_and_paths_are_relative_to_the_scenario(tmp_path, monkeypatch):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "g.csv").write_text("time,speed\n0,1.5\n1,2.5\n31,3.5\n")
    path = _scenario(tmp_path, 'kind = "trace"\nfile = "sub/g.csv"\nmax_gap_s = 40')
    monkeypatch.chdir(tmp_path / "sub")  # the file is found from the scenario's folder, not the cwd
    sc = load_scenario(path)
    assert sc.leader.times[-1] == pytest.approx(31.0 / sc.units.time_s)
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario(_scenario(tmp_path, 'kind = "trace"\nfile = "missing.csv"'))
    with pytest.raises(ScenarioError, match="speed_unit"):
        load_scenario(_scenario(tmp_path, 'kind = "trace"\nfile = "sub/g.csv"\nspeed_unit = "knots"'))
    with pytest.raises(ParameterError, match="exactly one"):
        read_trace_csv(tmp_path / "sub" / "g.csv")


def test_example_follow_csv_trace_quick(tmp_path):
    """examples/follow_csv_trace.py --quick: both laws follow the recorded vehicle without an event, the
    position-derived leader agrees with the speed column to the file's rounding (3 decimals of ft and
    ft/s: well below 0.01 m/s), and its saved output loads back with the same metrics."""
    import sys
    from pathlib import Path

    import aev_ocp

    sys.path.insert(0, str(Path(__file__).parents[1] / "examples"))
    try:
        import follow_csv_trace
    finally:
        sys.path.pop(0)
    res = follow_csv_trace.main(quick=True, out=str(tmp_path))
    assert res["status"] == {"proposed": "ok", "ovfl": "ok"}
    assert 0 < res["position_speed_diff_mps"] < 0.01
    r = aev_ocp.load(tmp_path, run="ovfl")
    assert r.metrics()[2]["omega_model"] == res["metrics"]["ovfl"][2]["omega_model"]
    assert r.meta["output"]["settings"]["document"]["leader"]["filter_value"] == 1042


def test_study_over_a_trace_leader_hashes_the_data_and_finds_the_file(tmp_path, monkeypatch):
    """A study whose scenario follows a CSV: the task hash covers the CSV's content (a changed file is
    recomputed, not served from the store), and the file is found relative to the scenario wherever
    the study runs."""
    from aev_ocp.study import read_study, run_study

    t, v = load_cycle_si("udds")
    _write(tmp_path / "u.csv", "time,speed", zip(t[:120], v[:120]))
    _scenario(tmp_path, 'kind = "trace"\nfile = "u.csv"', "trace.toml")
    study = tmp_path / "st.toml"
    study.write_text(
        'name = "tr"\nscenarios = ["trace.toml"]\nreference = "ovfl"\n'
        '[overrides]\n"simulation.t_end" = 20.0\n'
        '[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.02, 0.04]\n'
        '[controllers]\nlaws = ["proposed", "ovfl"]\n'
    )
    monkeypatch.chdir(tmp_path.parent)
    keys = [tk.key for tk in read_study(study).tasks()]
    out = run_study(read_study(study), tmp_path / "out", executor="inprocess", report=False)
    assert out.n_tasks == 3 and all(r["status"] == "ok" for r in out.rows)  # OVFL ignores kappa: 1 task
    _write(tmp_path / "u.csv", "time,speed", zip(t[:120], 1.01 * v[:120]))
    keys2 = [tk.key for tk in read_study(study).tasks()]
    assert len(set(keys) & set(keys2)) == 0


def test_position_trace_of_a_vehicle_starting_from_rest(tmp_path):
    """At rest for 2 s, then 2.3 m/s² (exact, non-decreasing positions, given as a str path): accepted (the
    second-order derivative's undershoot at the start is clipped, speeds ≥ 0 and exact on the ramp); a
    position that decreases is refused naming its row."""
    t = np.arange(0.0, 6.0, 0.1)
    x = np.where(t < 2.0, 50.0, 50.0 + 0.5 * 2.3 * (t - 2.0) ** 2)
    _write(tmp_path / "rest.csv", "time,pos", zip(t, x))
    ts, vs = read_trace_csv(str(tmp_path / "rest.csv"), position_column="pos")
    assert np.all(vs >= 0.0) and vs[0] == 0.0
    ramp = ts > 2.15
    np.testing.assert_allclose(vs[ramp][:-1], 2.3 * (ts[ramp][:-1] - 2.0), rtol=1e-9)
    x_back = x.copy()
    x_back[40] -= 0.7
    _write(tmp_path / "back.csv", "time,pos", zip(t, x_back))
    with pytest.raises(ParameterError, match=r"row 42, column 'pos': the position decreases"):
        read_trace_csv(tmp_path / "back.csv", position_column="pos")


def test_traffic_keys_under_the_s9_formulation_are_an_error(tmp_path):
    """The mirror of the §9-keys check: a TrafficParams key with formulation = "s9" would be ignored."""
    from aev_ocp.scenarios import load_with_sets

    with pytest.raises(ScenarioError, match="time_headway_s"):
        load_with_sets(find_scenario("mpc_paper_single"), ["mpc.time_headway_s=3.0"])


@pytest.mark.parametrize(
    "end, ok", [(1e15 * (1 - 1e-12), True), (1e15, True), (1e15 * (1 + 1e-12), False), (6.3e262, False)]
)
def test_a_trace_too_long_to_hold_its_last_speed_is_refused(end: float, ok: bool) -> None:
    """The interpolant's far knot end + 1e6 must be a new knot: traces up to 1e15 model time are held, longer ones
    (e.g. a cycle in SI converted with a length unit of 1e-259 m) are refused naming the units."""
    from aev_ocp.models.leader import SpeedTrace

    if ok:
        tr = SpeedTrace((0.0, end / 2, end), (1.3, 2.1, 0.7))
        assert float(tr._interp(end + 5e5)) == pytest.approx(0.7)
    else:
        with pytest.raises(ParameterError, match="too long to hold .* choose units of everyday size"):
            SpeedTrace((0.0, end / 2, end), (1.3, 2.1, 0.7))


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)
def _trace_scenario(tmp_path: Path, trace: Path) -> Path:
    f = tmp_path / "trace.toml"
    f.write_text(
        f'name = "tr"\n[leader]\nkind = "trace"\nfile = "{trace}"\ntime_column = "t"\n'
        'speed_column = "v"\n[platoon]\nfollowers = 1\ngap0_first = 1.0\nspeed0_factor = 1.0\n[simulation]\n'
        "t_end_s = 2.0\n"
    )
    return f


def test_trace_field_too_long_is_bad_input(tmp_path, capsys):
    trace = tmp_path / "long.csv"
    trace.write_text("t,v\n0," + "1" * 200_000 + "\n1,2\n")
    rc, _, err = run_cli(
        ["simulate", str(_trace_scenario(tmp_path, trace)), "--no-plots", "--out", str(tmp_path / "o")], capsys
    )
    line = one_error(err)
    assert rc == 2 and "not a valid CSV" in line and "internal error" not in line


def test_trace_with_bom_is_read_and_passwd_is_not_echoed(tmp_path):
    from aev_ocp.models.leader import read_trace_csv
    from aev_ocp.params import ParameterError

    f = tmp_path / "bom.csv"
    f.write_bytes("\ufefft,v\n0,1.5\n0.5,2.5\n".encode())
    t, v = read_trace_csv(f, time_column="t", speed_column="v")
    np.testing.assert_array_equal(v, [1.5, 2.5])
    secret = tmp_path / "passwd"
    secret.write_text("root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1::/usr/sbin:/usr/sbin/nologin\n")
    with pytest.raises(ParameterError) as info:
        read_trace_csv(secret, time_column="t", speed_column="v")
    assert "root" not in str(info.value) and "CSV" in str(info.value)


def test_a_fifo_trace_is_refused(tmp_path):
    from aev_ocp.models.leader import read_trace_csv
    from aev_ocp.params import ParameterError

    os.mkfifo(tmp_path / "fifo.csv")
    with pytest.raises(ParameterError, match="not a regular file"):
        read_trace_csv(tmp_path / "fifo.csv", time_column="t", speed_column="v")


def test_long_trace_is_streamed(tmp_path):
    from aev_ocp.models.leader import read_trace_csv

    n = 50_000
    f = tmp_path / "long.csv"
    with f.open("w") as fh:
        fh.write("t,v,lane\n")
        fh.writelines(f"{0.1 * i:.1f},{10 + (i % 7) * 0.25},3\n" for i in range(n))
    tracemalloc.start()
    t, v = read_trace_csv(f, time_column="t", speed_column="v")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert t.size == n and v[8] == 10.25
    assert peak < 60 * n  # 60 B per row: the old list of row lists took ~370 B per row


def test_trace_is_read_only_as_far_as_the_run_needs(tmp_path, capsys):
    """A trace leader is read up to twice (t_end + the MPC look-ahead): a damaged row far past that is never read
    (so the file is not read to its end), while the samples the run uses are exactly those of a full read."""
    from aev_ocp.models.leader import read_trace_csv
    from aev_ocp.params import ParameterError
    from aev_ocp.scenarios import load_scenario

    f = tmp_path / "long.csv"
    rows = [f"{0.1 * i:.1f},{10 + (i % 7) * 0.25}" for i in range(3000)]  # 300 s at 0.1 s
    rows[2500] = "250.0,not-a-number"  # at 250 s: far past what a 3.5 s run needs
    f.write_text("t,v\n" + "\n".join(rows) + "\n")
    with pytest.raises(ParameterError, match="row 2502"):
        read_trace_csv(f, time_column="t", speed_column="v")  # the whole file: the damaged row is found
    t, v = read_trace_csv(f, time_column="t", speed_column="v", t_max_s=7.25)
    assert t.size == 74 and t[-1] == pytest.approx(7.3) and v[73] == 10 + (73 % 7) * 0.25
    sc = _trace_scenario(tmp_path, f)
    sc.write_text(sc.read_text().replace("t_end_s = 2.0", "t_end_s = 3.5"))
    s = load_scenario(sc)
    need_s = 2 * (3.5 + s.units.time_to_si(25 * 0.1))  # twice (t_end + MPCSettings' default look-ahead N dt)
    assert s.leader.times[-1] * s.units.time_s == pytest.approx(np.ceil(need_s * 10 - 1e-9) / 10)  # 1st sample past it
    rc, _, err = run_cli(["simulate", str(sc), "--no-plots", "--out", str(tmp_path / "o")], capsys)
    assert rc == 0, err
    sc.write_text(sc.read_text().replace("t_end_s = 3.5", "t_end_s = 260.0"))  # a run that reaches the bad row
    rc, _, err = run_cli(["simulate", str(sc), "--no-plots", "--out", str(tmp_path / "o2")], capsys)
    assert rc == 2 and "row 2502" in one_error(err)


def test_a_trace_read_for_a_short_run_refuses_a_longer_one_in_python(tmp_path):
    """The trace was read only as far as the parsed t_end needs: a longer run through replace() (on a scenario
    without its document) or run(t_end=...) is refused by name instead of holding the last speed read; through
    with_overrides the file is read again, far enough."""
    import dataclasses

    from aev_ocp.scenarios import ScenarioError, load_scenario

    f = tmp_path / "long.csv"
    f.write_text("t,v\n" + "\n".join(f"{0.1 * i:.1f},{10 + (i % 7) * 0.25}" for i in range(3000)) + "\n")
    s = load_scenario(_trace_scenario(tmp_path, f))  # t_end_s = 2.0
    assert s.leader.read_for_t_end == pytest.approx(s.t_end)
    short = s.replace(t_end=0.5 * s.t_end)  # shorter: fine
    assert short.t_end == pytest.approx(0.5 * s.t_end)
    bare = dataclasses.replace(s, document=None)
    with pytest.raises(ScenarioError, match="trace leader's file was read only"):
        bare.replace(t_end=40.0 * s.t_end)
    with pytest.raises(ScenarioError, match="trace leader's file was read only"):
        s.run(t_end=40.0 * s.t_end)
    longer = s.with_overrides({"simulation.t_end_s": 80.0})  # re-read far enough
    assert longer.leader.times[-1] * s.units.time_s > 160.0
    full = load_scenario(_trace_scenario(tmp_path, f)).with_overrides({"simulation.t_end_s": 400.0})
    assert full.leader.read_for_t_end is None  # the whole file was read: nothing to refuse


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(0.0, 30.0), min_size=2, max_size=12),
    st.lists(st.floats(0.05, 4.0), min_size=11, max_size=11),
    st.floats(-1.0, 50.0),
)
def test_a_traces_top_speed_is_exact_on_any_horizon(speeds, steps, t_end) -> None:
    """SpeedTrace.max_speed (a knot or an end of [0, t_end]) against the trace's own CasADi speed evaluated on a
    fine grid that also holds every knot and t_end: equal (to rounding); a grid without the knots never exceeds
    it. Horizons before the start, between knots, on a knot and after the end."""
    times = np.concatenate([[0.0], np.cumsum(steps[: len(speeds) - 1])])
    trace = SpeedTrace(tuple(times), tuple(speeds))
    top = trace.max_speed(t_end)
    end = max(t_end, 0.0)
    grid = np.linspace(0.0, end, 2001)
    probe = np.concatenate([grid, times[times <= end], [end]])
    assert top == pytest.approx(float(np.max(trace.speed_np(probe))), rel=1e-13, abs=1e-13)
    assert float(np.max(trace.speed_np(grid))) <= top + 1e-13
    on_knot = trace.max_speed(float(times[1]))
    assert on_knot == pytest.approx(max(speeds[0], speeds[1]), rel=1e-15)


def test_a_shipped_cycle_is_read_once_and_each_caller_gets_its_own_arrays() -> None:
    """load_cycle_si reads the package's file once per process, yet gives the values of a fresh read, in new
    arrays: a caller that writes into them changes no other caller's cycle."""
    from importlib import resources

    from aev_ocp.models import leader as mod

    fresh = read_trace_csv(
        resources.files("aev_ocp") / "data" / "cycles" / "hwfet.csv",
        time_column="time_s",
        speed_column="speed_mps",
        max_gap_s=None,
    )
    t1, v1 = load_cycle_si("HWFET")
    np.testing.assert_array_equal(t1, fresh[0])
    np.testing.assert_array_equal(v1, fresh[1])
    v1[:] = -7.25
    t2, v2 = load_cycle_si("hwfet")
    np.testing.assert_array_equal(v2, fresh[1])
    assert mod._shipped_cycle.cache_info().currsize >= 1
