"""Compiling generated C into a cached shared library (used by the simulator's cascade and the MPC).

The cache folder is ``$AEV_OCP_CACHE`` if set, else ``$XDG_CACHE_HOME/aev_ocp`` or ``~/.cache/aev_ocp``.
A folder that is not owned by the current user, or that others can write to, is not used (a planted
library would be loaded): the library is then built in a fresh private temporary folder instead.
Libraries are keyed by a hash of the source, compiler and flags; each build writes to a per-process
temporary name and is moved into place atomically, so concurrent processes never see a partial file.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

FLAGS = ("-O2", "-fPIC", "-shared", "-fno-math-errno")


@dataclass(frozen=True)
class BuildResult:
    """Path of the built library (None on failure) and, on failure, why."""

    path: Path | None
    error: str = ""


def compiler() -> str | None:
    """The C compiler: $CC, else gcc, else cc; None if there is none."""
    cc = os.environ.get("CC") or "gcc"
    return shutil.which(cc) or shutil.which("cc")


def _private(d: Path) -> bool:
    """d is a folder owned by us that group/others cannot write to."""
    try:
        st = d.stat()
    except OSError:
        return False
    owner_ok = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    return stat.S_ISDIR(st.st_mode) and owner_ok and not (st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


def cache_dir(sub: str = "") -> Path:
    """A private cache folder (created with mode 0700), or a fresh private temp folder if that fails."""
    base = os.environ.get("AEV_OCP_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "aev_ocp")
    d = Path(base) / sub if sub else Path(base)
    try:
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
        if _private(d):
            return d
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix="aev_ocp_build_"))


def compile_shared(source: str, stem: str, sub: str = "", extra_flags: tuple[str, ...] = (),
                   timeout_s: float = 600.0) -> BuildResult:
    """Compile C ``source`` into ``<cache>/<stem>_<hash>.so`` unless it is already there."""
    cc = compiler()
    if cc is None:
        return BuildResult(None, "no C compiler found (set $CC or install gcc)")
    flags = FLAGS + tuple(extra_flags)
    key = hashlib.sha256("\0".join((source, cc, *flags)).encode()).hexdigest()[:24]
    d = cache_dir(sub)
    lib = d / f"{stem}_{key}.so"
    if lib.exists():
        return BuildResult(lib)
    c_file = d / f".{stem}_{key}_{os.getpid()}.c"
    tmp = d / f".{stem}_{key}_{os.getpid()}.so"
    try:
        c_file.write_text(source)
        proc = subprocess.run([cc, *flags, "-o", str(tmp), str(c_file), "-lm"], capture_output=True, text=True,
                              timeout=timeout_s)
        if proc.returncode != 0:
            last = (proc.stderr or proc.stdout).strip().splitlines()
            return BuildResult(None, f"{Path(cc).name} failed: {last[-1] if last else 'exit ' + str(proc.returncode)}")
        os.replace(tmp, lib)
        return BuildResult(lib)
    except (OSError, subprocess.SubprocessError) as exc:
        return BuildResult(None, f"compilation failed: {exc}")
    finally:
        for f in (c_file, tmp):
            try:
                f.unlink()
            except OSError:
                pass
