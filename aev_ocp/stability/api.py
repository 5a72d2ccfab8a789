"""Python API of the string-stability analysis, for notebooks, the CLI and studies (arguments in model units;
the rows and documents it writes lead with SI values converted with a :class:`~aev_ocp.params.Units`).

* :func:`stability_map` — criterion and platoon stability over a grid of two law coefficients.
* :func:`study_metrics` — one flat row of numbers for a (law, v*) point, for a study's sweep.
* :func:`run_stability` — the whole analysis of ``aev-ocp stability``: linear results per equilibrium
  speed, measured attenuations per amplitude, the linear prediction, files and plots.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..models.carfollowing import CarFollowingLaw
from ..params import ParameterError, Units
from ..results import write_json
from .linear import LinearStability, analyse
from .measure import (
    Attenuation,
    check_measure_size,
    fig5_amplitude,
    linear_agreement,
    linear_prediction,
    measure,
    measure_mpc,
)

SIGN_CONVENTION = (
    "v̇ = f(h, v, Δv) with Δv = v_l − v; f_h = ∂f/∂h, f_v = ∂f/∂v at fixed Δv, f_Δv = ∂f/∂Δv "
    "(= ∂f/∂v_l), at (h*, v*, 0); criterion C = f_v²/2 − f_Δv·f_v − f_h, string stable iff C ≥ 0 "
    "(and platoon stable: f_h > 0, f_Δv − f_v > 0); G(s) = (f_Δv s + f_h)/(s² + (f_Δv − f_v) s + f_h) "
    "from predecessor to follower speed. SI columns first (unit in the name: _mps, _m, _s, _per_s, _per_s2, "
    "_rad_per_s; converted with 'units', time unit T = L/U), model-unit columns with a _model suffix."
)


def units_table(units: Units) -> dict[str, float]:
    """The conversion a written table used: length_m L, speed_mps U, time_s T = L/U."""
    return {"length_m": units.length_m, "speed_mps": units.speed_mps, "time_s": units.time_s}


def default_amplitudes(v_star: float) -> list[float]:
    """1e-6 … Fig. 5's size (v_l(20) − min v_l of the paper's leader), kept below 0.95 v* [model speed]."""
    top = min(fig5_amplitude(), 0.95 * v_star)
    return [a for a in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 0.5) if a < top] + [round(top, 6)]


def coefficient_names(law: CarFollowingLaw) -> list[str]:
    """The law's numeric dataclass fields (its coefficients)."""
    return [
        f.name
        for f in dataclasses.fields(law)
        if isinstance(getattr(law, f.name), (int, float)) and not isinstance(getattr(law, f.name), bool)
    ]


def stability_map(
    law: CarFollowingLaw,
    v_star: float,
    x_name: str,
    xs: Sequence[float] | np.ndarray,
    y_name: str,
    ys: Sequence[float] | np.ndarray,
) -> dict[str, np.ndarray]:
    """Criterion C and platoon stability of ``law`` with coefficients x_name, y_name set to each grid pair.

    Returns arrays of shape (len(ys), len(xs)): 'criterion', 'locally_stable', 'string_stable',
    'max_gain' (inf where not platoon stable), and 'xs', 'ys'. A grid point whose law has no
    equilibrium at v* gets NaN and False."""
    names = coefficient_names(law)
    for nm in (x_name, y_name):
        if nm not in names:
            raise ParameterError(f"stability map: {type(law).__name__} has no coefficient {nm!r}: known are {names}")
    X, Y = np.asarray(xs, float), np.asarray(ys, float)
    C = np.full((Y.size, X.size), np.nan)
    loc = np.zeros_like(C, dtype=bool)
    gain = np.full_like(C, np.inf)
    for i, y in enumerate(Y):
        for j, x in enumerate(X):
            try:
                lin = analyse(
                    dataclasses.replace(law, **{x_name: float(x), y_name: float(y)}), v_star, with_peak_gain=False
                )
            except ParameterError:
                continue
            C[i, j], loc[i, j], gain[i, j] = lin.criterion, lin.locally_stable, lin.max_gain
    return {"xs": X, "ys": Y, "criterion": C, "locally_stable": loc, "string_stable": loc & (C >= 0), "max_gain": gain}


