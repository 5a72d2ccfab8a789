"""The Proposition 3.1 section of ``aev-ocp reproduce`` (OCP-A, both transcriptions)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from ..report import markdown_table
from .prop31 import run_prop31, write_prop31_outputs


def prop31_section(out_dir: Path, progress: Callable[[str], None]) -> str:
    """Solve OCP-A's four cases with multiple shooting and collocation; write prop31.json/.png; return Markdown."""
    progress("Proposition 3.1: OCP-A by multiple shooting")
    ms = run_prop31(method="ms")
    progress("Proposition 3.1: OCP-A by collocation")
    col = run_prop31(method="collocation")
    write_prop31_outputs(ms, out_dir)
    rows = []
    for case, e in ms.items():
        lq = e.get("lq_exact_discrete_J")
        rows.append([case, f"{e['objective_J']:.6g}", f"{col[case]['objective_J']:.6g}",
                     "—" if lq is None else f"{lq:.6g}", f"{e['max_abs_current_A']:.3g}",
                     f"{e['zero_heat_alternative_objective_J']:.3g} (max |I| "
                     f"{e['zero_heat_alternative_max_abs_current_A']:.3g} A)", f"{e['status']} / {e['iterations']}"])
    table = markdown_table(["case", "J* [J] (multiple shooting)", "J* [J] (collocation)", "J* exact LQ [J]",
                            "max |I*| [A]", "∫Q of I = −(V1+V2)/R_s [J]", "status / iterations"], rows)
    verdicts = "".join(f"- **{case}**: {e['verdict']}\n" for case, e in ms.items())
    return ("## Proposition 3.1: is I* = 0 the unique minimiser of ∫Q dt?\n\n"
            "OCP-A (PROBLEM.md §8): one A123 cell, t_f = 60 s, S(0) = 0.5, |I| ≤ 46 A, N = 200 intervals, "
            "IPOPT with exact Hessian. Cases: rest (V1 = V2 = 0) and relaxing polarisation (V1 = 0.02 V, "
            "V2 = 0.03 V), each with and without the constraint Q ≥ 0. The cases without Q ≥ 0 are "
            "linear-quadratic and are checked against an exact discrete Riccati solution. Files: prop31.json, "
            "prop31_currents.png.\n\n"
            + table + "\n" + verdicts +
            "\nWhy: Q = Q_irr + dW/dt with W = ½C1V1² + ½C2V2² the energy stored in the RC branches, so "
            "∫Q = ∫Q_irr + W(t_f) − W(0) ≥ −W(0). From rest W(0) = 0 and I* = 0 is the unique minimiser. "
            "With initial polarisation the paper's claims that Q stays non-negative and that the cost grows "
            "with |I| are false: without Q ≥ 0 the optimum is negative (the cell gives back stored energy), "
            "and with Q ≥ 0 the optimum 0 is reached by I = 0 and also by the non-zero current "
            "I = −(V1+V2)/R_s, so it is not unique.\n\n![Proposition 3.1 currents](prop31_currents.png)\n")


REPRODUCE_SECTIONS = [("prop31", prop31_section, 2)]
