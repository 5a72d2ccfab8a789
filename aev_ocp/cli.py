"""Command line: ``aev-ocp reproduce | simulate | scenarios | replay | ocp | mpc | mpc-export | stability | study | safety | sumo``.

A thin layer over the Python API (:mod:`aev_ocp.reproduce`, :mod:`aev_ocp.scenarios`,
:mod:`aev_ocp.report`). Every subcommand reports errors the same way (:func:`guarded`): one line
``aev-ocp: error: ...`` on stderr, never a traceback. Exit codes: 0 success, 1 a run failed (a
simulation event such as a collision, a solver failure; its results are still written), 2 bad input
(invalid scenario or parameters, unreadable file, bad arguments, an output folder holding another
run's files, a run too large for memory), 130 interrupted (Ctrl-C or SIGTERM; partial files are
never left behind). Set ``AEV_OCP_DEBUG=1`` to get the traceback of an unexpected error.
"""

from __future__ import annotations

import signal
import sys
import threading
from typing import Any


def _interrupted_while_starting(signum: int, frame: Any) -> None:  # noqa: ARG001 - signal handler signature
    """Ctrl-C or SIGTERM while the command still imports NumPy, CasADi, ...: the one line, exit 130, no traceback."""
    print("aev-ocp: error: interrupted", file=sys.stderr, flush=True)
    raise SystemExit(130)


# handlers can only be set on the main thread; a worker process that multiprocessing starts re-imports this module
# as __mp_main__, and a pool stopping it (SIGTERM) must not make it print the command's 'interrupted' line
_ON_MAIN = threading.current_thread() is threading.main_thread() and __name__ != "__mp_main__"
_BEFORE = (
    {s: signal.signal(s, _interrupted_while_starting) for s in (signal.SIGINT, signal.SIGTERM)} if _ON_MAIN else {}
)

import argparse  # noqa: E402 - after the handler: these imports can be interrupted too
import dataclasses  # noqa: E402
import importlib  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Sequence  # noqa: E402

from .console import EXIT_INTERRUPTED as EXIT_INTERRUPTED  # noqa: E402 - re-exported with the other exit codes
from .console import (  # noqa: E402
    EXIT_BAD_INPUT,
    EXIT_FAILED_RUN,
    EXIT_OK,
    OneLineParser,
    add_set_option,
    error_line,
    guarded,  # noqa: E402
    warning_line,
)

for _sig, _handler in _BEFORE.items():  # the modules are in: guarded() handles signals from here on
    signal.signal(_sig, _handler if _handler is not None else signal.SIG_DFL)

_err, _warn, _Parser = error_line, warning_line, OneLineParser


def _version_line() -> str:
    from .provenance import versions

    v = versions()
    commit = f", commit {v['git_commit']}" if v["git_commit"] else ""
    return (
        f"aev-ocp {v['aev_ocp']}{commit} (CasADi {v['casadi']}, NumPy {v['numpy']}, Python {v['python']}, "
        f"{v['platform']})"
    )


