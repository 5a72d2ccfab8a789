"""``aev-ocp reproduce``: every figure and table of the paper, the tolerance study, the battery side of
every shipped scenario, and a report.md that states where the numbers disagree with the paper.

The report is a list of sections (:mod:`aev_ocp.report_sections`: what a section is, the registry, the
:class:`SectionContext` a section runs in). Each section is a function ``fn(out_dir, ctx) -> str`` that
writes its own files into ``out_dir`` and returns Markdown; ``ctx(message)`` prints one line on
stderr. Other modules add sections with :func:`register_section`, either directly or by defining
``REPRODUCE_SECTIONS = [(name, fn, steps), ...]`` in a provider module listed in
:data:`SECTION_PROVIDERS` (imported lazily). A provider that is not installed at all adds no section
(a log line says so); a provider that fails to import, or a section that raises, stops ``reproduce``
with :class:`ReportSectionError` naming the section and the cause (the CLI exits 1), so a section can
never vanish from the report while the run exits 0.

This module only orchestrates (the sections in order, the progress counter, the report's head and summary); the
built-in sections are in :mod:`aev_ocp.paper_sections`, the others in their own packages' section modules.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, Sequence

from ._version import __version__
from .paper_sections import PaperRun
from .params import VehicleLimits
from .report import markdown_table, write_text
from .report_sections import SectionFn as SectionFn
from .report_sections import ReportSectionError as ReportSectionError  # re-exported: callers catch it here
from .report_sections import register_section as register_section
from .report_sections import (
    _REGISTRY,
    Claim,
    ProgressFn,
    ReproduceConfig,
    SectionContext,
    load_providers,
    run_section,
    summary_section,
)

_LIM = VehicleLimits()  # the default limits the report names

#: Modules whose ``REPRODUCE_SECTIONS`` are added after the built-in sections, in this order
#: (here, above them all: each provider imports :mod:`aev_ocp.report_sections`).
SECTION_PROVIDERS: tuple[str, ...] = (
    "aev_ocp.claims",
    "aev_ocp.ocp.section",
    "aev_ocp.mpc.report",
    "aev_ocp.mpc.cycles_section",
    "aev_ocp.stability.section",
    "aev_ocp.safety.section",
    "aev_ocp.ring_section",
    "aev_ocp.life_section",
    "aev_ocp.robustness",
)


#: The extended studies that ``reproduce`` runs reduced by default (the reproduction in minutes), as
#: (section heading, what the default runs, what ``reproduce --full`` adds); the report's head shows this table. The
#: sections read ``ReproduceConfig.extended``; the paper's figures and tables are whole either way.
REDUCED_BY_DEFAULT: tuple[tuple[str, str, str], ...] = (
    (
        "MPC on drive cycles",
        "the MPC with its default forecast (decaying-acceleration) beside the laws",
        "the MPC with each forecast (constant-velocity, decaying-acceleration) beside the laws",
    ),
    ("Robustness", "UDDS and US06, seeds 0, 1, 2", "UDDS, HWFET and US06, seeds 0, 1, 2"),
    ("Battery life", "UDDS and US06, hot and cold ambient", "UDDS, HWFET and US06, hot and cold ambient"),
)


def reduced_table(extended: bool) -> str:
    """The report's table of :data:`REDUCED_BY_DEFAULT`, saying which column this run ran."""
    lead = (
        "**Extended studies at full size** (this run: `aev-ocp reproduce --full`):"
        if extended
        else "**Extended studies reduced by default** (this run: the default column, to keep the reproduction to "
        "minutes; `aev-ocp reproduce --full` runs the other; the paper's figures and tables are whole either way):"
    )
    rows = [[head, default, full] for head, default, full in REDUCED_BY_DEFAULT]
    return f"\n{lead}\n\n" + markdown_table(["study", "default", "`--full`"], rows)


class Progress:
    """Prints ``[k/N] message`` lines on stderr with a FIXED denominator N (the steps the sections declare, the
    writing step and the final line): k is the step a line belongs to. A line beyond what its section declared
    (e.g. OCP-D's iteration lines) is a sub-step: it repeats k; a section that reports fewer lines than it
    declared (e.g. cached runs) moves k past its skipped steps when it ends. So N never moves, k never goes
    back or past N, and N/N is printed once, by :meth:`done`, after the last file is written.

    Sections that run at the same time (``reproduce(workers=2)``) each pass their own ``key`` to :meth:`begin`,
    :meth:`end` and the call: each keeps its own count of declared lines left; k counts them all."""

    def __init__(self, total: int, stream: Any = None, clock: Any = None) -> None:
        self.total, self.k, self.stream = total, 0, stream if stream is not None else sys.stderr
        self._left: dict[str, int] = {}  # declared lines not reported yet, per running section
        self.clock = clock if clock is not None else time.perf_counter
        self.t0 = self.clock()

    @property
    def left(self) -> int:
        """Declared lines of the running section(s) not reported yet."""
        return sum(self._left.values())

    def begin(self, steps: int, key: str = "") -> None:
        """A section that declared ``steps`` lines starts (its steps are part of N already)."""
        self._left[key] = steps

    def end(self, key: str = "") -> None:
        """The section ended: the steps it declared but did not report are passed over (k moves past them)."""
        self.k = min(self.k + self._left.pop(key, 0), self.total - 1)

    def __call__(self, message: str, key: str = "") -> None:
        if self._left.get(key, 0) > 0:
            self._left[key] -= 1
            self.k = min(self.k + 1, self.total - 1)  # N/N belongs to done() alone
        self._line(message)

    def done(self, message: str) -> None:
        """The final line: ``[N/N] message``."""
        self.k = self.total
        self._line(message)

    def _line(self, message: str) -> None:
        print(f"[{self.k}/{self.total}] {message} ({self.clock() - self.t0:.1f} s)", file=self.stream, flush=True)


