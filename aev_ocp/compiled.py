"""Compiling generated C into a cached shared library (used by the simulator's cascade and the MPC).

The cache folder is ``$AEV_OCP_CACHE`` if set, else ``$XDG_CACHE_HOME/aev_ocp`` or ``~/.cache/aev_ocp``.
A folder that is not owned by the current user, or that others can write to, is not used (a planted
library would be loaded): the library is then built in ONE private temporary folder per process,
removed when the process exits. Libraries are keyed by a hash of the source, compiler and flags; each
build writes to a per-process temporary name and is moved into place atomically, so concurrent
processes never see a partial file.

Every cached library has a sidecar ``<lib>.sha256`` (size and SHA-256 of the library, written after
the library). A cache hit is used only if the sidecar matches and the library loads (``ctypes.CDLL``);
otherwise (a truncated or damaged file, a library from an older version without a sidecar) it is
rebuilt once, with a :class:`CompileWarning` saying why. A build that fails warns once per library
and error, so a caller's fallback (CVODES for the simulator, interpreted CasADi for the MPC) is
never silent.
"""

from __future__ import annotations

import atexit
import ctypes
import hashlib
import os
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Sequence

from .errors import AevOcpWarning

FLAGS = ("-O2", "-fPIC", "-shared", "-fno-math-errno")
SIDECAR_SUFFIX = ".sha256"


def announce(message: str) -> None:
    """One progress line on stderr (``aev_ocp: …``): a compilation takes seconds and must not look like a hang."""
    print(f"aev_ocp: {message}", file=sys.stderr, flush=True)


class CompileWarning(AevOcpWarning, RuntimeWarning):
    """A cached library was damaged and rebuilt, or a build failed (the caller falls back)."""


@dataclass(frozen=True)
class BuildResult:
    """Path of the built library (None on failure) and, on failure, why; ``rebuilt`` says a damaged
    cached copy was replaced."""

    path: Path | None
    error: str = ""
    rebuilt: bool = False


def dense_outputs(f: Any) -> Any:
    """``f`` (a CasADi SX Function) with every output dense: hand-written C drivers (the cascade, the ring) read
    each output as a dense vector, and CasADi's generated code writes only an output's structural nonzeros, so a
    structurally zero entry (e.g. the acceleration of a constant-speed leader, ∂v_l/∂t) would be left as whatever
    the caller's stack held. Returns ``f`` itself when its outputs are already dense (its generated code is then
    unchanged)."""
    import casadi as ca

    if all(f.sparsity_out(i).is_dense() for i in range(f.n_out())):
        return f
    ins = [f.sx_in(i) for i in range(f.n_in())]
    outs = f.call(ins)
    return ca.Function(f.name(), ins, [ca.densify(o) for o in outs], f.name_in(), f.name_out())


#: Compilations this process ran (one per library actually built, not per cache hit): a counter tests and
#: benchmarks read (:func:`compilations`), never the clock.
_COMPILED: list[str] = []


def compilations() -> list[str]:
    """The stems of the libraries this process compiled so far, in order (a cache hit adds nothing)."""
    return list(_COMPILED)


_CC_WARNED: set[str] = set()  # $CC values already reported as not found (one line each per process)


def compiler() -> str | None:
    """The C compiler: $CC, else gcc, else cc; None if there is none. A $CC that is not found is reported once
    (one line on stderr naming what is used instead) rather than replaced without a word."""
    cc = os.environ.get("CC") or "gcc"
    found = shutil.which(cc) or shutil.which("cc")
    if os.environ.get("CC") and shutil.which(cc) is None and cc not in _CC_WARNED:
        _CC_WARNED.add(cc)
        announce(f"$CC = {cc!r} is not a compiler found on PATH; using {found or 'none (no C compiler)'} instead")
    return found


#: How long an interrupted compiler may take to clean up (its temporary .s/.o files) after SIGTERM [s].
TOOL_STOP_GRACE_S = 2.0