class _VersionAction(argparse.Action):
    """``--version``: one unwrapped line on stdout, exit 0."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kw: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kw)

    def __call__(self, parser: argparse.ArgumentParser, *args: Any, **kw: Any) -> None:
        print(_version_line())
        parser.exit(0)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (sub-commands reproduce, simulate, scenarios; ocp and mpc are dispatched)."""
    p = _Parser(prog="aev-ocp", description="Energy-aware control of autonomous electric vehicles (CasADi).")
    p.add_argument("--version", action=_VersionAction, help="print the versions and the git commit, then exit")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    r = sub.add_parser("reproduce", help="reproduce the paper's figures and Table 1, write report.md")
    r.add_argument("--out", default="results", help="output folder (default: results/)")
    size = r.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="a cheap smoke run (short horizons), not the reproduction")
    size.add_argument(
        "--full",
        action="store_true",
        help="the extended studies (robustness, MPC drive cycles, battery life) at full size; the default runs the "
        "reduced versions the report's table lists (the paper's figures and tables are whole either way)",
    )
    r.add_argument(
        "--workers",
        type=int,
        default=None,
        help="independent sections run on this many worker processes (default: min(2, cores); 1: one process)",
    )
    r.add_argument(
        "--model-units",
        action="store_true",
        help="figure axes in the paper's model units (default: s, m, km/h through each scenario's units)",
    )
    s = sub.add_parser("simulate", help="simulate a scenario file: trajectories CSV, metrics JSON, plots")
    s.add_argument("scenario", help="a scenario .toml file or the name of a shipped scenario (e.g. table1)")
    s.add_argument("--out", default=None, help="output folder (default: results/<scenario name>/)")
    s.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    add_set_option(
        s,
        "override a scenario key, e.g. --set simulation.t_end_s=40 (SI) or --set simulation.t_end=20 "
        "(model time); repeatable, checked like the file, the command line over the file",
    )
    s.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="S",
        help="wall-clock limit [s]: a run still going then is stopped (within ~0.05 s) and not written, runs not "
        "started are skipped, the finished ones written, exit 1 (default: none)",
    )
    sub.add_parser("scenarios", help="list the shipped scenarios (platoon, ring and SUMO)")
    rp = sub.add_parser(
        "replay",
        help="drive one vehicle exactly on a speed trace and print its battery energy (kWh/100 km), heat, "
        "charge throughput and SOC",
    )
    rp.add_argument(
        "trace", help="a shipped EPA cycle (udds, hwfet, us06) or a CSV file with columns time_s, speed_mps"
    )
    rp.add_argument(
        "--powertrain",
        choices=("map", "constant"),
        default="map",
        help="map: FASTSim's 2022 Tesla Model 3 RWD powertrain (default); constant: the paper's η switch (η = 0.8)",
    )
    rp.add_argument("--soc0", type=float, default=None, help="initial state of charge of the cells (default 0.8)")
    rp.add_argument("--json", default=None, metavar="FILE", help="also write the summary to FILE (JSON, atomically)")
    sub.add_parser("ocp", help="optimal-control problems (see aev-ocp ocp --help)", add_help=False)
    sub.add_parser("mpc", help="model predictive control (see aev-ocp mpc --help)", add_help=False)
    sub.add_parser(
        "mpc-export", help="export a scenario's MPC step as a C library (see aev-ocp mpc-export --help)", add_help=False
    )
    sub.add_parser(
        "stability", help="string stability of a law or the MPC (see aev-ocp stability --help)", add_help=False
    )
    sub.add_parser(
        "study", help="sweeps and Pareto fronts from a study file (see aev-ocp study --help)", add_help=False
    )
    sub.add_parser(
        "ring",
        help="mixed traffic on a ring road: Sugiyama, Stern, penetration sweep (see aev-ocp ring --help)",
        add_help=False,
    )
    sub.add_parser(
        "safety",
        help="the safety suite: braking, stationary, slower and cut-in cases for every controller "
        "(see aev-ocp safety --help)",
        add_help=False,
    )
    sub.add_parser(
        "tune",
        help="equal tuning effort: every controller tuned with the same budget, default vs tuned "
        "(see aev-ocp tune --help)",
        add_help=False,
    )
    sub.add_parser(
        "sumo",
        help="drive the toolkit's controllers inside SUMO (optional extra [sumo]; see aev-ocp sumo --help)",
        add_help=False,
    )
    return p


def _load_scenario_with_warnings(path: str, sets: Sequence[str] = ()):  # noqa: ANN202 - returns Scenario
    from .scenarios import load_with_sets

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scenario = load_with_sets(path, sets)
    for w in caught:
        _warn(str(w.message))
    from .provenance import declare

    declare(scenario)  # every JSON this command writes names the scenario and its SHA-256
    return scenario