def study_metrics(
    law: CarFollowingLaw,
    v_star: float,
    amplitude: float | None = None,
    *,
    units: Units | None = None,
    **measure_kw: Any,
) -> dict[str, Any]:
    """One flat row for a study: the linear results at v* [model speed], and (if amplitude [model speed]) the
    measured attenuation; SI keys first, converted with ``units`` (default the paper's), model keys after.

    Keys: law, v_star_mps, h_star_m, criterion_per_s2, unstable_band_hi_rad_per_s, string_stable, locally_stable,
    max_gain, peak_gain, with an amplitude amplitude_mps, ratio_peak, ratio_l2, max_step_peak, max_step_l2,
    string_stable_measured, status; then v_star_model, h_star_model, criterion_model, unstable_band_hi_model
    (and amplitude_model)."""
    u = units or Units()
    lin = analyse(law, v_star)
    band_hi = lin.unstable_band[1] if lin.unstable_band else 0.0
    row: dict[str, Any] = {
        "law": law.name,
        "v_star_mps": float(u.speed_to_si(v_star)),
        "h_star_m": float(u.length_to_si(lin.h_star)),
        "criterion_per_s2": lin.criterion / u.time_s**2,
        "unstable_band_hi_rad_per_s": band_hi / u.time_s,
        "string_stable": lin.string_stable,
        "locally_stable": lin.locally_stable,
        "max_gain": lin.max_gain,
        "peak_gain": lin.peak_gain,
    }
    model: dict[str, Any] = {
        "v_star_model": v_star,
        "h_star_model": lin.h_star,
        "criterion_model": lin.criterion,
        "unstable_band_hi_model": band_hi,
    }
    if amplitude is not None:
        a = measure(law, v_star, amplitude, lin=lin, **measure_kw)
        row.update(
            amplitude_mps=float(u.speed_to_si(amplitude)),
            ratio_peak=a.ratio_peak,
            ratio_l2=a.ratio_l2,
            max_step_peak=a.max_step_peak,
            max_step_l2=a.max_step_l2,
            string_stable_measured=a.string_stable_measured,
            status=a.status,
        )
        model["amplitude_model"] = amplitude
    return {**row, **model}


def _si_speed(u: Units) -> Callable[[float], str]:
    """'7.5 m/s (1.5)': a model speed in SI first, the model value in parentheses."""
    return lambda x: f"{u.speed_to_si(x):.4g} m/s ({x:g})"


def _stability_doc(
    law: CarFollowingLaw | None, mpc_predictor: str | None, u: Units, exp: dict[str, Any]
) -> dict[str, Any]:
    """stability.json's head (law, convention, units, the experiment with SI keys first), 'speeds' still empty;
    exp: kind, omega [rad/model time], duration [model time], n_followers."""
    T = u.time_s
    return {
        "law": law.describe() if law is not None else {"law": f"mpc ({mpc_predictor})"},
        "sign_convention": SIGN_CONVENTION,
        "units": units_table(u),
        "experiment": {
            "kind": exp["kind"],
            "omega_rad_per_s": exp["omega"] / T,
            "duration_s": exp["duration"] * T,
            "n_followers": exp["n_followers"],
            "omega_model": exp["omega"],
            "duration_model": exp["duration"],
            "sizes": "peak = max|v_n − v*|, l2 = ‖v_n − v*‖₂; ratio_* = geometric-mean "
            "step ratio over the platoon, max_step_* = largest step ratio; "
            "agrees_with_linear: every follower's peak/A within 5 % of the "
            "linearised law's",
        },
        "speeds": [],
    }


def _amplitudes_at(amplitudes: Sequence[float] | None, v: float, u: Units) -> list[float]:
    """The amplitudes [model speed] measured at v* = v: the given ones, each in (0, v*], or the defaults."""
    amps = list(amplitudes) if amplitudes is not None else default_amplitudes(float(v))
    bad = [a for a in amps if not (isinstance(a, (int, float)) and math.isfinite(a) and 0 < a <= float(v))]
    if bad:
        raise ParameterError(
            f"stability: amplitude {bad[0]!r} (model speed) is not allowed at v* = {_si_speed(u)(v)}: "
            "must be in (0, v*]"
        )
    return amps


