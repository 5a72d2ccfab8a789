"""The "Safety suite" section of ``aev-ocp reproduce``: in the full reproduction a representative subset of the
suite (:func:`aev_ocp.safety.cases.reproduce_cases`: every family, the motorway CCRs, both actuators, every
controller bare and under the layer; ``aev-ocp safety`` runs every case), on a process pool of one worker per core
unless this process is itself a pool's daemon worker (measured by benchmarks/bench_safety.py); in any reduced
configuration (a smoke run) the first case of each family of the quick subset on the declared actuator only
(:func:`smoke_cases`, :data:`QUICK_ACTUATORS`). The section shows the family figures it writes."""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path
from typing import Callable

from ..report_sections import SectionContext
from .cases import FAMILIES, SafetyCase, reproduce_cases, suite_cases
from .report import markdown, write_outputs
from .run import DEFAULT_ACTUATORS, run_suite


#: The actuators of a reduced configuration's quick subset: the declared one alone (its lag and jerk limit); the full
#: reproduction runs both.
QUICK_ACTUATORS = ("declared",)  # issue 40: half the quick subset's CPU (4.9 -> 2.3 s), every family and controller


def smoke_cases() -> list[SafetyCase]:
    """A reduced configuration's cases: the first case of each family in the suite's quick subset (3 s long), in the
    suite's order (issue 40: 5 of the quick subset's 8 cases; every family, figure and controller still runs)."""
    first: dict[str, SafetyCase] = {}
    for c in suite_cases(quick=True):
        first.setdefault(c.family, c)
    return list(first.values())


def figures_markdown(files: list[Path], out_dir: Path) -> str:
    """Markdown showing the family figures among ``files`` (safety_<family>.png, relative to ``out_dir``)."""
    names = {f"safety_{fam.replace('-', '')}.png": fam for fam in FAMILIES}
    lines = [
        f"![Safety suite, {names[p.name]}: min gap per case and controller against the bound]"
        f"({p.resolve().relative_to(out_dir.resolve()).as_posix()})"
        for p in files
        if p.name in names
    ]
    if not lines:
        return ""
    return (
        "Per family, the minimum gap of each case and controller (declared actuator; × marks a collision at 0) "
        "against the bound (full braking from t = 0) and the 2 m floor:\n\n" + "\n\n".join(lines) + "\n"
    )


def safety_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """Run the suite's subset, write its files into ``out_dir`` and return its Markdown (figures shown)."""
    quick = not SectionContext.of(progress).config.is_full
    progress("safety suite" + (" (quick)" if quick else " (representative subset)"))
    workers = 1 if quick or mp.current_process().daemon else None  # a daemon process cannot start a pool
    cases = smoke_cases() if quick else reproduce_cases()
    res = run_suite(cases, quick=quick, workers=workers, actuators=QUICK_ACTUATORS if quick else DEFAULT_ACTUATORS)
    files = write_outputs(res, out_dir)
    md = markdown(res)
    if not quick:
        n_all = len(suite_cases())
        head, sep, rest = md.partition("\n")
        md = (
            f"{head}{sep}\n**Representative subset**: {len(res.cases)} of the suite's {n_all} cases (every family, "
            f"the motorway CCRs at 100, 120 and 130 km/h, both actuators, every controller), to keep the "
            f"reproduction short; `aev-ocp safety` runs all {n_all} cases.\n{rest}"
        )
    return md + "\n" + figures_markdown(files, out_dir)


REPRODUCE_SECTIONS = [("safety", safety_section, 1)]  # listed in aev_ocp.reproduce.SECTION_PROVIDERS