def cmd_simulate(args: argparse.Namespace) -> int:
    """Run every law of a scenario and write its files; exit 1 if any run stopped on an event."""
    from .report import scenario_metrics_rows, write_scenario_outputs

    from .results import claim_output_dir, default_output_dir
    from .saved import OUTPUT_FILES, save_output, settings_of

    from .progress import TIME_LIMIT, Progress, TimeLimitReached, check_time_limit, time_limited

    time_limit = check_time_limit(args.time_limit)
    scenario = _load_scenario_with_warnings(args.scenario, args.sets)
    for sec in sorted(set(scenario.extra) & set(UNUSED_BY_SIMULATE)):
        _warn(
            f"scenario {scenario.name}: simulate does not use the [{sec}] table (it runs the closed-form laws "
            f"only); {UNUSED_BY_SIMULATE[sec].format(name=args.scenario)}"
        )
    out = Path(args.out) if args.out else default_output_dir(scenario.name)
    labels = [label for label, _ in scenario.runs()]
    claim_output_dir(
        out,
        "simulate",
        scenario.name,
        str(scenario.source) if scenario.source else None,
        [f"{lab}.{ext}" for lab in labels for ext in ("csv", "png")] + ["metrics.json", "metrics.md", *OUTPUT_FILES],
    )
    bars: dict[str, Progress] = {}
    T = scenario.units.time_s
    clock = Progress("", time_limit_s=time_limit)

    def progress(label: str, t: float, t_end: float) -> None:  # one line per run every 2 s, with an ETA, in s
        bar = bars.setdefault(label, Progress(f"{scenario.name}] [{label}", t_end * T, unit="s"))
        bar.update(t * T, t_end * T, "t [s] =")

    results: dict[str, Any] = {}
    skipped: list[str] = []
    stopped: str | None = None  # the run the time limit stopped while it ran (its partial result is dropped)
    with time_limited(clock):  # the compiled run polls the clock while it integrates, the Python one per chunk
        for label, _ in scenario.runs():
            if stopped is not None or clock.expired():
                skipped.append(label)
                continue
            try:
                results.update(scenario.run(progress=progress, only=label))
            except TimeLimitReached:
                stopped = label
    if not results:
        _err(
            f"scenario {scenario.name}: --time-limit {time_limit:g} s passed before the first run "
            f"{'finished' if stopped else 'started'}; nothing written"
        )
        return EXIT_FAILED_RUN
    files = write_scenario_outputs(scenario.name, results, out, plots=not args.no_plots)
    files += save_output(
        out, "simulate", results, settings=settings_of(scenario, sets=list(args.sets), time_limit_s=time_limit)
    )
    headers, rows = scenario_metrics_rows(results)
    keep = [0, 1, 2, 4, 5, 7, 8, 10]  # run, n, battery energy, ω [J/kg], pack ∫Q [J], ΔSOC, min gap [m], status
    keep += list(range(11, len(headers)))  # the thermal model's peak temperature [K], time above T_max [s]
    print("  ".join(f"{headers[k]:>12}" for k in keep))
    for row in rows:
        print("  ".join(f"{row[k]:>12}" for k in keep))
    print(f"wrote {len(files)} files to {out}/")
    failed = [(label, r.events[0]) for label, r in results.items() if r.events]
    for label, event in failed:
        _err(f"scenario {scenario.name}, run {label}: {event} (results up to that time written to {out}/)")
    if skipped or stopped:
        what = ([f"run {stopped} stopped before its end (not written)"] if stopped else []) + (
            [f"runs {', '.join(skipped)} not started"] if skipped else []
        )
        _err(
            f"scenario {scenario.name}: stopped by --time-limit {time_limit:g} s ({TIME_LIMIT}): "
            f"{'; '.join(what)}; the finished runs are written to {out}/"
        )
    return EXIT_FAILED_RUN if failed or skipped or stopped else EXIT_OK


