"""The built-in sections of ``aev-ocp reproduce`` (orchestration is :mod:`aev_ocp.reproduce`): Fig. 1/2, Fig. 3,
Table 1 and Fig. 5, the Table 1 hypotheses, the tolerance study, the battery side of every shipped scenario, and
the computed disagreements with the paper. They share one run's simulations (:class:`PaperRun`); each is a
section ``fn(out_dir, ctx) -> str`` (:mod:`aev_ocp.report_sections`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .models.carfollowing import V_INF
from .plots import (
    plot_compare_omega,
    plot_leader,
    plot_percent_change,
    plot_phase_planes,
    plot_platoon,
    plot_space_time,
)
from .report import (
    OVER_LIMIT_MARK,
    PAPER_TABLE1,
    PRINTED_HALF_ULP,
    markdown_table,
    fmt,
    platoon_checks,
    scenario_metrics_rows,
    table1_disagreements,
    table1_summary,
    write_table1,
)
from .report_sections import ProgressFn, ReproduceConfig, Section, SectionContext
from .results import SimulationResult, write_json
from .saved import FIGURE_MAX_SAMPLES, save_output, settings_of
from .scenarios import Scenario, iter_shipped, load_scenario
from .simulate import simulate_platoon

HEAD_FIG12 = "Fig. 1 and Fig. 2: phase planes (a_l = 0)"
HEAD_TABLE1 = "Table 1: the paper's inertial measure ω (platoon of 6, paper leader, t ∈ [0, 70])"
HEAD_FIG5 = "Fig. 5: the platoon under the proposed model"
HEAD_HYP = "Table 1: why our ω are below the printed ones (hypotheses tested)"


@dataclass
class PaperRun:
    """The built-in sections of one reproduction (:meth:`sections`); they share simulation results through
    ``cache`` and the disagreements they find through ``notes``."""

    config: ReproduceConfig
    cache: dict[Any, dict[str, SimulationResult]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: the folder (relative to the output folder) each set of runs was saved in, by the id of its cached dict: a
    #: later section showing the same runs points there instead of storing the trajectories twice
    saved: dict[int, str] = field(default_factory=dict)

    def simulate(self, s: Scenario, progress: ProgressFn, what: str, **overrides: Any) -> dict[str, SimulationResult]:
        settings = {"t_end": s.t_end, "rtol": s.rtol, "atol": s.atol, "dt_out": s.dt_out, **overrides}
        key = (s.name, tuple(sorted(settings.items())))
        if key not in self.cache:
            res: dict[str, SimulationResult] = {}
            for label, laws in s.runs():
                progress(f"{what}: {label}…")
                res[label] = simulate_platoon(s.leader, list(laws), **{**s.simulate_kwargs(), **overrides})
            self.cache[key] = res
        return self.cache[key]

    def simulate_mpc(self, s: Scenario, progress: ProgressFn, what: str) -> SimulationResult:
        """The scenario's [mpc] closed loop (cached like :meth:`simulate`)."""
        from .mpc.scenario import closed_loop_from_scenario

        key = (s.name, "mpc", s.t_end)
        if key not in self.cache:
            progress(f"{what}: mpc…")
            r = closed_loop_from_scenario(s, s.extra["mpc"]).run(list(s.gaps0), list(s.speeds0), s.t_end)
            self.cache[key] = {"mpc": r}
        return self.cache[key]["mpc"]

    # ------------------------------------------------------------------------- sections
    def fig12(self, out: Path, progress: ProgressFn) -> str:
        runs, panels1, panels2, facts = {}, [], [], []
        n_notes = len(self.notes)
        for name in ("fig1a", "fig1b"):
            s = load_scenario(name)
            if self.config.fig12_t_end is not None:
                s = s.replace(t_end=min(s.t_end, self.config.fig12_t_end))
            runs[name] = res = self.simulate(s, progress, name)
            save_output(out / name, "simulate", res, settings=settings_of(s))  # aev_ocp.load(out / name)
            self.saved[id(res)] = name
            cap = f"({name[-1]}) {s.description.split(': ', 1)[-1]}"
            panels1.append((cap, {"proposed": res["proposed"]}))
            panels2.append((cap, res))
            for label, r in res.items():
                chk = platoon_checks(r, t_eq=0.0)
                m = r.metrics()[0]
                facts.append(
                    [
                        name,
                        label,
                        r.status,
                        fmt(m["min_gap_model"]),
                        fmt(chk["final_gap_error"][0], 3),
                        fmt(chk["final_rel_speed"][0], 3),
                        fmt(m["omega_model"]),
                    ]
                )
                if r.status != "ok" or m["min_gap_model"] <= 0:
                    self.notes.append(
                        f"Fig. 1/2 {name}, {label}: the paper says the trajectory reaches the "
                        f"equilibrium without crossing h = 0; ours ends with status {r.status} "
                        f"(min gap {m['min_gap_model']:.4g})."
                    )
                elif abs(chk["final_gap_error"][0]) > 1e-3 or abs(chk["final_rel_speed"][0]) > 1e-3:
                    self.notes.append(
                        f"Fig. 1/2 {name}, {label}: not at the equilibrium at t = {s.t_end:g} "
                        f"(gap error {chk['final_gap_error'][0]:.3g})."
                    )
        si = self.config.si_units
        plot_phase_planes(panels1, out / "fig1_phase_plane.png", "Fig. 1: proposed model, a_l = 0", si=si)
        plot_phase_planes(panels2, out / "fig2_phase_plane_vs_ovfl.png", "Fig. 2: proposed vs OVFL, a_l = 0", si=si)
        table = markdown_table(["case", "law", "status", "min gap", "h(T) − V⁻¹(v_l)", "v_l − v at T", "ω"], facts)
        bad = self.notes[n_notes:]
        ctx = SectionContext.of(progress)
        ctx.record_claim(
            "Fig. 1/2: from both initial conditions the follower reaches the equilibrium (V⁻¹(v_l), 0) "
            "without crossing h = 0",
            "holds" if not bad else "fails",
            f"{len(facts)} runs (2 cases × proposed, OVFL): "
            + ("all end at the equilibrium (|h − V⁻¹(v_l)| < 1e-3) with min gap > 0" if not bad else "; ".join(bad)),
            HEAD_FIG12,
        )
        return (
            f"## {HEAD_FIG12}\n\n"
            "One follower behind a constant-speed leader, α = 2, β = 3, κ = 0.03, horizon "
            f"{load_scenario('fig1a').t_end if self.config.fig12_t_end is None else self.config.fig12_t_end:g}. "
            "Red dot: initial condition; magenta ×: equilibrium (V⁻¹(v_l), 0); gray dashed: h = 0.\n\n"
            "![Fig. 1](fig1_phase_plane.png)\n\n![Fig. 2](fig2_phase_plane_vs_ovfl.png)\n\n"
            + table
            + "\nThe minimum gap is over the continuous trajectory (Hermite refinement of the samples).\n"
        )

    def fig3(self, out: Path, progress: ProgressFn) -> str:
        s = load_scenario("table1")
        progress("fig3: leader profile")
        plot_leader(
            s.leader,
            s.t_end,
            out / "fig3_leader.png",
            "Fig. 3: the paper's leader",
            units=s.units,
            si=self.config.si_units,
        )
        v = s.leader.speed_np(np.linspace(0, s.t_end, 7001))
        return (
            "## Fig. 3: the leader\n\n"
            "a_l(t) = −(1.65/1.37)(sin(0.5πt) + cos(3.2πt)) on [0, 20], 0 after; v_l(0) = 1.7. "
            f"Speed range on [0, {s.t_end:g}]: {v.min():.4f} … {v.max():.4f} (V∞ = {V_INF:.4f}); "
            f"v_l(20) = {float(s.leader.speed_np(20.0)[0]):.4f}.\n\n![Fig. 3](fig3_leader.png)\n"
        )

    def table1(self, out: Path, progress: ProgressFn) -> str:
        s = load_scenario("table1")
        res = self.simulate(s, progress, "table1")
        summary = table1_summary(res)
        write_table1(out, summary)
        save_output(out / "table1", "simulate", res, settings=settings_of(s))  # aev_ocp.load(out / "table1")
        self.saved[id(res)] = "table1"
        self.table1_summary = summary
        progress("table1: Fig. 5 and ω plot")
        chk = platoon_checks(res["proposed"], t_eq=20.0)
        si = self.config.si_units
        plot_platoon(
            res["proposed"],
            out / "fig5_platoon.png",
            v_eq=chk["v_eq"],
            si=si,
            title="Fig. 5: platoon under the proposed model (gray: equilibrium for v_l(20))",
        )
        for law, r in res.items():
            plot_space_time(
                r, out / f"table1_space_time_{law}.png", si=si, title=f"Table 1 platoon under {law}: space-time diagram"
            )
        plot_compare_omega(
            {k: summary[f"{k}_omega"] for k in ("proposed", "ovfl")},
            out / "table1_omega.png",
            reference=PAPER_TABLE1,
            title="Table 1: ω per follower",
        )
        plot_percent_change(
            summary["percent_change"],
            summary["paper_percent_change"],
            out / "table1_percent.png",
            title="Table 1: % change of ω, proposed vs OVFL, per follower",
        )
        self._table1_claims(summary, chk, SectionContext.of(progress))
        self.fig5_checks = chk
        n = s.n_followers
        bat = markdown_table(
            ["law"] + [f"n = {i + 1}" for i in range(n)],
            [[f"{k} pack ∫Q [J]"] + [fmt(x) for x in summary["pack_heat_J"][k]] for k in res]
            + [[f"{k} pack ∫Q_irr [J]"] + [fmt(x) for x in summary["pack_heat_irr_J"][k]] for k in res]
            + [[f"{k} ΔSOC"] + [fmt(x, 3) for x in summary["delta_soc"][k]] for k in res]
            + [[f"{k} ω [J/kg]"] + [fmt(x) for x in summary["omega_J_per_kg"][k]] for k in res],
        )
        table_md = (out / "table1.md").read_text()
        u = s.units
        fig5_rows = [
            [
                f"n = {i + 1}",
                fmt(chk["min_gap"][i]),
                fmt(chk["min_speed"][i]),
                fmt(chk["peak_abs_rel_speed"][i]),
                fmt(chk["final_gap_error"][i], 3),
                fmt(chk["final_rel_speed"][i], 3),
            ]
            for i in range(n)
        ]
        return (
            f"## {HEAD_TABLE1}\n\n"
            f"Converged values (integrator {res['proposed'].meta.get('integrator', '?')}, rtol = atol = "
            f"{s.rtol:g}; the exact, non-smooth g is used — the cascade evaluates ω exactly from v at the "
            "zeros of v̇, CVODES integrates it as an error-controlled quadrature — and the run is split at "
            "the leader's switch t = 20; the tolerance study below and the test suite cross-check both "
            "integrators and an independent SciPy integration). "
            "Files: table1.csv, table1.md, table1.json.\n\n"
            + table_md
            + "\n![Table 1 ω](table1_omega.png)\n\n![Table 1 % change](table1_percent.png)\n\n"
            f"### Battery side of Table 1 (units L = {u.length_m:g} m, U = {u.speed_mps:g} m/s, T = {u.time_s:g} s; "
            "pack of 106s70p A123 cells)\n\n" + bat + f"\n## {HEAD_FIG5}\n\n![Fig. 5](fig5_platoon.png)\n\n"
            "Space-time diagrams of the same platoon (positions relative to the leader's start, coloured by "
            "speed):\n\n![space-time, proposed](table1_space_time_proposed.png)\n\n"
            "![space-time, OVFL](table1_space_time_ovfl.png)\n\n"
            + markdown_table(
                ["follower", "min gap", "min speed", "max |Δv|", "h(70) − V⁻¹(v_l(20))", "Δv(70)"], fig5_rows
            )
            + f"\nEquilibrium for v_l(20) = {chk['v_eq']:.4f}: gap V⁻¹(v_l(20)) = {chk['h_eq']:.4f}.\n"
        )

    def _table1_claims(self, summary: dict[str, Any], chk: dict[str, Any], ctx: SectionContext) -> None:
        """Summary rows for Table 1 and Fig. 5."""
        dev = {
            k: [100 * (a - b) / b for a, b in zip(summary[f"{k}_omega"], summary[f"paper_{k}_omega"])]
            for k in ("proposed", "ovfl")
        }
        far = any(
            abs(a - b) > PRINTED_HALF_ULP
            for k in dev
            for a, b in zip(summary[f"{k}_omega"], summary[f"paper_{k}_omega"])
        )
        ctx.record_claim(
            "Table 1: the printed ω per follower",
            "disagrees" if far else "holds",
            "ours are "
            + ", ".join(f"{min(v):+.1f} … {max(v):+.1f} % ({k})" for k, v in dev.items())
            + " from the printed values; hypotheses for the gap are tested",
            HEAD_TABLE1,
        )
        pc = summary["percent_change"]
        worse = [i + 1 for i, x in enumerate(pc) if x > 0]
        ctx.record_claim(
            "Table 1: the proposed law has a lower ω (the paper's measure) than OVFL for every follower",
            "fails" if worse else "holds",
            "% change " + ", ".join(f"{x:+.2f}" for x in pc) + (f"; follower(s) {worse} use more" if worse else ""),
            HEAD_TABLE1,
        )
        safe = chk["status"] == "ok" and min(chk["min_gap"]) > 0 and min(chk["min_speed"]) >= 0
        ctx.record_claim(
            "Fig. 5: no collision and no negative speed in the platoon",
            "holds" if safe else "fails",
            f"min gap {min(chk['min_gap']):.3g}, min speed {min(chk['min_speed']):.3g} [model]",
            HEAD_FIG5,
        )
        ctx.record_claim(
            "Fig. 5: the perturbation attenuates along the platoon",
            "holds" if chk["attenuates"] else "partly",
            "peak |v_(n−1) − v_n| per follower "
            + ", ".join(f"{x:.3f}" for x in chk["peak_abs_rel_speed"])
            + ("" if chk["attenuates"] else " (grows from follower 1 to 2, then decreases)"),
            HEAD_FIG5,
        )

    def table1_hypotheses(self, out: Path, progress: ProgressFn) -> str:
        from .table1_hypotheses import hypotheses_markdown, run_hypotheses, table1_setups

        progress("table1 hypotheses: g, η convention, window, integrator, sampling")
        res = {law: run_hypotheses(setup, PAPER_TABLE1[law]) for law, setup in table1_setups().items()}
        write_json(
            out / "table1_hypotheses.json",
            {
                law: {
                    "hypotheses": [
                        {
                            "key": h.key,
                            "description": h.description,
                            "omega": h.omega,
                            "deviation_pct": h.deviation_pct,
                            "fits": h.fits,
                        }
                        for h in hyps
                    ],
                    "printed": hyps[0].printed,
                    "fitted_regeneration_efficiency": extra["fitted_regeneration"],
                }
                for law, (hyps, extra) in res.items()
            },
        )
        fits = [f"{law}: {h.description}" for law, (hyps, _) in res.items() for h in hyps[1:] if h.fits]
        c = {law: extra["fitted_regeneration"] for law, (_, extra) in res.items()}
        ctx = SectionContext.of(progress)
        ctx.record_claim(
            "Table 1 (our question): is the gap to the printed ω a different g, η convention, window, "
            "integrator or sampling?",
            "explained" if fits else "not explained",
            ("fits: " + "; ".join(fits))
            if fits
            else f"none of {sum(len(h) - 1 for h, _ in res.values())} computed variants is within 1 % of every "
            "printed value; the braking efficiency that would fit ranges "
            f"{min(float(min(v)) for v in c.values()):.3f}–{max(float(max(v)) for v in c.values()):.3f} "
            "across followers",
            HEAD_HYP,
        )
        return (
            f"## {HEAD_HYP}\n\n"
            "Each candidate explanation of the 3–20 % gap, computed (not assumed): the Table 1 platoon is "
            "integrated once more by one CVODES integrator of the whole platoon with one quadrature "
            "v·g(a) per candidate g (its baseline row reproduces Table 1 from a second integrator), forward "
            "Euler runs of the whole platoon (CasADi mapaccum), and Riemann sums of the sampled trajectory. "
            "Entries: ω and its deviation from the printed value. `aev_ocp.table1_hypotheses` recomputes "
            "every row; file: table1_hypotheses.json.\n\n" + hypotheses_markdown(res)
        )

    def tolerance(self, out: Path, progress: ProgressFn) -> str:
        s = load_scenario("table1")
        rows: list[list[str]] = []
        json_rows: list[dict[str, Any]] = []
        settings = [(tol, s.dt_out) for tol in self.config.tolerances] + [(s.rtol, s.dt_out / 2)]
        for tol, dt in settings:
            res = self.simulate(
                s, progress, f"tolerance rtol=atol={tol:g}, dt_out={dt:g}", rtol=tol, atol=tol, dt_out=dt
            )
            for label, r in res.items():
                om = [float(x) for x in r.omega[-1]]
                rows.append([f"{tol:g}", f"{dt:g}", label] + [f"{x:.6f}" for x in om])
                json_rows.append(
                    {
                        "rtol": tol,
                        "atol": tol,
                        "dt_out": dt,
                        "law": label,
                        "omega": om,
                        "pack_heat_J": [float(x) for x in r.heat_J[-1]],
                    }
                )
        write_json(out / "tolerance_study.json", json_rows)
        ref = {(d["law"]): d["omega"] for d in json_rows if d["rtol"] == min(self.config.tolerances)}
        spread = {}
        for law in ref:
            tight = [d["omega"] for d in json_rows if d["law"] == law and d["rtol"] <= 1e-8]
            spread[law] = float(np.max(np.ptp(np.array(tight), axis=0))) if len(tight) > 1 else float("nan")
        self.tol_spread = spread
        n = s.n_followers
        text = (
            "## Tolerance study (Table 1 ω)\n\n"
            "The same Table 1 runs at several integrator tolerances (rtol = atol) and with the output "
            "spacing dt_out halved. File: tolerance_study.json.\n\n"
            + markdown_table(["rtol = atol", "dt_out", "law"] + [f"n = {i + 1}" for i in range(n)], rows)
            + "\nLargest change of any ω among the runs with rtol ≤ 1e-8: "
            + ", ".join(f"{k}: {v:.2e}" for k, v in spread.items())
            + ". The printed table has 3 decimals, so the converged values are settled far below that.\n"
        )
        return text

    def scenarios(self, out: Path, progress: ProgressFn) -> str:
        parts = [
            "## Battery side of every shipped scenario\n\n"
            "Pack ∫Q (the paper's power loss, unclipped) and ∫Q_irr (the heat actually dissipated), "
            "ΔSOC = S_end − S_0, per follower, each scenario under its own units. Per-run metrics: "
            'scenarios/<name>/metrics.json; the runs themselves: `aev_ocp.load("scenarios/<name>")` (runs longer '
            f"than {FIGURE_MAX_SAMPLES} samples stored thinned to about that many, for their figures; the runs of "
            'Fig. 1/2 and Table 1 are stored once, in their own folders: `aev_ocp.load("fig1a")`, '
            '`aev_ocp.load("table1")`; their metrics.json names that folder).\n'
        ]
        names = self.config.scenarios
        for name, path in iter_shipped():
            if names is not None and name not in names:
                continue
            parts += self._scenario(out, progress, name, path)
        return "".join(parts)

    def _shortened(self, s: Any) -> Any:
        """The scenario cut to the reduced configuration's horizon (an MPC scenario to a whole number of steps)."""
        if self.config.scenario_t_end_max is not None and s.t_end > self.config.scenario_t_end_max:
            s = s.replace(t_end=self.config.scenario_t_end_max)
        mpc_cfg = s.extra.get("mpc")
        cap_s = self.config.mpc_scenario_max_s
        if mpc_cfg is not None and cap_s is not None and s.units.time_to_si(s.t_end) > cap_s:
            dt = mpc_cfg.settings.dt  # a whole number of MPC steps
            s = s.replace(t_end=round(math.floor(s.units.time_from_si(cap_s) / dt + 1e-9) * dt, 12))
        return s

    @staticmethod
    def _mpc_line(mpc_cfg: Any, r_mpc: Any) -> str:
        """What the scenario's own [mpc] closed loop ran: formulation, forecast, solver path, fallbacks."""
        st = [x for x in r_mpc.solver_stats if x]
        form = (
            "model guide §9" if mpc_cfg.formulation.kind == "s9" else "the traffic formulation, aev_ocp/ocp/traffic.py"
        )
        return (
            f"\nThe `mpc` rows are the scenario's own [mpc] closed loop ({form}, forecast "
            f"{mpc_cfg.settings.predictor}) on the exact "
            f"plant: solver path {st[0]['solver_path'] if st else '?'} "
            f"(QP {(st[0].get('qp_solver') or '—') if st else '?'}), "
            f"{sum(x['fallbacks'] for x in st)} fallbacks in {sum(x['n_steps'] for x in st)} "
            "solves.\n"
            if st
            else ""
        )

    def _save_scenario(self, sub: Path, name: str, res: dict[str, Any], s: Any) -> None:
        """metrics.json, and the runs (unless an earlier section saved the same runs: then a pointer to them)."""
        elsewhere = self.saved.get(id(res))  # the same runs, saved by an earlier section (Fig. 1/2, Table 1)
        metrics: dict[str, Any] = {"scenario": name, "runs": {k: r.summary() for k, r in res.items()}}
        if elsewhere is not None:
            metrics["trajectories"] = f"../../{elsewhere}"  # aev_ocp.load(out / elsewhere): stored once
        write_json(sub / "metrics.json", metrics)
        if elsewhere is None:
            save_output(  # aev_ocp.load(sub); long runs thinned for their figures (metrics: every sample)
                sub,
                "mpc" if "mpc" in res else "simulate",
                res,
                settings=settings_of(s),
                max_samples=FIGURE_MAX_SAMPLES,
            )

    def _scenario_notes(self, name: str, res: dict[str, Any]) -> None:
        """Runs that ended early, and the proposed law dissipating more pack heat than OVFL, into the notes."""
        bad = {k: r.status for k, r in res.items() if r.status != "ok"}
        if bad:
            self.notes.append(f"Scenario {name}: runs ended early: {bad}.")
        p_heat = {k: float(np.sum(r.heat_J[-1])) for k, r in res.items()}
        if "proposed" in p_heat and "ovfl" in p_heat and p_heat["proposed"] > p_heat["ovfl"] * (1 + 1e-3):
            self.notes.append(
                f"Scenario {name}: the proposed law's platoon dissipates MORE pack heat ∫Q than "
                f"OVFL's ({p_heat['proposed']:.5g} J vs {p_heat['ovfl']:.5g} J summed over "
                "followers): the paper's efficiency claim is about ω, not ∫Q."
            )

    def _scenario(self, out: Path, progress: ProgressFn, name: str, path: Any) -> list[str]:
        """One shipped scenario: run it (and its [mpc] loop), save it, its Markdown parts."""
        s = load_scenario(path)
        t_full = s.t_end
        s = self._shortened(s)
        mpc_cfg = s.extra.get("mpc")
        res = self.simulate(s, progress, name)
        mpc_line = ""
        if mpc_cfg is not None:
            r_mpc = self.simulate_mpc(s, progress, name)
            res = {"mpc": r_mpc, **res}
            mpc_line = self._mpc_line(mpc_cfg, r_mpc)
        sub = out / "scenarios" / name
        self._save_scenario(sub, name, res, s)
        i_max = s.ev.cell.max_current_A
        headers, rows = scenario_metrics_rows(res, i_max_A=i_max, totals=True)
        u = s.units
        v_max = s.leader.max_speed(s.t_end)
        parts = [
            f"\n### {name}\n\n{s.description}. Units L = {u.length_m:g} m, U = {u.speed_mps:g} m/s "
            f"(T = {u.time_s:.4g} s); horizon {s.t_end:g} model time = {u.time_to_si(s.t_end):.4g} s"
            + (
                f" (the first part of the scenario's {u.time_to_si(t_full):.4g} s, to keep reproduce short)"
                if s.t_end < t_full
                else ""
            )
            + "; "
            f"leader top speed {v_max:.4f} model = {u.speed_to_si(v_max):.4g} m/s "
            f"(V∞·U = {u.speed_to_si(V_INF):.4g} m/s).\n\n" + markdown_table(headers, rows) + mpc_line
        ]
        over = sorted({r[0] for r in rows if OVER_LIMIT_MARK in r[8]})
        if over:
            parts.append(
                f"\n{OVER_LIMIT_MARK} The cell current exceeds the 20C limit ({i_max:g} A) in run(s) "
                f"{over}: the battery columns marked {OVER_LIMIT_MARK} are outside the cell model's "
                "validity and have no physical meaning (the closed-form laws do not know that limit; "
                "the simulator only stops on an infeasible demand, E² < 4 R_s P_c).\n"
            )
        if s.n_followers > 1:
            for label, r in res.items():
                f = sub / f"{label}_space_time.png"
                plot_space_time(r, f, si=self.config.si_units, title=f"{name}: {label}")
            parts.append(
                "\n"
                + " ".join(f"![{name} {label} space-time](scenarios/{name}/{label}_space_time.png)" for label in res)
                + "\n"
            )
        self._scenario_notes(name, res)
        return parts

    def disagreements(self, out: Path, progress: ProgressFn) -> str:
        progress("disagreements with the paper")
        lines = []
        if hasattr(self, "table1_summary"):
            lines += table1_disagreements(self.table1_summary)
        if hasattr(self, "fig5_checks"):
            c = self.fig5_checks
            if c["status"] != "ok" or min(c["min_gap"]) <= 0 or min(c["min_speed"]) < 0:
                lines.append(
                    f"Fig. 5: the paper reports no collision or negative speed; ours: status {c['status']}, "
                    f"min gap {min(c['min_gap']):.4g}, min speed {min(c['min_speed']):.4g}."
                )
            else:
                lines.append("Fig. 5 agrees: no collision and no negative speed in the platoon.")
            lines.append(
                "Fig. 5: the peak |relative velocity| "
                + ("decreases" if c["attenuates"] else "does NOT decrease monotonically")
                + " along the platoon ("
                + ", ".join(f"{x:.3f}" for x in c["peak_abs_rel_speed"])
                + "); the paper says the "
                "perturbation attenuates."
            )
            far = [i + 1 for i, e in enumerate(c["final_gap_error"]) if abs(e) > 1e-2]
            lines.append(
                "Fig. 5: at t = 70 "
                + (
                    "every follower is within 0.01 of the equilibrium gap for v_l(20)."
                    if not far
                    else f"follower(s) {far} are still more than 0.01 from the equilibrium gap "
                    f"V⁻¹(v_l(20)) = {c['h_eq']:.4f}."
                )
            )
        lines += self.notes
        if not lines:
            return ""
        return "## Where the numbers disagree with the paper (computed)\n\n" + "".join(f"- {x}\n" for x in lines)

    def sections(self) -> list[Section]:
        t1 = load_scenario("table1")
        n_tol = len([tol for tol in self.config.tolerances if (tol, tol) != (t1.rtol, t1.atol)]) + 1
        shipped = [
            load_scenario(p)
            for name, p in iter_shipped()
            if self.config.scenarios is None or name in self.config.scenarios
        ]
        n_scen = sum(len(s.runs()) + (s.extra.get("mpc") is not None) for s in shipped)
        table = {
            "fig1-2": Section("fig1-2", self.fig12, 4),
            "fig3": Section("fig3", self.fig3, 1),
            "table1": Section("table1", self.table1, 3),
            "table1-hypotheses": Section("table1-hypotheses", self.table1_hypotheses, 1),
            "tolerance": Section("tolerance", self.tolerance, 2 * n_tol),
            "scenarios": Section("scenarios", self.scenarios, n_scen),
            "disagreements": Section("disagreements", self.disagreements, 1),
        }
        return [table[k] for k in self.config.builtin]
