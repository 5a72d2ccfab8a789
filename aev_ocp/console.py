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