#: Scenario tables that ``simulate`` does not use, and where they are used (a one-line warning names them).
UNUSED_BY_SIMULATE: dict[str, str] = {"mpc": "run 'aev-ocp mpc {name}' for the MPC closed loop"}


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Reproduce the paper into ``--out``."""
    from .reproduce import ReproduceConfig, reproduce
    from .results import claim_output_dir

    claim_output_dir(args.out, "reproduce", "paper", None, ["report.md", "report.html"])
    config = ReproduceConfig.quick() if args.quick else ReproduceConfig.full() if args.full else ReproduceConfig()
    if args.model_units:
        config = dataclasses.replace(config, si_units=False)
    import os

    from .limits import check_local_workers

    workers = check_local_workers(args.workers) or min(2, os.cpu_count() or 1)  # a bad --workers names itself
    report = reproduce(
        args.out, config, workers=workers
    )  # its last stderr line: [N/N] done, both files and the verdict
    print(f"wrote {report} and {report.parent / 'report.html'}")
    return EXIT_OK


def cmd_scenarios(args: argparse.Namespace) -> int:
    """List shipped scenarios with their descriptions."""
    from .scenarios import shipped_scenarios

    from .scenarios import ScenarioError

    for name, path in shipped_scenarios().items():
        try:
            scenario = _load_scenario_with_warnings(str(path))
        except ScenarioError as exc:  # one broken local file must not hide the others
            _warn(f"skipping {path}: {exc}")
            continue
        print(f"{name:16s} {scenario.description}  [{path}]")
    # the ring and SUMO scenarios run under their own commands; their descriptions are read, not the scenarios
    others: list[tuple[str, str, Path]] = [("ring", n, p) for n, p in shipped_scenarios("ring").items()]
    try:
        from .sumo.scenario import shipped_sumo_scenarios

        others += [("sumo", n, p) for n, p in shipped_sumo_scenarios().items()]
    except ImportError:  # an installation without the SUMO coupling
        pass
    for command, name, path in others:
        print(f"{name:16s} {_description(path)}  [{path}] (aev-ocp {command} {name})")
    return EXIT_OK


def _description(path: Path) -> str:
    """The first line of a scenario file's ``description`` (empty if the file cannot be read)."""
    import tomllib

    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return ""
    text = doc.get("description", "")
    return " ".join(str(text).split())[:160] if isinstance(text, str) else ""


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay a speed trace exactly (:func:`aev_ocp.replay`) and print its battery energy; exit 1 on an event."""
    from .results import write_json
    from .trace_replay import replay

    res = replay(args.trace, powertrain=args.powertrain, soc0=args.soc0)
    s = res.summary()
    print(
        f"{s['trace']} ({s['powertrain']} powertrain): {s['distance_m'] / 1000:.4g} km in {s['duration_s']:.6g} s\n"
        f"  battery energy {s['battery_energy_kWh_per_100km']:.4g} kWh/100 km ({s['battery_energy_Wh_per_km']:.4g} "
        f"Wh/km, {s['battery_energy_J_per_km'] / 1e3:.4g} kJ/km)\n"
        f"  where it went per km: traction {s['traction_J_per_km'] / 1e3:.4g} kJ, losses "
        f"{s['powertrain_loss_J_per_km'] / 1e3:.4g} kJ, auxiliary {s['aux_J_per_km'] / 1e3:.4g} kJ, regeneration "
        f"−{s['regen_J_per_km'] / 1e3:.4g} kJ (friction brakes {s['friction_brake_J_per_km'] / 1e3:.4g} kJ)\n"
        f"  pack heat {s['heat_pack_J_per_km'] / 1e3:.4g} kJ/km, charge throughput "
        f"{s['charge_throughput_Ah_per_km']:.4g} Ah/km, SOC {s['soc_start']:.4g} -> {s['soc_end']:.4g}, "
        f"peak cell current {s['max_abs_current_A']:.4g} A (limit {s['cell_current_limit_A']:g} A)"
    )
    if args.json:
        try:
            print(f"wrote {write_json(args.json, s)}")
        except OSError as exc:  # a folder, a read-only place: name the option, not a temporary file
            _err(f"--json {args.json}: cannot write it ({exc.strerror or type(exc).__name__})")
            return EXIT_BAD_INPUT
    for e in res.events:
        _err(f"replay {s['trace']}: {e}")
    return EXIT_FAILED_RUN if res.events else EXIT_OK


def _dispatch(module: str, func: str, argv: list[str]) -> int:
    try:
        mod = importlib.import_module(module)
        fn = getattr(mod, func)
    except (ImportError, AttributeError) as exc:
        _err(f"'{module.split('.')[1]}' commands are not available in this installation ({exc})")
        return EXIT_BAD_INPUT
    rc = fn(argv)
    return int(rc or 0)


#: Sub-commands with their own parser: name -> (module, function returning the parser).
SUBCOMMAND_PARSERS: dict[str, tuple[str, str]] = {
    "ocp": ("aev_ocp.ocp.cli", "_parser"),
    "mpc": ("aev_ocp.mpc.cli", "build_parser"),
    "mpc-export": ("aev_ocp.mpc.export", "build_parser"),
    "stability": ("aev_ocp.stability.cli", "build_parser"),
    "study": ("aev_ocp.study.cli", "build_parser"),
    "safety": ("aev_ocp.safety.cli", "build_parser"),
    "ring": ("aev_ocp.ring.cli", "build_parser"),
    "sumo": ("aev_ocp.sumo.cli", "build_parser"),
    "tune": ("aev_ocp.tuning", "build_parser"),
}


def command_parser(name: str) -> argparse.ArgumentParser:
    """The argument parser of sub-command ``name`` (``simulate``, ``mpc``, ...); KeyError if there is none."""
    if name in SUBCOMMAND_PARSERS:
        module, func = SUBCOMMAND_PARSERS[name]
        parser: argparse.ArgumentParser = getattr(importlib.import_module(module), func)()
        return parser
    top = build_parser()
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def parse_command_line(argv: Sequence[str]) -> argparse.Namespace:
    """Parse (never run) the arguments of an ``aev-ocp`` command line, e.g. ``["mpc", "x.toml", "--t-end", "60"]``;
    a bad line raises SystemExit(2) after the one-line error, as the command would."""
    args = list(argv)
    if args and args[0] in SUBCOMMAND_PARSERS:
        return command_parser(args[0]).parse_args(args[1:])
    return build_parser().parse_args(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``aev-ocp``; returns the exit code (also raised as SystemExit by the script)."""
    rc = _main(list(sys.argv[1:] if argv is None else argv))
    if argv is None and _ON_MAIN:  # the command line's process: the command has ended and said so
        # a Ctrl-C or SIGTERM now (a second one, or one during the interpreter's shutdown) would end the process by
        # the signal (exit -2) instead of with the command's code: ignore it, the process is only exiting
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_IGN)
    return rc


