"""benchmarks/bench_suite.py: the suite's environment per --bytecode, the bytecode caches it clears, and runs taken in
turns (A B A B), the median run of the last configuration quoted (no suite is run here: ``run`` is replaced)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_suite  # noqa: E402


@pytest.mark.parametrize(
    "before, bytecode, after",
    [
        ("1", "on", None),
        (None, "on", None),
        ("1", "off", "1"),
        (None, "off", "1"),
        ("1", "inherit", "1"),
        (None, "inherit", None),
    ],
)
def test_the_suites_environment_per_bytecode_choice(monkeypatch, tmp_path, before, bytecode, after) -> None:
    if before is None:
        monkeypatch.delenv("PYTHONDONTWRITEBYTECODE", raising=False)
    else:
        monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", before)
    env = bench_suite.suite_env(tmp_path / "cache", bytecode)
    assert env.get("PYTHONDONTWRITEBYTECODE") == after
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(bench_suite.ROOT)
    assert env["AEV_OCP_CACHE"] == str(tmp_path / "cache")
    assert os.environ.get("PYTHONDONTWRITEBYTECODE") == before  # this process's own environment untouched


def test_clear_bytecode_removes_the_package_and_test_caches_only(monkeypatch, tmp_path) -> None:
    made = [tmp_path / p / "__pycache__" for p in ("aev_ocp", "aev_ocp/mpc", "tests", "tests/contracts", "docs")]
    for d in made:
        d.mkdir(parents=True)
        (d / "m.cpython-311.pyc").write_bytes(b"\0" * 7)
    monkeypatch.setattr(bench_suite, "ROOT", tmp_path)
    assert bench_suite.clear_bytecode() == 4
    assert [d.exists() for d in made] == [False, False, False, False, True]  # docs/ is not the suite's


def _fake_run(
    calls: list[tuple[str, str]], walls: dict[tuple[str, str], list[float]], pythons: list[str] | None = None
) -> Any:
    def run(
        mode: str, workers: str, cache: Path | None, extra: list[str], bytecode: str = "on", python: str = ""
    ) -> dict[str, Any]:
        calls.append((mode, bytecode))
        if pythons is not None:
            pythons.append(python)
        wall = walls[(mode, bytecode)].pop(0)
        return {
            "dist": mode,
            "bytecode": bytecode,
            "returncode": 0,
            "wall_s": wall,
            "cpu_s": 1.9 * wall,
            "load_1min_before": 0.3,
            "load_1min_after": 1.7,
            "summary": "2 passed",
            "file_seconds": {"tests/test_a.py": wall / 2.0},
        }

    return run


def test_configurations_run_in_turns_and_the_last_ones_median_run_is_quoted(monkeypatch, tmp_path, capsys) -> None:
    calls: list[tuple[str, str]] = []
    prepared: list[str] = []
    walls = {("loadfile", "off"): [171.0, 163.0, 158.0], ("loadfile", "on"): [166.0, 149.0, 177.0]}
    monkeypatch.setattr(bench_suite, "run", _fake_run(calls, walls))
    monkeypatch.setattr(bench_suite, "warm_bytecode", lambda env, python: prepared.append("warm"))
    monkeypatch.setattr(bench_suite, "clear_bytecode", lambda: prepared.append("clear") or 0)
    out = tmp_path / "b.json"
    rc = bench_suite.main(["--bytecode", "off", "--bytecode", "on", "--repeat", "3", "--out", str(out)])
    assert rc == 0
    assert calls == [("loadfile", "off"), ("loadfile", "on")] * 3  # in turns, not off off off on on on
    assert prepared == ["clear", "warm"] * 3  # each run starts from its own bytecode state
    doc = json.loads(out.read_text())
    assert [(m["bytecode"], m["wall_s_median"], m["repeats"]) for m in doc["medians"]] == [
        ("off", 163.0, 3),
        ("on", 166.0, 3),
    ]
    assert (doc["quoted"]["bytecode"], doc["quoted"]["wall_s"]) == ("on", 166.0)  # the median run, not the fastest
    assert "median of 3" in capsys.readouterr().out
    # one configuration: its caches are prepared once, not before every run
    calls.clear(), prepared.clear()
    walls[("loadfile", "on")] = [131.0, 127.0]
    assert bench_suite.main(["--bytecode", "on", "--repeat", "2", "--out", str(out)]) == 0
    assert calls == [("loadfile", "on")] * 2 and prepared == ["warm"]


def test_another_interpreter_runs_every_run_and_its_warm_up(monkeypatch, tmp_path) -> None:
    """--python: the suite and its untimed warm-up run by that interpreter (e.g. a fresh venv of .[test], as README's
    command makes it), not by the one running the benchmark; each run records it."""
    calls: list[tuple[str, str]] = []
    pythons: list[str] = []
    warmed: list[str] = []
    walls = {("loadfile", "on"): [139.0, 121.0, 118.0, 131.0]}
    monkeypatch.setattr(bench_suite, "run", _fake_run(calls, walls, pythons))
    monkeypatch.setattr(bench_suite, "warm_bytecode", lambda env, python: warmed.append(python))
    out = tmp_path / "b.json"
    assert bench_suite.main(["--repeat", "3", "--python", "/opt/fresh/bin/python", "--out", str(out)]) == 0
    assert pythons == ["/opt/fresh/bin/python"] * 3 and warmed == ["/opt/fresh/bin/python"]
    assert bench_suite.main(["--repeat", "1", "--out", str(out)]) == 0 and pythons[-1] == sys.executable


def test_distributions_counts_what_an_interpreter_sees() -> None:
    import importlib.metadata as m

    assert bench_suite.distributions(sys.executable) == len({d.metadata["Name"] for d in m.distributions()}) > 5


def test_machine_speed_is_a_positive_cpu_time() -> None:
    s = bench_suite.machine_speed_s(repeats=1)
    assert 0.0 < s < 60.0
