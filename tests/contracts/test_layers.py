"""The layer table (aev_ocp._layers) holds: every import edge of the package, found with ``ast`` (module-level,
function-local, ``TYPE_CHECKING``, a package ``__init__``'s lazy ``_EXPORTS``, literal ``importlib.import_module``
calls and registries held as strings: a module-level dict, tuple or list naming a module), goes to the same layer
or below, and no edges form a cycle."""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

import pytest

import aev_ocp
from aev_ocp._layers import LATE_EDGES, LAYERS, layer_of
from aev_ocp.lazy import target_module

PACKAGE_DIR = Path(aev_ocp.__file__).resolve().parent

#: Edges still open on this branch, each with its owner; the lead removes an entry when its fix is merged.
#: (importer, imported): why it is still here.
ALLOWED: dict[tuple[str, str], str] = {}


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def all_modules(package_dir: Path = PACKAGE_DIR) -> dict[str, Path]:
    """{dotted module name: file} of every module of the package."""
    root = package_dir.parent
    return {module_name(p, root): p for p in sorted(package_dir.rglob("*.py"))}


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The longest known module that ``name`` (a module or ``module.attribute``) names, else None."""
    while name not in modules:
        if "." not in name:
            return None
        name = name.rsplit(".", 1)[0]
    return name


def import_edges(
    module: str, path: Path, modules: dict[str, Path], registries: bool = True, outside_functions: bool = False
) -> list[tuple[str, int]]:
    """(imported module, line) for every import of ``aev_ocp`` code in ``path``, wherever it stands (``registries``:
    also the modules a registry held as strings names; ``outside_functions``: only the imports outside any
    function, run when the module is imported)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    if outside_functions:  # every function body emptied: what the module imports when it is imported
        for fn in [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
            fn.body = [ast.Pass()]
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    targets: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules]
            # `from pkg import submodule` imports the submodule; any other name is an attribute of base
            if len(subs) < len(node.names):
                targets.append((base, node.lineno))
            targets += [(s, node.lineno) for s in subs]
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str):
                name = node.args[0].value
                if name.startswith("."):
                    name = ".".join(package) + name
                targets.append((name, node.lineno))
        elif (
            isinstance(node, ast.Assign)
            and path.name == "__init__.py"
            and isinstance(node.value, ast.Dict)
            and any(isinstance(t, ast.Name) and t.id == "_EXPORTS" for t in node.targets)
        ):
            for v in node.value.values:  # lazy exports: {"Name": "submodule" or "aev_ocp.module"}
                if isinstance(v, ast.Constant) and isinstance(v.value, str):
                    targets.append((target_module(".".join(package), v.value), node.lineno))
    # registries held as strings: a module-level table naming modules, e.g. {"mpc": "aev_ocp.mpc.scenario"}
    # (the layer table itself names every module and imports none)
    for node in tree.body if registries and module != "aev_ocp._layers" else []:
        value = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
        if isinstance(value, (ast.Dict, ast.Tuple, ast.List, ast.Set)):
            for c in ast.walk(value):
                if isinstance(c, ast.Constant) and isinstance(c.value, str):
                    name = c.value.split(":", 1)[0]  # "module" or "module:function"
                    if name in modules:
                        targets.append((name, c.lineno))
    edges = []
    for name, line in targets:
        if name == "aev_ocp" or name.startswith("aev_ocp."):
            resolved = _resolve(name, modules)
            if resolved is not None and resolved != module:
                edges.append((resolved, line))
    return edges


def package_graph(package_dir: Path = PACKAGE_DIR, registries: bool = True) -> dict[str, dict[str, int]]:
    """{importer: {imported: first line}} over the whole package (a fresh copy: a test may plant edges in it)."""
    return {a: dict(targets) for a, targets in _package_graph(package_dir, registries).items()}


@functools.lru_cache(maxsize=None)
def _package_graph(package_dir: Path, registries: bool) -> dict[str, dict[str, int]]:
    """:func:`package_graph`, parsed once per folder and kind in this process (every test of this file reads it)."""
    modules = all_modules(package_dir)
    graph: dict[str, dict[str, int]] = {}
    for mod, path in modules.items():
        graph[mod] = {}
        for target, line in import_edges(mod, path, modules, registries):
            graph[mod].setdefault(target, line)
    return graph


