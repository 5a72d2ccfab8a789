"""The compile cache (issue 11 item 9): a damaged cached library is detected (size/checksum, load test),
rebuilt once with a warning, and the simulator then runs compiled again instead of silently on CVODES;
an unusable cache folder leaks no temporary build folders."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import aev_ocp.compiled as B

pytestmark = pytest.mark.skipif(B.compiler() is None, reason="needs a C compiler")

SRC = "double aev_test_twice(double x) { return 2.0 * x + %s; }\n"


def _build(src: str) -> tuple[B.BuildResult, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = B.compile_shared(src, "aevtest", "t")
    return res, [str(w.message) for w in caught if issubclass(w.category, B.CompileWarning)]


def _call(lib: Path, x: float) -> float:
    import ctypes

    f = ctypes.CDLL(str(lib)).aev_test_twice
    f.restype, f.argtypes = ctypes.c_double, [ctypes.c_double]
    return f(x)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "no_sidecar", "empty"])
def test_damaged_library_is_rebuilt_once_with_a_warning(tmp_path, monkeypatch, damage: str) -> None:
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    src = SRC % "0.25"
    first, w1 = _build(src)
    assert first.path is not None and not first.rebuilt and w1 == []
    assert _call(first.path, 1.5) == 3.25
    lib = first.path
    data = lib.read_bytes()

    def replace_with(content: bytes) -> None:  # a new file: the loaded (mapped) one must not change under us
        tmp = lib.with_name("damaged.tmp")
        tmp.write_bytes(content)
        os.replace(tmp, lib)

    if damage == "truncate":
        replace_with(data[: len(data) // 3])
    elif damage == "garbage":
        replace_with(data[:100] + bytes(len(data) - 100))  # same size, different content
    elif damage == "no_sidecar":
        lib.with_name(lib.name + B.SIDECAR_SUFFIX).unlink()
    else:
        replace_with(b"")
    B._WARNED.clear()
    second, w2 = _build(src)
    assert second.path == lib and second.rebuilt
    assert len(w2) == 1 and ("verified" if damage == "no_sidecar" else "damaged") in w2[0] and str(lib) in w2[0]
    assert lib.read_bytes() == data and _call(lib, -2.0) == -3.75
    third, w3 = _build(src)  # now verified: used as is, no warning
    assert not third.rebuilt and w3 == []
    assert not [p for p in lib.parent.iterdir() if p.name.startswith(".")]  # no temp files left


def test_a_build_sweeps_what_killed_builds_left_and_keeps_a_live_ones(tmp_path, monkeypatch) -> None:
    """A build killed mid-way (SIGKILL: no cleanup) leaves its build folder, library and checksum, named after its
    process, in the cache folder; the next build there removes those of processes that no longer exist and keeps a
    live process's, other files, and a cache hit touches nothing."""
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    first, _ = _build(SRC % "0.5")
    d = first.path.parent
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()  # reaped: its pid names no process
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        key = "0123456789abcdef01234567"

        def leftovers(pid: int) -> list[Path]:
            folder = d / f".aevtest_{key}_{pid}.build"
            folder.mkdir()
            (folder / f"aevtest_{key}.c").write_text("int x;\n")
            files = [d / f".aevtest_{key}_{pid}.so", d / f".aevtest_{key}_{pid}.sha256"]
            for f in files:
                f.write_text("partial")
            return [folder, *files]

        dead, alive = leftovers(child.pid), leftovers(live.pid)
        other = [d / "notes.txt", d / f".aevtest_{key}.so", d / f".aevtest_{key}_x7.so"]  # not a build's name
        for f in other:
            f.write_text("kept")
        hit, _ = _build(SRC % "0.5")  # a cache hit: nothing swept
        assert hit.path == first.path and all(f.exists() for f in dead)
        second, warned = _build(SRC % "0.75")  # a build: the dead process's leftovers go
        assert second.path is not None and _call(second.path, 2.0) == 4.75 and warned == []
        assert not any(f.exists() for f in dead)
        assert all(f.exists() for f in alive + other)
    finally:
        live.kill()
        live.wait()


