"""Re-runnable reliability probe of every ``aev-ocp`` command and of ``aev_ocp.load()`` (issue 28).

Each try runs one command (or one ``load()``) in a fresh subprocess, in its own folder, with a time box, and is
classified:

* ok: the promised behaviour (exit 0; or one ``aev-ocp: error:`` line and exit 2 for bad input, 1 for a failed run,
  130 for an interrupt; ``load()`` raises only ``LoadError``);
* minor: the right exit code, but a message that does not name what is wrong, more than one error line, ...;
* defect: a traceback, "internal error", a hang (time box passed), a wrong exit code, user files replaced,
  temporary files or worker processes left behind, a silently wrong result.

    PYTHONPATH=$PWD python tools/probes/probe_reliability.py [--only WORD] [--json probe.json]

prints one line per try and a table of counts per area, and writes the tries as JSON. Every try uses only the
shipped scenarios and small files it writes itself (a few minutes in all on 2 cores).
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))

from harness import summarize  # noqa: E402 - the probes' shared report: a table per area and the JSON

ROOT = Path(os.environ.get("AEV_PROBE_ROOT") or Path(__file__).resolve().parents[2])  # the checkout probed
PY = sys.executable
RNG = random.Random(int(os.environ.get("AEV_PROBE_SEED", "28")))  # interrupt delays: a rerun repeats them

STUDY = """
name = "{name}"
scenarios = ["table1"]
reference = "ovfl"
[overrides]
"simulation.t_end" = {t_end}
"simulation.dt_out" = 0.05
"platoon.followers" = 2
[[axes]]
key = "platoon.gap0_first"
values = {values}
[controllers]
laws = ["proposed", "ovfl"]
"""
TINY = dict(name="tiny", t_end=1.5, values="[0.35, 0.9]")
# a study that runs long enough to be interrupted: 40 points x 2 laws of 60 model time units each
LONG = dict(name="long", t_end=60.0, values="[" + ", ".join(f"{0.3 + 0.01 * i:.2f}" for i in range(40)) + "]")
SIM_SMALL = ["--set", "simulation.t_end=1.5", "--set", "platoon.followers=2", "--no-plots"]
TRACE_SC = (
    'name = "tr"\n[leader]\nkind = "trace"\nfile = "{file}"\ntime_column = "t"\nspeed_column = "v"\n'
    "[platoon]\nfollowers = 1\ngap0_first = 1.0\nspeed0_factor = 1.0\n[simulation]\nt_end_s = {t_end}\n"
)


@dataclass
class Run:
    rc: int | None
    out: str
    err: str
    wall_s: float
    leftover_pids: list[int] = field(default_factory=list)
    signalled: bool = False  # SIGINT was sent (the run had not ended by then)


@dataclass
class Try:
    area: str
    what: str
    fn: Callable[[Path], tuple[str, str]]
    timeout_s: float = 60.0


TRIES: list[Try] = []


def trial(area: str, what: str, timeout_s: float = 60.0) -> Callable[[Callable[[Path], tuple[str, str]]], None]:
    def deco(fn: Callable[[Path], tuple[str, str]]) -> None:
        TRIES.append(Try(area, what, fn, timeout_s))

    return deco


# ----------------------------------------------------------------------------- running and judging
def _env(d: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["TMPDIR"] = str(d / "_tmp")  # temporaries a run leaves behind show up here
    env["MPLBACKEND"] = "Agg"
    env.pop("AEV_OCP_DEBUG", None)
    env.update(extra or {})
    (d / "_tmp").mkdir(exist_ok=True)
    return env


def _marked_pids(tag: str) -> list[int]:
    """Live (non-zombie) processes whose environment holds the variable ``tag`` (Linux /proc): a run and every
    process it started, in whatever process group or session (a Dask cluster runs in a session of its own)."""
    needle = tag.encode() + b"="
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            if needle not in Path(f"/proc/{pid}/environ").read_bytes():
                continue
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[0]
        except OSError:
            continue
        if state not in "ZX":
            out.append(int(pid))
    return out


def run(
    d: Path,
    argv: list[str],
    timeout_s: float = 60.0,
    *,
    sigint_after_s: float | None = None,
    env: dict[str, str] | None = None,
    python: list[str] | None = None,
    stdin: str | None = None,
) -> Run:
    """``aev-ocp argv`` (or ``python -c ...``) in folder ``d``, in its own session; killed after timeout_s (rc None).
    SIGINT goes to the run's whole process group, as a terminal's Ctrl-C does."""
    cmd = python or [PY, "-m", "aev_ocp.cli", *argv]
    tag = f"AEV_OCP_PROBE_{uuid.uuid4().hex}"  # marks every process of this run, for the leftover check
    t0 = time.perf_counter()
    signalled = False
    p = subprocess.Popen(
        cmd,
        cwd=d,
        env={**_env(d, env), tag: "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        stdin=subprocess.PIPE if stdin is not None else subprocess.DEVNULL,
    )
    try:
        if sigint_after_s is not None:
            try:
                p.wait(sigint_after_s)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGINT)
                signalled = True
        out, err = p.communicate(stdin, timeout=timeout_s)
        rc: int | None = p.returncode
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        rc = None
    wall = time.perf_counter() - t0
    left: list[int] = []
    deadline = time.monotonic() + 3.0  # workers get a moment to exit after their parent
    while time.monotonic() < deadline:
        left = _marked_pids(tag)
        if not left:
            break
        time.sleep(0.2)
    for pid in left:  # never leave the probe's own stray processes running
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return Run(rc, out, err, wall, left, signalled)


def _ended_with(r: Run, delay_s: float) -> bool:
    """Whether the run ended within 0.5 s of its SIGINT (it may have been finishing: exit 0 is then right; a run
    that computes on for longer after the signal lost it)."""
    return r.wall_s - delay_s < 0.5


def temporaries(d: Path) -> list[str]:
    """Temporary files (atomic-write leftovers, figure temporaries, temp folders) anywhere under ``d``."""
    bad = []
    for p in d.rglob("*"):
        rel = p.relative_to(d)
        if rel.parts[0] == "_tmp" and len(rel.parts) > 1:
            bad.append(str(rel))
        elif ".tmp" in p.name or p.name.startswith(".fig_"):
            bad.append(str(rel))
    return bad


def judge(
    r: Run,
    expect: tuple[int, ...],
    d: Path | None = None,
    *,
    words: tuple[str, ...] = (),
    max_wall_s: float | None = None,
) -> tuple[str, str]:
    """The verdict on one command: (ok|minor|defect, note)."""
    if r.rc is None:
        return "defect", f"hang: killed after {r.wall_s:.0f} s"
    if "Traceback" in r.err or "Traceback" in r.out:
        return "defect", "traceback: " + r.err.strip().splitlines()[-1][:160]
    if "internal error" in r.err:
        return "defect", r.err.strip().splitlines()[-1][:160]
    if r.leftover_pids:
        return "defect", f"{len(r.leftover_pids)} process(es) left running after exit {r.rc}"
    if d is not None and (tmp := temporaries(d)):
        return "defect", f"temporaries left: {tmp[:3]}"
    errs = [ln for ln in r.err.splitlines() if ln.startswith("aev-ocp: error:")]
    last = errs[-1][16:][:150] if errs else ""
    if r.rc not in expect:
        return "defect", f"exit {r.rc}, expected {expect}: {last or r.err.strip()[-150:]}"
    if r.rc != 0 and len(errs) != 1:
        return "minor", f"exit {r.rc} with {len(errs)} error lines: {r.err.strip()[-150:]}"
    if max_wall_s is not None and r.wall_s > max_wall_s:
        return "minor", f"took {r.wall_s:.1f} s (> {max_wall_s:g} s) before exit {r.rc}: {last}"
    missing = [w for w in words if w.lower() not in r.err.lower()]
    if missing:
        return "minor", f"message does not name {missing}: {last}"
    return "ok", f"exit {r.rc}{': ' + last if last else ''}"


def cli(
    argv: list[str],
    expect: tuple[int, ...] = (2,),
    words: tuple[str, ...] = (),
    timeout_s: float = 60.0,
    max_wall_s: float | None = None,
    setup: Callable[[Path], None] | None = None,
) -> Callable[[Path], tuple[str, str]]:
    """A try that runs ``argv`` (``{d}`` replaced by the try's folder) and judges it."""

    def fn(d: Path) -> tuple[str, str]:
        if setup is not None:
            setup(d)
        r = run(d, [a.replace("{d}", str(d)) for a in argv], timeout_s)
        return judge(r, expect, d, words=words, max_wall_s=max_wall_s)

    return fn


def add(area: str, what: str, argv: list[str], *args: Any, **kw: Any) -> None:
    """A try of :func:`cli` in ``area``: ``args``, ``kw`` are cli's (expect, words, timeout_s, max_wall_s, setup)."""
    timeout_s = inspect.signature(cli).bind(argv, *args, **kw).arguments.get("timeout_s", 60.0)
    TRIES.append(Try(area, what, cli(argv, *args, **kw), timeout_s))


def write(rel: str, text: str | bytes) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        f = d / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(text if isinstance(text, bytes) else text.replace("{d}", str(d)).encode())

    return setup


def both(*setups: Callable[[Path], None]) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        for s in setups:
            s(d)

    return setup


def fifo(rel: str) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        os.mkfifo(d / rel)

    return setup


def symlink(rel: str, target: str) -> Callable[[Path], None]:
    def setup(d: Path) -> None:
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        (d / rel).symlink_to(target.replace("{d}", str(d)))

    return setup


def study_text(**kw: object) -> str:
    return STUDY.format(**{**TINY, **kw})


# ----------------------------------------------------------------------------- shared fixtures (built once)
FIX: dict[str, Path] = {}


def fixtures(base: Path) -> None:
    """A saved simulate folder and a finished study folder that the damage tries copy."""
    d = base / "_fixtures"
    d.mkdir()
    r = run(d, ["simulate", "table1", *SIM_SMALL, "--out", str(d / "sim")], 120)
    assert r.rc == 0, r.err
    (d / "tiny.toml").write_text(study_text())
    r = run(d, ["study", str(d / "tiny.toml"), "--out", str(d / "study"), "--in-process"], 120)
    assert r.rc == 0, r.err
    FIX.update(sim=d / "sim", study=d / "study", study_toml=d / "tiny.toml")


def copy_of(name: str, d: Path) -> Path:
    dst = d / name
    shutil.copytree(FIX[name], dst, symlinks=True)
    return dst


# ----------------------------------------------------------------------------- load() tries
LOAD_SNIPPET = textwrap.dedent("""
    import sys, aev_ocp
    from aev_ocp.saved import LoadError
    arg = eval(sys.argv[1])
    run = eval(sys.argv[2])
    try:
        obj = aev_ocp.load(arg, run) if run is not None else aev_ocp.load(arg)
        print("LOADED", type(obj).__name__, getattr(obj, "status", ""), len(getattr(obj, "t", getattr(obj, "rows", []))))
    except LoadError as exc:
        print("LOADERROR", str(exc)[:200])
""")


def load_try(
    area: str,
    what: str,
    prepare: Callable[[Path], object],
    expect: str = "LOADERROR",
    run_label: str | None = None,
    timeout_s: float = 30.0,
    env: dict[str, str] | None = None,
) -> None:
    """``aev_ocp.load(prepare(d))`` in a subprocess: expect 'LOADED' or 'LOADERROR'; anything else is a defect."""

    def fn(d: Path) -> tuple[str, str]:
        arg = prepare(d)
        r = run(
            d,
            [],
            timeout_s,
            python=[PY, "-c", LOAD_SNIPPET, repr(str(arg) if isinstance(arg, Path) else arg), repr(run_label)],
            env=env,
        )
        if r.rc is None:
            return "defect", f"load() hung (killed after {r.wall_s:.0f} s)"
        if "Traceback" in r.err:
            return "defect", "load() raised: " + r.err.strip().splitlines()[-1][:160]
        got = r.out.strip().splitlines()[-1] if r.out.strip() else ""
        if not got.startswith(expect):
            return "defect", f"expected {expect}, got {got[:160]}"
        return "ok", got[:160]

    TRIES.append(Try(area, what, fn, timeout_s))


def _sim(d: Path) -> Path:
    return copy_of("sim", d)


def _set_manifest(d: Path, change: Callable[[dict], object], which: str = "sim", fix_sha: bool = False) -> Path:
    f = copy_of(which, d)
    m = json.loads((f / "manifest.json").read_text())
    change(m)
    if fix_sha:
        m["arrays_sha256"] = hashlib.sha256((f / "trajectories.npz").read_bytes()).hexdigest()
    (f / "manifest.json").write_text(json.dumps(m))
    return f


def _replace(rel: str, how: Callable[[Path], None], which: str = "sim") -> Callable[[Path], Path]:
    def prep(d: Path) -> Path:
        f = copy_of(which, d)
        target = f / rel
        if target.exists() or target.is_symlink():
            target.unlink()
        how(target)
        return f

    return prep


def _rewrite_npz(
    d: Path, mutate: Callable[[dict[str, bytes]], dict[str, bytes]], compression: int = zipfile.ZIP_STORED
) -> Path:
    f = copy_of("sim", d)
    with zipfile.ZipFile(f / "trajectories.npz") as z:
        members = {n: z.read(n) for n in z.namelist()}
    members = mutate(members)
    with zipfile.ZipFile(f / "trajectories.npz", "w", compression=compression) as z:
        for n, b in members.items():
            z.writestr(n, b)
    m = json.loads((f / "manifest.json").read_text())
    m["arrays_sha256"] = hashlib.sha256((f / "trajectories.npz").read_bytes()).hexdigest()
    (f / "manifest.json").write_text(json.dumps(m))
    return f


def _npy(arr_text: str) -> bytes:
    import io

    import numpy as np

    buf = io.BytesIO()
    np.save(buf, eval(arr_text, {"np": np}), allow_pickle=True)
    return buf.getvalue()


def _first_run(m: dict) -> dict:
    return next(iter(m["runs"].values()))


def register_load_tries() -> None:
    A = "load"
    load_try(A, "a clean saved simulate folder", _sim, "LOADED")
    load_try(A, "its manifest.json path instead of the folder", lambda d: _sim(d) / "manifest.json", "LOADED")
    load_try(A, "a clean study folder", lambda d: copy_of("study", d), "LOADED")
    load_try(A, "a missing path", lambda d: d / "nope")
    load_try(A, "an empty folder", lambda d: (d / "empty").mkdir() or d / "empty")
    load_try(A, "a path that is a regular non-manifest file", lambda d: (d / "x.txt").write_text("hi") and d / "x.txt")
    load_try(A, "run label that does not exist", _sim, run_label="nope")
    load_try(A, "manifest.json is JSON [] ", lambda d: _replace("manifest.json", lambda t: t.write_text("[]"))(d))
    load_try(
        A,
        "manifest.json is binary junk",
        lambda d: _replace("manifest.json", lambda t: t.write_bytes(os.urandom(4096)))(d),
    )
    load_try(A, "manifest.json is a FIFO", lambda d: _replace("manifest.json", lambda t: os.mkfifo(t))(d), timeout_s=15)
    load_try(A, "manifest.json is a folder", lambda d: _replace("manifest.json", lambda t: t.mkdir())(d))
    load_try(
        A,
        "manifest.json -> /dev/urandom",
        lambda d: _replace("manifest.json", lambda t: t.symlink_to("/dev/urandom"))(d),
        timeout_s=15,
    )
    load_try(
        A,
        "manifest.json is a dangling symlink",
        lambda d: _replace("manifest.json", lambda t: t.symlink_to(d / "gone"))(d),
    )
    load_try(A, "manifest.json is a symlink loop", lambda d: _replace("manifest.json", lambda t: t.symlink_to(t))(d))
    load_try(
        A,
        "manifest.json 250 MB of spaces (sparse)",
        lambda d: _replace("manifest.json", lambda t: os.truncate(t.open("w").name, 250_000_000))(d),
    )
    load_try(
        A, "trajectories.npz is a FIFO", lambda d: _replace("trajectories.npz", lambda t: os.mkfifo(t))(d), timeout_s=15
    )
    load_try(
        A,
        "trajectories.npz -> /dev/zero",
        lambda d: _replace("trajectories.npz", lambda t: t.symlink_to("/dev/zero"))(d),
        timeout_s=15,
    )
    load_try(A, "trajectories.npz missing", lambda d: _replace("trajectories.npz", lambda t: None)(d))
    load_try(
        A,
        "trajectories.npz truncated to half",
        lambda d: _replace(
            "trajectories.npz", lambda t: t.write_bytes((FIX["sim"] / "trajectories.npz").read_bytes()[:2000])
        )(d),
    )
    load_try(
        A,
        "manifest format_version 1e308 (a float)",
        lambda d: _set_manifest(d, lambda m: m.update(format_version=1e308)),
    )
    load_try(A, "manifest format_version 2 (newer)", lambda d: _set_manifest(d, lambda m: m.update(format_version=2)))
    load_try(A, "manifest kind 'hack'", lambda d: _set_manifest(d, lambda m: m.update(kind="hack")))
    load_try(
        A,
        "manifest arrays '../../etc/passwd'",
        lambda d: _set_manifest(d, lambda m: m.update(arrays="../../etc/passwd")),
    )
    load_try(A, "manifest runs = []", lambda d: _set_manifest(d, lambda m: m.update(runs=[])))
    load_try(A, "manifest primary = 7", lambda d: _set_manifest(d, lambda m: m.update(primary=7)))
    load_try(A, "a run's 'ev' is a string", lambda d: _set_manifest(d, lambda m: _first_run(m).update(ev="x")))
    load_try(
        A,
        "a run's events hold a huge vehicle index",
        lambda d: _set_manifest(
            d, lambda m: _first_run(m).update(events=[{"kind": "collision", "t": 1.0, "vehicle": 10**30, "detail": ""}])
        ),
    )
    load_try(
        A,
        "manifest with 10^5-deep nesting",
        lambda d: _replace(
            "manifest.json", lambda t: t.write_text('{"format": ' + "[" * 100_000 + "]" * 100_000 + "}")
        )(d),
    )
    load_try(
        A,
        "npz member of 3 GB stated size (zip bomb, SHA updated)",
        lambda d: _rewrite_npz(d, lambda m: {**m, "proposed/bomb.npy": b"\0" * 3_000_000}, zipfile.ZIP_DEFLATED),
        env={"AEV_OCP_MAX_MEMORY_GB": "0.002"},
    )
    load_try(
        A,
        "npz member holding a pickled object array (SHA updated)",
        lambda d: _rewrite_npz(
            d,
            lambda m: {
                **{k: _npy("np.array([{'a': 1}], dtype=object)") if k.endswith("/t.npy") else v for k, v in m.items()}
            },
        ),
    )
    load_try(
        A,
        "npz 't' array of a different length (SHA updated)",
        lambda d: _rewrite_npz(
            d, lambda m: {k: _npy("np.arange(3.0)") if k.endswith("/t.npy") else v for k, v in m.items()}
        ),
    )
    load_try(
        A,
        "npz 'gap' array 3-D (SHA updated)",
        lambda d: _rewrite_npz(
            d, lambda m: {k: _npy("np.zeros((2, 2, 2))") if k.endswith("/gap.npy") else v for k, v in m.items()}
        ),
    )
    load_try(
        A,
        "npz 'speed' array of strings (SHA updated)",
        lambda d: _rewrite_npz(
            d, lambda m: {k: _npy("np.array(['a', 'b'])") if k.endswith("/speed.npy") else v for k, v in m.items()}
        ),
    )
    load_try(A, "npz with every member removed (SHA updated)", lambda d: _rewrite_npz(d, lambda m: {}))
    load_try(
        A,
        "study table.jsonl is a FIFO",
        lambda d: _replace("table.jsonl", lambda t: os.mkfifo(t), "study")(d),
        timeout_s=15,
    )
    load_try(
        A,
        "study table.jsonl holds junk lines",
        lambda d: _replace("table.jsonl", lambda t: t.write_text("{\n[1]\n"), "study")(d),
    )
    load_try(
        A,
        "study table.jsonl holds a JSON list per line",
        lambda d: _replace("table.jsonl", lambda t: t.write_text("[1]\n[2]\n"), "study")(d),
    )
    load_try(
        A,
        "study table.jsonl is latin-1 bytes",
        lambda d: _replace("table.jsonl", lambda t: t.write_bytes(b"\xe9\xff\n"), "study")(d),
    )
    load_try(
        A, "study manifest n_tasks = 'many'", lambda d: _set_manifest(d, lambda m: m.update(n_tasks="many"), "study")
    )
    load_try(
        A,
        "study manifest table = '/etc/passwd'",
        lambda d: _set_manifest(d, lambda m: m.update(table="/etc/passwd"), "study"),
    )
    load_try(A, "path given as int 5", lambda d: 5)
    load_try(A, "path given as None", lambda d: None)
    load_try(A, "path with a NUL byte", lambda d: str(d) + "/a\0b")
    load_try(
        A,
        "unicode folder name 'Ergebnisse ü 🚗'",
        lambda d: shutil.copytree(FIX["sim"], d / "Ergebnisse ü 🚗"),
        "LOADED",
    )
    load_try(A, "a folder 4096 characters deep", lambda d: d / (("a" * 300 + "/") * 14))


# ----------------------------------------------------------------------------- command tries
def register_cli_tries() -> None:
    S = "simulate"
    add("cli", "no arguments", [])
    add("cli", "unknown command", ["frobnicate"])
    add("cli", "--version", ["--version"], (0,))
    add("cli", "study --help", ["study", "--help"], (0,))
    add("cli", "unknown option after command", ["simulate", "table1", "--frob"])
    add(S, "missing scenario file", ["simulate", "nope.toml"], words=("nope",))
    add(S, "scenario is an empty string", ["simulate", ""])
    add(S, "scenario is a folder", ["simulate", "{d}"])
    add(S, "scenario is /dev/zero", ["simulate", "/dev/zero"], timeout_s=20)
    add(S, "scenario is a FIFO", ["simulate", "{d}/s.toml"], setup=fifo("s.toml"), timeout_s=20)
    add(
        S,
        "scenario -> /dev/urandom symlink",
        ["simulate", "{d}/s.toml"],
        setup=symlink("s.toml", "/dev/urandom"),
        timeout_s=20,
    )
    add(S, "scenario of binary junk", ["simulate", "{d}/s.toml"], setup=write("s.toml", os.urandom(3000)))
    add(
        S,
        "scenario of 10^5 nested arrays",
        ["simulate", "{d}/s.toml"],
        setup=write("s.toml", "x = " + "[" * 100_000 + "]" * 100_000 + "\n"),
    )
    add(
        S,
        "scenario 60 MB comment",
        ["simulate", "{d}/s.toml"],
        setup=write("s.toml", "#" + "x" * 60_000_000 + "\n"),
        max_wall_s=10,
    )
    add(
        S,
        "scenario with a BOM",
        ["simulate", "{d}/s.toml", *SIM_SMALL, "--out", "{d}/o"],
        (0, 2),
        setup=write("s.toml", "\ufeff" + (ROOT / "scenarios" / "table1.toml").read_text()),
    )
    add(
        S,
        "unknown top-level key",
        ["simulate", "{d}/s.toml"],
        setup=write("s.toml", (ROOT / "scenarios" / "table1.toml").read_text() + "\nfrobnicate = 1\n"),
        words=("frobnicate",),
    )
    add(
        S,
        "unicode scenario file and out folder",
        ["simulate", "{d}/Szenario ü 🚗.toml", *SIM_SMALL, "--out", "{d}/Ergebnis ü 🚗"],
        (0,),
        setup=write("Szenario ü 🚗.toml", (ROOT / "scenarios" / "table1.toml").read_text()),
    )
    for kv, word in [
        ("platoon.followers=-1", "followers"),
        ("platoon.followers=0", "followers"),
        ("platoon.followers=2.5", "followers"),
        ("platoon.followers=true", "followers"),
        ("platoon.followers=100000000", "followers"),
        ("simulation.t_end=nan", "t_end"),
        ("simulation.t_end=inf", "t_end"),
        ("simulation.t_end=-5", "t_end"),
        ("simulation.t_end=1e308", "t_end"),
        ("simulation.dt_out=0", "dt_out"),
        ("simulation.dt_out=1e-12", "dt_out"),
        ("simulation.rtol=-1", "rtol"),
        ("carfollowing.kappa=[1,2]", "kappa"),
        ('carfollowing.kappa="x"', "kappa"),
        ("carfollowing.kappa=nan", "kappa"),
        ("units.length_m=0", "length_m"),
        ("units.speed_mps=-3", "speed_mps"),
        ("frob.key=1", "frob"),
        ("platöon.followers=2", "platöon"),
        ("=", "key"),
        ("noequals", "noequals"),
        ("simulation.t_end=" + "9" * 5000, "t_end"),
        ('leader.kind="trace"', "file"),
        ("vehicle.efficiency=1.5", "efficiency"),
        ("simulation.t_end=2\nplatoon.followers=9", "line"),
        ("simulation.t_end_s=3", None),
        ('thermal.enabled="yes"', "thermal.enabled"),
        ("carfollowing.alpha=1e400", "alpha"),
    ]:
        ok = word is None
        small = ["--set", "platoon.followers=2"] if ok else ["--set", "simulation.t_end=1.5"]  # before kv: kv wins
        add(
            S,
            f"--set {kv[:40]!r}",
            ["simulate", "table1", "--no-plots", "--out", "{d}/o", *small, "--set", kv],
            (0,) if ok else (2,),
            words=() if ok else (word,),
        )
    for tl in ("nan", "-1", "0", "inf", "abc"):
        add(
            S,
            f"--time-limit {tl}",
            ["simulate", "table1", *SIM_SMALL, "--time-limit", tl, "--out", "{d}/o"],
            (2,) if tl in ("nan", "-1", "abc", "inf") else (1, 2),
            words=("time-limit",),
        )
    # output folders
    for name, out, setup, expect in [
        ("--out is a file", "{d}/f", write("f", "mine"), (2,)),
        ("--out under a file", "{d}/f/sub", write("f", "mine"), (2,)),
        ("--out -> /dev/null", "{d}/o", symlink("o", "/dev/null"), (2,)),
        ("--out is a dangling symlink", "{d}/o", symlink("o", "{d}/gone"), (0, 2)),
        ("--out symlink to a folder", "{d}/o", both(write("real/.keep", ""), symlink("o", "{d}/real")), (0,)),
        ("--out in /proc", "/proc/aev_probe", None, (2,)),
        ("--out 300-character name", "{d}/" + "n" * 300, None, (2,)),
        ("--out empty string", "", None, (0, 2)),
        ("--out holds a user's metrics.json", "{d}/o", write("o/metrics.json", '{"mine": 1}'), (2,)),
        (
            "--out holds another scenario's run",
            "{d}/o",
            write("o/aev-ocp-run.json", '{"command": "simulate", "scenario": "fig1a", "source": null}'),
            (2,),
        ),
        ("--out holds an unreadable marker", "{d}/o", write("o/aev-ocp-run.json", "\x00\x01"), (2,)),
        ("--out marker is a FIFO", "{d}/o", fifo("o/aev-ocp-run.json"), (2,)),
    ]:

        def check(d: Path, out: str = out, setup=setup, expect=expect) -> tuple[str, str]:
            if setup is not None:
                setup(d)
            before = {
                p: p.read_bytes() for p in d.rglob("*") if p.is_file() and not p.is_symlink() and "_tmp" not in p.parts
            }
            r = run(d, ["simulate", "table1", *SIM_SMALL, "--out", out.replace("{d}", str(d))], 40)
            v = judge(r, expect, d)
            changed = [str(p.name) for p, b in before.items() if not p.exists() or p.read_bytes() != b]
            if changed and v[0] != "defect":
                return "defect", f"user file(s) changed: {changed}"
            if out == "" and r.rc == 0:  # an empty --out wrote into the current folder: report where
                return "minor", "empty --out accepted (wrote into the current folder)"
            return v

        TRIES.append(Try("outdir", f"simulate {name}", check, 45))
    # the other commands' output folders
    for cmd, files in [
        (["stability", "--law", "ovm", "--linear-only"], "stability.json"),
        (["ring", "sugiyama", "--t-end-s", "3"], "ring.json"),
        (["safety", "--quick", "--no-plots"], "safety.json"),
        (["mpc", "mpc_paper_single", "--t-end", "1", "--no-ocpd"], "results.json"),
        (["mpc-export", "mpc_paper_single"], "mpc_step.c"),
        (["ocp", "prop31", "--N", "20", "--no-refine"], "prop31.json"),
        (["reproduce", "--quick"], "report.md"),
    ]:
        add(
            "outdir",
            f"{cmd[0]} --out holding a user's {files}",
            [*cmd, "--out", "{d}/o"],
            (2,),
            setup=write(f"o/{files}", "mine"),
            words=(files,),
            max_wall_s=8,
        )
        add(
            "outdir",
            f"{cmd[0]} --out is a file",
            [*cmd, "--out", "{d}/f"],
            (2,),
            setup=write("f", "mine"),
            max_wall_s=8,
        )
    # mpc
    M = "mpc"
    for extra, word in [
        (["--t-end", "-1"], "t-end"),
        (["--t-end", "nan"], "t-end"),
        (["--t-end", "0"], "t-end"),
        (["--t-end", "1e12"], "t"),
        (["--set", "mpc.N=0"], "mpc.N"),
        (["--set", "mpc.N=-4"], "mpc.N"),
        (["--set", "mpc.N=1000000000"], "mpc.N"),
        (["--set", "mpc.dt=0"], "mpc.dt"),
        (["--set", "mpc.dt=nan"], "mpc.dt"),
        (["--set", 'mpc.predictor="psychic"'], "predictor"),
        (["--solver", "magic"], "solver"),
        (["--time-limit", "-2"], "time-limit"),
        (["--progress-every", "0"], "progress-every"),
        (["--progress-every", "nan"], "progress-every"),
        (["--laws", "nope"], "nope"),
        (["--set", "mpc.frob=1"], "frob"),
        (["--t-end", "3", "--set", "simulation.t_end_s=3"], "t_end"),
    ]:
        add(
            M,
            " ".join(extra)[:50],
            ["mpc", "mpc_paper_single", "--no-ocpd", "--out", "{d}/o", *extra],
            (2,),
            words=(word,),
            max_wall_s=15,
        )
    add(
        M,
        "mpc table1 (no [mpc] table: defaults)",
        ["mpc", "table1", "--t-end", "1", "--no-ocpd", "--out", "{d}/o", "--set", "platoon.followers=1"],
        (0,),
        timeout_s=120,
    )
    add(
        M,
        "--time-limit 0.5 on a long run",
        ["mpc", "mpc_paper_single", "--no-ocpd", "--out", "{d}/o", "--time-limit", "0.5"],
        (1,),
        timeout_s=120,
    )
    # mpc-export
    E = "mpc-export"
    add(E, "no --out", ["mpc-export", "mpc_paper_single"], words=("--out",))
    for kv, word in [
        ("mpc.N=0", "mpc.N"),
        ("mpc.N=1e9", "mpc.N"),
        ('mpc.N="ten"', "mpc.N"),
        ("mpc.dt=-0.1", "mpc.dt"),
        ("mpc.frob=2", "frob"),
        ('mpc.solver="ipopt"', None),
    ]:
        add(
            E,
            f"--set {kv}",
            ["mpc-export", "mpc_paper_single", "--out", "{d}/o", "--set", kv],
            (2,) if word else (0, 2),
            words=(word,) if word else (),
            max_wall_s=20,
            timeout_s=120,
        )
    add(E, "scenario without an [mpc] table", ["mpc-export", "table1", "--out", "{d}/o"], (0, 2), timeout_s=120)
    add(
        E,
        "--out is a symlink to /dev/null",
        ["mpc-export", "mpc_paper_single", "--out", "{d}/o"],
        (2,),
        setup=symlink("o", "/dev/null"),
    )
    add(
        E,
        "unicode relative --out with --build",
        ["mpc-export", "mpc_paper_single", "--out", "Export ü 🚗", "--build"],
        (0,),
        timeout_s=240,
    )
    # stability
    T = "stability"
    for extra, word in [
        (["--law", "nope"], "nope"),
        (["--law", "ovm", "--speed-mps", "-1"], "speed"),
        (["--law", "ovm", "--speed-mps", "nan"], "speed"),
        (["--law", "ovm", "--speed-mps", "0"], "speed"),
        (["--law", "ovm", "--speed-mps", "1e9"], "speed"),
        (["--law", "ovm", "--amplitude-mps", "1e6"], "amplitude"),
        (["--law", "ovm", "--followers", "0"], "followers"),
        (["--law", "ovm", "--followers", "100000000"], "followers"),
        (["--law", "ovm", "--omega-rad-per-s", "0"], "omega"),
        (["--law", "ovm", "--duration-s", "-3"], "duration"),
        (["--law", "ovm", "--kind", "square"], "kind"),
        (["--law", "ovm", "--set", "carfollowing.ovm.frob=2"], "frob"),
        (["--law", "ovm", "--set", "carfollowing.kappa=inf"], "kappa"),
        (["--law", "ovm", "--units-length-m", "0"], "length"),
        (["--law", "ovm", "--ring", "0"], "ring"),
        (["--law", "ovm", "--ring", "1000000000"], "ring"),
        (["--law", "ovm", "--ring", "22", "--density-per-km", "0"], "density"),
        (["--law", "ovm", "--ring", "22", "--density-per-km", "1e9"], "density"),
        (["--law", "ovm", "--ring", "22", "--spacing-m", "-5"], "spacing"),
        (["--law", "mpc", "--predictor", "psychic"], "predictor"),
        (["--law", "ovm", "--speed-model", "1.7", "--speed-mps", "8"], "speed"),
    ]:
        add(
            T,
            " ".join(extra[2:] or extra)[:50],
            ["stability", *extra, "--linear-only", "--no-plots", "--out", "{d}/o"],
            (2,),
            words=(word,),
            max_wall_s=15,
        )
    add(
        T,
        "ovm linear only (a run that works)",
        ["stability", "--law", "ovm", "--linear-only", "--no-plots", "--out", "{d}/o"],
        (0,),
    )
    # ring
    R = "ring"
    for extra, word in [
        (["bogus"], "bogus"),
        (["sugiyama", "--t-end-s", "-1"], "t-end"),
        (["sugiyama", "--t-end-s", "nan"], "t-end"),
        (["sugiyama", "--t-end-s", "1e12"], "t"),
        (["sugiyama", "--seed", "-1"], "seed"),
        (["sugiyama", "--seed", "x"], "seed"),
        (["sweep", "--penetration", "23"], "penetration"),
        (["sweep", "--penetration", "-1"], "penetration"),
        (["sweep", "--length-m", "0"], "length"),
        (["sweep", "--length-m", "nan"], "length"),
        (["sweep", "--aev", "teleport"], "teleport"),
        (["{d}/r.toml"], "r.toml"),
    ]:
        add(
            R,
            " ".join(extra)[:50],
            ["ring", *extra, "--no-plots", "--out", "{d}/o"],
            (2,),
            words=(word,),
            max_wall_s=15,
            setup=write("r.toml", 'name = "r"\n[ring]\nfrob = 1\n'),
        )
    # ocp
    O = "ocp"
    for extra, word in [
        (["prop31", "--N", "0"], "N"),
        (["prop31", "--N", "-5"], "N"),
        (["prop31", "--N", "1e12"], "N"),
        (["prop31", "--N", "100000000"], "N"),
        (["nope"], "nope"),
        (["prop31", "--soc0", "2"], "soc0"),
        (["prop31", "--soc0", "nan"], "soc0"),
        (["prop31", "--cell", "unobtainium"], "unobtainium"),
        (["prop31", "--cell", "/dev/zero"], "zero"),
        (["prop31", "--v-relax-V", "a,b"], "v-relax"),
        (["current-profile", "--grid", "E_req=1,nan"], "E_req"),
        (["current-profile", "--grid", "frob=1"], "frob"),
        (["current-profile", "--grid-file", "/dev/zero"], "grid"),
        (["current-profile", "--grid-file", "{d}/g.toml"], "g.toml"),
        (["oracle", "{d}/nope.toml"], "nope"),
        (["prop31", "--time-limit", "nan"], "time-limit"),
    ]:
        add(
            O,
            " ".join(extra)[:50],
            ["ocp", *extra, "--out", "{d}/o"],
            (2,),
            words=(word,),
            max_wall_s=15,
            setup=write("g.toml", "E_req = [1e400]\n"),
        )
    # reproduce, safety, sumo, scenarios
    add("other", "reproduce --out is a file", ["reproduce", "--out", "{d}/f"], (2,), setup=write("f", "x"))
    add("other", "safety --out under a file", ["safety", "--quick", "--out", "{d}/f/x"], (2,), setup=write("f", "x"))
    add("other", "sumo with a missing scenario", ["sumo", "{d}/nope.toml"], (2,), words=("nope",))
    add("other", "scenarios (lists)", ["scenarios"], (0,))
    add("other", "sumo with an unknown option", ["sumo", "sumo_ring", "--bogus"], (2,), words=("--bogus",))
    add(
        "other",
        "ocp --grid-file holding a JSON list",
        ["ocp", "current-profile", "--grid-file", "{d}/g.json", "--out", "{d}/o"],
        (2,),
        words=("g.json",),
        setup=write("g.json", "[1, 2]"),
    )
    for cmd in (["study", "{d}/s.toml"], ["mpc", "mpc_paper_single"], ["ring", "sugiyama"], ["ocp", "prop31"]):
        add(
            "other",
            f"{cmd[0]} --out ''",
            [*cmd, "--out", ""],
            (2,),
            words=("--out",),
            setup=write("s.toml", study_text()),
        )


def register_study_tries() -> None:
    A = "study"

    def bad(what: str, text: str, word: str, extra: tuple[str, ...] = ()) -> None:
        add(
            A,
            what,
            ["study", "{d}/s.toml", "--out", "{d}/o", "--in-process", "--no-report", *extra],
            (2,),
            words=(word,),
            setup=write("s.toml", text),
            max_wall_s=10,
        )

    base = study_text()
    for what, text, word in [
        ("unknown top-level key", base + "\nfrob = 1\n", "frob"),
        ("name with a slash", base.replace('name = "tiny"', 'name = "a/b"'), "name"),
        ("name of 500 characters", base.replace('name = "tiny"', f'name = "{"n" * 500}"'), "name"),
        ("unicode name", base.replace('name = "tiny"', 'name = "Studie ü"'), "name"),
        ("scenarios empty", base.replace('scenarios = ["table1"]', "scenarios = []"), "scenarios"),
        ("scenario missing", base.replace('scenarios = ["table1"]', 'scenarios = ["nope"]'), "nope"),
        ("scenario /dev/zero", base.replace('scenarios = ["table1"]', 'scenarios = ["/dev/zero"]'), "zero"),
        ("axis values empty", base.replace("[0.35, 0.9]", "[]"), "values"),
        ("axis values nan", base.replace("[0.35, 0.9]", "[nan, 0.5]"), "nan"),
        ("axis values inf", base.replace("[0.35, 0.9]", "[inf]"), "inf"),
        ("axis values strings", base.replace("[0.35, 0.9]", '["a", "b"]'), "gap0_first"),
        ("axis values negative gap", base.replace("[0.35, 0.9]", "[-0.5]"), "gap0_first"),
        ("axis key unknown", base.replace("platoon.gap0_first", "platoon.frob"), "frob"),
        ("axis key empty", base.replace("platoon.gap0_first", ""), "key"),
        ("two axes on one key", base + '[[axes]]\nkey = "platoon.gap0_first"\nvalues = [0.5]\n', "gap0_first"),
        ("laws empty", base.replace('laws = ["proposed", "ovfl"]', "laws = []"), "laws"),
        ("laws unknown", base.replace('laws = ["proposed", "ovfl"]', 'laws = ["teleport"]'), "teleport"),
        ("laws a number", base.replace('laws = ["proposed", "ovfl"]', "laws = 3"), "laws"),
        ("reference not a controller", base.replace('reference = "ovfl"', 'reference = "idm"'), "reference"),
        ("overrides unknown key", base.replace('"platoon.followers" = 2', '"platoon.frob" = 2'), "frob"),
        (
            "overrides followers 10^8",
            base.replace('"platoon.followers" = 2', '"platoon.followers" = 100000000'),
            "followers",
        ),
        ("mpc controller N = 10^8", base + '[[controllers.mpc]]\nlabel = "m"\nN = 100000000\n', "N"),
        ("mpc controller unknown key", base + '[[controllers.mpc]]\nlabel = "m"\nfrob = 1\n', "frob"),
        ("mpc controller label clash", base + '[[controllers.mpc]]\nlabel = "ovfl"\n', "ovfl"),
    ]:
        bad(what, text, word)
    for what, rnd, word in [
        ("n = 0", "n = 0, seed = 1, low = [0.3], high = [0.5]", "n"),
        ("n = -3", "n = -3, seed = 1, low = [0.3], high = [0.5]", "n"),
        ("n = 2.5", "n = 2.5, seed = 1, low = [0.3], high = [0.5]", "n"),
        ("n = 10^12", "n = 1000000000000, seed = 1, low = [0.3], high = [0.5]", "n"),
        ("low > high", "n = 3, seed = 1, low = [0.5], high = [0.3]", "low"),
        ("seed -1", "n = 3, seed = -1, low = [0.3], high = [0.5]", "seed"),
        ("low nan", "n = 3, seed = 1, low = [nan], high = [0.5]", "low"),
    ]:
        bad(f"random {what}", base.replace("values = [0.35, 0.9]", f"random = {{ {rnd} }}"), word)
    bad(
        "random and values both",
        base.replace("values = [0.35, 0.9]", "values = [0.4]\nrandom = { n = 3, seed = 1, low = [0.3], high = [0.5] }"),
        "random",
    )
    bad(
        "1000 x 1000 grid",
        base.replace(
            'key = "platoon.gap0_first"\nvalues = [0.35, 0.9]',
            "".join(
                f'key = "carfollowing.{k}"\nvalues = ['
                + ", ".join(f"{0.01 + 1e-5 * i:.6f}" for i in range(1000))
                + "]\n"
                + ("[[axes]]\n" if k == "kappa" else "")
                for k in ("kappa", "alpha")
            ),
        ),
        "100000",
    )
    add(
        A,
        "report metric unknown (refused when the study is read, naming it)",
        ["study", "{d}/s.toml", "--out", "{d}/o", "--in-process"],
        (2,),
        words=("frob",),
        setup=write("s.toml", base + '[report]\nmetrics = ["frob"]\n'),
    )
    bad("study file of binary junk", os.urandom(2000).decode("latin-1"), "s.toml")
    bad("--set on the axis key", base, "gap0_first", ("--set", "platoon.gap0_first=0.5"))
    bad("--set kappa = nan", base, "nan", ("--set", "carfollowing.kappa=nan"))
    bad("--set unknown key", base, "frob", ("--set", "carfollowing.frob=1"))
    bad("--set followers = 0", base, "followers", ("--set", "platoon.followers=0"))
    bad("--time-limit nan", base, "time-limit", ("--time-limit", "nan"))
    bad("--time-limit -1", base, "time-limit", ("--time-limit", "-1"))
    for opt, val in [
        ("--workers", "0"),
        ("--workers", "-2"),
        ("--workers", "x"),
        ("--workers", "100000"),
        ("--dask-local", "0"),
        ("--dask-local", "100000"),
    ]:
        add(
            A,
            f"{opt} {val}",
            ["study", "{d}/s.toml", "--out", "{d}/o", opt, val],
            (2,),
            words=(opt.strip("-")[:4],),
            setup=write("s.toml", base),
            max_wall_s=10,
        )
    for sched, word in [
        ("nonsense", "nonsense"),
        ("tcp://127.0.0.1:1", "127.0.0.1"),
        ("tcp://256.1.1.1:8786", "256"),
        ("tls://127.0.0.1:1", "127.0.0.1"),
    ]:
        add(
            A,
            f"--scheduler {sched}",
            ["study", "{d}/s.toml", "--out", "{d}/o", "--scheduler", sched],
            (1, 2),
            words=(word,),
            setup=write("s.toml", base),
            timeout_s=60,
        )
    add(A, "study file is a FIFO", ["study", "{d}/s.toml", "--in-process"], (2,), setup=fifo("s.toml"), timeout_s=15)
    add(A, "study file is /dev/zero", ["study", "/dev/zero", "--in-process"], (2,), timeout_s=15)
    add(A, "study file is a folder", ["study", "{d}", "--in-process"], (2,))
    add(
        A,
        "a tiny study that works (pool of 2)",
        ["study", "{d}/s.toml", "--out", "{d}/o", "--workers", "2"],
        (0,),
        setup=write("s.toml", base),
        timeout_s=120,
    )
    add(
        A,
        "a tiny study that works (--dask-local 2)",
        ["study", "{d}/s.toml", "--out", "{d}/o", "--dask-local", "2", "--no-report"],
        (0,),
        setup=write("s.toml", base),
        timeout_s=180,
    )
    add(
        A,
        "--out holding a user's report.md",
        ["study", "{d}/s.toml", "--out", "{d}/o", "--in-process"],
        (2,),
        setup=both(write("s.toml", base), write("o/report.md", "mine")),
        words=("report.md",),
    )
    add(
        A,
        "--out is a symlink to /dev/null",
        ["study", "{d}/s.toml", "--out", "{d}/o", "--in-process"],
        (2,),
        setup=both(write("s.toml", base), symlink("o", "/dev/null")),
    )

    # the store, damaged in new ways
    def damaged(what: str, how: Callable[[Path], None], expect_warning: bool = True) -> None:
        def fn(d: Path) -> tuple[str, str]:
            o = copy_of("study", d)
            before = _rows(o / "table.jsonl")
            how(o)
            r = run(d, ["study", str(FIX["study_toml"]), "--out", str(o), "--in-process"], 60)
            v = judge(r, (0,), d)
            if v[0] != "ok":
                return v
            if _rows(o / "table.jsonl") != before:
                return "defect", "the rebuilt table differs from the original one"
            if expect_warning and "damaged" not in r.err:
                return "minor", "damaged entry recomputed without a warning"
            return "ok", "damaged entries recomputed, same table"

        TRIES.append(Try("store", what, fn, 70))

    def _rows(f: Path) -> list[dict]:  # the table without wall times and versions (a recomputed task has its own)
        meta = ("wall_s", "git_commit", "aev_ocp_version", "casadi_version")
        return [{k: v for k, v in json.loads(line).items() if k not in meta} for line in f.read_text().splitlines()]

    def entries(o: Path) -> list[Path]:
        return sorted((o / "points").glob("*.json"))

    damaged("a stray FIFO in points/", lambda o: os.mkfifo(o / "points" / "stray.json"), False)
    damaged("an entry -> /dev/zero", lambda o: (lambda f: (f.unlink(), f.symlink_to("/dev/zero")))(entries(o)[0]))
    damaged("an entry replaced by a folder", lambda o: (lambda f: (f.unlink(), f.mkdir()))(entries(o)[0]))
    damaged(
        "an entry with a NaN metric (hash kept)",
        lambda o: (lambda f: f.write_text(f.read_text().replace('"status": "ok"', '"status": NaN', 1)))(entries(o)[0]),
    )
    damaged("an entry truncated to 0 bytes", lambda o: entries(o)[1].write_bytes(b""))
    damaged("an entry of 10^5-deep nesting", lambda o: entries(o)[2].write_text("[" * 100_000 + "]" * 100_000))
    damaged("an entry in UTF-16", lambda o: (lambda f: f.write_bytes(f.read_text().encode("utf-16")))(entries(o)[3]))
    damaged("points/ replaced by a file", lambda o: (shutil.rmtree(o / "points"), (o / "points").write_text("x")))
    damaged("table.jsonl replaced by junk", lambda o: (o / "table.jsonl").write_text("junk\n"), False)
    damaged("manifest.json replaced by junk", lambda o: (o / "manifest.json").write_text("junk\n"), False)

    def foreign(what: str, how: Callable[[Path], None], word: str) -> None:  # damage that makes the folder foreign
        def fn(d: Path) -> tuple[str, str]:
            o = copy_of("study", d)
            how(o)
            r = run(d, ["study", str(FIX["study_toml"]), "--out", str(o), "--in-process"], 60)
            return judge(r, (2,), d, words=(word,))

        TRIES.append(Try("store", what, fn, 70))

    foreign(
        "marker removed (the folder now looks foreign)", lambda o: (o / "aev-ocp-run.json").unlink(), "manifest.json"
    )
    foreign(
        "marker names another study",
        lambda o: (o / "aev-ocp-run.json").write_text('{"command": "study", "scenario": "other", "source": null}'),
        "other",
    )

    def fifo_entry(d: Path) -> tuple[str, str]:  # a FIFO where an entry should be: must not hang
        o = copy_of("study", d)
        f = entries(o)[0]
        f.unlink()
        os.mkfifo(f)
        r = run(d, ["study", str(FIX["study_toml"]), "--out", str(o), "--in-process"], 30)
        return judge(r, (0, 2), d)

    TRIES.append(Try("store", "an entry replaced by a FIFO (named as the entry)", fifo_entry, 35))

    def resume_other_study(d: Path) -> tuple[str, str]:  # the same study NAME, another file and other values
        o = copy_of("study", d)
        (d / "t.toml").write_text(study_text(values="[0.4]"))
        r = run(d, ["study", str(d / "t.toml"), "--out", str(o), "--in-process"], 60)
        return judge(r, (2,), d, words=("tiny",))

    TRIES.append(Try("store", "same study name from another file into a finished folder", resume_other_study, 65))

    # interrupts and concurrency
    def interrupted(
        what: str,
        argv_extra: list[str],
        expect: tuple[int, ...] = (130,),
        lo: float = 2.0,
        hi: float = 6.0,
        timeout_s: float = 90.0,
        text: str | None = None,
    ) -> None:
        def fn(d: Path) -> tuple[str, str]:
            (d / "s.toml").write_text(text or study_text(**LONG))
            delay = RNG.uniform(lo, hi)
            r = run(
                d, ["study", str(d / "s.toml"), "--out", str(d / "o"), *argv_extra], timeout_s, sigint_after_s=delay
            )
            v = judge(r, expect if r.signalled and not _ended_with(r, delay) else (0, *expect), d)
            return v[0], f"SIGINT after {delay:.1f} s: {v[1]}"

        TRIES.append(Try("interrupt", what, fn, timeout_s + 10))

    interrupted("study --workers 2, SIGINT", ["--workers", "2"])
    interrupted("study --workers 2, SIGINT (2)", ["--workers", "2"], lo=0.5, hi=2.0)
    interrupted("study --in-process, SIGINT", ["--in-process"])
    interrupted("study --dask-local 2, SIGINT", ["--dask-local", "2"], lo=4.0, hi=9.0, timeout_s=120)
    interrupted("study --dask-local 2, SIGINT early", ["--dask-local", "2"], lo=0.3, hi=1.5, timeout_s=120)

    def time_limited(what: str, extra: list[str]) -> None:
        def fn(d: Path) -> tuple[str, str]:
            (d / "s.toml").write_text(study_text(**LONG))
            r = run(d, ["study", str(d / "s.toml"), "--out", str(d / "o"), "--time-limit", "3", *extra], 120)
            v = judge(r, (0, 1), d)  # 0: all 80 tasks finished within the 3 s
            if v[0] == "ok" and r.wall_s > 20:
                return "defect", f"--time-limit 3 stopped after {r.wall_s:.0f} s"
            return v[0], f"{v[1]} after {r.wall_s:.1f} s"

        TRIES.append(Try("interrupt", what, fn, 130))

    time_limited("study --time-limit 3, pool of 2", ["--workers", "2"])
    time_limited("study --time-limit 3, --dask-local 2", ["--dask-local", "2"])

    def sim_interrupt(what: str, argv: list[str], lo: float, hi: float) -> None:
        def fn(d: Path) -> tuple[str, str]:
            delay = RNG.uniform(lo, hi)
            r = run(d, [a.replace("{d}", str(d)) for a in argv], 120, sigint_after_s=delay)
            v = judge(r, (130,) if r.signalled and not _ended_with(r, delay) else (0, 130), d)
            return v[0], f"SIGINT after {delay:.1f} s: {v[1]}"

        TRIES.append(Try("interrupt", what, fn, 130))

    sim_interrupt("mpc closed loop, SIGINT", ["mpc", "mpc_paper_single", "--no-ocpd", "--out", "{d}/o"], 3.0, 6.0)
    sim_interrupt(
        "mpc-export --build, SIGINT", ["mpc-export", "mpc_paper_single", "--out", "{d}/o", "--build"], 1.0, 4.0
    )
    sim_interrupt("stability ovm (simulations), SIGINT", ["stability", "--law", "ovm", "--out", "{d}/o"], 1.5, 4.0)
    sim_interrupt("ring sugiyama, SIGINT", ["ring", "sugiyama", "--out", "{d}/o"], 1.5, 4.0)
    sim_interrupt("safety suite, SIGINT", ["safety", "--out", "{d}/o"], 2.0, 5.0)
    sim_interrupt("simulate us06_platoon, SIGINT", ["simulate", "us06_platoon", "--out", "{d}/o"], 1.0, 3.0)
    sim_interrupt("ocp current-profile sweep, SIGINT", ["ocp", "current-profile", "--out", "{d}/o"], 2.0, 5.0)

    def concurrent(what: str, argvs: list[list[str]], check: Callable[[Path, list[Run]], tuple[str, str]]) -> None:
        def fn(d: Path) -> tuple[str, str]:
            (d / "s.toml").write_text(study_text(t_end=8.0))
            procs = []
            for argv in argvs:
                cmd = [PY, "-m", "aev_ocp.cli", *[a.replace("{d}", str(d)) for a in argv]]
                procs.append(
                    subprocess.Popen(
                        cmd,
                        cwd=d,
                        env=_env(d),
                        stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE,
                        text=True,
                        start_new_session=True,
                    )
                )
            runs = []
            for p in procs:
                try:
                    out, err = p.communicate(timeout=150)
                    runs.append(Run(p.returncode, out, err, 0.0))
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
                    out, err = p.communicate()
                    runs.append(Run(None, out, err, 150.0))
            for r in runs:
                v = judge(r, (0, 1, 2), d)
                if v[0] == "defect":
                    return v
            return check(d, runs)

        TRIES.append(Try("concurrent", what, fn, 160))

    def two_studies(d: Path, runs: list[Run]) -> tuple[str, str]:
        rcs = sorted(r.rc or 0 for r in runs)
        if rcs not in ([0, 0], [0, 2]):
            return "defect", f"exit codes {rcs}"
        if rcs == [0, 2] and not any("in use" in r.err for r in runs):
            return "minor", "second run refused without saying the folder is in use"
        lines = (d / "o" / "table.jsonl").read_text().splitlines()
        return ("ok", f"exit codes {rcs}, {len(lines)} rows") if lines else ("defect", "empty table")

    concurrent(
        "two studies into one --out", [["study", "{d}/s.toml", "--out", "{d}/o", "--in-process"]] * 2, two_studies
    )

    def two_sims(d: Path, runs: list[Run]) -> tuple[str, str]:
        import numpy as np

        rcs = sorted(r.rc or 0 for r in runs)
        if rcs not in ([0, 0], [0, 2]):
            return "defect", f"exit codes {rcs}"
        try:
            sys.path.insert(0, str(ROOT))
            from aev_ocp import load
            from aev_ocp.saved import LoadError

            r = load(d / "o")
        except LoadError as exc:
            return "defect", f"the folder both runs wrote does not load: {str(exc)[:150]}"
        metrics = json.loads((d / "o" / "metrics.json").read_text())
        t_end = float(r.t[-1])
        saved = json.dumps(metrics)
        if rcs == [0, 0]:
            return "defect" if not np.isfinite(t_end) else "minor", (
                f"both runs wrote into one folder (loaded t_end = {t_end:g}); metrics.json {len(saved)} B"
            )
        return "ok", f"exit codes {rcs}: the second run was refused"

    concurrent(
        "two simulate runs (different t_end) into one --out",
        [
            ["simulate", "us06_platoon", "--no-plots", "--out", "{d}/o", "--set", "simulation.t_end_s=200"],
            ["simulate", "us06_platoon", "--no-plots", "--out", "{d}/o", "--set", "simulation.t_end_s=60"],
        ],
        two_sims,
    )

    def two_exports(d: Path, runs: list[Run]) -> tuple[str, str]:
        rcs = sorted(r.rc or 0 for r in runs)
        cfg = (d / "o" / "mpc_config.h").read_text() if (d / "o" / "mpc_config.h").exists() else ""
        if rcs == [0, 0]:
            return "defect", f"two exports of different N into one folder both succeeded ({len(cfg)} B config kept)"
        return ("ok" if rcs == [0, 2] else "defect"), f"exit codes {rcs}"

    concurrent(
        "two mpc-export runs (N = 12 and 30) into one --out",
        [
            ["mpc-export", "mpc_paper_single", "--out", "{d}/o", "--set", "mpc.N=12"],
            ["mpc-export", "mpc_paper_single", "--out", "{d}/o", "--set", "mpc.N=30"],
        ],
        two_exports,
    )


def register_trace_tries() -> None:
    A = "trace"

    def trace(
        what: str,
        csv: str | bytes | Callable[[Path], None],
        expect: tuple[int, ...] = (2,),
        word: str = "",
        t_end: float = 2.0,
        max_wall_s: float | None = 15,
        timeout_s: float = 60,
    ) -> None:
        setup_csv = csv if callable(csv) else write("tr.csv", csv)
        add(
            A,
            what,
            ["simulate", "{d}/s.toml", "--no-plots", "--out", "{d}/o"],
            expect,
            words=(word,) if word else (),
            setup=both(
                setup_csv, write("s.toml", TRACE_SC.replace("{file}", "{d}/tr.csv").replace("{t_end}", str(t_end)))
            ),
            max_wall_s=max_wall_s,
            timeout_s=timeout_s,
        )

    trace("a good 3-row trace", "t,v\n0,5\n1,5.5\n2,6\n", (0,))
    trace("header only", "t,v\n", word="2 samples")
    trace("NaN speed", "t,v\n0,5\n1,nan\n", word="row 3")
    trace("negative speed", "t,v\n0,5\n1,-1\n", word="negative")
    trace("decreasing time", "t,v\n0,5\n1,5\n0.5,5\n", word="increase")
    trace("missing speed column", "t,w\n0,5\n1,5\n", word="v")
    trace("latin-1 bytes", b"t,v\n0,5\n1,\xe9\n", word="UTF-8")
    trace("a NUL byte", b"t,v\n0,5\x00\n1,5\n", expect=(2,))
    trace("a 10^6-character line without newline", "t,v\n0," + "5" * 1_000_000, word="CSV")
    trace("trace is a FIFO", fifo("tr.csv"), word="regular")
    trace("trace -> /dev/zero", symlink("tr.csv", "/dev/zero"), word="regular")
    trace("trace is /etc/passwd", symlink("tr.csv", "/etc/passwd"))
    trace("semicolon separated", "t;v\n0;5\n1;5\n", word="t")
    trace("time in 1e300 steps", "t,v\n0,5\n1e300,5\n", word="gap")

    def big(n: int) -> Callable[[Path], None]:
        def setup(d: Path) -> None:
            with (d / "tr.csv").open("w") as fh:
                fh.write("t,v\n")
                fh.writelines(f"{0.1 * i:.1f},{10 + (i % 7) * 0.25}\n" for i in range(n))

        return setup

    def big_run(d: Path) -> tuple[str, str]:  # the run needs 2 s of a 10^6 s trace: reading it all is waste
        big(10_000_000)(d)
        (d / "s.toml").write_text(TRACE_SC.replace("{file}", str(d / "tr.csv")).replace("{t_end}", "2.0"))
        r = run(
            d,
            ["simulate", str(d / "s.toml"), "--no-plots", "--out", str(d / "o")],
            120,
            python=[
                PY,
                "-c",
                "import resource, runpy, sys; sys.argv = ['aev-ocp'] + sys.argv[1:];"
                "from aev_ocp.cli import main; rc = main(sys.argv[1:]);"
                "print('maxrss_kB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr);"
                "sys.exit(rc)",
                "simulate",
                str(d / "s.toml"),
                "--no-plots",
                "--out",
                str(d / "o"),
            ],
        )
        v = judge(r, (0,), d)
        rss = next((int(ln.split()[1]) for ln in r.err.splitlines() if ln.startswith("maxrss_kB")), 0) / 1e6
        if v[0] != "ok":
            return v
        if r.wall_s > 10 or rss > 1.0:
            return "minor", f"a 2 s run of a 10^7-row trace took {r.wall_s:.1f} s and {rss:.2f} GB"
        return "ok", f"{r.wall_s:.1f} s, {rss:.2f} GB peak"

    TRIES.append(Try(A, "10^7-row trace, 2 s run", big_run, 130))


def register_all() -> None:
    register_cli_tries()
    register_study_tries()
    register_trace_tries()
    register_load_tries()


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=None, help="run only the tries whose area or description contains WORD")
    ap.add_argument("--json", default="probe_reliability.json", help="where to write the tries (JSON)")
    ap.add_argument("--keep", action="store_true", help="keep the tries' folders")
    a = ap.parse_args(argv)
    register_all()
    tries = [t for t in TRIES if a.only is None or a.only in t.area or a.only in t.what]
    base = Path(tempfile.mkdtemp(prefix="aev_probe_"))
    os.environ["AEV_OCP_CACHE"] = str(base / "_cache")  # a cache of our own: leftovers of interrupted builds show
    rows = []
    try:
        t0 = time.perf_counter()
        fixtures(base)
        for k, t in enumerate(tries):
            d = base / f"t{k:03d}"
            d.mkdir()
            t1 = time.perf_counter()
            try:
                verdict, note = t.fn(d)
            except Exception as exc:  # noqa: BLE001 - a broken try is reported, not fatal
                verdict, note = "probe-error", f"{type(exc).__name__}: {exc}"[:200]
            cache_left = [p.name for p in (base / "_cache").rglob("*") if ".tmp" in p.name or p.suffix == ".c"]
            if cache_left and verdict == "ok":
                verdict, note = "defect", f"build leftovers in the cache: {cache_left[:3]}"
            rows.append(
                {
                    "id": k,
                    "area": t.area,
                    "name": t.what,
                    "cls": "harness" if verdict == "probe-error" else verdict,
                    "note": note,
                    "command": t.what,
                    "wall_s": round(time.perf_counter() - t1, 2),
                }
            )
            print(f"{k:3d} {verdict:7s} {t.area:10s} {t.what[:55]:55s} {note[:110]}", flush=True)
            if not a.keep:
                shutil.rmtree(d, ignore_errors=True)
        print(f"({time.perf_counter() - t0:.0f} s)")
        status = summarize(rows, Path(a.json))  # the probes' one table per area and JSON (tools/probes/harness.py)
    finally:
        if not a.keep:
            shutil.rmtree(base, ignore_errors=True)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