def _main(args_list: list[str]) -> int:
    if args_list and args_list[0] == "mpc-export":
        return guarded(lambda: _dispatch("aev_ocp.mpc.export", "cli_mpc_export", args_list[1:]))
    if args_list and args_list[0] == "tune":
        return guarded(lambda: _dispatch("aev_ocp.tuning", "cli_tune", args_list[1:]))
    if args_list[:1] == ["sumo"] and any(a == "--seeds" or a.startswith("--seeds=") for a in args_list):
        return guarded(lambda: _dispatch("aev_ocp.study.cli", "cli_sumo_seeds", args_list[1:]))
    if args_list and args_list[0] in ("ocp", "mpc", "stability", "study", "safety", "ring", "sumo"):
        name = args_list[0]
        return guarded(lambda: _dispatch(f"aev_ocp.{name}.cli", f"cli_{name}", args_list[1:]))
    try:
        args = build_parser().parse_args(args_list)
    except SystemExit as exc:
        return int(exc.code or 0)
    handlers = {
        "simulate": cmd_simulate,
        "reproduce": cmd_reproduce,
        "scenarios": cmd_scenarios,
        "replay": cmd_replay,
    }
    return guarded(lambda: handlers[args.command](args))


def _console() -> None:  # pragma: no cover - used when run as ``python -m aev_ocp.cli``
    raise SystemExit(main())


if __name__ == "__main__":  # pragma: no cover
    _console()
