"""Reliability probe of the ring (its start, its drivers, its cuts, Ctrl-C and --time-limit
in the compiled ring), SUMO (sizes, sumo_args, options, networks, --controller mpc), physical ranges of the
[thermal] and [cell] tables, stability --ring, and loading saved SUMO runs and studies.

It uses the probes' shared harness (``tools/probes/harness.py``) (each try in its own folder and process group, classified
``ok``/``minor``/``defect``: a traceback, a hang, an unexpected exit code, a temporary left behind, an error line
that does not name the key). Run: ``python tools/probes/probe_ring_sumo_inputs.py [--only SUBSTRING] [--json OUT]``;
prints every try and a table per area, writes the JSON (default ``probe_ring_sumo_inputs.json``).
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import (  # noqa: E402 - the probes' shared harness
    run_probe,
    STUDY,
    Try,
    api_expect,
    api_ok,
    chain,
    run_cli,
    scen,
    write,
)

RING = """\
name = "pring"
[ring]
length_m = 230.0
vehicles = 22
t_end_s = 30.0
noise_mps2 = 0.1
seed = 2
{extra}
"""


def ring(extra: str = "", **keys: str) -> str:
    text = RING.replace("{extra}", extra)
    for k, v in keys.items():
        text = text.replace(f"{k} = ", f"# {k} = ") + ""
        text = text.replace("[ring]\n", f"[ring]\n{k} = {v}\n", 1)
    return text


def back_to_front(n: int = 22, length: float = 230.0) -> str:
    x = sorted((-(i * length / n)) % length for i in range(n))  # increasing: each car behind its predecessor
    return f"[ring.initial]\npositions_m = {x}\nspeeds_mps = {[3.0] * n}\n"


SUMO = """\
name = "psumo"
[sumo]
network = "ring"
t_end_s = 3.0
share = 0.25
{extra}
"""


def sumo(extra: str = "") -> str:
    return SUMO.replace("{extra}", extra)


def cell_file(volts: list[float]) -> str:
    """The shipped A123 cell file with an inline OCV curve of ``volts`` at SOC 0, 0.3, 0.6, 1."""
    from aev_ocp.cells import shipped_cells

    text = shipped_cells()["a123_anr26650"].read_text(encoding="utf-8").split("[ocv]")[0]
    return text + f'[ocv]\nsoc = [0.0, 0.3, 0.6, 1.0]\nocv_V = {volts}\nsource = "probe"\n'


def tries() -> list[Try]:  # one try a line: a table
    # fmt: off
    T: list[Try] = []
    R, S = "r.toml", "s.toml"
    rg = ["ring", R, "--out", "o", "--no-plots"]
    su = ["sumo", S, "--out", "o", "--no-plots"]
    # --- item 1, 2: the ring's start ----------------------------------------------------------------------------------
    T.append(Try("ring/start", "initial back to front", rg, setup=write(R, ring(back_to_front())), ok=(2,), says="positions_m"))
    T.append(Try("ring/start", "initial speed 1e300", rg, setup=write(R, ring("[ring.initial]\npositions_m = " + str([(-(i * 230.0 / 22)) % 230.0 for i in range(22)]) + "\nspeeds_mps = " + str([3.0] * 21 + [1e300]) + "\n")), ok=(2,), says="speeds_mps"))
    T.append(Try("ring/start", "initial speed above [limits] v_max", rg, setup=write(R, "[limits]\nv_max_mps = 20.0\n" + ring("[ring.initial]\npositions_m = " + str([(-(i * 230.0 / 22)) % 230.0 for i in range(22)]) + "\nspeeds_mps = " + str([3.0] * 21 + [20.5]) + "\n")), ok=(2,), says="v_max"))
    T.append(Try("ring/start", "api uniform_flow shift -1e9", script=api_expect("from aev_ocp.ring.run import human_ring\nfrom aev_ocp.ring.simulate import uniform_flow\nuniform_flow(human_ring(230.0), shift_m=-1e9)", says="shift_m"), ok=(0,)))
    T.append(Try("ring/start", "api RingInitial back to front", script=api_expect("from aev_ocp.ring.run import human_ring\nfrom aev_ocp.ring.simulate import RingInitial, RingSimulator\nr = human_ring(230.0)\nx = tuple(sorted((-(i * 230.0 / 22)) % 230.0 for i in range(22)))\nRingSimulator(r).run(RingInitial(x, (3.0,) * 22), 5.0)", says="positions_m"), ok=(0,)))
    # --- item 3, 4: runaway drivers and cuts --------------------------------------------------------------------------
    T.append(Try("ring/drivers", "idm a 1e300", rg, setup=write(R, ring("[ring.idm]\na_mps2 = 1e300\n")), ok=(2,), says="a_mps2"))
    T.append(Try("ring/drivers", "ovm alpha 1e6", rg, setup=write(R, ring('[ring.ovm]\nalpha_per_s = 1e6\n', human='"ovm"')), ok=(2,), says="alpha_per_s"))
    T.append(Try("ring/drivers", "noise 1e3 m/s2", rg, setup=write(R, ring(noise_mps2="1e3")), ok=(2,), says="noise_mps2"))
    T.append(Try("ring/cuts", "noise_dt 1e-6", rg, setup=write(R, ring(noise_dt_s="1e-6")), ok=(2,), says="noise_dt_s"))
    T.append(Try("ring/cuts", "api controller dt 5e-8 s", script=api_expect("from aev_ocp import ControlSequence\nfrom aev_ocp.models.carfollowing import OVM\nfrom aev_ocp.params import EVParams\nfrom aev_ocp.ring.simulate import RingRoad, RingSimulator, uniform_flow\nev = EVParams()\nr = RingRoad(230.0, (ControlSequence((0.0,), 5e-8 / ev.units.time_s),) + (OVM(),) * 21, 5.0, ev)\nRingSimulator(r).run(uniform_flow(r, speed_mps=3.0), 5.0)", says="dt"), ok=(0,)))
    T.append(Try("ring/interrupt", "long ring SIGINT 4s", ["ring", "sugiyama", "--t-end-s", "36000", "--out", "o", "--no-plots"], sig=(signal.SIGINT, 4.0), ok=(130,), timeout=60))
    T.append(Try("ring/interrupt", "long ring --time-limit 3", ["ring", "sugiyama", "--t-end-s", "36000", "--time-limit", "3", "--out", "o", "--no-plots"], ok=(1,), says="time-limit", timeout=60))
    T.append(Try("ring/options", "file with --seed", ["ring", "ring_sugiyama", "--seed", "4", "--out", "o"], ok=(2,), says="ring.seed"))
    T.append(Try("ring/options", "stern with --length-m", ["ring", "stern", "--length-m", "300", "--out", "o"], ok=(2,), says="--length-m"))
    T.append(Try("ring/options", "stability --ring vehicle length -1", ["stability", "--law", "ovm", "--ring", "22", "--spacing-m", "10", "--vehicle-length-m", "-1", "--out", "o"], ok=(2,), says="--vehicle-length-m"))
    T.append(Try("ring/options", "stability --ring vehicle length nan", ["stability", "--law", "ovm", "--ring", "22", "--spacing-m", "10", "--vehicle-length-m", "nan", "--out", "o"], ok=(2,), says="--vehicle-length-m"))
    # --- item 5, 8, 13, 15: SUMO --------------------------------------------------------------------------------------
    T.append(Try("sumo/size", "t_end_s 1e7", su, setup=write(S, sumo().replace("t_end_s = 3.0", "t_end_s = 1e7")), ok=(2,), says="t_end_s"))
    T.append(Try("sumo/size", "t_end_s 1e300", su, setup=write(S, sumo().replace("t_end_s = 3.0", "t_end_s = 1e300")), ok=(2,), says="t_end_s"))
    T.append(Try("sumo/size", "--t-end-s 1e9", ["sumo", "sumo_ring", "--t-end-s", "1e9", "--out", "o"], ok=(2,), says="--t-end-s"))
    T.append(Try("sumo/size", "200000 cars", su, setup=write(S, sumo("[sumo.ring]\nlength_m = 99000.0\nvehicles = 20000\n").replace("t_end_s = 3.0", "t_end_s = 900.0")), ok=(2,), says="vehicles"))
    T.append(Try("sumo/size", "step 1e-6", su, setup=write(S, sumo("step_s = 1e-6")), ok=(2,), says="step_s"))
    T.append(Try("sumo/args", "sumo_args --help", su, setup=write(S, sumo('sumo_args = ["--help"]')), ok=(2,), says="sumo_args"))
    T.append(Try("sumo/args", "sumo_args tripinfo outside --out", su, setup=write(S, sumo('sumo_args = ["--tripinfo-output", "victim.xml"]')), keep_user={"victim.xml": "<mine/>"}, ok=(2,), says="sumo_args"))
    T.append(Try("sumo/args", "sumo_args --version", su, setup=write(S, sumo('sumo_args = ["--version"]')), ok=(2,), says="sumo_args"))
    T.append(Try("sumo/args", "sumo_args allowed teleport", su, setup=write(S, sumo('sumo_args = ["--time-to-teleport", "-1"]')), ok=(0,), timeout=180))
    T.append(Try("sumo/network", "unknown vtype on the ring", su, setup=write(S, sumo('vtypes = ["aev"]')), ok=(2,), says="vtypes"))
    T.append(Try("sumo/network", "ring lane speed 1e300", su, setup=write(S, sumo("[sumo.ring]\nlane_speed_mps = 1e300\n")), ok=(2,), says="lane_speed_mps"))
    T.append(Try("sumo/network", "ring speed0 above lane", su, setup=write(S, sumo("[sumo.ring]\nspeed0_mps = 45.0\n")), ok=(2,), says="speed0_mps"))
    T.append(Try("sumo/network", "merge flow 1e12", su, setup=write(S, sumo().replace('network = "ring"', 'network = "merge"') + "[sumo.merge]\nmain_flow_vph = 1e12\n"), ok=(2,), says="main_flow_vph"))
    T.append(Try("sumo/network", "merge after_m 1e300", su, setup=write(S, sumo().replace('network = "ring"', 'network = "merge"') + "[sumo.merge]\nafter_m = 1e300\n"), ok=(2,), says="after_m"))
    T.append(Try("sumo/options", "--controller mpc on sumo_ring", ["sumo", "sumo_ring", "--controller", "mpc", "--t-end-s", "1", "--out", "o", "--no-plots"], ok=(0,), timeout=600))
    T.append(Try("sumo/interrupt", "sweep SIGINT 8s", ["sumo", "sumo_ring", "--sweep", "--workers", "2", "--out", "o", "--no-plots"], sig=(signal.SIGINT, 8.0), ok=(130,), timeout=40))
    T.append(Try("sumo/options", "--sweep --share", ["sumo", "sumo_ring", "--sweep", "--share", "0.5", "--out", "o"], ok=(2,), says="--share"))
    T.append(Try("sumo/options", "--sweep --workers 0", ["sumo", "sumo_ring", "--sweep", "--workers", "0", "--out", "o"], ok=(2,), says="--workers"))
    T.append(Try("sumo/options", "--workers without --sweep", ["sumo", "sumo_ring", "--workers", "2", "--out", "o"], ok=(2,), says="--workers"))
    # --- item 10, 15: physical ranges of the vehicle tables -----------------------------------------------------------
    P = "p.toml"
    sim = ["simulate", P, "--out", "o", "--no-plots"]
    T.append(Try("physics", "cooling power drives the pack below 0 K", sim, setup=write(P, scen(extra="[thermal]\nenabled = true\ncooling_power_W = 1e7\n")), ok=(2,), says="cooling_power_W"))
    T.append(Try("physics", "T_max below ambient", sim, setup=write(P, scen(extra="[thermal]\nenabled = true\nT_max_K = 290.0\n")), ok=(2,), says="T_max_K"))
    T.append(Try("physics", "ambient 1e300 K", sim, setup=write(P, scen(extra="[thermal]\nenabled = true\nambient_K = 1e300\n")), ok=(2,), says="K"))
    T.append(Try("physics", "OCV falling with SOC", sim, setup=chain(write("c.toml", cell_file([3.4, 3.3, 3.5, 3.6])), write(P, scen(extra='[cell]\nfile = "c.toml"\n'))), ok=(2,), says="ocv_V"))
    T.append(Try("physics", "api EVParams cooling", script=api_expect("from aev_ocp.params import EVParams, ThermalParams\nEVParams(thermal=ThermalParams(enabled=True, cooling_power_W=1e9))", says="cooling_power_W"), ok=(0,)))
    T.append(Try("physics", "api EVParams limits None", script=api_expect("from aev_ocp.params import EVParams\nEVParams(limits=None)", "TypeError", says="limits"), ok=(0,)))
    # --- item 11, 12: loading -----------------------------------------------------------------------------------------
    T.append(Try("load", "study table swapped", script=api_expect("import aev_ocp, shutil\nshutil.copy('b/table.jsonl', 'a/table.jsonl')\naev_ocp.load('a')", "LoadError", says="table"), setup=chain(write(P, scen()), write("st.toml", STUDY.replace("{scen}", P)), write("st2.toml", STUDY.replace("{scen}", P).replace("0.02, 0.04", "0.05, 0.07").replace("pstudy", "other")), run_cli("study", "st.toml", "--out", "a", "--in-process"), run_cli("study", "st2.toml", "--out", "b", "--in-process")), ok=(0,), timeout=240))
    T.append(Try("load", "load_sumo not a sumo run", script=api_expect("from aev_ocp.sumo.outputs import load_sumo\nload_sumo('nowhere')", "LoadError", says="nowhere"), ok=(0,)))
    T.append(Try("load", "load_sumo relative cell from elsewhere", script=api_ok("import os\nfrom aev_ocp.sumo.outputs import load_sumo\nos.chdir('/')\nr = load_sumo(str(d / 'o'))\nassert r.scenario.ev.cell.soc0 == 0.71"), setup=chain(write("sc/c.toml", cell_file([3.1, 3.3, 3.4, 3.6])), write("sc/" + S, sumo() + '[cell]\nfile = "c.toml"\nsoc0 = 0.71\n'), run_cli("sumo", "sc/" + S, "--out", "o", "--no-plots")), ok=(0,), timeout=240))
    # fmt: on
    return T


def main(argv: list[str] | None = None) -> int:
    return run_probe(tries, argv, __doc__.splitlines()[0], "probe_ring_sumo_inputs.json", jobs=1, details=True)


if __name__ == "__main__":
    sys.exit(main())
