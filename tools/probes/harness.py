"""The harness the reliability probes share (tools/probes/probe_reliability_3.py, probe_new_surfaces.py,
probe_ring_sumo_inputs.py): a :class:`Try` states a command (or a Python snippet), its setup, the exit codes it
accepts and, for bad input, the word its one error line must name; :func:`run_try` runs it in its own temporary
folder and process group under a timeout and classifies it:

- ``defect``: a traceback or "internal error", a hang (timeout), an exit code outside the accepted ones (2 bad
  input, 1 failed run, 130 interrupt), a temporary file left behind, a process of its group still alive, a
  user file changed, or an error line that does not name the field;
- ``minor``: more than one stderr line for bad input, or a check of the try's own that says so;
- ``ok``: otherwise.

:func:`run_probe` is every probe's command line (``--only SUBSTRING``, ``--json OUT``, ``--jobs N``): the tries
that send no signal run ``--jobs`` at once, the others alone; it prints each try, a table per area and writes the
JSON (:func:`summarize`). The probes use the checkout they live in (``PYTHONPATH``), so they probe the code beside
them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import textwrap
import time
import zipfile
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]  # the checkout the probes live in
PY = sys.executable
CLI = [PY, "-m", "aev_ocp.cli"]

# ----------------------------------------------------------------------------- scenario text
BASE = """\
name = "probe"
compare = ["proposed", "ovfl"]
[units]
length_m = 10.0
speed_mps = 5.0
[leader]
kind = "paper"
v0 = 1.7
amplitude = 1.2
forcing_end = 20.0
[platoon]
followers = 2
law = "proposed"
gap0_first = 0.3
gap0_others = 3.5
speed0_factor = 1.1
[simulation]
t_end = 4.0
dt_out = 0.05
"""


def scen(**edits: str) -> str:
    """BASE with whole lines replaced: edits maps 'table.key' to the new line (or '' to drop it); a key
    'extra' appends text."""
    text = BASE
    lines = text.splitlines()
    table = ""
    out: list[str] = []
    for ln in lines:
        if ln.startswith("["):
            table = ln.strip("[]")
        key = ln.split("=")[0].strip() if "=" in ln else None
        full = f"{table}.{key}" if table and key else (key or "")
        if key and full in edits:
            if edits[full]:
                out.append(edits[full])
            continue
        out.append(ln)
    return "\n".join(out) + "\n" + edits.get("extra", "")


STUDY = """\
name = "pstudy"
scenarios = ["{scen}"]
reference = "ovfl"
[[axes]]
key = "carfollowing.kappa"
values = [0.02, 0.04]
[controllers]
laws = ["proposed", "ovfl"]
[report]
vehicle = 1
"""


def big_study(n: int = 40) -> str:
    vals = ", ".join(f"{0.01 + 0.4 * i / n:.4f}" for i in range(n))
    return STUDY.replace("values = [0.02, 0.04]", f"values = [{vals}]")


# ----------------------------------------------------------------------------- the try record
@dataclass
class Try:
    area: str
    name: str
    argv: list[str] | None = None  # after `python -m aev_ocp.cli`
    script: str | None = None  # Python code instead (run with -c; `d` = the try's folder)
    setup: Callable[[Path], None] | None = None
    ok: tuple[int, ...] = (0,)
    says: str | None = None  # a word the stderr must contain (the field), case-insensitive
    env: dict[str, str] = field(default_factory=dict)
    unset: tuple[str, ...] = ()
    sig: tuple[int, float] | None = None  # (signal, delay s)
    timeout: float = 120.0
    check: Callable[[Path, dict[str, Any]], str | None] | None = None  # returns "defect: ..." / "minor: ..."
    parallel: Try | None = None  # a second command started at the same time in the same folder
    keep_user: dict[str, str] = field(default_factory=dict)  # relative file -> content that must survive


def write(rel: str, text: str | bytes) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text, encoding="utf-8")

    return f


def chain(*fs: Callable[[Path], None]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        for g in fs:
            g(d)

    return f


def run_cli(*argv: str) -> Callable[[Path], None]:
    """Setup step: run a command in the try's folder (must succeed)."""

    def f(d: Path) -> None:
        r = subprocess.run([*CLI, *argv], cwd=d, capture_output=True, text=True, timeout=300, env=_env({}, ()))
        if r.returncode != 0:
            raise RuntimeError(f"setup {argv} failed: {r.stderr[-500:]}")

    return f


