"""The "Safety suite" section of ``aev-ocp reproduce``: the whole suite in the full reproduction (about 25 s on a
quiet two-core machine), the quick subset (a few seconds) in any reduced configuration."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from ..report_sections import SectionContext
from .report import markdown, write_outputs
from .suite import run_suite


def safety_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """Run the suite, write its files into ``out_dir`` and return its Markdown."""
    quick = not SectionContext.of(progress).config.is_full
    progress("safety suite" + (" (quick)" if quick else ""))
    res = run_suite(quick=quick)
    write_outputs(res, out_dir)
    return markdown(res)


REPRODUCE_SECTIONS = [("safety", safety_section, 1)]  # listed in aev_ocp.report_sections.SECTION_PROVIDERS