HELPER = "double aev_helper(double x) { return 3.0 * x + AEV_K; }\n"
MAIN = "double aev_helper(double x);\ndouble aev_test_twice(double x) { return aev_helper(x) * %s; }\n"


def test_an_object_is_compiled_once_for_every_library_that_links_it(tmp_path, monkeypatch) -> None:
    """compile_object caches an object per (source, headers, flags); libraries of different main sources link the
    same object without compiling it again, and a library's key names the object it links: another object (another
    define) gives another library, with its own numbers. A damaged object is rebuilt, with a warning."""
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(B, "_COMPILED", [])
    o1 = B.compile_object(HELPER, "aevhelp", "t", ("-DAEV_K=0.5",))
    assert o1.path is not None and o1.path.suffix == ".o" and B.verify_library(o1.path) == ""
    libs = [B.compile_shared(MAIN % f, "aevtest", "t", objects=[o1.path]) for f in ("2.0", "0.25")]
    assert [lib.path is not None for lib in libs] == [True, True] and libs[0].path != libs[1].path
    assert _call(libs[0].path, 1.5) == (3.0 * 1.5 + 0.5) * 2.0 and _call(libs[1].path, 1.5) == (3.0 * 1.5 + 0.5) * 0.25
    again = B.compile_object(HELPER, "aevhelp", "t", ("-DAEV_K=0.5",))
    assert again.path == o1.path and not again.rebuilt and B._COMPILED == ["aevhelp", "aevtest", "aevtest"]
    o2 = B.compile_object(HELPER, "aevhelp", "t", ("-DAEV_K=-1.25",))
    other = B.compile_shared(MAIN % "2.0", "aevtest", "t", objects=[o2.path])
    assert o2.path != o1.path and other.path != libs[0].path and _call(other.path, 1.5) == (4.5 - 1.25) * 2.0
    o1.path.write_bytes(o1.path.read_bytes()[:100])  # truncated
    B._WARNED.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fixed = B.compile_object(HELPER, "aevhelp", "t", ("-DAEV_K=0.5",))
    assert fixed.path == o1.path and fixed.rebuilt and B.verify_library(fixed.path) == ""
    assert any("damaged" in str(w.message) for w in caught)


def test_the_mpc_step_links_its_qp_solver_as_an_object_keyed_by_the_qp_dimensions(monkeypatch) -> None:
    """CompiledStep.build compiles ocp_qp.c as an object of its own, with the step's flags and the QP's dimensions,
    and links it into the step (not as one more source of the step's library)."""
    from aev_ocp.mpc.controller import MPCController
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.ocp.formulation import s9_formulation

    objects, libraries = [], []
    real_object, real_shared = B.compile_object, B.compile_shared

    def spy_object(source, stem, sub="", extra_flags=(), companions=None, timeout_s=600.0):  # noqa: ANN001, ANN202
        objects.append((stem, extra_flags, sorted(companions or {})))
        return real_object(source, stem, sub, extra_flags, companions, timeout_s)

    def spy_shared(source, stem, sub="", extra_flags=(), timeout_s=600.0, companions=None, objects=()):  # noqa: ANN001, ANN202
        libraries.append((stem, sorted(companions or {}), [o.name for o in objects]))
        return real_shared(source, stem, sub, extra_flags, timeout_s, companions, objects)

    monkeypatch.setattr(B, "compile_object", spy_object)
    monkeypatch.setattr(B, "compile_shared", spy_shared)
    # the settings of tests/test_compile_once.py's §9 compiled step: the same library
    c = MPCController(
        MPCSettings(N=6, dt=0.2, solver="rti", qp_solver="riccati", codegen=False), formulation=s9_formulation()
    )
    assert c.compiled_step is not None
    stem, flags, headers = objects[0]
    assert stem == "ocp_qp" and headers == ["ocp_qp.h"]
    dims = {f for f in flags if f.startswith("-DOCPQP_")}
    assert dims == {f"-DOCPQP_NX={c.nx}", f"-DOCPQP_NU={c.nu}", f"-DOCPQP_NC={c.nlp.ng_stage - c.nx}", "-DOCPQP_NCN=0"}
    step = [lib for lib in libraries if lib[0] == "mpc_step"][0]
    assert "ocp_qp.c" not in step[1] and "mpc_step.c" in step[1] and step[2][0].startswith("ocp_qp_")


