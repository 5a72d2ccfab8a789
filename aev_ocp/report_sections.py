"""The sections of ``aev-ocp reproduce``: what a section is, the one registry of them, and the context a section
runs in (orchestration is :mod:`aev_ocp.reproduce`).

A section is a function ``fn(out_dir, ctx) -> str`` that writes its own files into ``out_dir`` and returns
Markdown. ``ctx`` is a :class:`SectionContext`: call it with a message to print one progress line
(``ctx("solving…")``, so a plain ``progress(message)`` function works wherever a section expects one),
read the run's :class:`ReproduceConfig` from ``ctx.config`` and add a row to the report's summary with
``ctx.record_claim(...)``. A section reaches nothing else of the run: no module-level state.

Modules add sections with :func:`register_section`, either directly or by defining
``REPRODUCE_SECTIONS = [(name, fn, steps), ...]`` in a provider module listed in
:data:`aev_ocp.reproduce.SECTION_PROVIDERS` (imported by :func:`load_providers`; the list stands in
``reproduce``, above every provider, since each provider imports this module).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

from .errors import AevOcpError
from .report import markdown_table
from .report_html import heading_anchor

ProgressFn = Callable[[str], None]


@dataclass(frozen=True)
class ReproduceConfig:
    """What to compute. The defaults are the full reproduction; :meth:`quick` is a cheap smoke run.

    tolerances: rtol = atol values of the Table 1 tolerance study; fig12_t_end: horizon of Fig. 1/2
    [model time] (None: the scenario's, 700); scenario_t_end_max: cap on every shipped scenario's
    horizon in the battery section [model time] (None: full); mpc_scenario_max_s: cap on the horizon of
    the shipped scenarios with an [mpc] table in that section [s] (None: full; the default 150 s keeps the
    paper's MPC scenarios whole, 140 s, and runs the first 150 s of the MPC drive-cycle scenarios, whose
    whole cycles take minutes: the UDDS platoon of five MPC followers alone runs 15 516 steps each; the
    "MPC on drive cycles" section and benchmarks/bench_mpc_cycles.py --full measure the whole cycles);
    scenarios: names for that section (None: all shipped); si_units: figure axes in s, m, km/h (False:
    the paper's model units); extended: the extended studies at their full size (``aev-ocp reproduce --full``;
    False, the default: the reduced workloads :data:`aev_ocp.reproduce.REDUCED_BY_DEFAULT` lists, which the
    report states in a table; the paper's figures and tables are whole either way).
    """

    tolerances: tuple[float, ...] = (1e-6, 1e-8, 1e-10, 1e-12)
    fig12_t_end: float | None = None
    scenario_t_end_max: float | None = None
    mpc_scenario_max_s: float | None = 150.0
    scenarios: tuple[str, ...] | None = None
    builtin: tuple[str, ...] = (
        "fig1-2",
        "fig3",
        "table1",
        "table1-hypotheses",
        "tolerance",
        "scenarios",
        "disagreements",
    )
    si_units: bool = True
    extended: bool = False

    @classmethod
    def quick(cls) -> "ReproduceConfig":
        """A cheap configuration for tests (short horizons, two tolerances, two scenarios)."""
        return cls(
            tolerances=(1e-6, 1e-8), fig12_t_end=20.0, scenario_t_end_max=10.0, scenarios=("table1", "udds_platoon")
        )

    @property
    def is_full(self) -> bool:
        """True for the full reproduction (the defaults, with or without ``extended``), False for a reduced one such
        as :meth:`quick`."""
        return replace(self, extended=False) == ReproduceConfig()

    @classmethod
    def full(cls) -> "ReproduceConfig":
        """The reproduction with every extended study at full size (``aev-ocp reproduce --full``)."""
        return cls(extended=True)


@dataclass(frozen=True)
class Claim:
    """One paper claim as checked by a section: the claim, the verdict ('holds', 'fails', 'partly', or a
    short phrase), one line of evidence, and the heading of the section that shows it."""

    claim: str
    verdict: str
    evidence: str
    where: str


@dataclass
class SectionContext:
    """What a running section may use: ``ctx(message)`` prints a progress line; ``config`` is the run's
    configuration; :meth:`record_claim` adds a row to the summary (kept in ``claims``)."""

    progress: ProgressFn
    config: ReproduceConfig = field(default_factory=ReproduceConfig)
    claims: list[Claim] = field(default_factory=list)

    def __call__(self, message: str) -> None:
        self.progress(message)

    def record_claim(self, claim: str, verdict: str, evidence: str, where: str) -> None:
        """Add a row to the summary at the top of the report; ``where``: the section's heading text (without
        '#'), linked from the summary."""
        self.claims.append(Claim(claim, verdict, evidence, where))

    @classmethod
    def of(cls, progress: ProgressFn) -> "SectionContext":
        """``progress`` itself when it is a context, else a context of the full configuration around it (a
        section called directly, e.g. ``mpc_section(folder, print)``)."""
        return progress if isinstance(progress, SectionContext) else cls(progress)


SectionFn = Callable[[Path, SectionContext], str]


@dataclass(frozen=True)
class Section:
    """A report section: name, function, and how many progress steps it reports."""

    name: str
    fn: SectionFn
    steps: int = 1


_REGISTRY: dict[str, Section] = {}


def register_section(name: str, fn: SectionFn, steps: int = 1) -> None:
    """Add (or replace) a report section after the built-in ones; ``fn(out_dir, ctx) -> markdown``."""
    _REGISTRY[name] = Section(name, fn, max(1, int(steps)))


def registered_sections() -> list[Section]:
    """The registered sections, in the order they were first registered."""
    return list(_REGISTRY.values())


class ReportSectionError(AevOcpError, RuntimeError):
    """A report section (or its provider module) failed; the message names it and the cause."""


def cause(exc: BaseException) -> str:
    """``Type: message`` of an exception on one line."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())


def run_section(sec: "Section", out: Path, ctx: "SectionContext") -> str:
    """One section's Markdown; an exception becomes :class:`ReportSectionError` naming the section (used by the
    sequential reproduce and by the pool's workers alike)."""
    try:
        return sec.fn(out, ctx)
    except ReportSectionError:
        raise
    except Exception as exc:  # KeyboardInterrupt/SystemExit pass through untouched
        raise ReportSectionError(f"report section {sec.name!r} failed: {cause(exc)} (no report.md written)") from exc


def load_providers(providers: Sequence[str], log: ProgressFn | None = None) -> list[str]:
    """Import provider modules and register their ``REPRODUCE_SECTIONS``; returns the ones that loaded.

    A provider module that does not exist is skipped (logged); one that exists but fails to import
    raises :class:`ReportSectionError` (its sections would otherwise vanish silently)."""
    loaded = []
    for mod_name in providers:
        try:
            mod = importlib.import_module(mod_name)
        except ModuleNotFoundError as exc:
            if exc.name is None or not (mod_name == exc.name or mod_name.startswith(exc.name + ".")):
                raise ReportSectionError(f"report section provider {mod_name} failed to import: {cause(exc)}") from exc
            if log is not None:
                log(f"section provider {mod_name} is not installed; its sections are skipped")
            continue
        except Exception as exc:
            raise ReportSectionError(f"report section provider {mod_name} failed to import: {cause(exc)}") from exc
        for entry in getattr(mod, "REPRODUCE_SECTIONS", ()):
            register_section(*entry)
        loaded.append(mod_name)
    return loaded


def summary_section(claims: Sequence[Claim]) -> str:
    """The report's opening table: each paper claim, its verdict and a link to where it is shown."""
    if not claims:
        return ""
    rows = [[c.claim, f"**{c.verdict}**", c.evidence, f"[{c.where}](#{heading_anchor(c.where)})"] for c in claims]
    n_fail = sum(c.verdict.lower().startswith(("fails", "disagrees")) for c in claims)
    return (
        "## Summary: the paper's claims and what the computations say\n\n"
        f"{len(claims)} claims checked; {n_fail} fail or disagree. Each row links to the section with the "
        "numbers and figures.\n\n" + markdown_table(["paper claim", "verdict", "evidence", "where"], rows)
    )