def upward_edges(graph: dict[str, dict[str, int]]) -> list[str]:
    """'a (layer) -> b (layer) at line n' for every import to a higher layer not in ALLOWED."""
    bad = []
    for a, targets in sorted(graph.items()):
        for b, line in sorted(targets.items()):
            if layer_of(b) > layer_of(a) and (a, b) not in ALLOWED and (a, b) not in LATE_EDGES:
                bad.append(f"{a} ({LAYERS[layer_of(a)][0]}) imports {b} ({LAYERS[layer_of(b)][0]}) at line {line}")
    return bad


def find_cycle(graph: dict[str, dict[str, int]]) -> list[str] | None:
    """One cycle of imports not in ALLOWED as [a, b, ..., a], or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(a: str) -> list[str] | None:
        state[a] = 1
        stack.append(a)
        for b in sorted(graph.get(a, {})):
            if (a, b) in ALLOWED or (a, b) in LATE_EDGES:
                continue
            if state.get(b) == 1:
                return stack[stack.index(b) :] + [b]
            if b not in state:
                found = visit(b)
                if found:
                    return found
        stack.pop()
        state[a] = 2
        return None

    for a in sorted(graph):
        if a not in state:
            found = visit(a)
            if found:
                return found
    return None


def folder_of(module: str) -> str:
    """The folder a module stands in: its sub-package (``aev_ocp.mpc`` for ``aev_ocp.mpc.policy``), or the module
    itself for a module of the package's top folder (``aev_ocp.loop``)."""
    parts = module.split(".")
    return ".".join(parts[:2])


