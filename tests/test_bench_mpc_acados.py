"""benchmarks/bench_mpc_acados.py without acados (the project's venv and CI): it says why it skips, exits 0 and
writes nothing; and each acados configuration is compared with the aev_ocp step that solves the same QP."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_mpc_acados.py"


def _load():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("bench_mpc_acados", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_without_acados_it_skips_with_its_reason_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # neither layout importable, whatever this machine has installed
    monkeypatch.setitem(sys.modules, "acados", None)
    monkeypatch.setitem(sys.modules, "acados_template", None)
    bench = _load()
    assert bench.load_acados() is None
    out = tmp_path / "bench.json"
    assert bench.main(["--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "skipped" in said and "acados is not importable" in said and "docs/guide/mpc.md" in said
    assert not out.exists()


def test_each_acados_configuration_is_compared_with_the_step_of_the_same_hessian() -> None:
    bench = _load()
    assert bench.hessian_of(bench.ALL_CONFIGS["full-qpoases-exact"]) == "exact"
    assert bench.hessian_of(bench.ALL_CONFIGS["hpipm-exact"]) == "exact"
    assert bench.hessian_of(bench.ALL_CONFIGS["hpipm-balance"]) == "projected"
    assert bench.hessian_of(bench.ALL_CONFIGS["full-qpoases"]) == "projected"
    # every default configuration names a QP solver, and the exact ones condense fully but one extra
    assert all("qp_solver" in o for o in bench.ALL_CONFIGS.values())
    assert {n for n, o in bench.CONFIGS.items() if bench.hessian_of(o) == "exact"} == {
        "full-qpoases-exact",
        "full-hpipm-exact",
    }
