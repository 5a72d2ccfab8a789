"""Measured string stability: perturb the leader of a long platoon at equilibrium and watch the
perturbation travel down it (model units).

Every follower starts at the equilibrium (h*, v*) of its law; the leader is a
:class:`~aev_ocp.stability.perturbation.PerturbedLeader` (a sinusoid or a smooth speed dip of depth A).
Per vehicle n (n = 0 is the leader) we record the speed deviation ṽ_n = v_n − v* and three sizes:

* peak  = max_t |ṽ_n|;
* l2    = (∫ ṽ_n² dt)^½ over the run;
* harmonic (sinusoid only) = the amplitude of ṽ_n's component at the forcing frequency ω over the last
  ``periods`` whole periods (a Fourier projection, which ignores the other frequencies of transients).

Attenuation ratios: per step (size_n / size_{n−1}) and the geometric mean over the platoon
(size_N / size_0)^(1/N). In the linear regime the harmonic step ratio is |G(iω)| of
:mod:`aev_ocp.stability.linear`; the same run with the law's linearisation
(:class:`~aev_ocp.stability.linear.LinearizedLaw`) gives the linear prediction of every size, so
'measured vs linear' compares like with like at any amplitude.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence, TypedDict

import numpy as np

from ..models.carfollowing import CarFollowingLaw
from ..limits import estimate_run_bytes, memory_limit_bytes
from ..models.leader import PaperLeader
from ..params import UNLIMITED, EVParams, ParameterError, Units
from ..results import SimulationResult
from ..simulate import simulate_platoon
from .linear import LinearizedLaw, LinearStability, analyse
from .perturbation import PerturbedLeader


def fig5_amplitude(leader: PaperLeader | None = None) -> float:
    """The size of Fig. 5's disturbance: v_l(20) − min v_l on [0, 20] for the paper's leader [model speed]."""
    ld = leader or PaperLeader()
    t = np.linspace(0.0, ld.t_end, 40001)
    return float(ld.speed_np(ld.t_end)[0] - ld.speed_np(t).min())


def _geo(sizes: np.ndarray) -> float:
    if sizes[0] <= 0 or not np.all(np.isfinite(sizes)):
        return math.nan
    if sizes[-1] <= 0:
        return 0.0
    return float((sizes[-1] / sizes[0]) ** (1.0 / (sizes.size - 1)))


@dataclass
class Attenuation:
    """One perturbed-platoon run: sizes per vehicle (index 0 = leader) and attenuation ratios.

    ratio_*: geometric-mean step ratio over the platoon; max_step_*: the largest size_n/size_{n−1};
    string_stable_measured: no step ratio of l2 (and harmonic, for a sinusoid) above 1 + tol."""

    label: str
    v_star: float
    amplitude: float
    kind: str
    omega: float
    duration: float
    n_followers: int
    t_end: float
    status: str
    peak: list[float]
    l2: list[float]
    harmonic: list[float] | None
    ratio_peak: float
    ratio_l2: float
    ratio_harmonic: float | None
    max_step_peak: float
    max_step_l2: float
    max_step_harmonic: float | None
    string_stable_measured: bool
    max_abs_rel_speed: list[float] = field(default_factory=list)
    agrees_with_linear: bool | None = None  # set against a linear prediction (:func:`linear_agreement`)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)

    def to_table(self, units: Units) -> dict[str, Any]:
        """JSON-ready, SI first: v_star_mps, amplitude_mps, omega_rad_per_s, duration_s, t_end_s and per vehicle
        peak_mps, l2_m_per_sqrt_s (‖v_n − v*‖₂ = (∫ṽ² dt)^½), harmonic_mps, max_abs_rel_speed_mps, converted
        with ``units``; then the dimensionless ratios and verdicts; then the model-unit values with a ``_model``
        suffix."""
        d = self.to_dict()
        U, T = units.speed_mps, units.time_s
        scale = {
            "v_star": ("v_star_mps", U),
            "amplitude": ("amplitude_mps", U),
            "omega": ("omega_rad_per_s", 1.0 / T),
            "duration": ("duration_s", T),
            "t_end": ("t_end_s", T),
            "peak": ("peak_mps", U),
            "l2": ("l2_m_per_sqrt_s", U * math.sqrt(T)),
            "harmonic": ("harmonic_mps", U),
            "max_abs_rel_speed": ("max_abs_rel_speed_mps", U),
        }
        out: dict[str, Any] = {k: d[k] for k in ("label", "kind", "n_followers", "status")}
        for k, (si, f) in scale.items():
            x = d[k]
            out[si] = None if x is None else [v * f for v in x] if isinstance(x, list) else x * f
        out.update({k: v for k, v in d.items() if k not in scale and k not in out})
        out.update({f"{k}_model": d[k] for k in scale})
        return out


class Sizes(TypedDict):
    """What :func:`sizes_of` returns: per vehicle, leader first [model speed]."""

    peak: np.ndarray  # max |v_n − v*|
    l2: np.ndarray  # ‖v_n − v*‖₂ over time
    harmonic: np.ndarray | None  # amplitude of the ω harmonic (None without omega)
    rel: np.ndarray  # max |v_{n−1} − v_n|, one per follower


def sizes_of(
    res: SimulationResult,
    v_star: float,
    omega: float | None = None,
    periods: int = 6,
    t_from: float = 0.0,
    baseline: SimulationResult | None = None,
) -> Sizes:
    """Peak, ℓ2 and (if omega) harmonic size of v_n − v* per vehicle, leader first [model speed].

    baseline: an unperturbed run on the same time grid; the followers' deviations are then taken from
    it instead of from v* (for controllers, like the MPC, whose steady state is not exactly v*)."""
    t = res.t
    dv = np.column_stack([res.leader_speed, res.speed]) - v_star
    if baseline is not None:
        k = min(t.size, baseline.t.size)
        t, dv = t[:k], dv[:k].copy()
        dv[:, 1:] = res.speed[:k] - baseline.speed[:k]
    keep = t >= t_from
    t, dv = t[keep], dv[keep]
    peak = np.max(np.abs(dv), axis=0)
    sq = dv * dv
    l2 = np.sqrt(np.sum(0.5 * (sq[1:] + sq[:-1]) * np.diff(t)[:, None], axis=0))
    harm = None
    if omega:
        span = periods * 2.0 * math.pi / omega
        m = t >= t[-1] - span
        tw, x = t[m], dv[m]
        ph = np.exp(-1j * omega * tw)[:, None] * x
        integ = np.sum(0.5 * (ph[1:] + ph[:-1]) * np.diff(tw)[:, None], axis=0)
        harm = 2.0 * np.abs(integ) / (tw[-1] - tw[0])
    rel = np.column_stack([res.leader_speed, res.speed])[: len(keep)][keep]
    rel_speed = np.max(np.abs(rel[:, :-1] - rel[:, 1:]), axis=0)
    return {"peak": peak, "l2": l2, "harmonic": harm, "rel": rel_speed}


def default_t_end(
    lin: LinearStability, n_followers: int, kind: str, omega: float, duration: float, periods: int = 6
) -> float:
    """A horizon long enough for the perturbation to reach the last follower and settle [model time]:
    1.5 × N × the linear group delay per vehicle (1/V'-like, −f_v/f_h at ω → 0) + 10 decay times, plus
    the forcing (``periods`` periods of the sinusoid, or the dip's duration)."""
    delay = max(-lin.f_v / lin.f_h if lin.f_h > 0 else 1.0, lin.f_dv / max(lin.f_h, 1e-9), 0.5)
    decay = 1.0 / max(1e-3, -max(p.real for p in lin.poles))
    base = 1.5 * n_followers * delay + 10.0 * decay
    return float(base + (periods * 2.0 * math.pi / omega if kind == "sine" else duration))


#: Output step of a measured run [model time]: 0.02, fine enough for the peak of a pulse of duration >= 0.5
MEASURE_DT_OUT = 0.02


def check_measure_size(
    lins: Sequence[LinearStability], n_followers: int, kind: str, omega: float, duration: float, key: str
) -> None:
    """Refuse (ParameterError naming ``key``, the option or argument that sets the platoon size) measured runs of
    ``n_followers`` behind the perturbed leader at the equilibria ``lins`` that need more than the memory budget
    ($AEV_OCP_MAX_MEMORY_GB), before the first runs: their horizon, :func:`default_t_end`, grows with the platoon."""
    limit = memory_limit_bytes()

    def need(n: int) -> float:
        return max(estimate_run_bytes(n, default_t_end(lin, n, kind, omega, duration), MEASURE_DT_OUT) for lin in lins)

    if not lins or need(n_followers) <= limit:
        return
    lo, hi = 0, n_followers  # the largest platoon that fits: need(n) grows with n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if need(mid) <= limit else (lo, mid)
    raise ParameterError(
        f"stability: {key} {n_followers}: the measured runs need about {need(n_followers) / 1e9:.3g} GB (their "
        f"horizon grows with the platoon), more than the limit of {limit / 1e9:.3g} GB ($AEV_OCP_MAX_MEMORY_GB): "
        f"use at most {lo} followers" + (", or --linear-only" if key.startswith("--") else "")
    )


def measure(
    law: CarFollowingLaw,
    v_star: float,
    amplitude: float,
    *,
    kind: str = "pulse",
    omega: float = 0.5 * math.pi,
    duration: float = 4.0,
    n_followers: int = 50,
    t_end: float | None = None,
    lin: LinearStability | None = None,
    periods: int = 6,
    dt_out: float = MEASURE_DT_OUT,
    rtol: float | None = None,
    atol: float | None = None,
    method: str = "auto",
    tol: float = 1e-3,
    label: str | None = None,
) -> Attenuation:
    """Perturb the leader of ``n_followers`` followers of ``law`` at equilibrium speed v_star by a sinusoid
    (kind 'sine', frequency omega [rad/model time]) or a dip (kind 'pulse', duration [model time]) of
    size ``amplitude`` [model speed], simulate without the battery, and measure the attenuation.

    rtol, atol: integrator tolerances; default scaled with the amplitude (rtol = min(1e-9, 1e-5 A),
    atol = min(1e-11, 1e-8 A)), since the deviations at the platoon's tail are far below A."""
    if not (isinstance(n_followers, int) and n_followers >= 1):
        raise ParameterError(f"stability: n_followers = {n_followers!r} is not allowed: must be an integer >= 1")
    lin = lin or analyse(law, v_star)
    leader = PerturbedLeader(v_star, amplitude, kind, omega=omega, duration=duration)
    T = float(t_end) if t_end is not None else default_t_end(lin, n_followers, kind, omega, duration, periods)
    rtol = min(1e-9, 1e-5 * amplitude) if rtol is None else rtol
    atol = min(1e-11, 1e-8 * amplitude) if atol is None else atol
    res = simulate_platoon(
        leader,
        [law] * n_followers,
        [lin.h_star] * n_followers,
        [v_star] * n_followers,
        T,
        battery=False,
        dt_out=dt_out,
        rtol=rtol,
        atol=atol,
        method=method,
        ev=EVParams(limits=UNLIMITED),
    )  # the law as linearised: no vehicle limits
    return attenuation_of(res, label or law.name, v_star, leader, T, periods, tol)


def attenuation_of(
    res: SimulationResult,
    label: str,
    v_star: float,
    leader: PerturbedLeader,
    t_end: float,
    periods: int = 6,
    tol: float = 1e-3,
    baseline: SimulationResult | None = None,
) -> Attenuation:
    """The :class:`Attenuation` of a finished perturbed-platoon run (any simulator, e.g. the MPC's closed loop)."""
    s = sizes_of(
        res, v_star, leader.omega if leader.kind == "sine" else None, periods, t_from=leader.t_start, baseline=baseline
    )
    peak, l2, harm = s["peak"], s["l2"], s["harmonic"]
    steps_l2 = l2[1:] / l2[:-1]
    steps_h = harm[1:] / harm[:-1] if harm is not None else None
    stable = bool(np.all(steps_l2 <= 1 + tol) and (steps_h is None or np.all(steps_h <= 1 + tol)))
    return Attenuation(
        label=label,
        v_star=float(v_star),
        amplitude=float(leader.amplitude),
        kind=leader.kind,
        omega=float(leader.omega),
        duration=float(leader.duration),
        n_followers=int(res.n_vehicles),
        t_end=float(t_end),
        status=res.status,
        peak=peak.tolist(),
        l2=l2.tolist(),
        harmonic=harm.tolist() if harm is not None else None,
        ratio_peak=_geo(peak),
        ratio_l2=_geo(l2),
        ratio_harmonic=_geo(harm) if harm is not None else None,
        max_step_peak=float(np.max(peak[1:] / peak[:-1])),
        max_step_l2=float(np.max(steps_l2)),
        max_step_harmonic=float(np.max(steps_h)) if steps_h is not None else None,
        string_stable_measured=stable,
        max_abs_rel_speed=s["rel"].tolist(),
    )


def linear_prediction(
    law: CarFollowingLaw, v_star: float, *, lin: LinearStability | None = None, amplitude: float = 1e-4, **kw: Any
) -> Attenuation:
    """The same experiment with the law's linearisation at (h*, v*): ratios independent of the amplitude
    (``amplitude`` [model speed], at most v_star). kw: :func:`measure`'s options (kind, omega, duration,
    n_followers, ...; its defaults)."""
    lin = lin or analyse(law, v_star)
    return measure(
        LinearizedLaw.of(lin), v_star, min(amplitude, v_star), lin=lin, label=f"{law.name} (linearised)", **kw
    )


def linear_agreement(att: Attenuation, lin: Attenuation, rel: float = 0.05) -> bool:
    """Every vehicle's peak |ṽ|/A within ``rel`` of the linearised law's (the linear theory describes the run)."""
    a = np.asarray(att.peak) / att.amplitude
    b = np.asarray(lin.peak) / lin.amplitude
    return bool(a.size == b.size and np.all(np.abs(a - b) <= rel * b))


def sweep_amplitudes(law: CarFollowingLaw, v_star: float, amplitudes: Sequence[float], **kw: Any) -> list[Attenuation]:
    """:func:`measure` at each amplitude [model speed] (the linear analysis is done once)."""
    lin = kw.pop("lin", None) or analyse(law, v_star)
    return [measure(law, v_star, float(a), lin=lin, **kw) for a in amplitudes]


def measure_mpc(
    v_star: float,
    amplitude: float,
    *,
    n_followers: int = 6,
    predictor: str = "constant-velocity",
    kind: str = "pulse",
    omega: float = 0.5 * math.pi,
    duration: float = 4.0,
    t_start: float = 2.0,
    t_end: float = 30.0,
    settings: Any = None,
    periods: int = 3,
    baseline: SimulationResult | None = None,
    units: Units | None = None,
) -> tuple[Attenuation, SimulationResult]:
    """The MPC platoon (model guide §9) in closed loop with the exact plant behind the perturbed leader.

    Every follower runs its own MPC (``settings``, default MPCSettings with the 'rti' path) and starts at
    (V⁻¹(v*), v*); predictor 'cooperative' means vehicles 2… use their predecessor's last plan and vehicle 1
    a constant-velocity forecast. The MPC's own steady state is not exactly (V⁻¹(v*), v*) (its cost also
    weighs the pack heat), so the deviations are taken from an unperturbed run (``baseline``, returned
    for reuse) and measured from t_start on. units: the vehicles' [units] (default the paper's), which the MPC's
    SI-tuned formulation and the battery see. Returns (attenuation, baseline result)."""
    from dataclasses import replace

    from ..models.carfollowing import equilibrium_gap
    from ..control import run_closed_loop
    from ..mpc.policy import MPCVehicle
    from ..mpc.settings import MPCSettings
    from ..params import EVParams

    st = settings or MPCSettings(solver="rti", codegen=True)
    if predictor == "cooperative":
        ctrl = [MPCVehicle(replace(st, predictor="constant-velocity"))] + [
            MPCVehicle(replace(st, predictor="cooperative"))
        ] * (n_followers - 1)
    else:
        ctrl = [MPCVehicle(replace(st, predictor=predictor))] * n_followers
    leader = PerturbedLeader(v_star, amplitude, kind, omega=omega, duration=duration, t_start=t_start)
    h = equilibrium_gap(v_star)
    ev = EVParams(units=units) if units is not None else None
    if baseline is None:
        calm = PerturbedLeader(v_star, 0.0, kind, omega=omega, duration=duration, t_start=t_start)
        baseline = run_closed_loop(calm, ctrl, [h] * n_followers, [v_star] * n_followers, t_end, ev=ev)
    res = run_closed_loop(leader, ctrl, [h] * n_followers, [v_star] * n_followers, t_end, ev=ev)
    return attenuation_of(res, f"mpc ({predictor})", v_star, leader, t_end, periods, baseline=baseline), baseline
