"""Adversarial probe of the surfaces of the loop/calibration/replay/stability wave (issue 38, "new tries of your own"):
the closed loop's command stages ([limits] command_filter_s, command_jerk_max_mps3, safety_layer), the SI law keys
and [carfollowing] calibrated, calibration (calibrate/save/load), the replay, the map powertrain and named cells,
stability --ring --aev, and the safety suite's memory budget.

It uses the probes' shared harness (``tools/probes/harness.py``) (each try in its own folder and process group, classified
``ok``/``minor``/``defect``). Run: ``python tools/probes/probe_new_surfaces.py [--only SUBSTRING] [--json OUT]``; prints
every try and a table per area, writes the JSON (default ``probe_new_surfaces.json``).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import Try, api_expect, api_ok, run_probe, scen, write  # noqa: E402 - the probes' shared harness


def csv(rows: str) -> str:
    return "time_s,speed_mps\n" + rows.replace(";", "\n") + "\n"


def tries() -> list[Try]:  # one try a line: a table
    # fmt: off
    T: list[Try] = []
    P = "p.toml"
    sim = ["simulate", P, "--out", "o", "--no-plots", "--set"]
    w = write(P, scen())
    # --- the loop's command stages ([limits]) -------------------------------------------------------------------------
    for key, val, ok, says in [
        ("limits.command_filter_s", "nan", 2, "command_filter_s"), ("limits.command_filter_s", "-1", 2, "command_filter_s"),
        ("limits.command_filter_s", "1e300", 2, "command_filter_s"), ("limits.command_filter_s", "5", 0, None),
        ("limits.command_filter_s", "5.01", 2, "command_filter_s"), ("limits.command_jerk_max_mps3", "0", 0, None),
        ("limits.command_jerk_max_mps3", "1e-300", 2, "command_jerk_max_mps3"), ("limits.command_jerk_max_mps3", "0.1", 0, None),
        ("limits.command_jerk_max_mps3", "-2", 2, "command_jerk_max_mps3"), ("limits.safety_layer", "2", 2, "safety_layer"),
        ("limits.safety_layer", '"yes"', 2, "safety_layer"),
        # --- SI law keys and calibrated sets --------------------------------------------------------------------------
        ("carfollowing.alpha_per_s", "-1", 2, "alpha_per_s"), ("carfollowing.h_scale_m", "0", 2, "h_scale_m"),
        ("carfollowing.v_scale_mps", "inf", 2, "v_scale_mps"), ("carfollowing.calibrated", '"nope"', 2, "calibrated"),
        ("carfollowing.calibrated", '"/etc"', 2, "calibrated"), ("carfollowing.calibrated", "3", 2, "calibrated"),
        ("carfollowing.idm.a_mps2", "0", 2, "a_mps2"), ("carfollowing.idm.T_s", "-1", 2, "T_s"),
        ("vehicle.powertrain", '"mapx"', 2, "powertrain"), ("vehicle.powertrain", "3", 2, "powertrain"),
        ("cell.name", '"nope"', 2, "cell.name"), ("cell.name", "3", 2, "cell.name"),
    ]:
        T.append(Try(key.split(".")[0], f"{key} = {val}", [*sim, f"{key}={val}"], setup=w, ok=(ok,), says=says))
    # --- calibration (Python API) -------------------------------------------------------------------------------------
    cal = "from aev_ocp.calibration import calibrate, save, load\n"
    for name, body, says in [
        ("speed 1e300", "calibrate('idm', [5.0, 10.0, 1e300], [20.0, 30.0, 40.0])", "speed_mps"),
        ("2-D target", "calibrate('idm', [[5.0, 10.0]], [[20.0, 30.0]])", "speed_mps"),
        ("string target", "calibrate('idm', ['a', 'b'], [1.0, 2.0])", "speed_mps"),
        ("bool target", "calibrate('idm', [True, False], [20.0, 30.0])", "speed_mps"),
        ("free as a string", "calibrate('idm', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0], free='T_s')", "free"),
        ("free without effect", "calibrate('idm', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0], free=['a_mps2'])", "a_mps2"),
        ("free unknown", "calibrate('idm', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0], free=['nope'])", "nope"),
        ("law unknown", "calibrate('zzz', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0])", "zzz"),
        ("load binary", "open('b.toml', 'wb').write(b'\\xff\\xfe')\nload('b.toml')", "b.toml"),
        ("load a folder", "load('.')", "cannot read"),
        ("save under a file", "open('f', 'w').write('x')\nsave(calibrate('idm', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0]), 'f/x.toml')", "cannot write"),
    ]:
        T.append(Try("calibration", name, script=api_expect(cal + body, says=says), ok=(0,)))
    T.append(Try("calibration", "save a quoted name and load it", script=api_ok(cal + "c = calibrate('idm', [5.0, 10.0, 15.0], [21.0, 32.0, 43.0])\nassert load(save(c, 'q.toml', target_name='a\"b'))[1]['target']['name'] == 'a\"b'"), ok=(0,)))
    # --- replay -------------------------------------------------------------------------------------------------------
    for name, rows, ok, says in [
        ("speed 1e300", "0,0;1,1e300;2,3", 2, "speed_mps"), ("top speed 62.6", "0,0;10,62.6;20,60", 2, "v_max_mps"),
        ("top speed on 62.5", "0,0;10,62.5;20,60", 0, None), ("jump 60 m/s in 1 us", "0,0;1e-6,60;2,3", 2, "a_min_mps2"),
        ("grip on 8 m/s2", "0,0;1,8;2,0", 0, None), ("grip 8.01 m/s2", "0,0;1,8.01;2,3", 2, "a_min_mps2"),
        ("nan speed", "0,0;1,nan;2,3", 2, "speed_mps"), ("negative speed", "0,0;1,-5;2,3", 2, "speed_mps"),
        ("repeated time", "0,0;0,1;2,3", 2, "time_s"), ("one sample", "0,0", 2, "2 samples"),
    ]:
        T.append(Try("replay", name, ["replay", "t.csv"], setup=write("t.csv", csv(rows)), ok=(ok,), says=says))
    T.append(Try("replay", "--soc0 nan", ["replay", "udds", "--soc0", "nan"], ok=(2,), says="soc0"))
    T.append(Try("replay", "--soc0 1.5", ["replay", "udds", "--soc0", "1.5"], ok=(2,), says="soc0"))
    T.append(Try("replay", "--soc0 0 (empty cell)", ["replay", "udds", "--soc0", "0"], ok=(1,), says="soc_out_of_range"))
    T.append(Try("replay", "--json onto a folder", ["replay", "hwfet", "--json", "."], ok=(2,), says="--json"))
    T.append(Try("replay", "binary csv", ["replay", "b.csv"], setup=write("b.csv", b"\xff\xfe"), ok=(2,), says="b.csv"))
    T.append(Try("replay", "no such file", ["replay", "nowhere.csv"], ok=(2,), says="nowhere.csv"))
    # --- stability --ring --aev ---------------------------------------------------------------------------------------
    st = ["stability", "--law", "ovm", "--ring", "22", "--spacing-m", "10", "--no-plots", "--out", "o"]
    for name, extra, ok, says in [
        ("aev-count 0", ["--aev", "proposed", "--aev-count", "0"], 0, None), ("aev-count 22 (all)", ["--aev", "proposed", "--aev-count", "22"], 0, None),
        ("aev-count 23", ["--aev", "proposed", "--aev-count", "23"], 2, "--aev-count"), ("aev-count -1", ["--aev", "proposed", "--aev-count", "-1"], 2, "--aev-count"),
        ("aev unknown", ["--aev", "zzz"], 2, "--aev"), ("aev mpc", ["--aev", "mpc"], 2, "--aev"),
        ("aev-count without --aev", ["--aev-count", "3"], 2, "--aev-count"), ("delay without --aev", ["--delay-s", "3"], 2, "--delay-s"),
        ("delay -1", ["--aev", "proposed", "--delay-s", "-1"], 2, "--delay-s"), ("delay nan", ["--aev", "proposed", "--delay-s", "nan"], 2, "--delay-s"),
        ("delay on 5 s", ["--aev", "proposed", "--delay-s", "5"], 0, None), ("delay 1e300", ["--aev", "proposed", "--delay-s", "1e300"], 2, "--delay-s"),
    ]:
        T.append(Try("stability", name, [*st, *extra], ok=(ok,), says=says))
    T.append(Try("stability", "ring 1 with --aev", ["stability", "--law", "ovm", "--ring", "1", "--spacing-m", "10", "--aev", "idm", "--out", "o"], ok=(2,), says="--ring"))
    T.append(Try("stability", "spacing 1e300 with --aev", ["stability", "--law", "ovm", "--ring", "22", "--spacing-m", "1e300", "--aev", "idm", "--out", "o"], ok=(2,), says="length"))
    # --- the safety suite's memory budget -----------------------------------------------------------------------------
    sf = ["safety", "--quick", "--controllers", "proposed+layer", "--actuators", "ideal", "--workers", "1", "--no-plots", "--out", "o"]
    T.append(Try("safety", "memory budget abc", sf, env={"AEV_OCP_MAX_MEMORY_GB": "abc"}, ok=(2,), says="AEV_OCP_MAX_MEMORY_GB"))
    T.append(Try("safety", "memory budget 1e-6 GB", sf, env={"AEV_OCP_MAX_MEMORY_GB": "1e-6"}, ok=(2,), says="AEV_OCP_MAX_MEMORY_GB"))
    # --- the closed loop's estimates (Python API) ---------------------------------------------------------------------
    T.append(Try("loop", "NaN gap estimate stops the run", script=api_ok(
        "import dataclasses\nfrom aev_ocp.control import ClosedLoop\nfrom aev_ocp.estimation import EKF, Sensors\nfrom aev_ocp.mpc.cycles import cycle_scenario\n"
        "sc = cycle_scenario('udds', 30.0)\nclass E:\n    name = 'bad'\n    def __init__(s, i): s.i = i\n    def reset(s, m): return s.i.reset(m)\n"
        "    def update(s, m): return dataclasses.replace(s.i.update(m), gap_m=float('nan'))\n    def describe(s): return {}\n"
        "r = ClosedLoop(sc.leader, [sc.law('proposed')], sc.ev, sensors=Sensors(seed=2), estimator=lambda ev, s, off, i: E(EKF(ev, s, ocv_offset_V=off)), law_dt=0.2).run(sc.gaps0, sc.speeds0, sc.t_end)\n"
        "assert r.status == 'estimation_failed', r.status"), ok=(0,)))
    # fmt: on
    return T


def main(argv: list[str] | None = None) -> int:
    return run_probe(tries, argv, __doc__.splitlines()[0], "probe_new_surfaces.json", jobs=1, details=False)


if __name__ == "__main__":
    sys.exit(main())
