"""The one set of executor options (``--workers``, ``--dask-local``, ``--scheduler``, ``--in-process``) of
``aev-ocp study`` and ``aev-ocp tune``: each flag read into run_study's keywords, bad values named by their flag."""

from __future__ import annotations

import os

import pytest
from cli_helpers import one_error, run_cli

from aev_ocp.console import executor_options
from aev_ocp.limits import MAX_WORKERS_PER_CORE
from aev_ocp.params import ParameterError
from aev_ocp.study.cli import build_parser as study_parser
from aev_ocp.tuning import build_parser as tune_parser

CAP = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
PARSERS = {"study": lambda argv: study_parser().parse_args(["s.toml", *argv]), "tune": tune_parser().parse_args}


@pytest.mark.parametrize("command", sorted(PARSERS))
@pytest.mark.parametrize(
    "argv, want",
    [
        ([], {"executor": "pool", "workers": None}),
        (["--workers", "3"], {"executor": "pool", "workers": 3}),
        (["--workers", str(CAP)], {"executor": "pool", "workers": CAP}),  # the limit itself is allowed
        (["--workers", "1"], {"executor": "pool", "workers": 1}),
        (["--dask-local", "2"], {"executor": "dask", "workers": 2, "scheduler": None}),
        (
            ["--scheduler", "tcp://10.0.0.5:8786"],
            {"executor": "dask", "workers": None, "scheduler": "tcp://10.0.0.5:8786"},
        ),
        (["--in-process"], {"executor": "inprocess"}),
    ],
)
def test_each_flag_is_read(command: str, argv: list[str], want: dict) -> None:
    assert executor_options(PARSERS[command](argv)) == want


@pytest.mark.parametrize("command", sorted(PARSERS))
@pytest.mark.parametrize(
    "argv, flag",
    [
        (["--workers", "0"], "--workers 0"),
        (["--workers", "-2"], "--workers -2"),
        (["--workers", str(CAP + 1)], f"--workers {CAP + 1}"),  # just above the limit
        (["--dask-local", "0"], "--dask-local 0"),
        (["--dask-local", str(CAP + 1)], f"--dask-local {CAP + 1}"),
        (["--scheduler", " "], "--scheduler"),
    ],
)
def test_bad_values_name_their_flag(command: str, argv: list[str], flag: str) -> None:
    with pytest.raises(ParameterError, match=flag):
        executor_options(PARSERS[command](argv))


@pytest.mark.parametrize(
    "argv, words", [(["--workers", "two"], "--workers"), (["--workers", "2", "--in-process"], "not allowed with")]
)
def test_the_parser_refuses_a_non_number_and_two_executors(argv: list[str], words: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        tune_parser().parse_args(argv)
    assert exc.value.code == 2 and words in one_error(capsys.readouterr().err)


def test_tune_refuses_a_bad_worker_count_before_running(capsys) -> None:
    """The command line: exit 2 with one error line naming the flag (nothing is tuned)."""
    rc, _out, err = run_cli(["tune", "--dask-local", "0", "--out", "unused"], capsys)
    assert rc == 2 and "--dask-local 0" in one_error(err)
