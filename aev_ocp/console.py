"""What every ``aev-ocp`` command shares: exit codes, the one-line error and warning format, an argument
parser that reports errors that way, and :func:`guarded`, which runs a command with that behaviour.

A leaf of the entry-point layer: every command module imports it, it imports no command module.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from typing import Any, Callable

from . import interrupts
from .overrides import OverrideError
from .params import ParameterError
from .results import OutputError, release_output_locks
from .scenarios import ScenarioError

EXIT_OK, EXIT_FAILED_RUN, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _err(message: str) -> None:
    first = " ".join(str(message).split())  # one line, whatever the message holds
    print(f"aev-ocp: error: {first}", file=sys.stderr, flush=True)


error_line = _err  # public name, used by the ocp and mpc subcommands


def _warn(message: str) -> None:
    print(f"aev-ocp: warning: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


warning_line = _warn  # public name, used by the subcommands


def os_error_text(exc: OSError) -> str:
    """An OSError in one line: the system's reason and the file it names, when it names one."""
    return f"{exc.strerror or exc}: {exc.filename}" if getattr(exc, "filename", None) else str(exc)


def bad_input(exc: Exception) -> int:
    """Report ``exc`` (bad input: an invalid value, an unreadable file) as the one error line; returns
    EXIT_BAD_INPUT, for a command that handles it itself instead of leaving it to :func:`guarded`."""
    _err(os_error_text(exc) if isinstance(exc, OSError) else str(exc))
    return EXIT_BAD_INPUT


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: object = None,
    line: str | None = None,
) -> None:
    _warn(str(message))


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error format and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        _err(f"{message} (try '{self.prog} --help')")
        raise SystemExit(EXIT_BAD_INPUT)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        """argparse's, and ``--out ''`` refused (every command's output folder: an empty name, e.g. an unset
        shell variable, would silently mean the default folder or the current one)."""
        ns, rest = super().parse_known_args(args, namespace)
        if getattr(ns, "out", None) == "":
            self.error("argument --out: an empty folder name (give a folder, or leave --out out for the default)")
        return ns, rest


OneLineParser = _Parser  # public name, used by the ocp and mpc subcommands


def add_set_option(parser: argparse.ArgumentParser, help: str) -> None:
    """The repeatable scenario override ``--set KEY=VALUE`` (into ``args.sets``, default []); ``help`` says
    what the command does with it."""
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help=help)


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    """Where the tasks of a command that runs study tasks (``aev-ocp study``, ``aev-ocp tune``) run, at most one
    of: ``--workers N`` (a local process pool, default one per core), ``--dask-local N`` (a Dask LocalCluster),
    ``--scheduler ADDRESS`` (a running Dask scheduler), ``--in-process``; read back with :func:`executor_options`."""
    ex = parser.add_mutually_exclusive_group()
    ex.add_argument(
        "--workers", type=int, default=None, metavar="N", help="local process pool of N workers (default: one per core)"
    )
    ex.add_argument(
        "--dask-local",
        type=int,
        default=None,
        metavar="N",
        help="start a Dask LocalCluster of N worker processes (needs aev_ocp[dask])",
    )
    ex.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on a running Dask scheduler, e.g. tcp://10.0.0.5:8786 (needs aev_ocp[dask])",
    )
    ex.add_argument("--in-process", action="store_true", help="run every task in this process (debugging)")


def executor_options(args: argparse.Namespace) -> dict[str, Any]:
    """The executor keywords (``executor``, ``workers``, ``scheduler``) of :func:`aev_ocp.study.run_study` and
    :func:`aev_ocp.tuning.run_tuning` from the options of :func:`add_executor_options`. ParameterError naming the
    option for a worker count this machine does not allow (1 … 4 per core) or an empty scheduler address."""
    from .limits import check_local_workers

    for opt in ("workers", "dask_local"):
        check_local_workers(getattr(args, opt), f"--{opt.replace('_', '-')}")
    if args.scheduler is not None and not args.scheduler.strip():
        raise ParameterError("--scheduler '': an empty address (give one such as tcp://10.0.0.5:8786)")
    if args.in_process:
        return {"executor": "inprocess"}
    if args.dask_local is not None or args.scheduler is not None:
        return {"executor": "dask", "workers": args.dask_local, "scheduler": args.scheduler}
    return {"executor": "pool", "workers": args.workers}


def guarded(run: Callable[[], int]) -> int:
    """Run one command with the one error behaviour of every subcommand; returns the exit code.

    Bad input (ScenarioError, ParameterError, OutputError, TypeError/ValueError from argument checks,
    unreadable files) -> one line, exit 2; a failed run (RuntimeError, MemoryError) -> one line,
    exit 1; Ctrl-C or SIGTERM -> 'interrupted', exit 130, also when a solver swallowed the signal.
    """
    # Already inside a guarded command (main -> cli_mpc): the outer one reports. The depth lives in
    # aev_ocp.interrupts, imported once even when this file also runs as __main__ (python -m).
    if interrupts._state.get("depth", 0):
        return int(run() or 0)
    debug = os.environ.get("AEV_OCP_DEBUG", "") not in ("", "0")
    interrupts._state["depth"] = 1
    try:
        return _guarded(run, debug)
    finally:
        interrupts._state["depth"] = 0
        release_output_locks()  # the output folders this command claimed are free for the next run


def _guarded(run: Callable[[], int], debug: bool) -> int:
    with interrupts.handle_signals(), warnings.catch_warnings():
        warnings.showwarning = _show_warning  # every warning is one line 'aev-ocp: warning: ...'
        try:
            try:
                rc = int(run() or 0)
            except Exception:
                interrupts.check()  # a Ctrl-C that a library turned into another error (CasADi: SystemError)
                raise
            if rc == EXIT_INTERRUPTED and interrupts.interrupted():
                return rc  # the command caught the interrupt and said so itself: one line, not two
            interrupts.check()  # a signal that a solver turned into a failed solve
            return rc
        except SystemExit as exc:
            interrupts.check()
            return int(exc.code) if isinstance(exc.code, int) else (EXIT_BAD_INPUT if exc.code else EXIT_OK)
        except KeyboardInterrupt:
            _err("interrupted")
            return EXIT_INTERRUPTED
        except (ScenarioError, ParameterError, OutputError, OverrideError) as exc:
            return bad_input(exc)
        except BrokenPipeError:  # output piped into e.g. `head`: stop quietly, as Unix tools do
            try:
                sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - nothing more may reach the closed pipe
            except OSError:
                pass
            return EXIT_OK
        except OSError as exc:
            return bad_input(exc)
        except MemoryError:
            _err("run failed: out of memory (lower platoon.followers or simulation.t_end, or raise simulation.dt_out)")
            return EXIT_FAILED_RUN
        except RuntimeError as exc:  # a solver failure that the simulator could not turn into an event
            if debug:
                raise
            _err(f"run failed: {exc}")
            return EXIT_FAILED_RUN
        except (TypeError, ValueError, RecursionError) as exc:
            if debug:
                raise
            _err(f"{type(exc).__name__}: {exc}")
            return EXIT_BAD_INPUT
        except Exception as exc:  # noqa: BLE001 - never a traceback on the command line
            if debug:
                raise
            _err(f"internal error ({type(exc).__name__}: {exc}); please report it, AEV_OCP_DEBUG=1 shows the traceback")
            return EXIT_FAILED_RUN