def _env(extra: dict[str, str], unset: tuple[str, ...]) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT)
    env.setdefault("MPLBACKEND", "Agg")
    env.pop("AEV_OCP_DEBUG", None)
    env.update(extra)
    for k in unset:
        env.pop(k, None)
    return env


TEMP_MARKS = (".tmp", ".fig_", ".partial", "~")


def _temporaries(d: Path) -> list[str]:
    bad = []
    for p in d.rglob("*"):
        n = p.name
        if any(m in n for m in TEMP_MARKS) and not n.startswith("~") and ".lock" not in n:
            bad.append(str(p.relative_to(d)))
    return bad


def _group_alive(pgid: int) -> list[str]:
    out = subprocess.run(["ps", "-eo", "pid,pgid,stat,cmd"], capture_output=True, text=True).stdout
    alive = []
    for ln in out.splitlines()[1:]:
        parts = ln.split(None, 3)
        if len(parts) >= 3 and parts[1] == str(pgid) and not parts[2].startswith("Z"):
            alive.append(ln.strip()[:120])
    return alive


_SILENT: list[Any] = []


def _silent_port() -> int:
    """A TCP port on localhost that accepts connections and never answers (a scheduler that hangs)."""
    import socket
    import threading

    if not _SILENT:
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen(16)
        held: list[Any] = []
        threading.Thread(target=lambda: [held.append(srv.accept()) for _ in iter(int, 1)], daemon=True).start()
        _SILENT.extend([srv, held])
    return int(_SILENT[0].getsockname()[1])


def _start(t: Try, d: Path) -> subprocess.Popen[str]:
    argv = [a.replace("PORT", str(_silent_port())) if "PORT" in a else a for a in (t.argv or [])]
    cmd = [*CLI, *argv] if t.argv is not None else [PY, "-c", t.script or ""]
    return subprocess.Popen(
        cmd,
        cwd=d,
        env=_env(t.env, t.unset),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        start_new_session=True,
    )


def _finish(p: subprocess.Popen[str], t: Try) -> dict[str, Any]:
    t0 = time.monotonic()
    if t.sig is not None:
        sig, delay = t.sig
        try:
            p.wait(timeout=delay)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, sig)
    try:
        out, err = p.communicate(timeout=t.timeout)
        rc: int | None = p.returncode
        if rc is not None and rc < 0:  # ended by the signal itself (e.g. during interpreter exit): a shell sees 128 + n
            rc = 128 - rc
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        rc = None
    time.sleep(0.3)
    return {"rc": rc, "stdout": out, "stderr": err, "wall_s": time.monotonic() - t0, "alive": _group_alive(p.pid)}


def describe(t: Try) -> str:
    parts = []
    if t.env or t.unset:
        parts.append(" ".join([*(f"{k}={v}" for k, v in t.env.items()), *(f"-u {k}" for k in t.unset)]))
    if t.argv is not None:
        parts.append("aev-ocp " + " ".join(repr(a) if (" " in a or not a) else a for a in t.argv))
    else:
        parts.append("python -c " + repr((t.script or "")[:300]))
    if t.sig:
        parts.append(f"(signal {signal.Signals(t.sig[0]).name} after {t.sig[1]} s)")
    return " ".join(parts)


