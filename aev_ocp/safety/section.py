"""The "Safety suite" section of ``aev-ocp reproduce``: the whole suite (both actuators, every controller bare and
under the layer) in the full reproduction, on a process pool of one worker per core unless this process is itself
a pool's daemon worker (measured by benchmarks/bench_safety.py), the quick subset in any reduced configuration."""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path
from typing import Callable

from ..report_sections import SectionContext
from .report import markdown, write_outputs
from .suite import run_suite


def safety_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """Run the suite, write its files into ``out_dir`` and return its Markdown."""
    quick = not SectionContext.of(progress).config.is_full
    progress("safety suite" + (" (quick)" if quick else ""))
    workers = 1 if quick or mp.current_process().daemon else None  # a daemon process cannot start a pool
    res = run_suite(quick=quick, workers=workers)
    write_outputs(res, out_dir)
    return markdown(res)


REPRODUCE_SECTIONS = [("safety", safety_section, 1)]  # listed in aev_ocp.report_sections.SECTION_PROVIDERS