def verdict(claims: Sequence[Claim]) -> str:
    """One line: how many of the paper's claims hold, and which fail or disagree (the report's summary table)."""
    if not claims:
        return "no paper claim checked"
    bad = [c for c in claims if c.verdict.lower().startswith(("fails", "disagrees"))]
    holds = sum(c.verdict.lower().startswith("holds") for c in claims)
    text = f"{holds} of {len(claims)} paper claims hold, {len(bad)} fail or disagree"
    return text + (": " + "; ".join(c.claim for c in bad) if bad else "")


def reproduce(
    out_dir: str | Path = "results",
    config: ReproduceConfig | None = None,
    *,
    registered: bool = True,
    stream: Any = None,
    workers: int = 1,
) -> Path:
    """Run every section, write all files into ``out_dir`` and return the path of report.md.

    registered: also run the sections registered by other modules (after loading the providers). workers: run
    independent sections on a pool of this many worker processes (1: one after another in this process); the
    report, its claims and every file are the same either way (each section writes its own files; its Markdown
    and claims are put in the declared order), only the progress lines interleave.
    """
    config = config or ReproduceConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stream = stream if stream is not None else sys.stderr
    log = lambda m: print(f"aev-ocp: {m}", file=stream, flush=True)  # noqa: E731
    run = PaperRun(config)
    claims: list[Claim] = []
    sections = run.sections()
    n_builtin = len(sections)  # PaperRun's sections share its state: they run together, in order
    if registered:
        load_providers(SECTION_PROVIDERS, log=log)
        sections += list(_REGISTRY.values())
    progress = Progress(sum(s.steps for s in sections) + 2, stream)  # + writing the report, + the final line
    parts = [
        f"# aev_ocp {__version__}: reproduction of Yeo et al. (2025)\n\n"
        "Generated by `aev-ocp reproduce`. Tables: model (dimensionless) units as in the paper unless a "
        "column says otherwise; the battery side uses each scenario's units L, U (§1 of the model guide, docs/guide/model.md). Figures: "
        + ("s, m, km/h through the scenario's units" if config.si_units else "model units")
        + ". "
        "The same report as HTML, showing the figures of this folder: report.html. "
        "The paper's figures, Table 1 and its MPC scenarios run the paper's laws as printed, without vehicle "
        "limits (`[limits] enabled = false` in their scenario files); every other scenario (the drive cycles) "
        f"applies each vehicle's default limits (a ∈ [{_LIM.a_min_mps2:g}, {_LIM.a_max_mps2:g}] m/s², "
        f"v ≤ {_LIM.v_max_mps:g} m/s) to every controller.\n"
    ]
    if not config.is_full:
        parts.append(f"\n**Reduced configuration** (not the full reproduction): {config}\n")
    else:
        parts.append(reduced_table(config.extended))
    from .provenance import provenance

    prov = provenance()
    parts.append(
        "\nProvenance: "
        + ", ".join(f"{k} `{v}`" for k, v in prov.items() if v is not None)
        + "; random seeds are in each section's JSON (e.g. `theorem41.json`).\n"
    )
    if workers > 1:
        from .reproduce_pool import run_sections_pooled

        for md, sec_claims in run_sections_pooled(sections, n_builtin, out, config, progress, workers):
            claims.extend(sec_claims)
            if md:
                parts.append("\n" + md.rstrip() + "\n")
    else:
        for sec in sections:
            progress.begin(sec.steps)
            md = run_section(sec, out, SectionContext(_prefixed(progress, sec.name), config, claims))
            if md:
                parts.append("\n" + md.rstrip() + "\n")
            progress.end()
    _claims_from_outputs(out, parts, claims)
    parts.insert(1, "\n" + summary_section(claims))
    progress.begin(1)
    progress("writing report.md and report.html")
    progress.end()
    text = "".join(parts)
    from .report_html import write_report_html

    write_report_html(text, out, out / "report.html", title=f"aev_ocp {__version__}: reproduction of Yeo et al. (2025)")
    path = write_text(out / "report.md", text)
    progress.done(f"done: wrote {path} and {out / 'report.html'}; verdict: {verdict(claims)}")
    return path


def _prefixed(progress: ProgressFn, name: str) -> ProgressFn:
    """``progress`` with each message prefixed by the section's name (unless it already starts with it)."""
    return lambda msg: progress(msg if msg.startswith(name) else f"{name}: {msg}")


def _claims_from_outputs(out: Path, parts: Sequence[str], claims: list[Claim]) -> None:
    """Summary rows for sections that record no claim themselves, read from the files they wrote
    (string_stability.json: the §6 claim). A file that is missing or has another layout adds no row."""
    import json

    path = out / "string_stability.json"
    head = next((ln[3:].strip() for p in parts for ln in p.splitlines() if ln.startswith("## String stability")), None)
    if not path.exists() or head is None:
        return
    try:
        d = json.loads(path.read_text())
        lin, meas = d["linear"], d["measured"]
        grows = [m["amplitude"] for m in meas if max(m["max_step_peak"], m["max_step_l2"]) > 1.0]
        crit = float(lin["criterion"])
        stable = bool(lin["string_stable"])
    except (KeyError, TypeError, ValueError):
        return
    verdict = "holds" if stable and not grows else ("partly" if stable else "fails")
    claims.append(
        Claim(
            "§6: the κ term keeps the platoon string stable (disturbances attenuate)",
            verdict,
            f"linear criterion C = {crit:.3g} ({'stable' if stable else 'unstable'}); measured growth "
            f"along the platoon for dip amplitudes {', '.join(f'{a:g}' for a in grows) or 'none'}",
            head,
        )
    )