def folder_graph(graph: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    """The import graph between folders: a -> b when some module of folder a imports one of folder b."""
    out: dict[str, dict[str, int]] = {}
    for a, targets in graph.items():
        for b, line in targets.items():
            if (a, b) in LATE_EDGES:  # a result's .plot(): imported when called, never by importing the result
                continue
            fa, fb = folder_of(a), folder_of(b)
            if fa != fb:
                out.setdefault(fa, {}).setdefault(fb, line)
            out.setdefault(fb, {})
    return out


#: Folder edges still open, each with its owner; the list only shrinks. (importer folder, imported folder): why.
FOLDER_ALLOWED: dict[tuple[str, str], str] = {}


def test_no_folder_circle() -> None:
    """A folder says what its files may import: no two folders import each other, directly or round a circle
    (issue 39). Registries held as strings are plug-in points chosen at run time (the scenario loader names
    ``aev_ocp.mpc.scenario``, which reads its table with the loader's reader), so this check reads imports only."""
    graph = folder_graph(package_graph(registries=False))
    for a, b in FOLDER_ALLOWED:
        graph.get(a, {}).pop(b, None)
    cycle = find_cycle(graph)
    assert cycle is None, "folder circle: " + " -> ".join(cycle or [])


def test_folder_allow_list_is_still_needed() -> None:
    graph = folder_graph(package_graph(registries=False))
    gone = [edge for edge in FOLDER_ALLOWED if edge[1] not in graph.get(edge[0], {})]
    assert not gone, f"remove from FOLDER_ALLOWED: {gone}"


def test_a_folder_circle_is_found() -> None:
    """Planted: the problem description (ocp/) importing the MPC (mpc/), which imports ocp/, is a circle."""
    graph = package_graph(registries=False)
    graph["aev_ocp.ocp.problem"] = {**graph["aev_ocp.ocp.problem"], "aev_ocp.mpc.settings": 1}
    cycle = find_cycle(folder_graph(graph))
    assert cycle is not None and "aev_ocp.mpc" in cycle and "aev_ocp.ocp" in cycle


def test_every_module_has_exactly_one_layer() -> None:
    listed = [m for _name, mods in LAYERS for m in mods]
    assert len(listed) == len(set(listed)), sorted({m for m in listed if listed.count(m) > 1})
    modules = set(all_modules())
    assert sorted(modules - set(listed)) == [], "modules missing from aev_ocp._layers.LAYERS"
    assert sorted(set(listed) - modules) == [], "aev_ocp._layers.LAYERS names modules that do not exist"


def test_no_import_goes_up_a_layer() -> None:
    bad = upward_edges(package_graph())
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_no_import_cycle() -> None:
    cycle = find_cycle(package_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_allow_list_is_still_needed() -> None:
    """An allowed edge that no longer exists must leave the list (it only ever shrinks)."""
    graph = package_graph()
    gone = [edge for edge in ALLOWED if edge[1] not in graph.get(edge[0], {})]
    assert not gone, f"remove from ALLOWED: {gone}"


def test_late_edges_are_function_local_and_still_needed() -> None:
    """A late edge (LATE_EDGES: a result's .plot() importing its figure module) exists, and only inside a function:
    importing the result imports nothing of the figure module."""
    modules = all_modules()
    graph = package_graph()
    for a, b in LATE_EDGES:
        assert b in graph.get(a, {}), f"remove ({a!r}, {b!r}) from aev_ocp._layers.LATE_EDGES: no such import"
        at_import = {t for t, _line in import_edges(a, modules[a], modules, outside_functions=True)}
        assert b not in at_import, f"{a} imports {b} at module level: a late edge must be function-local"


def test_a_late_edge_at_module_level_is_refused(tmp_path: Path) -> None:
    """Planted: results importing plots at module level (not inside .plot()) is seen as an import at import time."""
    modules = all_modules()
    text = modules["aev_ocp.results"].read_text(encoding="utf-8") + "\nfrom .plots import plot_trajectories\n"
    planted = tmp_path / "results.py"
    planted.write_text(text, encoding="utf-8")
    at_import = {t for t, _line in import_edges("aev_ocp.results", planted, modules, outside_functions=True)}
    assert "aev_ocp.plots" in at_import
    inside = {
        t for t, _line in import_edges("aev_ocp.results", modules["aev_ocp.results"], modules, outside_functions=True)
    }
    assert "aev_ocp.plots" not in inside


def test_result_imports_no_figure_module() -> None:
    """Importing the result types loads no plotting module (the late edges run only when .plot() is called)."""
    loaded = loaded_modules("import aev_ocp.results, aev_ocp.ocp_result, aev_ocp.saved")
    assert not [m for m in loaded if m in ("aev_ocp.plots", "aev_ocp.ocp.plots")], loaded


def _write(root: Path, rel: str, text: str) -> None:
    p = root / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")


def test_the_walker_sees_every_kind_of_import(tmp_path: Path) -> None:
    """A planted package: function-local, TYPE_CHECKING, relative, lazy-export and import_module edges."""
    pkg = tmp_path / "aev_ocp"
    _write(
        tmp_path, "aev_ocp/__init__.py", '_EXPORTS = {"Thing": "low", "Other": "sub.deep", "Far": "aev_ocp.other"}\n'
    )
    _write(tmp_path, "aev_ocp/low.py", "def f():\n    from .sub import deep\n")
    _write(tmp_path, "aev_ocp/sub/__init__.py", "")
    _write(
        tmp_path,
        "aev_ocp/sub/deep.py",
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from ..low import f\nimport importlib\n"
        "importlib.import_module('aev_ocp.other')\n",
    )
    _write(tmp_path, "aev_ocp/other.py", "from aev_ocp.sub.deep import x as y\nfrom . import low\n")
    # registries held as strings: a module-level table naming a module (or module:function); a logger name is no edge
    _write(
        tmp_path,
        "aev_ocp/sub/__init__.py",
        'import logging\nLOG = logging.getLogger("aev_ocp.low")\n'
        'PROVIDERS = {"a": "aev_ocp.other", "b": ("aev_ocp.low:run", "f")}\n',
    )
    graph = package_graph(pkg)
    assert graph["aev_ocp"] == {"aev_ocp.low": 1, "aev_ocp.sub.deep": 1, "aev_ocp.other": 1}
    assert graph["aev_ocp.sub"] == {"aev_ocp.other": 3, "aev_ocp.low": 3}
    assert graph["aev_ocp.low"] == {"aev_ocp.sub.deep": 2}
    assert graph["aev_ocp.sub.deep"] == {"aev_ocp.low": 3, "aev_ocp.other": 5}
    assert graph["aev_ocp.other"] == {"aev_ocp.sub.deep": 1, "aev_ocp.low": 2}
    assert find_cycle(graph) == ["aev_ocp.low", "aev_ocp.sub.deep", "aev_ocp.low"]


def test_an_upward_import_is_named() -> None:
    """params (foundation) importing plots (outputs), planted in a copy of the graph, is reported by name."""
    graph = package_graph()
    before = set(upward_edges(graph))
    graph["aev_ocp.params"] = {**graph["aev_ocp.params"], "aev_ocp.plots": 7}
    assert set(upward_edges(graph)) - before == {
        "aev_ocp.params (foundation) imports aev_ocp.plots (outputs) at line 7"
    }


def loaded_modules(code: str) -> list[str]:
    """The ``aev_ocp`` modules a fresh interpreter holds after running ``code``."""
    probe = f"import sys\n{code}\nprint(sorted(m for m in sys.modules if m == 'aev_ocp' or m.startswith('aev_ocp.')))"
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True, cwd=PACKAGE_DIR.parent
    )
    loaded: list[str] = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    return loaded


#: (what a user runs, the layer it stands in, most aev_ocp modules it may load): one cheap entry per layer, measured
#: with lazy package __init__s (the figure beside each; a limit a little above it, so an eager import fails it).
IMPORT_BUDGETS = [
    ("import aev_ocp", 0, 4),  # 3: the package, its version and the lazy-export helper
    ("import aev_ocp.params", 0, 7),  # 5
    ("import aev_ocp.models.carfollowing", 1, 9),  # 7
    ("import aev_ocp.results", 2, 10),  # 8
    ("import aev_ocp.simulate", 3, 26),  # 23
    ("import aev_ocp.ocp.problem", 4, 12),  # 7
    ("import aev_ocp.ocp.oracle", 5, 44),  # 39
    ("from aev_ocp import load_scenario; load_scenario('udds_platoon')", 6, 25),  # 24 (issue 39: at most 25)
    ("import aev_ocp.saved", 7, 12),  # 9
    ("import aev_ocp.cli", 9, 16),  # 13: the command line imports a command's module when it runs
]


@pytest.mark.parametrize("code, layer, limit", IMPORT_BUDGETS)
def test_imports_stay_small_and_below_their_layer(code: str, layer: int, limit: int) -> None:
    """Importing (or running) ``code`` loads at most ``limit`` aev_ocp modules, none of a layer above ``layer``
    (the lazy package __init__s are what keep this: an eager ``from .x import y`` in one fails it)."""
    loaded = loaded_modules(code)
    assert len(loaded) <= limit, f"{code} loads {len(loaded)} aev_ocp modules: {loaded}"
    packages = {m for _name, mods in LAYERS for m in mods if (PACKAGE_DIR.parent / m.replace(".", "/")).is_dir()}
    above = [m for m in loaded if m not in packages and layer_of(m) > layer]  # a package __init__ loads lazily
    assert not above, f"{code} loads modules above layer {layer} ({LAYERS[layer][0]}): {above}"


def test_the_docs_page_lists_the_same_table() -> None:
    """docs/guide/layers.md states the table of aev_ocp._layers row by row (layer name and its modules)."""
    page = Path(__file__).resolve().parents[2] / "docs" / "guide" / "layers.md"  # the checkout's docs
    assert page.is_file(), f"{page} is missing"
    rows = [ln for ln in page.read_text(encoding="utf-8").splitlines() if ln.startswith("| ") and "`aev_ocp" in ln]
    table = [
        (cells[2], [m.strip(" `") for m in cells[3].split(",")])
        for cells in ([c.strip() for c in ln.split("|")] for ln in rows)
    ]
    assert table == [(name, list(mods)) for name, mods in LAYERS]