def _measure_law_at(
    law: CarFollowingLaw,
    v: float,
    amps: list[float],
    lin: LinearStability | None,
    exp: dict[str, Any],
    say: Callable[[str], None],
    u: Units,
) -> tuple[list[Attenuation], Attenuation]:
    """The law's measured attenuations at v* = v [model speed], one per amplitude, each marked against the linear
    prediction; and that prediction. exp: kind, omega, duration, n_followers."""
    meas = []
    for a in amps:
        say(f"{law.name}, v* = {_si_speed(u)(v)}: amplitude {_si_speed(u)(a)}")
        meas.append(measure(law, float(v), a, lin=lin, **exp))
    ref = linear_prediction(law, float(v), lin=lin, **exp)
    for m in meas:
        m.agrees_with_linear = linear_agreement(m, ref)
    return meas, ref


def _measure_mpc_at(
    v: float, amps: list[float], predictor: str | None, exp: dict[str, Any], say: Callable[[str], None], u: Units
) -> list[Attenuation]:
    """The MPC platoon's measured attenuations at v* = v [model speed], one per amplitude (the undisturbed run
    computed once and reused as the baseline)."""
    meas: list[Attenuation] = []
    base = None
    for a in amps:
        say(f"mpc ({predictor}), v* = {_si_speed(u)(v)}: amplitude {_si_speed(u)(a)}")
        att, base = measure_mpc(
            float(v),
            a,
            n_followers=exp["n_followers"],
            predictor=predictor or "constant-velocity",
            kind=exp["kind"],
            omega=exp["omega"],
            duration=exp["duration"],
            baseline=base,
            units=u,
        )
        meas.append(att)
    return meas


def _region_plot(
    law: CarFollowingLaw,
    region: tuple[str, str] | None,
    region_n: int,
    v_map: float,
    out: Path,
    say: Callable[[str], None],
    u: Units,
) -> dict[str, Any] | None:
    """Plot the string-stable region of the two coefficients ``region`` (default the law's first two) at v* = v_map
    into out/stable_region.png; returns stability.json's 'stable_region' entry (None: no two coefficients)."""
    from .plots import plot_region

    names = coefficient_names(law)
    if region is None and len(names) >= 2:
        region = (names[0], names[1])
    if region is None:
        return None
    x0, y0 = (float(getattr(law, n)) for n in region)
    xs = np.linspace(0.0, max(5.0, 2.5 * x0), region_n)
    ys = np.linspace(0.0, max(5.0, 2.5 * y0), region_n)
    say(f"stable region in ({region[0]}, {region[1]}) at v* = {_si_speed(u)(v_map)}")
    smap = stability_map(law, v_map, region[0], xs, region[1], ys)
    plot_region(
        xs,
        ys,
        smap["criterion"],
        smap["locally_stable"],
        region[0],
        region[1],
        out / "stable_region.png",
        f"{law.name}: string-stable region at v* = {_si_speed(u)(v_map)}"
        + "".join(f", {k} = {getattr(law, k):g}" for k in names if k not in region),
        mark=(x0, y0),
    )
    return {
        "x": region[0],
        "y": region[1],
        "v_star_mps": float(u.speed_to_si(v_map)),
        "v_star_model": v_map,
        "xs": xs.tolist(),
        "ys": ys.tolist(),
        "criterion": smap["criterion"].tolist(),
    }


