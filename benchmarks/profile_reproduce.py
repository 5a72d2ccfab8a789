"""Profile ``aev-ocp reproduce`` section by section (issue 40): cProfile per section, CPU and wall per section, and
the generated C source of every library it compiles (to see why a library is built more than once).

Run by ``benchmarks/bench_reproduce.py --profile DIR`` in the child process (or directly:
``python benchmarks/profile_reproduce.py DIR [reproduce options]``). Writes into DIR:

* ``<section>.prof``: the section's cProfile statistics (``python -m pstats DIR/<section>.prof``);
* ``sections.json``: per section, wall [s], CPU of this process [s] and of its finished children [s];
* ``sources/<stem>_<key>/``: each compiled library's source, companions and flags (one folder per build).

The run is in ONE process (``--workers 1`` unless the options say otherwise): a pool worker would run its sections
unprofiled, and the sections the pool cannot import by name (wrapped here) would run after it in this process, so
the profile would be of another schedule. cProfile counts this process's CPU time (``time.process_time``), not the
wall clock, so that a loaded machine does not inflate the sections that wait. Note for reading the profiles: CasADi
times every call of an integrator's or a solver's inner functions with ``std::clock()``, a real system call on a
virtual machine (~1 µs): in the closed loops' CVODES plants that is millions of calls (battery life: ~4 M, ~4 s of
its ~24 s; ``strace -c -f`` shows them as ``clock_gettime(CLOCK_PROCESS_CPUTIME_ID)``).
"""

from __future__ import annotations

import cProfile
import json
import resource
import sys
import time
from pathlib import Path
from typing import Any


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def install(folder: Path) -> dict[str, Any]:
    """Wrap every reproduce section in a profiler and every library build in a source dump; returns the per-section
    record (filled as sections run)."""
    import aev_ocp.compiled as compiled
    import aev_ocp.reproduce as rep
    from aev_ocp.report_sections import Section

    folder.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {}
    build = compiled._build_locked

    def dumping_build(source, stem, key, d, lib, cc, flags, comp, timeout_s):  # type: ignore[no-untyped-def]
        if not lib.exists():
            sub = folder / "sources" / f"{stem}_{key}"
            sub.mkdir(parents=True, exist_ok=True)
            (sub / f"main_{stem}.c").write_text(source)  # companions may hold <stem>.c
            (sub / "flags.txt").write_text(" ".join(flags) + "\n")
            for name, text in comp.items():
                (sub / name).write_text(text)
        return build(source, stem, key, d, lib, cc, flags, comp, timeout_s)

    compiled._build_locked = dumping_build  # type: ignore[assignment]

    def wrap(sec: Section) -> Section:
        def fn(out: Path, ctx: Any) -> str:
            prof = cProfile.Profile(time.process_time)
            w0, c0, k0 = time.perf_counter(), time.process_time(), _children_cpu_s()
            prof.enable()
            try:
                return sec.fn(out, ctx)
            finally:
                prof.disable()
                record[sec.name] = {
                    "wall_s": time.perf_counter() - w0,
                    "cpu_s": time.process_time() - c0,
                    "children_cpu_s": _children_cpu_s() - k0,
                }
                prof.dump_stats(str(folder / f"{sec.name}.prof"))
                (folder / "sections.json").write_text(json.dumps(record, indent=1))

        return Section(sec.name, fn, sec.steps)

    sections = rep.PaperRun.sections

    def wrapped_sections(self):  # type: ignore[no-untyped-def]
        return [wrap(s) for s in sections(self)]

    rep.PaperRun.sections = wrapped_sections  # type: ignore[method-assign]
    load = rep.load_providers

    def wrapped_load(*a, **k):  # type: ignore[no-untyped-def]
        names = load(*a, **k)
        for name, s in list(rep._REGISTRY.items()):
            rep._REGISTRY[name] = wrap(s)
        return names

    rep.load_providers = wrapped_load  # type: ignore[assignment]
    return record


def main(argv: list[str]) -> int:
    install(Path(argv[0]))
    from aev_ocp.cli import main as cli_main

    opts = list(argv[1:])
    if not any(a == "--workers" or a.startswith("--workers=") for a in opts):
        opts += ["--workers", "1"]  # every section profiled, in this process (module docstring)
    return int(cli_main(["reproduce", *opts]) or 0)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
