"""Provenance: every JSON output says which code, libraries, scenario and seeds produced it (issue 10)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import casadi
import numpy as np
import pytest

from aev_ocp import __version__
from aev_ocp.provenance import context, provenance, scenario_sha256
from aev_ocp.results import write_json
from aev_ocp.scenarios import find_scenario, load_scenario

ROOT = Path(__file__).parents[1]


@pytest.mark.quick
def test_record_has_versions_time_scenario_and_seeds(tmp_path: Path) -> None:
    sc = load_scenario(find_scenario("table1"))
    before = provenance().get("scenario")
    with context(sc, theorem=2025):
        p = write_json(tmp_path / "x.json", {"value": np.float64(3.25)})
        rec = json.loads(p.read_text())["provenance"]
    assert rec["aev_ocp"] == __version__ and rec["casadi"] == casadi.__version__ and rec["numpy"] == np.__version__
    assert rec["python"] == sys.version.split()[0] and rec["utc"].endswith("+00:00")
    assert rec["scenario"] == "table1" and rec["seeds"] == {"theorem": 2025}
    doc = json.dumps(sc.document, sort_keys=True, separators=(",", ":"), default=str).encode()
    assert rec["scenario_sha256"] == hashlib.sha256(doc).hexdigest()
    # an override changes the scenario, so its hash
    assert scenario_sha256(sc.with_overrides({"carfollowing.kappa": 0.041})) != rec["scenario_sha256"]
    assert provenance().get("scenario") == before  # the context ended


def test_cli_version_and_reproduce_seed(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "aev_ocp.cli", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0 and res.stdout.startswith(f"aev-ocp {__version__}") and "CasADi" in res.stdout
    from aev_ocp.claims import THEOREM41_SEED, theorem41_section

    theorem41_section(tmp_path, lambda m: None, n_cases=3)
    rec = json.loads((tmp_path / "theorem41.json").read_text())["provenance"]
    assert rec["seeds"] == {"theorem41_random_cases": THEOREM41_SEED}
