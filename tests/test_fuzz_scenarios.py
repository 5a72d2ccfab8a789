"""Fuzzing the scenario loader and ``aev-ocp simulate`` with random and mutated scenario files (issue 11).

Mutations start from every shipped scenario: a key set to a random TOML value (any type, huge, tiny,
NaN, inf, path-like strings), a key deleted, a key added, a table replaced, or raw bytes flipped,
inserted or cut. The loader must either return a Scenario or raise ScenarioError (never anything
else); the command line must exit 0 (a valid run), 1 (a run stopped by an event, with its error
line) or 2 with exactly one ``aev-ocp: error:`` line, and never print a traceback or crash.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
import warnings
from pathlib import Path
from typing import Any

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from aev_ocp.cli import main  # noqa: E402
from aev_ocp.scenarios import Scenario, ScenarioError, load_scenario, shipped_scenarios  # noqa: E402

SHIPPED = {name: tomllib.loads(path.read_text(encoding="utf-8")) for name, path in shipped_scenarios().items()}
COUNTS = {"loader": 0, "loader_valid": 0, "cli": 0, "cli_rc": {}}


# ----------------------------------------------------------------------------- a small TOML writer
def _key(k: str) -> str:
    return json.dumps(k, ensure_ascii=False)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(doc: dict[str, Any], prefix: str = "") -> str:
    """TOML text of a document: scalars and arrays first, then one [table] per dict."""
    lines = [f"{_key(k)} = {_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for k, v in doc.items():
        if isinstance(v, dict):
            name = f"{prefix}.{_key(k)}" if prefix else _key(k)
            lines.append(f"\n[{name}]")
            lines.append(to_toml(v, name))
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- strategies
SPECIAL_STR = [
    "",
    "../../x",
    "/tmp/abs",
    "idm",
    "ovfl",
    "proposed",
    "all",
    "cycle",
    "udds",
    "si",
    "paper",
    "constant",
    "array",
    "nan",
    "é✓",
    "a" * 300,
]
scalars = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.sampled_from([0, 1, -1, 2**62, 10**7, 10**9]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e-30, 1e-9, 1e12, 1e308, -0.0, 0.3, 1.7, 70.0]),
    st.booleans(),
    st.sampled_from(SPECIAL_STR),
    st.text(max_size=12),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6,
)


def _paths(doc: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for k, v in doc.items():
        out.append(prefix + (k,))
        if isinstance(v, dict):
            out.extend(_paths(v, prefix + (k,)))
    return out


@st.composite
def mutated_docs(draw: Any) -> dict[str, Any]:
    doc = json.loads(json.dumps(SHIPPED[draw(st.sampled_from(sorted(SHIPPED)))]))
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        op = draw(st.sampled_from(["set", "perturb", "perturb", "perturb", "delete", "add"]))
        path = draw(st.sampled_from(paths)) if paths else ("name",)
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        old = parent.get(path[-1])
        if op == "perturb" and isinstance(old, (int, float)) and not isinstance(old, bool):
            # a plausible edit: scale a number (keeps its type), often into range, sometimes out of it
            f = draw(st.sampled_from([0, -1, 0.5, 0.9, 1.1, 2, 10, 1e3, 1e-3]))
            parent[path[-1]] = type(old)(old * f) if isinstance(old, float) or f == int(f) else old * f
        elif op in ("set", "perturb"):
            parent[path[-1]] = draw(values)
        elif op == "delete":
            parent.pop(path[-1], None)
        else:
            target = parent if isinstance(parent, dict) else doc
            target[
                draw(
                    st.sampled_from(
                        [
                            "extra",
                            "rtol",
                            "atol",
                            "law",
                            "laws",
                            "followers",
                            "compare",
                            "dt_out",
                            "name",
                            "mpc",
                            "N",
                            "kind",
                            "v0",
                        ]
                    )
                )
            ] = draw(values)
    return doc


@st.composite
def plausible_docs(draw: Any) -> dict[str, Any]:
    """A shipped scenario with one or two numbers scaled by 0.5 ... 2: mostly valid, so they run."""
    doc = json.loads(json.dumps(SHIPPED[draw(st.sampled_from(sorted(SHIPPED)))]))
    nums = [p for p in _paths(doc) if not isinstance(_get(doc, p), bool) and isinstance(_get(doc, p), (int, float))]
    for _ in range(draw(st.integers(1, 2))):
        path = draw(st.sampled_from(nums))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        f = draw(st.sampled_from([0.5, 0.8, 1.25, 2.0]))
        parent[path[-1]] = type(parent[path[-1]])(parent[path[-1]] * f) or parent[path[-1]]
    return doc


def _get(doc: dict[str, Any], path: tuple[str, ...]) -> Any:
    for k in path:
        doc = doc[k]
    return doc


@st.composite
def scenario_bytes(draw: Any) -> bytes:
    """Either a mutated document as TOML, or shipped TOML text with raw bytes flipped, inserted or cut."""
    if draw(st.booleans()):
        return to_toml(draw(mutated_docs())).encode("utf-8", "surrogatepass")
    name = draw(st.sampled_from(sorted(SHIPPED)))
    data = bytearray(shipped_scenarios()[name].read_bytes())
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        op = draw(st.sampled_from(["flip", "insert", "cut"]))
        if op == "flip" and data:
            data[i] = draw(st.integers(0, 255))
        elif op == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=8))
        else:
            del data[i : i + draw(st.integers(1, 40))]
    return bytes(data)


def _clamp(doc: Any) -> Any:
    """A valid-looking document with a short horizon and a small platoon (for full CLI runs)."""
    if isinstance(doc, dict):
        sim, pl = doc.get("simulation"), doc.get("platoon")
        if isinstance(sim, dict) and isinstance(sim.get("t_end"), (int, float)) and not isinstance(sim["t_end"], bool):
            sim["t_end"] = min(sim["t_end"], 3.0) if sim["t_end"] == sim["t_end"] else sim["t_end"]
        if isinstance(pl, dict) and isinstance(pl.get("followers"), int) and not isinstance(pl["followers"], bool):
            pl["followers"] = min(pl["followers"], 8)
    return doc


# ----------------------------------------------------------------------------- the properties
@settings(
    max_examples=int(os.environ.get("AEV_OCP_FUZZ_LOADER", 300)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=scenario_bytes())
def test_loader_returns_a_scenario_or_a_scenario_error(tmp_path: Path, data: bytes) -> None:
    p = tmp_path / "fuzz.toml"
    p.write_bytes(data)
    COUNTS["loader"] += 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            s = load_scenario(p)
        except ScenarioError as exc:
            assert str(exc).startswith(str(p)), exc  # names the file
            return
    COUNTS["loader_valid"] += 1
    assert isinstance(s, Scenario) and s.n_followers >= 1 and s.t_end > 0 and s.dt_out > 0


@settings(
    max_examples=int(os.environ.get("AEV_OCP_FUZZ_CLI", 15)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(doc=st.one_of(mutated_docs(), plausible_docs()))
def test_simulate_exits_cleanly_on_any_mutated_scenario(
    tmp_path_factory: pytest.TempPathFactory, capsys: pytest.CaptureFixture[str], doc: dict[str, Any]
) -> None:
    d = tmp_path_factory.mktemp("fz")
    p = d / "fuzz.toml"
    p.write_text(to_toml(_clamp(doc)), encoding="utf-8", errors="surrogatepass")
    rc = main(["simulate", str(p), "--out", str(d / "out"), "--no-plots"])
    _, err = capsys.readouterr()
    COUNTS["cli"] += 1
    COUNTS["cli_rc"][rc] = COUNTS["cli_rc"].get(rc, 0) + 1
    assert "Traceback" not in err and "internal error" not in err, err
    errors = [ln for ln in err.splitlines() if ln.startswith("aev-ocp: error:")]
    assert rc in (0, 1, 2), (rc, err)
    if rc == 2:
        assert len(errors) == 1, err
    elif rc == 1:
        assert errors and all(" run " in ln or "run failed" in ln for ln in errors), err
    else:
        assert not errors and (d / "out" / "metrics.json").is_file()
        assert not [f for f in (d / "out").iterdir() if ".tmp" in f.name]


def test_report_fuzz_counts() -> None:
    """Prints how many inputs the fuzz tests above tried (run with -s to see it)."""
    print(
        f"\nfuzz: loader {COUNTS['loader']} inputs ({COUNTS['loader_valid']} valid), "
        f"CLI {COUNTS['cli']} runs, exit codes {COUNTS['cli_rc']}"
    )
