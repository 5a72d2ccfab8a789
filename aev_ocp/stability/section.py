"""The "String stability" section of ``aev-ocp reproduce`` (Fig. 5's claim and §6's linear argument).

Cheap by design (a few seconds): the linear analysis is closed form; the measurements use a platoon
of 20 followers (compiled cascade, about 0.1 s per run plus 0.3 s of compilation per new disturbance).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..models.carfollowing import IDM, OVFL, OVM, Proposed, equilibrium_gap
from ..models.leader import PaperLeader
from ..params import UNLIMITED, EVParams, Units
from ..results import write_json
from ..simulate import simulate_platoon
from .linear import LinearStability, analyse
from .measure import Attenuation, fig5_amplitude, linear_agreement, linear_prediction, measure

ProgressFn = Callable[[str], None]
N_REPORT = 50  # followers in the report's measured platoon
AMPLITUDES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
UNITS = Units()  # the paper's units (L = 10 m, U = 5 m/s), for the SI twins of the model-unit columns


def fig5_origin(law_factory: Callable[[], Any] = Proposed) -> dict[str, list[float]]:
    """Peak |relative velocity| per follower of the Table 1 platoon under variations of its initial state.

    Returns lists for: 'paper' (gap 0.3 then 3.5, speeds 1.87), 'equilibrium' (all at (V⁻¹(1.7), 1.7)),
    'close_first' (follower 1 as in the paper, the others at equilibrium), and 'paper_speed_dev'
    (peak |v_n − 1.7| in the paper's run)."""
    h = equilibrium_gap(1.7)
    law = law_factory()
    cases = {
        "paper": ([0.3] + [3.5] * 4, [1.87] * 5),
        "equilibrium": ([h] * 5, [1.7] * 5),
        "close_first": ([0.3] + [h] * 4, [1.87] + [1.7] * 4),
    }
    out: dict[str, list[float]] = {}
    for name, (g, v) in cases.items():
        r = simulate_platoon(
            PaperLeader(),
            [law] * 5,
            g,
            v,
            70.0,
            battery=False,
            dt_out=0.01,
            rtol=1e-10,
            atol=1e-10,
            ev=EVParams(limits=UNLIMITED),
        )  # the paper's run: no vehicle limits
        s = np.column_stack([r.leader_speed, r.speed])
        out[name] = np.max(np.abs(s[:, :-1] - s[:, 1:]), axis=0).tolist()
        if name == "paper":
            out["paper_speed_dev"] = np.max(np.abs(r.speed - 1.7), axis=0).tolist()
    return out


def _f(x: float, d: int = 4) -> str:
    return "∞" if x == float("inf") else f"{x:.{d}f}"


@dataclass
class _Runs:
    """What the section computed: the paper's law at v* (linear), the linear table's rows, the criterion's
    minimum over speeds, the measured dips (proposed and OVFL) and Fig. 5's origin."""

    law: Proposed
    v_star: float
    lin: LinearStability
    rows: list[str]
    grid: np.ndarray
    c_min: LinearStability
    top: float
    amps: list[float]
    ref: Attenuation
    meas: list[Attenuation]
    ovfl: dict[float, Attenuation]
    origin: dict[str, list[float]]
    origin_ovfl: dict[str, list[float]]
    holds: float | None


def _linear_rows(law: Proposed, v_star: float, lin: LinearStability) -> list[str]:
    """The linear table's rows: the paper's law and four others (OVM, OVFL, IDM, OVM at 0.964)."""
    cases = [("proposed (paper)", lin)] + [
        (f"{lw.name}" + (f", α = {lw.alpha:g}" if isinstance(lw, OVM) else ""), analyse(lw, v))
        for lw, v in (
            (OVM(), v_star),
            (OVFL(), v_star),
            (IDM().in_units(UNITS), v_star),
            (OVM(), 0.964),
            (OVM(1.0), 0.964),
        )
    ]
    rows = []
    for tag, ls in cases:
        band = f"(0, {ls.unstable_band[1]:.4f})" if ls.unstable_band else "—"
        rows.append(
            f"| {tag} | {UNITS.speed_to_si(ls.v_star):.4g} | {UNITS.length_to_si(ls.h_star):.4g} | "
            f"{ls.v_star:g} | {ls.h_star:.4f} | {ls.f_h:.4f} | {ls.f_v:.4f} | {ls.f_dv:.4f} | "
            f"{ls.criterion:.4f} | {'yes' if ls.string_stable else 'no'} | {_f(ls.max_gain)} | {band} | "
            f"{_f(ls.peak_gain)} |"
        )
    return rows


def _run(progress: ProgressFn) -> _Runs:
    """The linear analysis, the measured dips in N_REPORT followers and Fig. 5's origin."""
    law = Proposed(2.0, 3.0, 0.03, 1e-6)
    v_star = float(PaperLeader().speed_np(20.0)[0])
    progress("string stability: linear analysis")
    lin = analyse(law, v_star)
    rows = _linear_rows(law, v_star, lin)
    grid = np.linspace(0.05, 1.95, 39)
    over = [analyse(law, float(v), with_peak_gain=False) for v in grid]
    c_min = min(over, key=lambda x: x.criterion)
    top = round(min(fig5_amplitude(), 0.95 * v_star), 4)
    amps = list(AMPLITUDES) + [top]
    progress(f"string stability: dip in {N_REPORT} followers, {len(amps)} sizes")
    dt_out = 0.05
    ref = linear_prediction(law, v_star, lin=lin, n_followers=N_REPORT, dt_out=dt_out)
    meas = [measure(law, v_star, a, lin=lin, n_followers=N_REPORT, dt_out=dt_out) for a in amps]
    ovfl = {a: measure(OVFL(2.0, 3.0), v_star, a, n_followers=N_REPORT, dt_out=dt_out) for a in (1e-4, top)}
    progress("string stability: where Fig. 5's growth 1 → 2 comes from")
    origin = fig5_origin()
    origin_ovfl = fig5_origin(lambda: OVFL(2.0, 3.0))
    agree = [m.amplitude for m in meas if linear_agreement(m, ref)]
    holds = max((a for a in amps if all(a2 in agree for a2 in amps if a2 <= a)), default=None)
    return _Runs(law, v_star, lin, rows, grid, c_min, top, amps, ref, meas, ovfl, origin, origin_ovfl, holds)


def _write_files(out_dir: Path, x: _Runs) -> None:
    """string_stability.json and string_stability.png."""
    write_json(
        out_dir / "string_stability.json",
        {
            "law": x.law.describe(),
            "units": {"length_m": UNITS.length_m, "speed_mps": UNITS.speed_mps},
            "v_star_mps": UNITS.speed_to_si(x.v_star),
            "v_star": x.v_star,
            "linear": x.lin.to_dict(),
            "linear_prediction": x.ref.to_dict(),
            "measured": [m.to_dict() for m in x.meas],
            "ovfl_measured": [a.to_dict() for a in x.ovfl.values()],
            "fig5_origin": {"proposed": x.origin, "ovfl": x.origin_ovfl},
            "linear_agreement_up_to": x.holds,
        },
    )
    from .plots import plot_attenuation

    plot_attenuation(
        {"proposed": x.meas, "ovfl": list(x.ovfl.values())},
        {"proposed": x.ref},
        out_dir / "string_stability.png",
        f"Dip of depth A in {N_REPORT} followers at v* = {x.v_star:g} (dashed: linearisation)",
    )


def _measured_rows(meas: list[Attenuation], ref: Attenuation) -> list[str]:
    return [
        f"| {UNITS.speed_to_si(m.amplitude):.4g} | {m.amplitude:g} | {m.peak[1] / m.amplitude:.4g} | "
        f"{m.ratio_peak:.4f} | {m.max_step_peak:.4g} | "
        f"{m.max_step_l2:.4g} | {m.peak[-1] / m.amplitude:.4g} | "
        f"{'yes' if linear_agreement(m, ref) else 'no'} | {m.status} |"
        for m in meas
    ]


def _linear_deviation(run: Attenuation, ref: Attenuation) -> float:
    """Largest relative distance of a run's peak/A from the linear prediction's, over the followers."""
    return float(
        np.max(
            np.abs(np.asarray(run.peak) / run.amplitude - np.asarray(ref.peak) / ref.amplitude)
            / (np.asarray(ref.peak) / ref.amplitude)
        )
    )


def _linear_text(x: _Runs) -> str:
    lin, v_star, grid, c_min = x.lin, x.v_star, x.grid, x.c_min
    return (
        "## String stability (Fig. 5 and §6)\n\n"
        "Convention: v̇ = f(h, v, Δv) with Δv = v_l − v; exact partials f_h, f_v (at fixed Δv), f_Δv at "
        "(h* = V⁻¹(v*), v*, 0); criterion C = f_v²/2 − f_Δv·f_v − f_h (string stable iff C ≥ 0); "
        "G(s) = (f_Δv s + f_h)/(s² + (f_Δv − f_v)s + f_h) from predecessor speed to follower speed; "
        "∫|g| is the ℓ∞ gain (growth of the peak speed deviation per vehicle; 1 iff the impulse response "
        "never changes sign). `aev-ocp stability --law NAME` computes all of it for any law. "
        "Files: string_stability.json, string_stability.png.\n\n"
        f"**Linear, the paper's platoon** (α = 2, β = 3, κ = 0.03, ε = 1e-6, v* = v_l(20) = {v_star:g}): "
        f"C = {lin.criterion:.4f} ≥ 0, so it is string stable; sup|G| = {lin.max_gain:g}, reached only as ω → 0; "
        f"poles {lin.poles[0].real:.4f}, {lin.poles[1].real:.4f} (real), so ∫|g| = {lin.peak_gain:.4f}: linear theory "
        "forbids any growth of speed deviations, in ℓ2 and in peak (ℓ∞). The κ term has zero "
        "derivatives at Δv = 0, so these numbers equal OVFL's (§6's claim is right for the linearisation). "
        f"Over equilibrium speeds v* ∈ [{grid[0]:g}, {grid[-1]:g}] ({grid.size} points) the smallest C is "
        f"{c_min.criterion:.4f} (at v* = {c_min.v_star:g}): "
        + (
            "the paper's coefficients are linearly string stable at every speed.\n\n"
            if c_min.criterion >= 0
            else "the paper's coefficients are NOT linearly string stable at every speed.\n\n"
        )
        + f"Model units as in the paper; the SI columns use L = {UNITS.length_m:g} m, U = {UNITS.speed_mps:g} m/s.\n\n"
        "| law | v* [m/s] | h* [m] | v* (model) | h* (model) | f_h | f_v | f_Δv | C | string stable | sup\\|G\\| | "
        "\\|G\\| > 1 on ω ∈ | ∫\\|g\\| |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(x.rows) + "\n\n"
    )


def _measured_text(x: _Runs) -> str:
    ref, ovfl, top = x.ref, x.ovfl, x.top
    return (
        f"**Measured.** The leader of {N_REPORT} followers, all at equilibrium, dips by A (smooth, duration 4 = the "
        "period of the paper leader's slow component) and returns to v*. Columns: follower 1's peak |v − v*| "
        "over A; the geometric-mean step ratio of peaks over the platoon; the largest step ratios of the peak and of "
        f"‖v_n − v*‖₂; the last follower's peak over A. Linear prediction (the linearised law, same run): first "
        f"follower {ref.peak[1] / ref.amplitude:.4f}, mean ratio {ref.ratio_peak:.4f}, largest step "
        f"{ref.max_step_peak:.4f} (peak) and {ref.max_step_l2:.4f} (ℓ2), last follower {ref.peak[-1] / ref.amplitude:.4g}. "
        "'Linear' = every follower's peak within 5 % of the prediction.\n\n"
        "![attenuation against amplitude](string_stability.png)\n\n"
        "| A [m/s] | A (model) | follower 1 peak / A | mean peak ratio | max peak step | max ℓ2 step | last peak / A | "
        "linear | status |\n"
        "|---|---|---|---|---|---|---|---|---|\n" + "\n".join(_measured_rows(x.meas, ref)) + "\n\n"
        f"OVFL, same runs: mean peak ratio {ovfl[1e-4].ratio_peak:.4f} at A = 1e-4 and {ovfl[top].ratio_peak:.4f} at "
        f"A = {top:g} (largest ℓ2 step {ovfl[1e-4].max_step_l2:.4f}, {ovfl[top].max_step_l2:.4f}): it attenuates at "
        "every size, as its linearisation says.\n\n"
    )


def _answer_text(x: _Runs) -> str:
    v_star, top, holds, ref = x.v_star, x.top, x.holds, x.ref
    big, ov_big = x.meas[-1], x.ovfl[top]
    amplified = [m for m in x.meas if m.max_step_peak > 1 + 1e-3 or m.max_step_l2 > 1 + 1e-3]
    worst = max(amplified, key=lambda m: m.max_step_peak) if amplified else None
    big_dev, ov_dev = _linear_deviation(big, ref), _linear_deviation(ov_big, ref)
    return (
        f"**Answer.** §6's linear argument describes the proposed platoon only for disturbances up to "
        f"A = {holds if holds is not None else 'none of those tried'} (model speed). The κ term is "
        "κv²Δv²/(Δv² + ε) ≈ (κv²/ε)·Δv² for |Δv| ≪ √ε: at v* = 1.7 its curvature κv²/ε ≈ "
        f"{0.03 * v_star**2 / 1e-6:.3g} makes it as large as the linear terms once |Δv| ≈ ε/(κv²) ≈ "
        f"{1e-6 / (0.03 * v_star**2):.1e}, i.e. two orders below √ε = 1e-3; above that it is a braking of about κv² "
        f"= {0.03 * v_star**2:.3f} whenever the relative velocity is not tiny, which does not scale with A. "
        + (
            f"Some follower-to-follower step grows (peak or ℓ2 above 1) for A in {[m.amplitude for m in amplified]}. "
            if amplified
            else ""
        )
        + (
            f"Worst, a dip of A = {worst.amplitude:g} makes follower 1 dip by {worst.peak[1]:.3g} "
            f"({worst.peak[1] / worst.amplitude:.3g} × A) and the deviation keeps growing along the platoon (last "
            f"follower {worst.peak[-1]:.3g}): the size of the response is set by κ, not by A. "
            if worst
            else ""
        )
        + f"At Fig. 5's size (A = {top:g}; Fig. 5's leader dips by {fig5_amplitude():.3f}) the run is far outside the "
        f"linear range for both laws (some follower's peak is {100 * big_dev:.0f} % (proposed) and {100 * ov_dev:.0f} % "
        "(OVFL) away from the linear prediction); the braking term (≤ κv² = "
        f"{0.03 * v_star**2:.3f}) is small next to such a dip, and the peaks "
        + ("decrease at every step" if big.max_step_peak <= 1 + 1e-3 else "do not decrease at every step")
        + f" (mean ratio {big.ratio_peak:.4f}, OVFL {ov_big.ratio_peak:.4f}; largest step {big.max_step_peak:.4f})"
        + (
            f", while ‖v_n − v*‖₂ grows at some step of the tail (largest step {big.max_step_l2:.4f}; OVFL "
            f"{ov_big.max_step_l2:.4f}), where the deviation has shrunk to the size at which the braking term "
            "matters again. "
            if big.max_step_l2 > 1 + 1e-3
            else f" and so does ‖v_n − v*‖₂ (largest step {big.max_step_l2:.4f}). "
        )
        + "So Fig. 5's 'the perturbation attenuates' is borne out at Fig. 5's own size for the peaks, and §6's "
        f"linear argument covers only A ≤ {holds if holds is not None else '—'}; in between, the proposed platoon "
        "amplifies small disturbances although its linearisation is string stable.\n\n"
    )


def _origin_text(x: _Runs) -> str:
    o, oo = x.origin, x.origin_ovfl
    lst = lambda xs: ", ".join(f"{x:.3f}" for x in xs)  # noqa: E731
    return (
        "**Fig. 5's 0.88 → 1.19** (peak |Δv| of followers 1 and 2 in the Table 1 platoon) comes from the "
        "initial condition, not from string instability: peak |v_l − v| per follower, proposed law — paper's start "
        f"(gap 0.3 then 3.5, speeds 1.87): {lst(o['paper'])}; everyone at equilibrium (V⁻¹(1.7), 1.7): "
        f"{lst(o['equilibrium'])}; only follower 1 starts at gap 0.3 and speed 1.87: {lst(o['close_first'])}. "
        f"OVFL gives the same picture ({lst(oo['paper'])} vs {lst(oo['equilibrium'])}), so the κ term is not the "
        "cause. Follower 1 starts 0.3 behind the leader at 1.87 and brakes hard (β/h² = 33), so its speed drops faster "
        "than the leader's; follower 2 cannot follow that abrupt drop and its relative velocity peaks higher. The "
        f"speed deviations themselves, |v_n − 1.7| ({lst(o['paper_speed_dev'])}), do decrease along the platoon, as "
        "∫|g| = 1 requires; relative velocity is not the signal the transfer function bounds.\n"
    )


def string_stability_section(out_dir: Path, progress: ProgressFn) -> str:
    """Report section: the paper's platoon, linear and measured; writes string_stability.json."""
    x = _run(progress)
    _write_files(out_dir, x)
    return _linear_text(x) + _measured_text(x) + _answer_text(x) + _origin_text(x)


REPRODUCE_SECTIONS = [("string-stability", string_stability_section, 3)]
