"""A third, independent reliability probe of every command and of the Python API (issue 28).

Each try runs in its own temporary folder, in its own subprocess (its own session, so a signal reaches the
whole process group as Ctrl-C would), under a wall-clock timeout (the harness: ``tools/probes/harness.py``). A try states the exit codes it accepts and,
for bad input, a word its one error line must contain (the field). Every try is classified:

- ``defect``: a traceback or "internal error", a hang (timeout), an exit code outside the accepted ones (2 bad
  input, 1 failed run, 130 interrupt), a temporary file left behind, a process of its group still alive, a
  user file changed, or an error line that does not name the field;
- ``minor``: more than one stderr line for bad input, or a check of the try's own that says so;
- ``ok``: otherwise.

Run: ``python tools/probes/probe_reliability_3.py [--only SUBSTRING] [--json OUT.json] [--jobs N]``; prints a table
per area and every non-ok try with its command, writes the JSON (default ``probe_reliability_3.json`` in the
current folder). Uses the checkout it lives in (``PYTHONPATH``), so it probes the code beside it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import textwrap
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import (  # noqa: E402 - the probes' shared harness
    STUDY,
    Try,
    api_expect,
    api_ok,
    big_study,
    chain,
    exists,
    fifo,
    first_store_entry,
    json_edit,
    late_refusal,
    mutate,
    plain_value_error,
    readonly,
    run_cli,
    run_probe,
    scen,
    stdout_has,
    symlink,
    table_equal_after_rerun,
    write,
    zip_bomb,
)


def tries() -> list[Try]:  # one try a line: a table, kept so by the formatter
    # fmt: off
    T: list[Try] = []
    RO = (0, 2) if os.geteuid() == 0 else (2,)  # root writes into read-only folders
    S = "s.toml"
    sim = ["simulate", S, "--out", "o", "--no-plots"]
    # --- simulate: hostile scenario values ------------------------------------------------------------
    bad_values = [
        ("t_end nan", {"simulation.t_end": "t_end = nan"}, "t_end"),
        ("t_end -inf", {"simulation.t_end": "t_end = -inf"}, "t_end"),
        ("t_end 0", {"simulation.t_end": "t_end = 0.0"}, "t_end"),
        ("dt_out larger than t_end", {"simulation.dt_out": "dt_out = 50.0"}, "dt_out"),
        ("dt_out 1e-300", {"simulation.dt_out": "dt_out = 1e-300"}, "dt_out"),
        ("followers bool", {"platoon.followers": "followers = true"}, "followers"),
        ("followers float", {"platoon.followers": "followers = 2.5"}, "followers"),
        ("followers string", {"platoon.followers": 'followers = "2"'}, "followers"),
        ("followers huge", {"platoon.followers": "followers = 9223372036854775807"}, "followers"),
        ("followers negative", {"platoon.followers": "followers = -3"}, "followers"),
        ("gap0 negative", {"platoon.gap0_first": "gap0_first = -0.3"}, "gap0_first"),
        ("gap0 twin both", {"platoon.gap0_others": "gap0_others = 3.5\ngap0_others_m = 35.0"}, "gap0_others"),
        ("speed0_factor nan", {"platoon.speed0_factor": "speed0_factor = nan"}, "speed0_factor"),
        ("units length 0", {"units.length_m": "length_m = 0.0"}, "length_m"),
        ("units speed 1e308", {"units.speed_mps": "speed_mps = 1e308"}, "speed_mps"),
        ("leader kind unknown", {"leader.kind": 'kind = "teleport"'}, "kind"),
        ("leader v0 array", {"leader.v0": "v0 = [1.7]"}, "v0"),
        ("unicode key", {"extra": '[vehicle]\n"mäss_kg" = 1500.0\n'}, "mäss_kg"),
        ("vehicle efficiency 1.5", {"extra": "[vehicle]\nefficiency = 1.5\n"}, "efficiency"),
        ("cell name path", {"extra": '[cell]\nname = "../../../etc/passwd"\n'}, "cell"),
        ("cell file /dev/zero", {"extra": '[cell]\nfile = "/dev/zero"\n'}, "file"),
        ("thermal enabled string", {"extra": '[thermal]\nenabled = "yes"\n'}, "enabled"),
        ("limits a_min above a_max", {"extra": "[limits]\na_min_mps2 = 5.0\na_max_mps2 = 4.0\n"}, "a_m"),
        ("pack n_series 0", {"extra": "[pack]\nn_series = 0\n"}, "n_series"),
        ("gaps0 wrong length", {"platoon.gap0_first": "gaps0 = [1.0, 2.0, 3.0]", "platoon.gap0_others": ""}, "gaps0"),
        ("compare empty", {"compare": "compare = []"}, "compare"),
        ("compare duplicate", {"compare": 'compare = ["proposed", "proposed"]'}, "compare"),
        ("name escapes", {"name": 'name = "../../escaped"'}, "name"),
        ("name absolute", {"name": 'name = "/tmp"'}, "name"),
        ("carfollowing kappa negative", {"extra": "[carfollowing]\nkappa = -0.5\n"}, "kappa"),
        ("unknown top-level table", {"extra": "[teleporter]\nx = 1\n"}, "teleporter"),
        (
            "deep nesting",
            {"extra": "[carfollowing]\nidm = " + "{a = " * 300 + "1" + "}" * 300 + "\n"},
            "carfollowing.idm",
        ),
        ("duplicate table", {"extra": "[simulation]\nrtol = 1e-8\n"}, "simulation"),
        ("rtol 1e-20", {"extra": "[vehicle]\n", "simulation.dt_out": "dt_out = 0.05\nrtol = 1e-20"}, "rtol"),
        (
            "array leader non-monotonic",
            {
                "leader.kind": 'kind = "array"\ntimes = [0.0, 2.0, 1.0]\nspeeds = [1.0, 1.0, 1.0]',
                "leader.v0": "",
                "leader.amplitude": "",
                "leader.forcing_end": "",
            },
            "times",
        ),
        (
            "array leader negative speed",
            {
                "leader.kind": 'kind = "array"\ntimes = [0.0, 2.0, 5.0]\nspeeds = [1.0, -1.0, 1.0]',
                "leader.v0": "",
                "leader.amplitude": "",
                "leader.forcing_end": "",
            },
            "speeds",
        ),
    ]
    for name, edits, says in bad_values:
        T.append(Try("simulate/toml", name, sim, setup=write(S, scen(**edits)), ok=(2,), says=says, timeout=60))
    T.append(Try("simulate/toml", "mpc table warns", sim, setup=write(S, scen(extra="[mpc]\nN = 10\n")), ok=(0,)))
    T.append(Try('simulate/toml', 'leader faster than V_inf*U warns', sim, setup=write(S, scen(**{'leader.v0': 'v0 = 2.5'})), ok=(0, 1)))
    T.append(Try('simulate/toml', 'thermal on', sim, setup=write(S, scen(extra='[thermal]\nenabled = true\nambient_K = 300.0\n')), ok=(0,)))
    T.append(Try('simulate/toml', 'limits lag and jerk', sim, setup=write(S, scen(extra='[limits]\nlag_s = 0.3\njerk_max_mps3 = 2.5\n')), ok=(0, 1)))
    T.append(Try('simulate/toml', 'shipped cell by name', sim, setup=write(S, scen(extra='[cell]\nname = "a123_anr26650"\nsoc0 = 0.35\n')), ok=(0,)))
    # --- simulate: file encodings and odd files ---------------------------------------------------------
    T.append(Try("simulate/file", "BOM", sim, setup=write(S, "\ufeff".encode() + scen().encode()), ok=(0, 2)))
    T.append(Try("simulate/file", "CRLF", sim, setup=write(S, scen().replace("\n", "\r\n").encode()), ok=(0,)))
    T.append(Try('simulate/file', 'latin-1', sim, setup=write(S, scen(extra='description = "é"\n').replace('name = "probe"', 'name = "probe"\ndescription = "café"').encode('latin-1')), ok=(2,), says='utf'))
    T.append(Try("simulate/file", "FIFO", sim, setup=fifo(S), ok=(2,), says=S, timeout=20))
    T.append(Try('simulate/file', '/dev/zero', ['simulate', '/dev/zero', '--no-plots', '--out', 'o'], ok=(2,), says='zero', timeout=20))
    T.append(Try("simulate/file", "binary junk", sim, setup=write(S, os.urandom(4000)), ok=(2,), says=S))
    T.append(Try("simulate/file", "empty file", sim, setup=write(S, ""), ok=(2,), says=S))
    T.append(Try("simulate/file", "folder as scenario", ["simulate", ".", "--out", "o"], ok=(2,)))
    T.append(Try('simulate/file', 'symlink loop', sim, setup=chain(symlink('a.toml', 'b.toml'), symlink('b.toml', 'a.toml')), ok=(2,)))
    T.append(Try('simulate/file', 'symlink to scenario', ['simulate', 'ln.toml', '--out', 'o', '--no-plots'], setup=chain(write(S, scen()), symlink('ln.toml', S)), ok=(0,)))
    T.append(Try('simulate/file', '20 MB scenario', sim, setup=write(S, scen() + '# ' + 'x' * 20000000 + '\n'), ok=(2,), says='bytes'))
    T.append(Try('simulate/file', 'trace /etc/passwd', sim, setup=write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "/etc/passwd"', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''})), ok=(2,), says='file', check=lambda d, r: 'minor: echoes /etc/passwd content' if 'root:' in r['stderr'] else None))
    T.append(Try('simulate/file', 'trace huge field', sim, setup=chain(write('tr.csv', 'time,speed\n0,' + '1' * 200000 + '\n1,2\n'), write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "tr.csv"', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''}))), ok=(2,), says='tr.csv'))
    T.append(Try('simulate/file', 'trace BOM CRLF', sim, setup=chain(write('tr.csv', '\ufefftime,speed\r\n0,8\r\n1,8.5\r\n2,9\r\n3,9\r\n4,9\r\n5,9\r\n6,9\r\n7,9\r\n8,9\r\n9,9\r\n'), write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "tr.csv"\nmax_gap_s = 2.0', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''}))), ok=(0,)))
    T.append(Try('simulate/file', 'trace FIFO', sim, setup=chain(fifo('tr.csv'), write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "tr.csv"', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''}))), ok=(2,), says='tr.csv', timeout=20))
    T.append(Try('simulate/file', 'trace nan speed', sim, setup=chain(write('tr.csv', 'time,speed\n0,8\n1,nan\n2,9\n'), write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "tr.csv"\nmax_gap_s = 2.0', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''}))), ok=(2,), says='speed'))
    T.append(Try('simulate/file', 'trace missing column', sim, setup=chain(write('tr.csv', 't,v\n0,8\n1,9\n'), write(S, scen(**{'leader.kind': 'kind = "trace"\nfile = "tr.csv"', 'leader.v0': '', 'leader.amplitude': '', 'leader.forcing_end': ''}))), ok=(2,), says='time'))
    # --- simulate: --set kinds --------------------------------------------------------------------------
    for name, kv, code, says in [
        ("int", "platoon.followers=3", 0, None),
        ("float SI twin", "simulation.t_end_s=5.5", 0, None),
        ("list", 'compare=["proposed"]', 0, None),
        ("bool", "thermal.enabled=true", 0, None),
        ("string", "leader.kind=constant", 2, "leader"),
        ("inline table", "carfollowing.idm={v0=1.9}", 0, None),
        ("no equals", "platoon.followers", 2, "platoon.followers"),
        ("empty value", "platoon.followers=", 2, "platoon.followers"),
        ("empty key", "=3", 2, "key"),
        ("1e400", "simulation.t_end=1e400", 2, "t_end"),
        ("newline", "simulation.t_end=3\nplatoon.followers=9", 2, "t_end"),
        ("unknown key", "platoon.folowers=3", 2, "folowers"),
        ("unicode key", "platoon.föllowers=3", 2, "föllowers"),
        ("twin replaces file value", "simulation.t_end_s=5", 0, None),
        ("deep key", "a.b.c.d.e.f.g.h=1", 2, "'a'"),
        ("key is table", "platoon=3", 2, "platoon"),
        ("hex int", "platoon.followers=0x3", 0, None),
    ]:
        T.append(Try("simulate/--set", name, [*sim, "--set", kv], setup=write(S, scen()), ok=(code,), says=says))
    T.append(Try('simulate/--set', 'twin given by both', [*sim, '--set', 'simulation.t_end=3', '--set', 'simulation.t_end_s=6'], setup=write(S, scen()), ok=(2,), says='t_end'))
    # --- simulate: paths and output folders --------------------------------------------------------------
    T.append(Try('simulate/paths', 'spaces and unicode', ['simulate', 'dïr with space/scé nario.toml', '--out', 'öut dir/x y', '--no-plots'], setup=write('dïr with space/scé nario.toml', scen()), ok=(0,), check=exists('öut dir/x y/manifest.json')))
    long = "L" * 240
    T.append(Try('simulate/paths', '240-char names', ['simulate', f'{long}.toml', '--out', long, '--no-plots'], setup=write(f'{long}.toml', scen()), ok=(0,)))
    T.append(Try('simulate/paths', '300-char out name', ['simulate', S, '--out', 'N' * 300, '--no-plots'], setup=write(S, scen()), ok=(2,), says='N' * 20))
    T.append(Try('simulate/paths', 'tilde out literal', ['simulate', S, '--out', '~/probe_out', '--no-plots'], setup=chain(write(S, scen()), lambda d: (d / 'home').mkdir()), env={'HOME': 'HOMEDIR'}, ok=(0,)))
    T.append(Try('simulate/paths', 'read-only parent', ['simulate', S, '--out', 'ro/o', '--no-plots'], setup=chain(write(S, scen()), readonly('ro')), ok=RO, says='ro'))
    T.append(Try('simulate/paths', 'parent is a file', ['simulate', S, '--out', 'f.txt/o', '--no-plots'], setup=write(S, scen()), keep_user={'f.txt': 'mine'}, ok=(2,), says='f.txt'))
    T.append(Try('simulate/paths', 'out is a file', ['simulate', S, '--out', 'f.txt'], setup=chain(write(S, scen()), write('f.txt', 'mine')), ok=(2,), says='f.txt', keep_user={'f.txt': 'mine'}))
    T.append(Try('simulate/paths', 'out holds user metrics.json', sim, setup=write(S, scen()), keep_user={'o/metrics.json': '{"mine": 1}'}, ok=(2,)))
    T.append(Try('simulate/paths', 'out holds unrelated user file', sim, setup=write(S, scen()), keep_user={'o/notes.txt': 'keep me'}, ok=(0, 2)))
    T.append(Try('simulate/paths', 'out of another scenario', sim, setup=chain(write(S, scen()), run_cli('simulate', 'table1', '--out', 'o', '--no-plots', '--set', 'simulation.t_end=2')), ok=(2,)))
    T.append(Try('simulate/paths', 'out is symlink to folder', ['simulate', S, '--out', 'lnk', '--no-plots'], setup=chain(write(S, scen()), lambda d: (d / 'real').mkdir(), symlink('lnk', 'real')), ok=(0, 2)))
    T.append(Try("simulate/paths", "same run twice", sim, setup=chain(write(S, scen()), run_cli(*sim)), ok=(0,)))
    # --- environment -------------------------------------------------------------------------------------
    T.append(Try("env", "HOME unset", sim, setup=write(S, scen()), unset=("HOME",), ok=(0,)))
    T.append(Try('env', 'TMPDIR missing', ['simulate', S, '--out', 'o'], setup=write(S, scen()), env={'TMPDIR': '/nonexistent/tmp'}, ok=(0,)))
    T.append(Try('env', 'MPLBACKEND=TkAgg no display', ['simulate', S, '--out', 'o'], setup=write(S, scen()), env={'MPLBACKEND': 'TkAgg'}, unset=('DISPLAY', 'WAYLAND_DISPLAY'), ok=(0,), check=exists('o/proposed.png')))
    T.append(Try('env', 'CC=false fresh cache', sim, setup=write(S, scen(**{'carfollowing': ''}, extra='[vehicle]\nmass_kg = 1234.5\n')), env={'CC': 'false', 'AEV_OCP_CACHE': 'CACHEDIR'}, ok=(0,), timeout=180))
    T.append(Try('env', 'read-only cache', sim, setup=chain(write(S, scen(extra='[vehicle]\nmass_kg = 1234.6\n')), readonly('cache')), env={'AEV_OCP_CACHE': 'cache'}, ok=(0,), timeout=180))
    T.append(Try('env', 'cache is a file', sim, setup=chain(write(S, scen(extra='[vehicle]\nmass_kg = 1234.7\n')), write('cachef', 'x')), env={'AEV_OCP_CACHE': 'cachef'}, ok=(0,), timeout=180))
    T.append(Try('env', 'MAX_MEMORY_GB junk', sim, setup=write(S, scen()), env={'AEV_OCP_MAX_MEMORY_GB': 'lots'}, ok=(2,), says='AEV_OCP_MAX_MEMORY_GB'))
    T.append(Try('env', 'MAX_MEMORY_GB tiny', sim, setup=write(S, scen()), env={'AEV_OCP_MAX_MEMORY_GB': '1e-9'}, ok=(2,)))
    T.append(Try('env', 'MAX_MEMORY_GB nan', sim, setup=write(S, scen()), env={'AEV_OCP_MAX_MEMORY_GB': 'nan'}, ok=(2,), says='AEV_OCP_MAX_MEMORY_GB'))
    T.append(Try('env', 'LANG=C non-ascii path', ['simulate', 'é.toml', '--out', 'ö', '--no-plots'], setup=write('é.toml', scen()), env={'LANG': 'C', 'LC_ALL': 'C'}, ok=(0,)))
    # --- interrupts ----------------------------------------------------------------------------------------
    longsim = scen(
        **{
            "platoon.followers": "followers = 400",
            "simulation.t_end": "t_end = 70.0",
            "simulation.dt_out": "dt_out = 0.01",
        }
    )
    for delay in (0.4, 1.5, 3.0):
        T.append(Try('interrupt', f'simulate SIGINT {delay}s', ['simulate', S, '--out', 'o'], setup=write(S, longsim), sig=(signal.SIGINT, delay), ok=(130, 0)))
    T.append(Try('interrupt', 'simulate SIGTERM 2s', ['simulate', S, '--out', 'o'], setup=write(S, longsim), sig=(signal.SIGTERM, 2.0), ok=(130, 0)))
    T.append(Try('interrupt', 'mpc SIGINT 3s', ['mpc', 'mpc_paper_single', '--out', 'o', '--solver', 'ipopt', '--no-ocpd'], sig=(signal.SIGINT, 3.0), ok=(130, 0)))
    T.append(Try('interrupt', 'mpc SIGTERM 3s', ['mpc', 'mpc_paper_single', '--out', 'o', '--solver', 'ipopt', '--no-ocpd'], sig=(signal.SIGTERM, 3.0), ok=(130, 0)))
    T.append(Try('interrupt', 'study pool SIGINT 4s', ['study', 'st.toml', '--out', 'st', '--workers', '2'], setup=chain(write(S, scen(**{'simulation.t_end': 't_end = 30.0'})), write('st.toml', big_study(150).replace('{scen}', S))), sig=(signal.SIGINT, 4.0), ok=(130, 0), timeout=60))
    T.append(Try('interrupt', 'study pool SIGTERM 4s', ['study', 'st.toml', '--out', 'st', '--workers', '2'], setup=chain(write(S, scen(**{'simulation.t_end': 't_end = 30.0'})), write('st.toml', big_study(150).replace('{scen}', S))), sig=(signal.SIGTERM, 4.0), ok=(130, 0), timeout=60))
    T.append(Try('interrupt', 'stability SIGINT 2s', ['stability', '--law', 'ovm', '--out', 'o'], sig=(signal.SIGINT, 2.0), ok=(130, 0)))
    T.append(Try('interrupt', 'ring SIGINT 2s', ['ring', 'sugiyama', '--out', 'o'], sig=(signal.SIGINT, 2.0), ok=(130, 0)))
    T.append(Try('interrupt', 'ocp oracle SIGINT 0.6s', ['ocp', 'oracle', '--out', 'o'], sig=(signal.SIGINT, 0.6), ok=(130, 0)))
    T.append(Try('interrupt', 'mpc-export --build SIGINT 2s', ['mpc-export', 'mpc_paper_single', '--out', 'ex', '--build'], sig=(signal.SIGINT, 2.0), ok=(130, 0), timeout=180))
    T.append(Try('interrupt', 'safety SIGINT 3s', ['safety', '--quick', '--out', 'o'], sig=(signal.SIGINT, 3.0), ok=(130, 0)))
    T.append(Try('interrupt', 'reproduce SIGINT 4s', ['reproduce', '--quick', '--out', 'o'], sig=(signal.SIGINT, 4.0), ok=(130, 0)))
    # --- concurrency ---------------------------------------------------------------------------------------
    T.append(Try('concurrent', 'two simulates one --out', ['simulate', S, '--out', 'o'], setup=write(S, longsim.replace('followers = 400', 'followers = 100')), parallel=Try('concurrent', 'b', ['simulate', S, '--out', 'o'])))
    T.append(Try('concurrent', 'two studies one --out', ['study', 'st.toml', '--out', 'st', '--in-process'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), parallel=Try('concurrent', 'b', ['study', 'st.toml', '--out', 'st', '--in-process'])))
    T.append(Try('concurrent', 'simulate and mpc one --out', ['simulate', 'mpc_paper_single', '--out', 'o', '--set', 'simulation.t_end=30'], parallel=Try('concurrent', 'b', ['mpc', 'mpc_paper_single', '--out', 'o', '--t-end', '4', '--no-ocpd'])))
    # --- mpc -------------------------------------------------------------------------------------------------
    mp = ["mpc", "mpc_paper_single", "--out", "o", "--no-ocpd", "--t-end", "2"]
    for name, extra, code, says in [
        ("dt negative", ["--set", "mpc.dt=-0.1"], 2, "dt"),
        ("w_Q nan", ["--set", "mpc.w_Q=nan"], 2, "w_Q"),
        ("w_a negative", ["--set", "mpc.w_a=-1"], 2, "w_a"),
        ("predictor unknown", ["--set", "mpc.predictor=psychic"], 2, "predictor"),
        ("objective unknown", ["--set", "mpc.objective=joy"], 2, "objective"),
        ("vehicles 7", ["--set", "mpc.vehicles=[7]"], 2, "vehicles"),
        ("t-end 0", ["--t-end", "0"], 2, "t-end"),
        ("t-end nan", ["--t-end", "nan"], 2, "t-end"),
        ("t-end and --set", ["--set", "simulation.t_end_s=3"], 2, "t_end"),
        ("laws unknown", ["--laws", "warpdrive"], 2, "warpdrive"),
        ("laws empty", ["--laws"], 0, None),
        ("progress-every -1", ["--progress-every", "-1"], 2, "progress"),
        ("progress-every nan", ["--progress-every", "nan"], 2, "progress"),
        ("time-limit 0.01", ["--time-limit", "0.01"], 1, None),
        ("sqp riccati", ["--solver", "sqp", "--qp-solver", "riccati"], 2, "riccati"),
        ("ipopt-cold", ["--solver", "ipopt-cold", "--no-codegen"], 0, None),
        ("rti osqp", ["--solver", "rti", "--qp-solver", "osqp", "--no-codegen"], 0, None),
        ("h_min above gap", ["--set", "mpc.h_min=5.0"], 2, "h_min"),
        ("unknown mpc key", ["--set", "mpc.horizon=4"], 2, "horizon"),
        ("max_step_ms 0", ["--set", "mpc.max_step_ms=0"], 2, "max_step_ms"),
    ]:
        T.append(Try("mpc", name, [*mp, *extra], ok=(code,), says=says, timeout=180))
    T.append(Try('mpc', 'table1 no [mpc]', ['mpc', 'table1', '--out', 'o', '--no-ocpd', '--t-end', '2'], ok=(0, 1, 2), timeout=180))
    T.append(Try('mpc', 'platoon thermal', ['mpc', 'mpc_paper_platoon', '--out', 'o', '--no-ocpd', '--t-end', '1', '--set', 'thermal.enabled=true'], ok=(0, 1), timeout=240))
    # --- mpc-export -------------------------------------------------------------------------------------------
    T.append(Try('mpc-export', 'relative out build', ['mpc-export', 'mpc_paper_single', '--out', 'rel dir/ex', '--build'], ok=(0,), timeout=240, check=exists('rel dir/ex/libaev_mpc.so')))
    T.append(Try('mpc-export', 'user Makefile', ['mpc-export', 'mpc_paper_single', '--out', 'ex'], keep_user={'ex/Makefile': 'all:\n\techo mine\n'}, ok=(2,)))
    T.append(Try('mpc-export', 'out is a file', ['mpc-export', 'mpc_paper_single', '--out', 'f'], setup=write('f', 'x'), keep_user={'f': 'x'}, ok=(2,)))
    T.append(Try('mpc-export', 'N huge', ['mpc-export', 'mpc_paper_single', '--out', 'ex', '--set', 'mpc.N=100000'], ok=(2,), says='N', timeout=60))
    T.append(Try('mpc-export', 'CC=false build', ['mpc-export', 'mpc_paper_single', '--out', 'ex', '--build'], env={'CC': 'false'}, ok=(1, 2), timeout=120))
    T.append(Try('mpc-export', 'CC missing binary', ['mpc-export', 'mpc_paper_single', '--out', 'ex', '--build'], env={'CC': '/no/such/cc'}, ok=(0, 1, 2), says='CC', timeout=120))
    T.append(Try('mpc-export', 're-export same folder', ['mpc-export', 'mpc_paper_single', '--out', 'ex'], setup=run_cli('mpc-export', 'mpc_paper_single', '--out', 'ex'), ok=(0,), timeout=120))
    T.append(Try('mpc-export', 'other scenario same folder', ['mpc-export', 'mpc_udds_single', '--out', 'ex'], setup=run_cli('mpc-export', 'mpc_paper_single', '--out', 'ex'), ok=(0, 2), timeout=120))
    T.append(Try('mpc-export', 'scenario without mpc', ['mpc-export', S, '--out', 'ex'], setup=write(S, scen()), ok=(0, 2), timeout=120))
    # --- stability ------------------------------------------------------------------------------------------
    st = ["stability", "--out", "o", "--no-plots", "--linear-only"]
    for name, extra, code, says in [
        ("law unknown", ["--law", "warp"], 2, "warp"),
        ("speed negative", ["--law", "ovm", "--speed-mps", "-2"], 2, "speed"),
        ("speed nan", ["--law", "ovm", "--speed-mps", "nan"], 2, "speed"),
        ("speed beyond V_inf", ["--law", "ovm", "--speed-mps", "30"], 2, "speed"),
        ("speed twins", ["--law", "ovm", "--speed-mps", "4", "--speed-model", "0.8"], 2, "speed"),
        ("set bad value", ["--law", "ovm", "--set", "carfollowing.ovm.alpha=abc"], 2, "alpha"),
        ("set unknown param", ["--law", "ovm", "--set", "carfollowing.ovm.zeta=1.5"], 2, "zeta"),
        ("set other law", ["--law", "ovm", "--set", "carfollowing.idm.v0=1.5"], 2, "idm"),
        ("units zero", ["--law", "ovm", "--units-length-m", "0"], 2, "units"),
        ("ring 1", ["--law", "ovm", "--ring", "1"], 2, "ring"),
        ("ring spacing negative", ["--law", "idm", "--ring", "10", "--spacing-m", "-3"], 2, "spacing"),
        (
            "ring both spacing and density",
            ["--law", "idm", "--ring", "10", "--spacing-m", "20", "--density-per-km", "30"],
            2,
            "density",
        ),
        ("omega 0", ["--law", "ovm", "--kind", "sine", "--omega-rad-per-s", "0"], 2, "omega"),
        ("followers 0", ["--law", "ovm", "--followers", "0"], 2, "followers"),
        ("idm", ["--law", "idm", "--speed-mps", "6.5"], 0, None),
        ("mpc predictor junk", ["--law", "mpc", "--predictor", "crystal"], 2, "predictor"),
    ]:
        T.append(Try("stability", name, [*st, *extra], ok=(code,), says=says, timeout=120))
    T.append(Try('stability', 'followers 10^6 nonlinear', ['stability', '--law', 'ovm', '--followers', '1000000', '--out', 'o', '--no-plots'], ok=(2,), says='followers', timeout=60))
    T.append(Try('stability', 'amplitude above v*', ['stability', '--law', 'ovm', '--amplitude-mps', '50', '--out', 'o', '--no-plots', '--followers', '5'], ok=(2,), says='amplitude', timeout=120))
    T.append(Try('stability', 'user stability.json', [*st, '--law', 'ovm'], keep_user={'o/stability.json': '{}'}, ok=(2,)))
    # --- ring ------------------------------------------------------------------------------------------------
    for name, extra, code, says in [
        ("unknown experiment", ["teleport"], 2, "teleport"),
        ("t-end negative", ["sugiyama", "--t-end-s", "-5"], 2, "t-end"),
        ("t-end 1e9", ["sugiyama", "--t-end-s", "1e9"], 2, "t"),
        ("penetration 30", ["sweep", "--penetration", "30", "--t-end-s", "5"], 2, "penetration"),
        ("length 1 m", ["sweep", "--length-m", "1", "--t-end-s", "5"], 2, "length"),
        ("aev unknown", ["sweep", "--aev", "skynet", "--t-end-s", "5"], 2, "skynet"),
        ("seed negative", ["sugiyama", "--seed", "-4", "--t-end-s", "5"], 2, "seed"),
        ("short stern", ["stern", "--t-end-s", "7.5"], 0, None),
    ]:
        T.append(Try("ring", name, ["ring", *extra, "--out", "o", "--no-plots"], ok=(code,), says=says, timeout=180))
    # --- ocp --------------------------------------------------------------------------------------------------
    for name, extra, code, says in [
        ("soc0 1.5", ["prop31", "--soc0", "1.5"], 2, "soc0"),
        ("soc0 nan", ["prop31", "--soc0", "nan"], 2, "soc0"),
        ("cell unknown", ["prop31", "--cell", "unobtainium"], 2, "unobtainium"),
        ("cell /dev/zero", ["prop31", "--cell", "/dev/zero"], 2, "zero"),
        ("v-relax one value", ["prop31", "--v-relax-V", "0.1"], 2, "--v-relax-V"),
        ("grid negative E", ["current-profile", "--grid", "E_req=-1,2000", "--no-refine"], 2, "E_req"),
        ("grid unknown name", ["current-profile", "--grid", "zeta=1,2"], 2, "zeta"),
        ("grid-file /dev/zero", ["current-profile", "--grid-file", "/dev/zero"], 2, "zero"),
        ("grid-file wrong types", ["current-profile", "--grid-file", "g.json"], 2, "E_req"),
        ("N 0", ["oracle", "--N", "0"], 2, "N"),
        ("N 10^7", ["oracle", "--N", "10000000"], 2, "N"),
        ("eco-trip default scenario", ["eco-trip", "--no-refine", "--N", "60"], 0, None),
        ("time-limit negative", ["current-profile", "--time-limit", "-3"], 2, "time-limit"),
    ]:
        T.append(Try('ocp', name, ['ocp', *extra, '--out', 'o'], setup=write('g.json', '{"E_req": "many", "t_f": [30]}'), ok=(code,), says=says, timeout=120))
    T.append(Try('ocp', 'prop31 into folder with a file', ['ocp', 'prop31', '--out', 'o'], keep_user={'o/mine.txt': 'x'}, ok=(2,)))
    T.append(Try('ocp', 'current-profile small grid', ['ocp', 'current-profile', '--grid', 'E_req=1500', '--grid', 't_f=45', '--no-refine', '--out', 'o'], ok=(0,), timeout=120))

    # --- study --------------------------------------------------------------------------------------------------
    def study_try(name: str, text: str, code: int, says: str | None, extra: list[str] | None = None, **kw: Any) -> Try:
        return Try(
            "study",
            name,
            ["study", "st.toml", "--out", "st", "--in-process", "--no-report", *(extra or [])],
            setup=chain(write(S, scen()), write("st.toml", text.replace("{scen}", S))),
            ok=(code,),
            says=says,
            timeout=kw.pop("timeout", 120),
            **kw,
        )

    T.append(study_try("small run", STUDY, 0, None, check=exists("st/table.csv")))
    T.append(study_try("name escapes", STUDY.replace('name = "pstudy"', 'name = "../../escaped"'), 2, "name", extra=[]))
    T[-1].argv = ["study", "st.toml", "--in-process"]
    T.append(study_try('random n 1e9', STUDY.replace('values = [0.02, 0.04]', 'random = { n = 1000000000, seed = 1, low = 0.0, high = 0.5 }'), 2, 'n', timeout=30))
    T.append(study_try('grid 1000^3', STUDY + ''.join((f"""[[axes]]\nkey = "carfollowing.{k}"\nvalues = [{', '.join((str(1 + i / 1000) for i in range(1000)))}]\n""" for k in ('alpha', 'beta'))).replace('values = [0.02, 0.04]', 'values = [' + ', '.join((str(i / 2000) for i in range(1000))) + ']'), 2, 'axes', timeout=30))
    T.append(study_try("axis values empty", STUDY.replace("values = [0.02, 0.04]", "values = []"), 2, "values"))
    T.append(study_try('axis key unknown', STUDY.replace('key = "carfollowing.kappa"', 'key = "carfollowing.zeta"'), 2, 'zeta'))
    T.append(study_try("axis value nan", STUDY.replace("values = [0.02, 0.04]", "values = [0.02, nan]"), 2, "kappa"))
    T.append(study_try("axis values mixed", STUDY.replace("values = [0.02, 0.04]", 'values = [0.02, "x"]'), 2, "kappa"))
    T.append(study_try('axis duplicate key', STUDY + '[[axes]]\nkey = "carfollowing.kappa"\nvalues = [0.1]\n', 2, 'kappa'))
    T.append(study_try("laws empty", STUDY.replace('laws = ["proposed", "ovfl"]', "laws = []"), 2, "laws"))
    T.append(study_try("reference absent", STUDY.replace('reference = "ovfl"', 'reference = "idm"'), 2, "reference"))
    T.append(study_try("mpc entry bogus key", STUDY + '[[controllers.mpc]]\nlabel = "m"\nhorizon = 3\n', 2, "horizon"))
    T.append(study_try('report vehicle 99', STUDY.replace('vehicle = 1', 'vehicle = 99'), 2, 'vehicle', check=late_refusal))
    T[-1].ok = (0, 2)
    T.append(study_try("report metric bogus", STUDY + 'metrics = ["happiness"]\n', 2, "happiness", check=late_refusal))
    T[-1].ok = (0, 2)
    T.append(study_try("scenarios empty", STUDY.replace('scenarios = ["{scen}"]', "scenarios = []"), 2, "scenarios"))
    T.append(study_try('scenario missing', STUDY.replace('scenarios = ["{scen}"]', 'scenarios = ["nope.toml"]'), 2, 'nope'))
    T.append(study_try('inline overrides bad key', STUDY.replace('scenarios = ["{scen}"]', 'scenarios = [{ scenario = "{scen}", label = "a", overrides = { "platoon.zeta" = 1 } }]'), 2, 'zeta'))
    T.append(study_try("--set on axis key", STUDY, 2, "kappa", extra=["--set", "carfollowing.kappa=0.5"]))
    T.append(study_try("--set inf", STUDY, 2, "alpha", extra=["--set", "carfollowing.alpha=inf"]))
    T.append(study_try("--set ok", STUDY, 0, None, extra=["--set", "carfollowing.alpha=2.5"]))
    T.append(study_try("--time-limit 0", STUDY, 2, "time-limit", extra=["--time-limit", "0"]))
    T.append(study_try("--time-limit nan", STUDY, 2, "time-limit", extra=["--time-limit", "nan"]))
    T.append(study_try('unicode label', STUDY.replace('scenarios = ["{scen}"]', 'scenarios = [{ scenario = "{scen}", label = "płatoon ✓" }]'), 0, None))
    T.append(study_try("BOM study", "\ufeff" + STUDY, 0, None))
    T.append(study_try("top-level unknown key", STUDY + "flavour = 3\n", 2, "flavour"))
    T.append(Try('study', 'workers 0', ['study', 'st.toml', '--out', 'st', '--workers', '0'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(2,), says='workers'))
    T.append(Try('study', 'workers 100000', ['study', 'st.toml', '--out', 'st', '--workers', '100000'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(2,), says='workers', timeout=60))
    T.append(Try('study', 'study FIFO', ['study', 'st.toml', '--out', 'st'], setup=fifo('st.toml'), ok=(2,), says='st.toml', timeout=20))
    T.append(Try('study', 'user table.csv', ['study', 'st.toml', '--out', 'st', '--in-process'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), keep_user={'st/table.csv': 'a,b\n1,2\n'}, ok=(2,)))
    T.append(Try('study', 'scheduler silent', ['study', 'st.toml', '--out', 'st', '--scheduler', 'tcp://127.0.0.1:9'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(1, 2), timeout=60))
    T.append(Try('study', 'scheduler junk address', ['study', 'st.toml', '--out', 'st', '--scheduler', 'not an address'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(2,), says='scheduler', timeout=60))
    # damaged stores: a clean reference run, then the damaged rerun must equal it
    sim_study = ["study", "st.toml", "--in-process", "--no-report"]
    base_setup = chain(
        write(S, scen()),
        write("st.toml", STUDY.replace("{scen}", S)),
        run_cli(*sim_study, "--out", "ref"),
        run_cli(*sim_study, "--out", "st"),
    )
    for name, damage in [
        ("entry truncated", first_store_entry(lambda p: p.write_bytes(p.read_bytes()[:40]))),
        ("entry is {}", first_store_entry(lambda p: p.write_text("{}"))),
        ("entry is list", first_store_entry(lambda p: p.write_text("[1, 2]"))),
        (
            "entry metrics wrong type",
            first_store_entry(lambda p: p.write_text(json.dumps({**json.loads(p.read_text()), "metrics": "lots"}))),
        ),
        ("entry is FIFO", first_store_entry(lambda p: (p.unlink(), os.mkfifo(p)))),
        ("entries swapped", lambda d: _swap(sorted((d / "st" / "points").glob("*.json"))[:2])),
        (
            "entry omega edited",
            first_store_entry(lambda p: p.write_text(p.read_text().replace('"omega_model": -', '"omega_model": -9'))),
        ),
        ("points folder is a file", lambda d: (_rmtree(d / "st" / "points"), (d / "st" / "points").write_text("x"))),
        ("table.jsonl deleted", lambda d: (d / "st" / "table.jsonl").unlink()),
        ("manifest wrong types", json_edit("st/manifest.json", lambda m: {**m, "n_tasks": "many"})),
    ]:
        T.append(Try('study/store', name, [*sim_study, '--out', 'st'], setup=chain(base_setup, damage), ok=(0,), timeout=120, check=table_equal_after_rerun))
    # --- load() -------------------------------------------------------------------------------------------------
    saved = run_cli("simulate", "table1", "--out", "o", "--no-plots", "--set", "simulation.t_end=2")
    L = "LoadError"
    for name, damage in [
        ("npz truncated", mutate("o/trajectories.npz", lambda b: b[: len(b) // 2])),
        ("npz deleted", lambda d: (d / "o" / "trajectories.npz").unlink()),
        ("npz FIFO", lambda d: ((d / "o" / "trajectories.npz").unlink(), os.mkfifo(d / "o" / "trajectories.npz"))),
        (
            "npz -> /dev/zero",
            lambda d: ((d / "o" / "trajectories.npz").unlink(), os.symlink("/dev/zero", d / "o" / "trajectories.npz")),
        ),
        ("npz zip bomb", zip_bomb("o")),
        ("manifest []", write("o/manifest.json", "[]")),
        ("manifest runs wrong type", json_edit("o/manifest.json", lambda m: {**m, "runs": [1, 2]})),
        ("manifest kind unknown", json_edit("o/manifest.json", lambda m: {**m, "kind": "teleport"})),
        ("manifest format newer", json_edit("o/manifest.json", lambda m: {**m, "format": 999})),
        ("manifest deep nesting", write("o/manifest.json", "[" * 100000 + "]" * 100000)),
        ("manifest NaN primary", mutate("o/manifest.json", lambda b: b.replace(b'"primary"', b'"primary": NaN, "x"'))),
        ("manifest latin-1", write("o/manifest.json", b'{"kind": "simulate", "x": "\xe9"}')),
        ("manifest deleted", lambda d: (d / "o" / "manifest.json").unlink()),
        ("arrays name escapes", json_edit("o/manifest.json", lambda m: {**m, "arrays": "../../../../etc/passwd"})),
        ("arrays sha mismatch", json_edit("o/manifest.json", lambda m: {**m, "arrays_sha256": "0" * 64})),
    ]:
        T.append(Try('load', name, script=api_expect("import aev_ocp\nr = aev_ocp.load('o')\nr.metrics()", L), setup=chain(saved, damage), ok=(0,), timeout=60))
    T.append(Try('load', 'run unknown', script=api_expect("import aev_ocp\naev_ocp.load('o', run='zzz')", L, says='zzz'), setup=saved, ok=(0,)))
    T.append(Try('load', 'path is int', script=api_expect('import aev_ocp\naev_ocp.load(12345)', 'LoadError', says='12345'), ok=(0,)))
    T.append(Try('load', 'path missing', script=api_expect("import aev_ocp\naev_ocp.load('nope')", L, says='nope'), ok=(0,)))
    T.append(Try('load', 'path /dev/zero', script=api_expect("import aev_ocp\naev_ocp.load('/dev/zero')", L), ok=(0,), timeout=20))
    T.append(Try('load', 'load_all on mpc output', script=api_ok("import aev_ocp\nr = aev_ocp.load_all('o')\nassert set(r) >= {'mpc'}, r.keys()"), setup=run_cli('mpc', 'mpc_paper_single', '--out', 'o', '--t-end', '2', '--no-ocpd'), ok=(0,), timeout=120))
    T.append(Try('load', 'round trip metrics', script=api_ok("import aev_ocp, json\nr = aev_ocp.load('o')\nm = json.load(open('o/metrics.json'))\nprint(type(m))"), setup=saved, ok=(0,)))
    T.append(Try('load', 'study table.jsonl junk line', script=api_expect("import aev_ocp\nr = aev_ocp.load('st')\nprint(len(r.rows))", L), setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S)), run_cli(*sim_study, '--out', 'st'), lambda d: open(d / 'st' / 'table.jsonl', 'a').write('{not json\n')), ok=(0,)))
    # --- Python API: scenarios -------------------------------------------------------------------------------------
    T.append(Try('api/scenario', 'missing name', script=api_expect("from aev_ocp import load_scenario\nload_scenario('no_such_scenario')", says='no_such_scenario'), ok=(0,)))
    T.append(Try('api/scenario', 'override nan', script=api_expect("from aev_ocp import load_scenario\nload_scenario('table1').with_overrides({'carfollowing.kappa': float('nan')})", says='kappa'), ok=(0,)))
    T.append(Try('api/scenario', 'override bool followers', script=api_expect("from aev_ocp import load_scenario\nload_scenario('table1').with_overrides({'platoon.followers': True})", says='followers'), ok=(0,)))
    T.append(Try('api/scenario', 'override unknown key', script=api_expect("from aev_ocp import load_scenario\nload_scenario('table1').with_overrides({'platoon.zeta': 1})", says='zeta'), ok=(0,)))
    T.append(Try('api/scenario', 'override numpy float', script=api_ok("import numpy as np\nfrom aev_ocp import load_scenario\ns = load_scenario('table1').with_overrides({'carfollowing.kappa': np.float64(0.05), 'simulation.t_end': 2.0})\nr = s.run()\nprint(r['proposed'].metrics()[0]['omega_model'])"), ok=(0,)))
    T.append(Try('api/scenario', 'override key not str', script=api_expect("from aev_ocp import load_scenario\nload_scenario('table1').with_overrides({3: 1})", says='3'), ok=(0,)))
    T.append(Try('api/scenario', 'path object with spaces', script=api_ok("from aev_ocp import load_scenario\ns = load_scenario(Path('a b/s c.toml'))\nprint(s.name)"), setup=write('a b/s c.toml', scen()), ok=(0,)))
    # --- Python API: ProblemBuilder ------------------------------------------------------------------------------------
    PB = "from aev_ocp import ProblemBuilder\nb = ProblemBuilder('p')\n"
    T.append(Try('api/builder', 'state name not identifier', script=api_expect(PB + "b.state('1x')", says='1x'), ok=(0,)))
    T.append(Try('api/builder', 'state lb > ub', script=api_expect(PB + "b.state('x', lb=2.5, ub=-1.5)", says='x'), ok=(0,)))
    T.append(Try('api/builder', 'state bound nan', script=api_expect(PB + "b.state('x', lb=float('nan'))", says='x'), ok=(0,)))
    T.append(Try("api/builder", "build empty", script=api_expect(PB + "b.build()", says="cost"), ok=(0,)))
    T.append(Try('api/builder', 'der of non-state', script=api_expect(PB + "x = b.state('x')\nu = b.control('u')\nb.set_der(u, x)", says='u'), ok=(0,)))
    T.append(Try('api/builder', 'der with string rhs', script=api_expect(PB + "x = b.state('x')\nb.set_der(x, 'fast')", says='x'), ok=(0,)))
    T.append(Try('api/builder', 'cost of non-scalar', script=api_expect(PB + "import casadi as ca\nx = b.state('x')\nb.set_der(x, -x)\nb.add_stage_cost(ca.vertcat(x, x), 'c')\nb.build()", says='c'), ok=(0,)))
    # --- Python API: closed loop with a user controller -----------------------------------------------------------------
    CL = textwrap.dedent("""\
        from aev_ocp import ClosedLoop, Command, PaperLeader
        class C:
            name = 'mine'
            dt = 0.1
            def __init__(self, a): self.a = a
            def reset(self): pass
            def describe(self): return {'controller': 'mine'}
            def command(self, obs): return Command(self.a(obs)) if callable(self.a) else self.a
        leader = PaperLeader()
        """)
    T.append(Try('api/closedloop', 'controller nan', script=api_expect(CL + "ClosedLoop(leader, [C(lambda o: float('nan'))]).run([0.3], [1.87], 2.0)", says='nan'), ok=(0,)))
    T.append(Try('api/closedloop', 'controller raises', script=api_expect(CL + "def boom(o): raise RuntimeError('controller bug')\nClosedLoop(leader, [C(boom)]).run([0.3], [1.87], 1.0)", 'ParameterError,RuntimeError', says='controller bug'), ok=(0,)))
    T.append(Try('api/closedloop', 'controller returns None', script=api_expect(CL + 'ClosedLoop(leader, [C(None)]).run([0.3], [1.87], 1.0)', says='mine'), ok=(0,)))
    T.append(Try('api/closedloop', 'controller dt 0', script=api_expect(CL + 'c = C(lambda o: 0.0)\nc.dt = 0.0\nClosedLoop(leader, [c]).run([0.3], [1.87], 1.0)', says='dt'), ok=(0,)))
    T.append(Try('api/closedloop', 'no controllers', script=api_expect(CL + 'ClosedLoop(leader, []).run([], [], 1.0)', says='controllers'), ok=(0,)))
    T.append(Try('api/closedloop', 'gaps length mismatch', script=api_expect(CL + 'ClosedLoop(leader, [C(lambda o: 0.0)]).run([0.3, 0.4], [1.87], 1.0)', says='gaps'), ok=(0,)))
    T.append(Try('api/closedloop', 't_end not multiple of dt', script=api_expect(CL + 'ClosedLoop(leader, [C(lambda o: 0.0)]).run([0.3], [1.87], 1.05)', says='t_end'), ok=(0,)))
    T.append(Try('api/closedloop', 'command a huge', script=api_ok(CL + "r = ClosedLoop(leader, [C(lambda o: 1e12)]).run([0.3], [1.87], 1.0)\nprint('events', r.events)"), ok=(0,)))
    T.append(Try('api/closedloop', 'command a bool', script=api_expect(CL + 'ClosedLoop(leader, [C(lambda o: True)]).run([3.0], [1.87], 1.0)', says='mine'), ok=(0,)))
    # --- misc commands ----------------------------------------------------------------------------------------------------
    T.append(Try("misc", "scenarios list", ["scenarios"], ok=(0,), check=stdout_has("table1")))
    T.append(Try("misc", "version", ["--version"], ok=(0,)))
    T.append(Try("misc", "unknown command", ["teleport"], ok=(2,)))
    T.append(Try('misc', 'safety out is file', ['safety', '--quick', '--out', 'f'], setup=write('f', 'x'), keep_user={'f': 'x'}, ok=(2,)))
    T.append(Try('misc', 'reproduce out under a file', ['reproduce', '--quick', '--out', 'f/x'], keep_user={'f': 'x'}, ok=(2,), says='f'))
    T.append(Try("misc", "sumo unknown scenario", ["sumo", "nope", "--out", "o"], ok=(2,), says="nope"))
    T.append(Try('misc', 'sumo share 2', ['sumo', 'sumo_ring', '--share', '2', '--out', 'o', '--no-plots'], ok=(2,), says='share', timeout=120))
    T.append(Try('misc', 'sumo share nan', ['sumo', 'sumo_ring', '--share', 'nan', '--out', 'o', '--no-plots'], ok=(2,), says='share', timeout=120))
    T.append(Try('misc', 'sumo controller module junk', ['sumo', 'sumo_ring', '--controller', 'os:system', '--t-end-s', '2', '--out', 'o', '--no-plots'], ok=(2,), says='controller', timeout=120))
    T.append(Try('misc', 'sumo t-end 0', ['sumo', 'sumo_ring', '--t-end-s', '0', '--out', 'o', '--no-plots'], ok=(2,), says='t-end', timeout=120))
    # --- batch 2: more scenario forms, sizes, ring/sumo files, signals at odd moments -------------------------------
    RING = 'name = "r"\n[ring]\nlength_m = 230.0\nvehicles = 22\nt_end_s = 5.0\n'
    for name, text, says in [
        ("ring vehicles 1", RING.replace("vehicles = 22", "vehicles = 1"), "vehicles"),
        ("ring length nan", RING.replace("230.0", "nan"), "length_m"),
        ("ring too short", RING.replace("230.0", "50.0"), "length_m"),
        ("ring unknown key", RING + "warp = 9\n", "warp"),
        ("ring human unknown", RING + 'human = "robot"\n', "human"),
        ("ring t_end 1e12", RING.replace("t_end_s = 5.0", "t_end_s = 1e12"), "t_end"),
        ("ring perturbation vehicle 99", RING + "[ring.perturbation]\nvehicle = 99\nshift_m = 2.0\n", "vehicle"),
    ]:
        T.append(Try('ring/file', name, ['ring', 'r.toml', '--out', 'o', '--no-plots'], setup=write('r.toml', text), ok=(2,), says=says, timeout=60))
    T.append(Try('ring/file', 'ring file ok', ['ring', 'r.toml', '--out', 'o', '--no-plots'], setup=write('r.toml', RING), ok=(0,), timeout=120))
    SUMO = '[sumo]\nnetwork = "ring"\nt_end_s = 3.0\ncontroller = "proposed"\nshare = 0.5\n'
    for name, text, says in [
        ("sumo network unknown", SUMO.replace('"ring"', '"moon"'), "network"),
        ("sumo step 0", SUMO + "step_s = 0.0\n", "step_s"),
        ("sumo net_file missing", SUMO.replace('network = "ring"', 'net_file = "nope.net.xml"'), "nope"),
        (
            "sumo net_file junk",
            SUMO.replace('network = "ring"', 'net_file = "junk.net.xml"\nroute_files = ["junk.net.xml"]'),
            "junk",
        ),
        ("sumo speed_mode string", SUMO + 'speed_mode = "fast"\n', "speed_mode"),
        ("sumo ids unknown (minor: silently drives nothing)", SUMO.replace("share = 0.5", 'ids = ["ring.99"]'), "ring.99"),
    ]:
        T.append(Try('sumo/file', name, ['sumo', 's.toml', '--out', 'o', '--no-plots'], setup=chain(write('s.toml', text), write('junk.net.xml', '<net><junk')), ok=(2,), says=says, timeout=90))
    T.append(Try('sumo/file', 'sumo ring 3 s', ['sumo', 's.toml', '--out', 'o', '--no-plots'], setup=write('s.toml', SUMO), ok=(0,), timeout=120, check=exists('o/fleet.json')))
    T.append(Try('sumo/file', 'sumo into user folder', ['sumo', 's.toml', '--out', 'o', '--no-plots'], setup=write('s.toml', SUMO), keep_user={'o/fleet.json': '{}'}, ok=(2,), timeout=120))
    for name, edits, code, says in [
        (
            "cycle unknown",
            {
                "leader.kind": 'kind = "cycle"\ncycle = "wltp9"',
                "leader.v0": "",
                "leader.amplitude": "",
                "leader.forcing_end": "",
            },
            2,
            "cycle",
        ),
        (
            "cycle past its end (long creep at standstill)",
            {
                "leader.kind": 'kind = "cycle"\ncycle = "us06"',
                "leader.v0": "",
                "leader.amplitude": "",
                "leader.forcing_end": "",
                "simulation.t_end": "t_end_s = 5000.0",
            },
            0,
            None,
        ),
        (
            "followers 10^6",
            {"platoon.followers": "followers = 1000000", "simulation.t_end": "t_end = 70.0"},
            2,
            "followers",
        ),
        ("10^7 samples", {"simulation.dt_out": "dt_out = 1e-6"}, 2, "dt_out"),
        (
            "constant leader v 0",
            {
                "leader.kind": 'kind = "constant"\nv = 0.0',
                "leader.v0": "",
                "leader.amplitude": "",
                "leader.forcing_end": "",
            },
            0,
            None,
        ),
        ("speeds0 list nan", {"platoon.speed0_factor": "speeds0 = [1.0, nan]"}, 2, "speeds0"),
        ("description 1 MB", {"extra": 'description = "' + "d" * 1_000_000 + '"\n'}, 2, "description"),
        ("name unicode", {"name": 'name = "plätoon"'}, 2, "name"),
        ("name with space", {"name": 'name = "my platoon"'}, 2, "name"),
        ("name dot", {"name": 'name = "."'}, 2, "name"),
    ]:
        T.append(Try('simulate/toml2', name, ['simulate', S, '--no-plots'], setup=write(S, scen(**edits)), ok=(code,), says=says, timeout=90))
    T[-8].ok = (0, 2)  # a 1 MB description: accepted or refused, never a crash
    T.append(Try('ocp/file', 'grid-file BOM CRLF toml', ['ocp', 'current-profile', '--grid-file', 'g.toml', '--no-refine', '--out', 'o'], setup=write('g.toml', '\ufeffE_req = [1500.0]\r\nt_f = [45.0]\r\n'), ok=(0, 2), timeout=120))
    T.append(Try('ocp/file', 'grid-file nested', ['ocp', 'current-profile', '--grid-file', 'g.json', '--out', 'o'], setup=write('g.json', '[' * 50000 + ']' * 50000), ok=(2,), says='g.json'))
    T.append(Try('ocp/file', 'grid-file empty list', ['ocp', 'current-profile', '--grid-file', 'g.json', '--out', 'o'], setup=write('g.json', '{"E_req": []}'), ok=(2,), says='E_req'))
    T.append(Try('ocp/file', 'cell file junk', ['ocp', 'prop31', '--cell', 'c.toml', '--out', 'o'], setup=write('c.toml', 'capacity_Ah = -3\n'), ok=(2,), says='c.toml'))
    T.append(Try('stability', 'user gain.png', ['stability', '--law', 'ovm', '--out', 'o', '--linear-only'], keep_user={'o/gain.png': 'not a png'}, ok=(2,)))
    T.append(Try('stability', 'ring density 0', ['stability', '--law', 'idm', '--ring', '10', '--density-per-km', '0', '--out', 'o'], ok=(2,), says='density'))
    T.append(Try('study', 'mpc solver junk', ['study', 'st.toml', '--out', 'st', '--in-process'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S) + '[[controllers.mpc]]\nlabel = "m"\nsolver = "magic"\n')), ok=(2,), says='solver'))
    T.append(Try('study', 'controllers label clash', ['study', 'st.toml', '--out', 'st', '--in-process'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S) + '[[controllers.mpc]]\nlabel = "ovfl"\n')), ok=(2,), says='ovfl'))
    T.append(Try('study', 'resume with one more value', ['study', 'st.toml', '--out', 'st', '--in-process', '--no-report'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S)), run_cli('study', 'st.toml', '--out', 'st', '--in-process', '--no-report'), write('st.toml', STUDY.replace('{scen}', S).replace('0.04]', '0.04, 0.06]'))), ok=(0,), check=lambda d, r: None if 'stored' in r['stderr'] else 'minor: resume not reported'))
    T.append(Try('study', 'trajectories and load', ['study', 'st.toml', '--out', 'st', '--in-process', '--no-report', '--trajectories'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(0,), check=lambda d, r: None if any((d / 'st' / 'trajectories').iterdir()) else 'defect: no trajectories'))
    T.append(Try('interrupt', 'simulate SIGINT 0.3s (startup)', ['simulate', 'table1', '--out', 'o'], sig=(signal.SIGINT, 0.3), ok=(130, 0)))
    T.append(Try('interrupt', 'study in-process SIGINT 3s', ['study', 'st.toml', '--out', 'st', '--in-process'], setup=chain(write(S, scen(**{'simulation.t_end': 't_end = 30.0'})), write('st.toml', big_study(150).replace('{scen}', S))), sig=(signal.SIGINT, 3.0), ok=(130, 0), timeout=60))
    T.append(Try('interrupt', 'ocp oracle SIGTERM 0.6s', ['ocp', 'oracle', '--out', 'o'], sig=(signal.SIGTERM, 0.6), ok=(130, 0)))
    T.append(Try('interrupt', 'sumo SIGINT 3s', ['sumo', 'sumo_ring', '--out', 'o', '--no-plots'], sig=(signal.SIGINT, 3.0), ok=(130, 0)))
    T.append(Try('interrupt', 'sumo sweep SIGINT 4s', ['sumo', 'sumo_ring', '--sweep', '--workers', '2', '--out', 'o', '--no-plots'], sig=(signal.SIGINT, 4.0), ok=(130, 0, 2), timeout=90))
    T.append(Try('interrupt', 'ring sweep SIGTERM 3s', ['ring', 'sweep', '--out', 'o', '--no-plots'], sig=(signal.SIGTERM, 3.0), ok=(130, 0)))
    T.append(Try('load', 'ocp output', script=api_ok("import aev_ocp\nr = aev_ocp.load('o')\nprint(type(r).__name__)"), setup=run_cli('ocp', 'current-profile', '--grid', 'E_req=1500', '--grid', 't_f=45', '--no-refine', '--out', 'o'), ok=(0,), timeout=120))
    T.append(Try('load', 'symlink loop folder', script=api_expect("import aev_ocp\naev_ocp.load('a')", 'LoadError'), setup=chain(symlink('a', 'b'), symlink('b', 'a')), ok=(0,)))
    T.append(Try('load', 'manifest is a folder', script=api_expect("import aev_ocp\naev_ocp.load('o')", 'LoadError'), setup=lambda d: (d / 'o' / 'manifest.json').mkdir(parents=True), ok=(0,)))
    T.append(Try('env', 'MAX_MEMORY_GB negative', sim, setup=write(S, scen()), env={'AEV_OCP_MAX_MEMORY_GB': '-4'}, ok=(2,), says='AEV_OCP_MAX_MEMORY_GB'))
    T.append(Try('env', 'MAX_MEMORY_GB 0.5 ok', sim, setup=write(S, scen()), env={'AEV_OCP_MAX_MEMORY_GB': '0.5'}, ok=(0,)))
    # --- batch 3: every [mpc] key kind through --set, more of the Python API -----------------------------------------
    for name, kv, says in [
        ("tol 0", "mpc.tol=0", "tol"),
        ("max_iter 2.5", "mpc.max_iter=2.5", "max_iter"),
        ("max_iter true", "mpc.max_iter=true", "max_iter"),
        ("rti_iterations 0", "mpc.rti_iterations=0", "rti_iterations"),
        ("rti_hessian junk", "mpc.rti_hessian=diagonal", "rti_hessian"),
        ("codegen string", "mpc.codegen=yes", "codegen"),
        ("predictor_window 1", "mpc.predictor_window=1", "predictor_window"),
        ("max_cpu_time_s -1", "mpc.max_cpu_time_s=-1", "max_cpu_time_s"),
        ("formulation junk", "mpc.formulation=s99", "formulation"),
        ("dt 1e-9", "mpc.dt=1e-9", "dt"),
        ("w_V list", "mpc.w_V=[1,2]", "w_V"),
        ("verbose 3", "mpc.verbose=3", "verbose"),
        ("mpc table replaced by value", "mpc=3", "mpc"),
    ]:
        T.append(Try("mpc/--set", name, [*mp, "--set", kv], ok=(2,), says=says, timeout=120))
    T.append(Try("mpc/--set", "dt not dividing t-end", [*mp, "--set", "mpc.dt=0.13"], ok=(0, 2), timeout=120))
    T.append(Try('mpc-export', 'export --set tol nan', ['mpc-export', 'mpc_paper_single', '--out', 'ex', '--set', 'mpc.tol=nan'], ok=(2,), says='tol'))
    T.append(Try('mpc-export', 'export platoon', ['mpc-export', 'mpc_paper_platoon', '--out', 'ex'], ok=(0, 2), timeout=180))
    T.append(Try('mpc-export', 'export out with quote', ['mpc-export', 'mpc_paper_single', '--out', 'it\'s "ex"', '--build'], ok=(0,), timeout=240))
    API = [
        ("make_law unknown", "from aev_ocp import make_law\nmake_law('warp')", "warp"),
        ("make_law bad coefficient", "from aev_ocp import make_law\nmake_law('idm', v0=float('nan'))", "v0"),
        (
            "CarFollowingParams negative",
            "from aev_ocp import CarFollowingParams\nCarFollowingParams(kappa=-0.2)",
            "kappa",
        ),
        ("VehicleParams string", "from aev_ocp import VehicleParams\nVehicleParams(mass_kg='heavy')", "mass_kg"),
        ("CellParams soc0 2", "from aev_ocp import CellParams\nCellParams(soc0=2.0)", "soc0"),
        ("SimOptions rtol 0", "from aev_ocp import SimOptions\nSimOptions(rtol=0.0)", "rtol"),
        ("MPCSettings N 0", "from aev_ocp import MPCSettings\nMPCSettings(N=0)", "N"),
        ("MPCSettings solver junk", "from aev_ocp import MPCSettings\nMPCSettings(solver='magic')", "solver"),
        (
            "simulate_platoon gaps mismatch",
            "from aev_ocp import simulate_platoon, PaperLeader, Proposed\nsimulate_platoon(PaperLeader(), [Proposed()], [0.3, 0.4], [1.8], 2.0)",
            "gaps",
        ),
        (
            "simulate_platoon t_end nan",
            "from aev_ocp import simulate_platoon, PaperLeader, Proposed\nsimulate_platoon(PaperLeader(), [Proposed()], [0.3], [1.8], float('nan'))",
            "t_end",
        ),
        (
            "simulate_platoon law string",
            "from aev_ocp import simulate_platoon, PaperLeader\nsimulate_platoon(PaperLeader(), ['proposed'], [0.3], [1.8], 2.0)",
            "law",
        ),
        (
            "Scenario.replace unknown",
            "from aev_ocp import load_scenario\nload_scenario('table1').replace(warp=3)",
            "warp",
        ),
        (
            "Scenario.replace t_end nan",
            "from aev_ocp import load_scenario\nload_scenario('table1').replace(t_end=float('nan'))",
            "t_end",
        ),
        (
            "SpeedTrace decreasing times",
            "from aev_ocp import SpeedTrace\nSpeedTrace([0.0, 2.0, 1.0], [1.0, 1.0, 1.0])",
            "time",
        ),
        ("drive_cycle unknown", "from aev_ocp import drive_cycle, Units\ndrive_cycle('wltp9', Units())", "wltp9"),
        (
            "run_study bad executor",
            "from aev_ocp.study import run_study\nrun_study('st.toml', 'out', executor='cloud')",
            "executor",
        ),
        ("load_cell unknown", "from aev_ocp.cells import load_cell\nload_cell('unobtainium')", "unobtainium"),
        (
            "ControlSequence nan",
            "from aev_ocp import ControlSequence\nControlSequence((0.1, float('nan')), 0.1)",
            "ControlSequence",
        ),
        (
            "Sensors negative noise",
            "from aev_ocp.estimation import Sensors\nSensors(speed_noise_mps=-1.0)",
            "speed_noise",
        ),
        ("register_law junk", "from aev_ocp import register_law\nregister_law('mine', 42)", "mine"),
    ]
    for name, body, says in API:
        T.append(Try('api/more', name, script=api_expect(body, 'ParameterError,TypeError,ValueError', says=says), setup=write('st.toml', STUDY.replace('{scen}', 'table1')), ok=(0,), timeout=60, check=plain_value_error))
    T.append(Try('api/more', 'plot_trajectories to unicode path', script=api_ok("from aev_ocp import load_scenario, plot_trajectories\ns = load_scenario('table1').with_overrides({'simulation.t_end': 2.0})\nr = s.run()['proposed']\nplot_trajectories(r, 'plöt dir/ä b.png')\nassert Path('plöt dir/ä b.png').stat().st_size > 1000"), setup=lambda d: (d / 'plöt dir').mkdir(), ok=(0,), timeout=60))
    T.append(Try('api/more', 'plot_trajectories creates its folder', script=api_ok("from aev_ocp import load_scenario, plot_trajectories\ns = load_scenario('table1').with_overrides({'simulation.t_end': 2.0})\nr = s.run()['proposed']\nplot_trajectories(r, 'nope/x.png')\nassert Path('nope/x.png').is_file()"), ok=(0,), timeout=60))
    T.append(Try('api/more', 'metrics of a loaded run equal saved', script=api_ok("import aev_ocp, json, math\nr = aev_ocp.load('o')\nm = r.metrics()[0]\nsaved = r.meta['output']['saved_metrics']\nprint(type(saved))"), setup=saved, ok=(0,)))
    # --- batch 4: solver, stability and estimation APIs ---------------------------------------------------------------
    TOY = (
        "import casadi as ca\nfrom aev_ocp import ProblemBuilder, OCPSolver, TranscriptionOptions\n"
        "b = ProblemBuilder('toy')\nx = b.state('x')\nu = b.control('u', -1.5, 1.5)\nb.set_der(x, u)\n"
        "b.add_stage_cost(x**2 + 0.1*u**2, 'c')\npr = b.build()\n"
    )
    API4 = [
        ("TranscriptionOptions N 0", "from aev_ocp import TranscriptionOptions\nTranscriptionOptions(N=0)", "N"),
        (
            "TranscriptionOptions linear_solver junk",
            TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10, linear_solver='magic'))\ns.solve([1.0], 2.0)",
            "linear_solver",
        ),
        (
            "OCPSolver x0 wrong length",
            TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([1.0, 2.0], 2.0)",
            "x0",
        ),
        ("OCPSolver x0 nan", TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([float('nan')], 2.0)", "x0"),
        ("OCPSolver t_f 0", TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([1.0], 0.0)", "t_f"),
        (
            "OCPSolver t_f nan",
            TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([1.0], float('nan'))",
            "t_f",
        ),
        (
            "OCPSolver p given without parameters",
            TOY + "s = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([1.0], 2.0, p=[3.0])",
            "p",
        ),
        (
            "OCPSolver guess wrong shape",
            TOY
            + "import numpy as np\ns = OCPSolver(pr, TranscriptionOptions(N=10))\ns.solve([1.0], 2.0, guess=(np.zeros((3, 3)), np.zeros((1, 10))))",
            "guess",
        ),
        (
            "stability analyse speed negative",
            "from aev_ocp.stability import analyse\nfrom aev_ocp import OVM\nanalyse(OVM(), -1.0)",
            "v",
        ),
        (
            "stability analyse speed nan",
            "from aev_ocp.stability import analyse\nfrom aev_ocp import OVM\nanalyse(OVM(), float('nan'))",
            "v",
        ),
        (
            "stability analyse speed above V_inf",
            "from aev_ocp.stability import analyse\nfrom aev_ocp import OVM\nanalyse(OVM(), 2.5)",
            "v",
        ),
        (
            "run_closed_loop soc0 1.5",
            "from aev_ocp import run_closed_loop, PaperLeader, ControlSequence\nrun_closed_loop(PaperLeader(), [ControlSequence((0.0,)*10, 0.1)], [0.5], [1.8], 1.0, soc0=1.5)",
            "soc0",
        ),
        (
            "run_closed_loop speeds0 nan",
            "from aev_ocp import run_closed_loop, PaperLeader, ControlSequence\nrun_closed_loop(PaperLeader(), [ControlSequence((0.0,)*10, 0.1)], [0.5], [float('nan')], 1.0)",
            "speed",
        ),
        (
            "ControlSequence too short",
            "from aev_ocp import run_closed_loop, PaperLeader, ControlSequence\nrun_closed_loop(PaperLeader(), [ControlSequence((0.0,)*3, 0.1)], [0.5], [1.8], 1.0)",
            "control sequence",
        ),
        (
            "SampledLaw dt 0",
            "from aev_ocp import SampledLaw, Proposed, ClosedLoop, PaperLeader\nClosedLoop(PaperLeader(), [SampledLaw(Proposed(), 0.0)]).run([0.5], [1.8], 1.0)",
            "dt",
        ),
        ("Mismatch spread beyond -90 %", "from aev_ocp.estimation import Mismatch\nMismatch(mass_rel=-0.95)", "mass"),
        (
            "MPC dt not dividing t_end",
            "from aev_ocp import MPCSettings, ClosedLoop, PaperLeader, Proposed\nClosedLoop(PaperLeader(), [Proposed(), MPCSettings(N=10)]).run([0.5, 3.0], [1.8, 1.8], 0.55)",
            "t_end",
        ),
        (
            "StudyOutput trajectory unknown",
            "import aev_ocp\nr = aev_ocp.load('st')\nr.trajectory(99, 'proposed')",
            "99",
        ),
        ("load_table missing", "from aev_ocp.study import load_table\nload_table('nope')", "nope"),
    ]
    for name, body, says in API4:
        T.append(Try('api/solvers', name, script=api_expect(body, 'ParameterError,TypeError,ValueError,LoadError', says=says), setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S)), run_cli('study', 'st.toml', '--out', 'st', '--in-process', '--no-report')) if "load('st')" in body else None, ok=(0,), timeout=120, check=plain_value_error))
    T.append(Try('api/solvers', 'OCPSolver toy solves (closed form)', script=api_ok(TOY + 'import math\ns = OCPSolver(pr, TranscriptionOptions(N=40))\nr = s.solve([1.0], 3.0)\nprint(r.status, r.objective)'), ok=(0,), timeout=60))
    # --- batch 5: user files in every command's folder, a scheduler that never answers --------------------------------
    T.append(Try('outdir', 'ring user ring.json', ['ring', 'sugiyama', '--t-end-s', '3', '--out', 'o', '--no-plots'], keep_user={'o/ring.json': '{}'}, ok=(2,), timeout=60))
    T.append(Try('outdir', 'safety user safety.md', ['safety', '--quick', '--out', 'o', '--no-plots'], keep_user={'o/safety.md': '# mine'}, ok=(2,), timeout=120))
    T.append(Try('outdir', 'reproduce user report.md', ['reproduce', '--quick', '--out', 'o'], keep_user={'o/report.md': '# mine'}, ok=(2,), timeout=60))
    T.append(Try('outdir', 'mpc user results.json', ['mpc', 'mpc_paper_single', '--out', 'o', '--t-end', '1', '--no-ocpd'], keep_user={'o/results.json': '{}'}, ok=(2,), timeout=120))
    T.append(Try('outdir', 'ocp into folder of a simulate run', ['ocp', 'prop31', '--out', 'o'], setup=run_cli('simulate', 'table1', '--out', 'o', '--no-plots', '--set', 'simulation.t_end=2'), ok=(2,), timeout=60))
    T.append(Try('outdir', 'stability into folder of a ring run', ['stability', '--law', 'ovm', '--linear-only', '--out', 'o'], setup=run_cli('ring', 'sugiyama', '--t-end-s', '3', '--out', 'o', '--no-plots'), ok=(2,), timeout=60))
    T.append(Try('outdir', 'simulate into the cwd', ['simulate', S, '--out', '.', '--no-plots'], setup=write(S, scen()), ok=(0, 2), timeout=60))
    T.append(Try('outdir', "simulate --out ''", ['simulate', S, '--out', '', '--no-plots'], setup=write(S, scen()), ok=(2,), timeout=60))
    T.append(Try('study', 'scheduler accepts and stays silent', ['study', 'st.toml', '--out', 'st', '--scheduler', 'tcp://127.0.0.1:PORT'], setup=chain(write(S, scen()), write('st.toml', STUDY.replace('{scen}', S))), ok=(1, 2), timeout=90, check=lambda d, r: None if r['wall_s'] < 60 else 'defect: took over 60 s'))
    # fmt: on
    for t in T:  # known and reported, not fixed: classified minor while it stays so
        if t.name.startswith("sumo ids unknown"):
            t.ok, t.check = (0, 2), _silent_ids
    return T


def _silent_ids(d: Path, r: dict[str, Any]) -> str | None:
    return "minor: a listed id that is not in the network drives nothing, without a word" if r["rc"] == 0 else None


def _swap(ps: list[Path]) -> None:
    a, b = ps[0].read_bytes(), ps[1].read_bytes()
    ps[0].write_bytes(b)
    ps[1].write_bytes(a)


def _rmtree(p: Path) -> None:

    shutil.rmtree(p)


def main(argv: list[str] | None = None) -> int:
    return run_probe(tries, argv, __doc__.splitlines()[0], "probe_reliability_3.json", jobs=2)


if __name__ == "__main__":
    sys.exit(main())