def _write_stability_plots(
    doc: dict[str, Any],
    law: CarFollowingLaw | None,
    lins: list[LinearStability],
    series: dict[str, list[Attenuation]],
    linear_refs: dict[str, Attenuation],
    out: Path,
    region: tuple[str, str] | None,
    region_n: int,
    v_map: float,
    kind: str,
    say: Callable[[str], None],
    u: Units,
) -> list[str]:
    """gain.png, stable_region.png (its grid into doc['stable_region']) and attenuation.png; the files written."""
    from .plots import plot_attenuation, plot_gain

    files: list[str] = []
    if lins:
        assert law is not None  # lins holds the linear analyses of a law
        plot_gain(lins, out / "gain.png", f"|G(iω)| of {law.name}")
        files.append(str(out / "gain.png"))
        entry = _region_plot(law, region, region_n, v_map, out, say, u)
        if entry is not None:
            files.append(str(out / "stable_region.png"))
            doc["stable_region"] = entry
    if any(series.values()):
        plot_attenuation(
            series, linear_refs, out / "attenuation.png", f"{doc['law']['law']}: attenuation vs amplitude ({kind})"
        )
        files.append(str(out / "attenuation.png"))
    return files


def run_stability(
    law: CarFollowingLaw | None,
    speeds: Sequence[float],
    out_dir: str | Path | None = None,
    *,
    amplitudes: Sequence[float] | None = None,
    kind: str = "pulse",
    omega: float = 0.5 * math.pi,
    duration: float = 4.0,
    n_followers: int = 50,
    measure_runs: bool = True,
    mpc_predictor: str | None = None,
    region: tuple[str, str] | None = None,
    region_n: int = 21,
    plots: bool = True,
    progress: Callable[[str], None] | None = None,
    units: Units | None = None,
    size_key: str = "n_followers",
) -> dict[str, Any]:
    """Everything ``aev-ocp stability`` writes: returns the stability.json document (and writes it and the
    plots into out_dir when given). speeds, amplitudes [model speed], omega [rad/model time], duration [model
    time]; units: the [units] (default the paper's) that convert them to the document's SI keys, which come
    first in every entry (v_star_mps, amplitude_mps, ...; model values keep a ``_model`` suffix), and that the
    MPC platoon's vehicles use. law None with mpc_predictor: measure the MPC platoon only (no linear
    analysis: the MPC has no closed-form law). region: the two coefficients of the stable-region plot
    (default: the law's first two), gridded over [0, 2.5 × their value] (at least [0, 5]). The measured runs are
    checked against the memory budget before the first one (ParameterError naming ``size_key``, what sets
    n_followers)."""
    say = progress or (lambda m: None)
    u = units or Units()
    exp = {"kind": kind, "omega": omega, "duration": duration, "n_followers": n_followers}
    doc = _stability_doc(law, mpc_predictor, u, exp)
    lins: list[LinearStability] = []
    lin_of = {float(v): analyse(law, float(v)) for v in speeds} if law is not None else {}
    if measure_runs:
        check_measure_size(list(lin_of.values()), n_followers, kind, omega, duration, size_key)
    series: dict[str, list[Attenuation]] = {}
    linear_refs: dict[str, Attenuation] = {}
    for v in speeds:
        entry: dict[str, Any] = {"v_star_mps": float(u.speed_to_si(float(v)))}
        lin = None
        if law is not None:
            lin = lin_of[float(v)]
            lins.append(lin)
            entry.update(lin.to_table(u))
            entry.pop("law", None)
        else:
            entry["v_star_model"] = float(v)
        amps = _amplitudes_at(amplitudes, v, u)
        meas: list[Attenuation] = []
        if measure_runs:
            label = f"v* = {float(v):g}"
            if law is not None:
                meas, ref = _measure_law_at(law, v, amps, lin, exp, say, u)
                entry["linear_prediction"] = ref.to_table(u)
                linear_refs[label] = ref
            else:
                meas = _measure_mpc_at(v, amps, mpc_predictor, exp, say, u)
            series[label] = meas
        entry["measured"] = [a.to_table(u) for a in meas]
        doc["speeds"].append(entry)
    if out_dir is not None:
        out = Path(out_dir)
        files = []
        if plots:
            v_map = float(speeds[0]) if lins else 0.0
            files = _write_stability_plots(
                doc, law, lins, series, linear_refs, out, region, region_n, v_map, kind, say, u
            )
        doc["files"] = files + [str(out / "stability.json"), str(out / "manifest.json")]
        write_json(out / "stability.json", doc)
        from .outputs import save_stability_manifest

        save_stability_manifest(out, "stability")  # aev_ocp.load(out_dir) reads it back
    return doc