def run_tool(cmd: list[str], cwd: str | os.PathLike[str], timeout_s: float) -> subprocess.CompletedProcess[str]:
    """Run a build tool (the C compiler) with its output captured, in a process group of its own: on a timeout,
    Ctrl-C or any other exception the WHOLE group gets SIGTERM (gcc then removes its temporary files), SIGKILL
    after TOOL_STOP_GRACE_S [s], and is reaped before the exception propagates. Killing gcc alone (what
    subprocess.run does) leaves its cc1/as/ld children running and their temporaries in $TMPDIR."""

    p = subprocess.Popen(
        cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        out, err = p.communicate(timeout=timeout_s)
    except BaseException:
        _stop_group(p)
        raise
    return subprocess.CompletedProcess(cmd, p.returncode, out, err)


def _stop_group(p: subprocess.Popen[str]) -> None:
    """SIGTERM the process group of ``p``, wait TOOL_STOP_GRACE_S [s] for it, else SIGKILL it; reap ``p``. A
    second Ctrl-C during the grace wait (the user is in a hurry) goes straight to the SIGKILL, then propagates."""
    import signal

    stopped = False
    try:
        os.killpg(p.pid, signal.SIGTERM)
        p.communicate(timeout=TOOL_STOP_GRACE_S)
        stopped = True
    except (ProcessLookupError, subprocess.TimeoutExpired):
        pass
    finally:  # runs also when a second interrupt cuts the grace wait short
        if not stopped:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            while True:  # killed: the reap is immediate; a further Ctrl-C must not leave a zombie behind
                try:
                    p.communicate()
                    break
                except KeyboardInterrupt:
                    continue


_ARCH: list[str] = []


def native_arch() -> str:
    """The CPU the C compiler targets with -march=native, resolved to its name (e.g. 'znver3'), or '' when the
    compiler cannot tell. The resolved name, not 'native', goes into the compile flags and so into the cache key
    of the built library: a cache shared by two machines never hands one the other's instructions."""
    if not _ARCH:
        arch = ""
        cc = compiler()
        if cc is not None:
            try:
                out = subprocess.run(
                    [cc, "-march=native", "-Q", "--help=target"], capture_output=True, text=True, timeout=30
                ).stdout
                for line in out.splitlines():
                    parts = line.split()
                    if len(parts) == 2 and parts[0] == "-march=" and parts[1].replace("-", "").isalnum():
                        arch = parts[1]
                        break
            except (OSError, subprocess.SubprocessError):
                arch = ""
        _ARCH.append(arch)
    return _ARCH[0]


def exact_tuned_flags() -> tuple[str, ...]:
    """Flags that make a library faster without changing one bit of its results: -O3 and the native CPU's
    instructions with floating-point contraction off (no fused multiply-adds the plain build does not have; IEEE
    operations give the same result in any instruction set, and GCC never reorders them without -ffast-math), and
    -fno-semantic-interposition (CasADi's helpers such as casadi_sq, global functions in a shared library, are
    then inlined instead of called through the PLT). () when the CPU cannot be resolved."""
    arch = native_arch()
    return ("-O3", f"-march={arch}", "-ffp-contract=off", "-fno-semantic-interposition") if arch else ()


def _private(d: Path) -> bool:
    """d is a folder owned by us that group/others cannot write to."""
    try:
        st = d.stat()
    except OSError:
        return False
    owner_ok = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    return stat.S_ISDIR(st.st_mode) and owner_ok and not (st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


_PROCESS_TMP: Path | None = None


def _process_temp_dir() -> Path:
    """One private temporary folder per process (mode 0700), removed at exit."""
    global _PROCESS_TMP
    if _PROCESS_TMP is None or not _PROCESS_TMP.is_dir():
        _PROCESS_TMP = Path(tempfile.mkdtemp(prefix="aev_ocp_build_"))
        atexit.register(shutil.rmtree, str(_PROCESS_TMP), True)
    return _PROCESS_TMP


def cache_dir(sub: str = "") -> Path:
    """A private cache folder (created with mode 0700), or this process's private temp folder if that fails."""
    base = os.environ.get("AEV_OCP_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "aev_ocp"
    )
    d = Path(base) / sub if sub else Path(base)
    try:
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
        if _private(d):
            return d
    except OSError:
        pass
    t = _process_temp_dir() / sub if sub else _process_temp_dir()
    t.mkdir(parents=True, exist_ok=True, mode=0o700)
    return t


def _digest(path: Path) -> str:
    """'<size> <sha256>' of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return f"{path.stat().st_size} {h.hexdigest()}"


def verify_library(lib: Path) -> str:
    """'' if ``lib`` matches its sidecar and loads (an object file, ``.o``: matches it), else why not (one line)."""
    side = lib.with_name(lib.name + SIDECAR_SUFFIX)
    try:
        want = side.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return "no readable checksum file beside it"
    try:
        got = _digest(lib)
    except OSError as exc:
        return f"cannot read it ({exc.strerror or exc})"
    if got != want:
        size_want = want.split(" ")[0]
        return f"size/checksum mismatch ({got.split(' ')[0]} bytes, {size_want} expected)"
    if lib.suffix == ".o":
        return ""
    try:
        ctypes.CDLL(str(lib))
    except OSError as exc:
        return f"it does not load ({' '.join(str(exc).split())})"
    return ""


def _remove(*paths: Path) -> None:
    for f in paths:
        try:
            f.unlink()
        except OSError:
            pass


_WARNED: set[tuple[str, str]] = set()


def _warn_once(stem: str, message: str) -> None:
    if (stem, message) not in _WARNED:
        _WARNED.add((stem, message))
        warnings.warn(CompileWarning(message), stacklevel=3)


_LOCAL_INCLUDE = re.compile(r'^#include "([A-Za-z0-9_]+\.h)"[^\n]*$', re.MULTILINE)


def driver_source(name: str) -> str:
    """The text of the package's C file ``aev_ocp/c/<name>`` with each ``#include "<header>.h"`` of a header of
    that folder replaced by the header's text (once each), so one self-contained source is compiled and the cache
    key of :func:`compile_shared` covers the headers too."""
    folder = resources.files("aev_ocp") / "c"
    seen: set[str] = set()

    def inline(m: re.Match[str]) -> str:
        if m.group(1) in seen:
            return ""
        seen.add(m.group(1))
        return _LOCAL_INCLUDE.sub(inline, (folder / m.group(1)).read_text())

    return _LOCAL_INCLUDE.sub(inline, (folder / name).read_text())


def compile_shared(
    source: str,
    stem: str,
    sub: str = "",
    extra_flags: tuple[str, ...] = (),
    timeout_s: float = 600.0,
    companions: dict[str, str] | None = None,
    objects: Sequence[Path] = (),
) -> BuildResult:
    """Compile C ``source`` into ``<cache>/<stem>_<hash>.so`` unless a verified copy is already there.
    ``companions``: further files by name (headers, and ``.c`` files compiled into the same library),
    written beside the source and part of the cache key; ``objects``: compiled objects linked in
    (:func:`compile_object`'s, whose names, a hash of what they were compiled from, are part of the key)."""
    return _compile(source, stem, sub, FLAGS + tuple(extra_flags), companions, objects, timeout_s, ".so")


def compile_object(
    source: str,
    stem: str,
    sub: str = "",
    extra_flags: tuple[str, ...] = (),
    companions: dict[str, str] | None = None,
    timeout_s: float = 600.0,
) -> BuildResult:
    """Compile C ``source`` into the object ``<cache>/<stem>_<hash>.o`` (position-independent, for
    :func:`compile_shared`'s ``objects``) unless a verified copy is already there: a source that several libraries
    link, and that depends only on its own text, headers (``companions``) and flags, is compiled once for them all
    (issue 40: the MPC step's ocp_qp.c, 4 of a step's 10 s of gcc, the same for every step of its dimensions)."""
    return _compile(source, stem, sub, FLAGS + tuple(extra_flags) + ("-c",), companions, (), timeout_s, ".o")


def _compile(
    source: str,
    stem: str,
    sub: str,
    flags: tuple[str, ...],
    companions: dict[str, str] | None,
    objects: Sequence[Path],
    timeout_s: float,
    suffix: str,
) -> BuildResult:
    cc = compiler()
    if cc is None:
        return BuildResult(None, "no C compiler found (set $CC or install gcc)")
    comp = dict(sorted((companions or {}).items()))
    # an object's name holds the hash of what it was compiled from (its source, headers, flags, compiler)
    linked = tuple(o.name for o in objects)
    key = hashlib.sha256(
        "\0".join((source, cc, *flags, *(f"{k}\0{v}" for k, v in comp.items()), *linked)).encode()
    ).hexdigest()[:24]
    d = cache_dir(sub)
    lib = d / f"{stem}_{key}{suffix}"
    if lib.exists() and not verify_library(lib):
        return BuildResult(lib)
    # one build per library per machine: concurrent processes (a study's or reproduce's workers) that need the same
    # library wait for the one that builds it, then find it in the cache, instead of each compiling it again (the
    # lock is on the cache folder itself: nothing is left behind; builds into one folder take turns)
    with _build_lock(d):
        return _build_locked(source, stem, key, d, lib, cc, flags, comp, timeout_s, tuple(objects))


def fastest_builds(
    source: str,
    stem: str,
    sub: str = "",
    flag_sets: Sequence[tuple[str, ...]] | None = None,
    extra_flags: tuple[str, ...] = (),
    companions: dict[str, str] | None = None,
    objects: dict[str, tuple[str, dict[str, str]]] | None = None,
) -> Iterator[BuildResult]:
    """:func:`compile_shared` with each of ``flag_sets`` in turn (default: :func:`exact_tuned_flags`, then the plain
    build; ``extra_flags`` added to each), yielding every result: the caller stops at the first it can use. A build
    that fails falls back to the next without a word unless it is the last; what a build that succeeds says (a
    damaged cache rebuilt) is said. ``objects``: {stem: (source, its headers)} compiled by :func:`compile_object`
    with the same flags and linked in."""
    sets = list(dict.fromkeys(flag_sets if flag_sets is not None else (exact_tuned_flags(), ())))
    for k, flags in enumerate(sets):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            objs = [
                compile_object(src, name, sub, (*flags, *extra_flags), hdr)
                for name, (src, hdr) in (objects or {}).items()
            ]
            failed = next((o for o in objs if o.path is None), None)
            if failed is not None:
                built = failed
            else:
                paths = [o.path for o in objs if o.path is not None]
                built = compile_shared(source, stem, sub, (*flags, *extra_flags), companions=companions, objects=paths)
        if built.path is not None or k == len(sets) - 1:
            for w in said:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        yield built


def load_fastest(
    source: str, stem: str, sub: str = "", flag_sets: Sequence[tuple[str, ...]] | None = None
) -> tuple[ctypes.CDLL | None, str]:
    """The first library of :func:`fastest_builds` that loads, or (None, why the last one did not)."""
    err = ""
    for built in fastest_builds(source, stem, sub, flag_sets):
        if built.path is None:
            err = built.error
            continue
        try:
            return ctypes.CDLL(str(built.path)), ""
        except OSError as exc:
            err = f"cannot load {built.path}: {exc}"
    return None, err


class _build_lock:
    """An exclusive advisory lock (``fcntl.flock``) on the cache folder while a library is checked and built; a
    no-op where flock is unavailable (the atomic rename still keeps concurrent builds safe, only duplicated)."""

    def __init__(self, path: Path) -> None:
        self.path, self.fd = path, -1

    def __enter__(self) -> "_build_lock":
        try:
            import fcntl

            self.fd = os.open(self.path, os.O_RDONLY)
            fcntl.flock(self.fd, fcntl.LOCK_EX)
        except (ImportError, OSError):
            if self.fd >= 0:
                os.close(self.fd)
            self.fd = -1
        return self

    def __exit__(self, *exc: object) -> None:
        if self.fd >= 0:
            os.close(self.fd)  # closing releases the lock


#: what a build in progress keeps in the cache folder, named after its process (:func:`_build_locked`'s ``tag``): the
#: build folder, the library and its checksum before they are renamed into place
_IN_PROGRESS = re.compile(r"^\.(?P<stem>.+)_(?P<key>[0-9a-f]{24})_(?P<pid>[0-9]+)\.(?:build|so|o|sha256)$")


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists (a process we may not signal exists too)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def sweep_stale_builds(d: Path) -> list[str]:
    """Remove from cache folder ``d`` what builds left that were killed mid-way (SIGKILL, a worker that died with its
    study, the machine's power): the build folders, libraries and checksums named after processes that no longer
    exist. Returns the names removed. A live process's files are kept (pid reuse only keeps a leftover longer)."""
    gone: list[str] = []
    try:
        entries = list(d.iterdir())
    except OSError:
        return gone
    for f in entries:
        m = _IN_PROGRESS.match(f.name)
        if m is None or _alive(int(m["pid"])):
            continue
        if f.is_dir() and not f.is_symlink():
            shutil.rmtree(f, ignore_errors=True)
        else:
            _remove(f)
        gone.append(f.name)
    return gone


def _build_locked(
    source: str,
    stem: str,
    key: str,
    d: Path,
    lib: Path,
    cc: str,
    flags: tuple[str, ...],
    comp: dict[str, str],
    timeout_s: float,
    objects: tuple[Path, ...] = (),
) -> BuildResult:
    """:func:`compile_shared` (or :func:`compile_object`: ``lib`` an ``.o``) under the library's lock: use a verified
    cached copy, else build it."""
    side = lib.with_name(lib.name + SIDECAR_SUFFIX)
    rebuilt = False
    if lib.exists():
        why = verify_library(lib)
        if not why:
            return BuildResult(lib)
        _warn_once(
            stem,
            f"cached library {lib} cannot be verified ({why}; built by an older version?); rebuilding it"
            if why.startswith("no readable checksum")
            else f"cached library {lib} is damaged ({why}); rebuilding it",
        )
        _remove(lib, side)
        rebuilt = True
    sweep_stale_builds(d)  # before building: what killed builds left here goes (a cache hit reads nothing more)
    tag = f".{stem}_{key}_{os.getpid()}"
    # The source gets the same relative name in every process (gcc records it in the library), so
    # concurrent builds of one library are byte-identical and whichever lands first verifies.
    build_dir = d / f"{tag}.build"
    c_file, tmp, tmp_side = build_dir / f"{stem}_{key}.c", d / f"{tag}{lib.suffix}", d / f"{tag}.sha256"
    try:
        build_dir.mkdir(mode=0o700, exist_ok=True)
        c_file.write_text(source)
        for name, text in comp.items():
            (build_dir / name).write_text(text)
        more = [k for k in comp if k.endswith(".c")]
        announce(f"compiling {stem} with {Path(cc).name} (once: the library is cached in {d}) …")
        _COMPILED.append(stem)
        t0 = time.perf_counter()
        if lib.suffix == ".o":  # an object: the source alone (its flags hold -c)
            cmd = [cc, *flags, "-o", str(tmp), c_file.name]
        else:
            cmd = [cc, *flags, "-o", str(tmp), c_file.name, *more, *(str(o) for o in objects), "-lm"]
        proc = run_tool(cmd, build_dir, timeout_s)
        if proc.returncode != 0:
            last = (proc.stderr or proc.stdout).strip().splitlines()
            err = f"{Path(cc).name} failed: {last[-1] if last else 'exit ' + str(proc.returncode)}"
            _warn_once(stem, f"compiling {stem} failed ({err}); the caller falls back to its uncompiled path")
            return BuildResult(None, err, rebuilt)
        announce(f"compiled {stem} in {time.perf_counter() - t0:.1f} s")
        tmp_side.write_text(_digest(tmp) + "\n", encoding="ascii")
        os.replace(tmp, lib)
        os.replace(tmp_side, side)  # after the library: a sidecar never vouches for a missing library
        why = verify_library(lib)
        if why:  # a concurrent build replaced one of the pair, or the disk is full: do not use it
            _warn_once(stem, f"freshly built {lib} failed verification ({why}); the caller falls back")
            return BuildResult(None, f"built library failed verification: {why}", rebuilt)
        return BuildResult(lib, "", rebuilt)
    except (OSError, subprocess.SubprocessError) as exc:
        _warn_once(stem, f"compiling {stem} failed ({exc}); the caller falls back to its uncompiled path")
        return BuildResult(None, f"compilation failed: {exc}", rebuilt)
    finally:
        _remove(c_file, tmp, tmp_side, *(build_dir / k for k in comp))
        try:
            build_dir.rmdir()
        except OSError:
            pass