def test_failed_build_warns(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    B._WARNED.clear()
    res, w = _build("this is not C;\n")
    assert res.path is None and "failed" in res.error
    assert len(w) == 1 and "falls back" in w[0]
    assert not [p for p in (tmp_path / "cache" / "t").iterdir()]


def test_truncated_simulator_cache_is_rebuilt_and_the_cascade_still_runs(tmp_path) -> None:
    """End to end in fresh interpreters: build the cascade, truncate its .so, run again -> rebuilt, cascade."""
    env = {**os.environ, "AEV_OCP_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(Path(__file__).parents[1])}
    code = (
        "import warnings; warnings.simplefilter('always');"
        "from aev_ocp.simulate import simulate_platoon; from aev_ocp.models.leader import ConstantSpeed;"
        "from aev_ocp.models.carfollowing import Proposed;"
        "r = simulate_platoon(ConstantSpeed(1.3), [Proposed()], [1.1], [1.2], 2.0, dt_out=0.5);"
        "print(r.meta['integrator'], round(float(r.gap[-1, 0]), 6))"
    )
    run = lambda: subprocess.run(  # noqa: E731
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    a = run()
    assert a.returncode == 0, a.stderr
    libs = list((tmp_path / "cache" / "simulate").glob("aevsim_*.so"))
    assert len(libs) == 1
    libs[0].write_bytes(libs[0].read_bytes()[:4096])  # no process has it loaded now
    b = run()
    assert b.returncode == 0, b.stderr
    assert b.stdout == a.stdout and b.stdout.startswith("cascade")
    assert "damaged" in b.stderr and "rebuilding" in b.stderr


def test_unusable_cache_folder_uses_one_temp_folder_removed_at_exit(tmp_path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    env = {
        **os.environ,
        "AEV_OCP_CACHE": str(blocker / "cache"),
        "TMPDIR": str(tmpdir),
        "PYTHONPATH": str(Path(__file__).parents[1]),
    }
    code = (
        "import aev_ocp.compiled as B;"
        "a = B.compile_shared('double f(double x){return x;}', 'aevleak', 'x');"
        "b = B.compile_shared('double g(double x){return x;}', 'aevleak', 'x');"
        "assert a.path and b.path and a.path.parent == b.path.parent, (a, b); print(a.path.parent)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith(str(tmpdir))
    assert list(tmpdir.iterdir()) == []  # no aev_ocp_build_* folder left behind


def test_concurrent_builds_of_one_library_all_succeed_without_warnings(tmp_path) -> None:
    """Four processes build the same (new) library into one empty cache at once: each gets a verified
    library, none warns, ONE of them compiles it (the others wait on its lock and find it in the cache: the
    "compiling" line appears once per library per machine), and no temporary file is left."""
    env = {**os.environ, "AEV_OCP_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(Path(__file__).parents[1])}
    code = (
        "import warnings, aev_ocp.compiled as B; warnings.simplefilter('error', B.CompileWarning);"
        "r = B.compile_shared('double aev_conc(double x){return 3.0*x - 0.125;}', 'aevconc', 'c');"
        "assert r.path is not None and not r.rebuilt, r; print(B.verify_library(r.path) or 'verified')"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )
        for _ in range(4)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    assert [o.strip() for o, _ in outs] == ["verified"] * 4
    assert sum(e.count("aev_ocp: compiling aevconc") for _, e in outs) == 1, [e for _, e in outs]
    files = sorted(p.name for p in (tmp_path / "cache" / "c").iterdir())
    assert len(files) == 2 and files[0].endswith(".so") and files[1].endswith(".so.sha256"), files


def test_builds_of_one_source_are_byte_identical(tmp_path, monkeypatch) -> None:
    """gcc records the source file's name in the library: every build uses the same relative name, so
    concurrent builds of one library produce the same bytes and never fail each other's verification
    (the flaky 'size/checksum mismatch (15128 bytes, 15128 expected)' of a loaded machine)."""
    if B.compiler() is None:
        pytest.skip("no C compiler")
    digests = []
    for k in range(2):
        monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / f"cache{k}"))
        monkeypatch.setattr(B.os, "getpid", lambda k=k: 41000 + k)  # as two different processes
        res = B.compile_shared(SRC % "0.75", "twice")
        assert res.path is not None
        digests.append(B._digest(res.path))
    assert digests[0] == digests[1]


def test_driver_source_inlines_the_shared_header_once() -> None:
    """cascade.c and ring.c share c/dopri5.h (the tableau, the law dispatch, the dense output); the source that is
    compiled (and hashed for the cache) holds the header's text once and no local #include is left to resolve."""
    header = (Path(B.__file__).parent / "c" / "dopri5.h").read_text()
    for name in ("cascade.c", "ring.c"):
        raw = (Path(B.__file__).parent / "c" / name).read_text()
        assert '#include "dopri5.h"' in raw
        src = B.driver_source(name)
        assert '#include "' not in src
        assert src.count("static const double DP_P[7][4]") == 1 and header in src


def test_dense_outputs_fills_structural_zeros_and_keeps_dense_functions() -> None:
    """A constant leader's (v_l, dv_l/dt) has a structurally zero second entry: the C drivers read it densely."""
    import casadi as ca

    from aev_ocp.compiled import dense_outputs

    t, q = ca.SX.sym("t"), ca.SX.sym("q", 2)
    sparse = ca.Function("lead", [t, q], [ca.vertcat(q[0], ca.jacobian(q[0], t))])
    assert not sparse.sparsity_out(0).is_dense()
    dense = dense_outputs(sparse)
    assert dense.sparsity_out(0).is_dense() and dense.name() == "lead"
    np.testing.assert_array_equal(np.asarray(dense(3.7, [8.3, -0.4])).ravel(), [8.3, 0.0])
    full = ca.Function("f", [t], [ca.vertcat(ca.sin(t), 2.5 * t)])
    assert dense_outputs(full) is full


_ORDER_SCRIPT = """
import hashlib, sys
from aev_ocp.scenarios import load_scenario
from aev_ocp.simulate import simulate_platoon

def run(name):
    s = load_scenario(name)
    label, laws = next(iter(s.runs()))
    r = simulate_platoon(s.leader, list(laws), **{**s.simulate_kwargs(), "t_end": 12.0, "dt_out": s.dt_out})
    return hashlib.sha256(r.gap.tobytes() + r.speed.tobytes() + r.omega.tobytes()).hexdigest()

for name in sys.argv[1:-1]:
    run(name)
print(run(sys.argv[-1]))
"""


def test_a_constant_leader_run_does_not_depend_on_what_ran_before_it() -> None:
    """Bit for bit: Fig. 1b's platoon (a constant-speed leader) alone, and after Table 1's (the paper's leader) in the
    same process. Before the cascade densified the leader's output, its acceleration was read from stale stack
    memory and the two differed by ~1e-12."""

    def run(*names: str) -> str:
        out = subprocess.run([sys.executable, "-c", _ORDER_SCRIPT, *names], capture_output=True, text=True, check=True)
        return out.stdout.strip().splitlines()[-1]

    assert run("fig1b") == run("table1", "fig1b")


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)
def test_a_compiler_in_cc_that_does_not_exist_is_reported_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """CC=/nonexistent/cc aev-ocp mpc-export --build built with gcc without a word."""
    import shutil

    from aev_ocp import compiled

    monkeypatch.setenv("CC", "/nonexistent/cc-7")
    monkeypatch.setattr(compiled, "_CC_WARNED", set())
    first, second = compiled.compiler(), compiled.compiler()
    err = capsys.readouterr().err
    assert first == second == shutil.which("cc")
    assert err.count("$CC = '/nonexistent/cc-7' is not a compiler found on PATH") == 1, err
    monkeypatch.setenv("CC", "gcc")
    compiled.compiler()
    assert capsys.readouterr().err == ""
