"""``reproduce`` on a process pool: independent report sections run at the same time.

Tasks: PaperRun's built-in sections together, in their order, in one task (they share the run's state: its
cache, notes and the Table 1 summary the disagreements section reads); every other section whose function a
worker can import by name (the providers' sections) one task each; a section registered from elsewhere (a
function made at run time) runs in this process after the pool. Tasks are submitted longest first
(:data:`SECTION_COST_S`) so that two workers end close together. Each worker process starts fresh (spawn),
sends its progress lines through a queue and returns each section's Markdown and claims; this process puts
them in the declared order, so report.md, report.html and every file are those of a run in one process.
A section that fails stops the run with :class:`~aev_ocp.report_sections.ReportSectionError` naming it (the
other workers are stopped); Ctrl-C stops the workers too.
"""

from __future__ import annotations

import importlib
import os
import queue as queue_mod
from pathlib import Path
from typing import Any, Iterator, Sequence

from .report_sections import Claim, ReportSectionError, ReproduceConfig, Section, SectionContext, run_section

#: CPU time of each section in the default reproduce [s] (its own process and its children: compilations, a section's
#: pool), measured section by section in a reproduce from an empty compile cache (2-core machine at load 3-4, issue
#: 40; the robustness studies run in the section's process): only the ORDER in which tasks are submitted follows it
#: (longest first), never a result. "paper" is PaperRun's built-in sections together.
SECTION_COST_S: dict[str, float] = {
    "mpc-cycles": 65.9,
    "robustness": 65.1,
    "paper": 51.5,
    "safety": 46.7,
    "battery-life": 32.9,
    "ring": 15.5,
    "ocp_checks": 8.1,
    "theorem41": 5.4,
    "prop31": 5.2,
    "string-stability": 5.2,
    "mpc": 4.5,
}

_QUEUE: Any = None  # the worker's end of the progress queue (set by _init_worker)
_END = "\0end"  # a section's last message: it ended (its undeclared steps are passed over)


def _importable(fn: Any) -> tuple[str, str] | None:
    """(module, qualified name) of a module-level function a fresh process can import, else None."""
    mod, qual = getattr(fn, "__module__", None), getattr(fn, "__qualname__", "")
    if not mod or not qual or "<" in qual or "." in qual:
        return None
    try:
        return (mod, qual) if getattr(importlib.import_module(mod), qual, None) is fn else None
    except Exception:
        return None


def _init_worker(parent_pid: int, q: Any) -> None:
    """Pool-worker initializer: the progress queue; end with the parent (as a study's workers do)."""
    global _QUEUE
    from .study.runner import _end_with

    _QUEUE = q
    _end_with(parent_pid)


def _task(
    key: str, names: list[str], refs: list[tuple[str, str] | None], out: str, config: ReproduceConfig
) -> list[tuple[str, str, list[Claim], str]]:
    """Run sections in a worker: PaperRun's (``refs`` None: by name from a fresh PaperRun) or importable functions.
    Returns per section (name, Markdown, claims, error: '' or the ReportSectionError message)."""
    from .paper_sections import PaperRun

    paper = {s.name: s for s in PaperRun(config).sections()} if any(r is None for r in refs) else {}
    done: list[tuple[str, str, list[Claim], str]] = []
    for name, ref in zip(names, refs):
        sec = paper[name] if ref is None else Section(name, getattr(importlib.import_module(ref[0]), ref[1]))
        claims: list[Claim] = []

        def say(message: str, name: str = name) -> None:
            _QUEUE.put((name, message if message.startswith(name) else f"{name}: {message}"))

        try:
            md = run_section(sec, Path(out), SectionContext(say, config, claims))
        except ReportSectionError as exc:
            _QUEUE.put((name, _END))
            done.append((name, "", claims, str(exc)))
            return done
        _QUEUE.put((name, _END))
        done.append((name, md, claims, ""))
    return done


def run_sections_pooled(
    sections: Sequence[Section], n_builtin: int, out: Path, config: ReproduceConfig, progress: Any, workers: int
) -> Iterator[tuple[str, list[Claim]]]:
    """(Markdown, claims) of each section, in the order of ``sections`` (the first ``n_builtin`` are PaperRun's),
    computed on ``workers`` processes; progress lines go to ``progress`` (a :class:`aev_ocp.reproduce.Progress`)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from . import interrupts
    from .study.runner import _export_path

    tasks: dict[str, tuple[list[str], list[tuple[str, str] | None]]] = {}
    local: list[Section] = []
    if n_builtin:
        tasks["paper"] = ([s.name for s in sections[:n_builtin]], [None] * n_builtin)
    for sec in sections[n_builtin:]:
        ref = _importable(sec.fn)
        if ref is None:
            local.append(sec)
        else:
            tasks[sec.name] = ([sec.name], [ref])
    order = sorted(tasks, key=lambda k: -SECTION_COST_S.get(k, 0.0))  # longest first (stable for unknowns)
    for sec in sections:
        progress.begin(sec.steps, sec.name)
    results: dict[str, tuple[str, list[Claim]]] = {}
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    _export_path()
    ex = ProcessPoolExecutor(
        max_workers=max(1, min(workers, len(tasks))),
        mp_context=ctx,
        initializer=_init_worker,
        initargs=(os.getpid(), q),
    )
    try:
        with interrupts.deferred(), interrupts.sigint_blocked():
            futures = [ex.submit(_task, k, *tasks[k], str(out), config) for k in order]
        ended: set[str] = set()
        expected = {n for k in order for n in tasks[k][0]}
        error = ""
        while not error and (ended != expected or not all(f.done() for f in futures)):
            try:
                name, message = q.get(timeout=0.25)
                if message == _END:
                    ended.add(name)
                    progress.end(name)
                else:
                    progress(message, name)
            except queue_mod.Empty:
                pass
            for f in futures:
                if not f.done():
                    continue
                exc = f.exception()
                if exc is not None:  # the pool itself failed (a worker died); sections record their own errors
                    raise ReportSectionError(
                        f"a reproduce worker process failed ({type(exc).__name__}: {exc}); no report.md written"
                    )
                for sec_name, sec_md, sec_claims, err in f.result():
                    results[sec_name] = (sec_md, sec_claims)
                    error = error or err
        if error:
            raise ReportSectionError(error)
    except BaseException:
        interrupts.stop_pool(ex)
        raise
    ex.shutdown(wait=True)

    for sec in local:  # functions a worker cannot import: here, after the pool
        claims: list[Claim] = []

        def say(message: str, name: str = sec.name) -> None:
            progress(message if message.startswith(name) else f"{name}: {message}", name)

        md = run_section(sec, out, SectionContext(say, config, claims))
        progress.end(sec.name)
        results[sec.name] = (md, claims)
    for sec in sections:
        yield results[sec.name]