def run_try(t: Try) -> dict[str, Any]:
    """Run one try in a fresh temporary folder (removed afterwards unless $PROBE_KEEP is set)."""
    d = Path(tempfile.mkdtemp(prefix="probe3_"))
    try:
        return _run_try(t, d)
    finally:
        if not os.environ.get("PROBE_KEEP"):
            for p in [d, *d.rglob("*")]:  # read-only folders made by a try's setup
                if p.is_dir() and not p.is_symlink():
                    os.chmod(p, stat.S_IRWXU)
            shutil.rmtree(d, ignore_errors=True)


def _run_try(t: Try, d: Path) -> dict[str, Any]:
    res: dict[str, Any] = {"area": t.area, "name": t.name, "command": describe(t), "folder": str(d)}
    try:
        if t.setup:
            t.setup(d)
        for rel, text in t.keep_user.items():
            write(rel, text)(d)
        p = _start(t, d)
        q = _start(t.parallel, d) if t.parallel else None
        r = _finish(p, t)
        r2 = _finish(q, t.parallel) if q and t.parallel else None
    except Exception as exc:  # the harness's own setup failed
        res.update(cls="harness", note=f"setup failed: {exc}")
        return res
    res.update(rc=r["rc"], wall_s=round(r["wall_s"], 2), stderr_tail=r["stderr"][-600:])
    notes: list[str] = []
    cls = "ok"

    def flag(level: str, note: str) -> None:
        nonlocal cls
        notes.append(f"{level}: {note}")
        if level == "defect" or (level == "minor" and cls == "ok"):
            cls = level

    both = [r] + ([r2] if r2 else [])
    for k, rr in enumerate(both):
        who = "" if k == 0 else "second run: "
        err = rr["stderr"] + (rr["stdout"] if t.script else "")
        if rr["rc"] is None:
            flag("defect", f"{who}hang (killed after {t.timeout} s)")
        if "Traceback" in err or "internal error" in err.lower():
            flag("defect", f"{who}traceback/internal error")
        if rr["alive"]:
            flag("defect", f"{who}processes left: {rr['alive'][:2]}")
    if r2 is not None:
        codes = sorted([r["rc"] if r["rc"] is not None else -999, r2["rc"] if r2["rc"] is not None else -999])
        res["rc2"] = r2["rc"]
        said = r["stderr"] + r2["stderr"]
        refused = any(w in said for w in ("in use by another", "holds the results of"))
        res["stderr2_tail"] = r2["stderr"][-600:]
        if codes not in ([0, 2], [0, 0]) or (codes == [0, 2] and not refused):
            flag("defect", f"concurrent runs gave exit codes {codes}")
    elif r["rc"] is not None and r["rc"] not in t.ok:
        flag("defect", f"exit {r['rc']} (expected {t.ok})")
    if t.says and r["rc"] == 2 and t.says.lower() not in r["stderr"].lower():
        flag("defect", f"error does not name {t.says!r}")
    if r["rc"] == 2 and t.argv is not None:
        lines = [ln for ln in r["stderr"].splitlines() if ln.strip() and "warning" not in ln]
        lines = [ln for ln in lines if not ln.startswith("[")]  # progress lines
        if len(lines) > 1 and not any(x in r["stderr"] for x in ("usage:",)):
            flag("minor", f"{len(lines)} stderr lines for bad input")
    tmp = _temporaries(d)
    if tmp:
        flag("defect", f"temporaries left: {tmp[:3]}")
    for rel, text in t.keep_user.items():
        p = d / rel
        if not p.is_file() or p.read_text(encoding="utf-8", errors="replace") != text:
            flag("defect", f"user file {rel} changed or removed")
    if t.check:
        try:
            note = t.check(d, r)
        except Exception as exc:
            note = f"defect: check raised {type(exc).__name__}: {exc}"
        if note:
            level, _, msg = note.partition(": ")
            flag(level, msg)
    res.update(cls=cls, note="; ".join(notes))
    return res


# ----------------------------------------------------------------------------- checks
def stdout_has(word: str, level: str = "defect") -> Callable[[Path, dict[str, Any]], str | None]:
    def f(d: Path, r: dict[str, Any]) -> str | None:
        return None if word in r["stdout"] else f"{level}: stdout lacks {word!r}: {r['stdout'][-300:]!r}"

    return f


def exists(rel: str, want: bool = True) -> Callable[[Path, dict[str, Any]], str | None]:
    def f(d: Path, r: dict[str, Any]) -> str | None:
        return None if (d / rel).exists() == want else f"defect: {rel} {'missing' if want else 'exists'}"

    return f


def py(code: str) -> str:
    """A script: `d` is the cwd; EXPECT(exc_types) wraps the body: an expected exception prints and exits 0."""
    return "from pathlib import Path\nimport sys, os\nd = Path.cwd()\n" + textwrap.dedent(code)


def api_expect(body: str, errors: str = "ParameterError", says: str | None = None) -> str:
    """Python code that must raise one of ``errors`` (from aev_ocp) with ``says`` in its message; prints
    'EXPECTED' then, else 'NO ERROR' (exit 3) — any other exception is a traceback (a defect)."""
    names = [e.strip() for e in errors.split(",")]
    imports = "from aev_ocp.params import ParameterError\nfrom aev_ocp.saved import LoadError\n"
    imports += "from aev_ocp.scenarios.tables import ScenarioError\nfrom aev_ocp.overrides import OverrideError"
    names = names + ["ScenarioError", "OverrideError"] if "ParameterError" in names else names  # the scenario layer's
    tup = "(" + ", ".join(names) + ",)"
    check = (
        f"\n    if {says!r}.lower() not in str(exc).lower(): print('NOT NAMING', {says!r}); sys.exit(4)" if says else ""
    )
    return py(
        f"{imports}\ntry:\n"
        + textwrap.indent(textwrap.dedent(body), "    ")
        + f"\nexcept {tup} as exc:\n    print('EXPECTED', type(exc).__name__, str(exc)[:300]){check}\n"
        + "else:\n    print('NO ERROR'); sys.exit(3)\n"
    )


def api_ok(body: str) -> str:
    return py(body + "\nprint('DONE')\n")


def fifo(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        os.mkfifo(d / rel)

    return f


def symlink(rel: str, target: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        os.symlink(target, d / rel)

    return f


def readonly(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        (d / rel).mkdir(parents=True, exist_ok=True)
        os.chmod(d / rel, stat.S_IRUSR | stat.S_IXUSR)

    return f


def mutate(rel: str, fn: Callable[[bytes], bytes]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        p.write_bytes(fn(p.read_bytes()))

    return f


def json_edit(rel: str, fn: Callable[[Any], Any]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        p.write_text(json.dumps(fn(json.loads(p.read_text()))))

    return f


def first_store_entry(fn: Callable[[Path], None]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        entries = sorted((d / "st" / "points").glob("*.json"))
        fn(entries[0])

    return f


def zip_bomb(rel: str) -> Callable[[Path], None]:
    """Replace trajectories.npz by a zip whose one member claims 3 GB of zeros (and fix the manifest's hash)."""

    def f(d: Path) -> None:
        import hashlib

        p = d / rel / "trajectories.npz"
        with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as z:
            with z.open("t.npy", "w", force_zip64=True) as w:
                chunk = b"\0" * (1 << 24)
                for _ in range(180):
                    w.write(chunk)
        m = json.loads((d / rel / "manifest.json").read_text())
        m["arrays_sha256"] = hashlib.sha256(p.read_bytes()).hexdigest()
        (d / rel / "manifest.json").write_text(json.dumps(m))

    return f


def plain_value_error(d: Path, r: dict[str, Any]) -> str | None:
    """API bad input: a ParameterError (or a TypeError for a wrong type) is the promise; a bare ValueError is minor."""
    return "minor: a bare ValueError, not a ParameterError" if "EXPECTED ValueError" in r["stdout"] else None


def late_refusal(d: Path, r: dict[str, Any]) -> str | None:
    """A [report] entry no row can satisfy: refused (exit 2) before work, or only a warning after the run (minor)."""
    if r["rc"] == 0 and "warning" in r["stderr"]:
        return "minor: accepted, warned only after every task ran (checkable before)"
    return None


def table_equal_after_rerun(d: Path, r: dict[str, Any]) -> str | None:
    """The study table after the damaged rerun equals a clean reference run's table (metrics)."""
    ref = d / "ref" / "table.jsonl"
    got = d / "st" / "table.jsonl"
    if not ref.is_file() or not got.is_file():
        return "defect: table missing"

    def rows(p: Path) -> list[tuple[Any, ...]]:
        out = []
        for ln in p.read_text().splitlines():
            row = json.loads(ln)
            out.append((row.get("point"), row.get("controller"), row.get("vehicle"), row.get("omega_model")))
        return sorted(out, key=str)

    return None if rows(ref) == rows(got) else "defect: rerun table differs from a clean run (damaged entry trusted)"


# ----------------------------------------------------------------------------- the tries
def summarize(results: list[dict[str, Any]], json_path: Path, details: bool = True) -> int:
    """Print the tries' table per area (and, with ``details``, every try that is not ok), write the JSON; exit
    status 1 when any try is a defect (shared by the probes that reuse this harness)."""
    areas: dict[str, dict[str, int]] = {}
    for res in results:
        c = areas.setdefault(res["area"].split("/")[0], {"ok": 0, "minor": 0, "defect": 0, "harness": 0})
        c[res["cls"]] = c.get(res["cls"], 0) + 1
    print(f"\n{'area':16}{'tries':>7}{'ok':>6}{'minor':>7}{'defect':>8}{'harness':>9}")
    for area, c in areas.items():
        print(f"{area:16}{sum(c.values()):>7}{c['ok']:>6}{c['minor']:>7}{c['defect']:>8}{c['harness']:>9}")
    tot = {k: sum(c[k] for c in areas.values()) for k in ("ok", "minor", "defect", "harness")}
    print(f"{'total':16}{len(results):>7}{tot['ok']:>6}{tot['minor']:>7}{tot['defect']:>8}{tot['harness']:>9}")
    for res in results if details else []:
        if res["cls"] != "ok":
            print(
                f"\n[{res['cls']}] {res['area']}/{res['name']}: {res.get('note')}\n  {res['command']}\n  stderr: {res.get('stderr_tail', '')[-300:]!r}"
            )
    json_path.write_text(json.dumps(results, indent=1))
    return 1 if tot["defect"] else 0


def run_probe(
    tries: Callable[[], list[Try]],
    argv: list[str] | None,
    description: str,
    default_json: str,
    *,
    jobs: int = 1,
    details: bool = True,
) -> int:
    """A probe's command line: parse ``argv`` (``--only``, ``--json``, ``--start``, ``--jobs``), run the selected
    tries (those that send no signal and run no parallel command ``--jobs`` at once, the others alone, so their
    timing is not skewed), print each, then :func:`summarize`; the exit status."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--only", default="", help="run only tries whose 'area/name' contains this")
    ap.add_argument("--json", default=default_json)
    ap.add_argument("--start", type=int, default=0, help="skip the first START tries (e.g. to run a new batch)")
    ap.add_argument("--jobs", type=int, default=jobs, help="tries run at once (the interrupt tries run alone)")
    a = ap.parse_args(argv)
    ts = [t for t in tries()[a.start :] if a.only.lower() in f"{t.area}/{t.name}".lower()]
    quiet = [t for t in ts if t.sig is None and t.parallel is None]
    timed = [t for t in ts if t not in quiet]
    results: list[dict[str, Any]] = []

    def show(res: dict[str, Any]) -> None:
        results.append(res)
        print(f"{res['cls']:7} {res['area']}/{res['name']}  {res.get('rc')}  {res.get('note', '')[:150]}", flush=True)

    with ThreadPoolExecutor(max(1, a.jobs)) as ex:
        for res in ex.map(run_try, quiet):
            show(res)
    for t in timed:
        show(run_try(t))
    return summarize(results, Path(a.json), details=details)
