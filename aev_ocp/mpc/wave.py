"""The wave-damping MPC: one automated EV that dissolves a ring's stop-and-go wave.

The traffic MPC (:mod:`aev_ocp.ocp.traffic`) follows its predecessor: it tracks the predecessor's speed and a
constant time gap, so among human drivers it rides the wave they make. A wave-dampener does the opposite
(Stern et al. 2018, Transp. Res. C 89: FollowerStopper and "PI with saturation"; Cui, Seibold, Stern, Work 2017):
it drives at the *average* speed of the traffic and lets its gap breathe, so the oscillation of the car ahead is
absorbed in the gap instead of being passed on. :func:`wave_problem` states that as an optimal-control problem with
the toolkit's :class:`~aev_ocp.ocp.problem.ProblemBuilder`: it is the traffic problem (same states, battery,
ω epigraph (the paper's measure), pack heat, acceleration and jerk terms, the same soft safety constraints on the gap) with a
different objective for the motion:

* **speed tracking** w_v (v − v_ref)², v_ref an own state of the problem (dv_ref/dt = 0 over the horizon) that the
  controller sets at every step from what it measures itself (no V2V, no knowledge of the future), as Stern et
  al.'s PI with saturation does: the mean U of its own speed over the last ``window_s`` plus a saturated gap
  catch-up k (h̄ − s_t − T_t U), h̄ the mean measured gap over the same window. The catch-up is a slow integral
  action: in steady state the car's mean gap is s_t + T_t U, and on a ring that sets the speed at which the humans
  behind it drive (the faster, the more string-stable these humans are: benchmarks/bench_wave_mpc.py --bound);
* **a weak gap centring** w_g (h − h_c(v))², h_c(v) = s_c + T_c v: in steady state the car keeps this gap, so the
  ring's equilibrium speed drops only by what the extra gap costs (the throughput guard);
* **a gap band**: the traffic problem's soft floor h ≥ s_min + T_min v (with the braking-distance constraint) below,
  and a soft ceiling h ≤ s_max + T_max v above (an exact L1 penalty ρ_band per metre beyond it, plus 1e-3 σ²), so it
  never opens an absurd gap;
* **terminal cost** w_vT (v_N − v_ref)² + w_gT (h_N − h_c(v_N))² (the short horizon does not plan a swing after it).

Optionally (``WaveParams.hold_*``, off by default; a ring scenario's ``[ring.wave]``) v_ref is a **latched speed
hold**: once the car has left the jam it starts in (its mean speed back at ``hold_min_mps`` after falling below it)
and while its predecessor's measured speed std is at most ``hold_sigma_mps``, v_ref is held in [``hold_min_mps``,
``hold_max_mps``] instead of chasing the gap; a growing wave (or a mean speed below ``hold_release_mps``) returns it
to the catch-up, which collects the wave in the car's gap.

Optionally (``WaveParams.follower_*``, off by default; the calibrated ring's ``[ring.wave]`` sets it) the car also leads the driver **behind** it, as leading cruise
control does (Wang, Zheng, Chen, Xu, Li 2022, IEEE T-ITS 23(8); DeeP-LCC: Wang, Zheng, Li, Xu 2023, IEEE T-CST
31(6)): it measures that follower's gap h_f to it and its speed v_f (a rear radar:
:attr:`aev_ocp.loop.Observation.follower`), predicts them over the horizon with a human car-following law linearised
at its equilibrium at v_ref (dh_f/dt = v − v_f, dv_f/dt = α_h (h_f − h*(v_ref)) + α_v (v_f − v_ref) + α_l (v − v_ref):
:func:`follower_linearisation`, the calibrated ring population's median IDM by default) and adds
w_f (v_f − v_ref)² (and w_fT at the end), so it pulls a slow follower and holds back a fast one. Without a measured
follower the term is off (its states are decoupled: the weight-0 solution to round-off); with both weights 0 the
problem is built without them.

The predecessor-speed term of the traffic problem (w_r (v̂_l − v)²) and its time-gap terms are off (weights 0): the
predecessor forecast (its measured speed and acceleration, decaying) enters only the dynamics of the gap and the
braking-distance constraint. Energy awareness is the traffic problem's: the paper's ω rate v g(a),
pack heat, a² and jerk, in W/kg.

:class:`WaveMPC` is the closed-loop controller (:class:`~aev_ocp.mpc.policy.MPCPolicy`: built once, warm-started
real-time iterations, the safe fallback and the safety filter of the traffic MPC), usable wherever a
:class:`~aev_ocp.loop.Controller` is: the ring (``controllers = ["wave-mpc"]``), SUMO, a platoon.
:func:`linear_gains` linearises its converged first move at an equilibrium, so the mixed-ring theory
(:mod:`aev_ocp.stability.mixed`) says whether one such car makes a ring of humans linearly stable
(benchmarks/bench_wave_mpc.py).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace
from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np

from ..control import Command, Observation
from ..models.carfollowing import IDM, CarFollowingLaw, idm_accel
from ..ocp.formulation import problem_formulation
from ..ocp.problem import ProblemBuilder
from ..ocp.traffic import SLACK_MAX_M, TrafficParams, traffic_problem
from ..params import EVParams, ParameterError, Units, as_dict, spec, validate_fields
from .controller import MPCController
from .policy import MPCPolicy
from .predictors import make_predictor
from .settings import MPCSettings

WAVE_NAME = "wave-mpc"  # the controller's name in ring scenarios and tables


@dataclass(frozen=True)
class WaveParams:
    """Parameters of :func:`wave_problem`, SI (cost unit W/kg, integrated over seconds, as the traffic problem).
    Sources: 'our choice' unless stated, tuned on ring seeds 0–2 (benchmarks/bench_wave_mpc.py, evaluated on
    seeds 20–39, 60–79 and 80–99; a 90 s window with v_c = 0.5 m/s, tuned on seeds 0–9 and 40–49, did about as well
    there and worse behind the drive cycles: docs/guide/studies.md) and checked with the mixed-ring linear theory
    (docs/guide/studies.md, "The wave-damping MPC")."""

    speed_weight: float = spec(100.0, ge=0.0)  # w_v [W/kg per (m/s)²] on (v − v_ref)² (our choice, tuned on the
    # calibrated ring's seeds 0–2: the car must hold its speed while its gap swings; the linear theory gives one car
    # a stable ring of 21 calibrated humans from w_v ≈ 3.3 on, of 21 Treiber humans from
    # w_v ≈ 0.7 on with the earlier gap settings)
    gap_weight: float = spec(0.01, ge=0.0)  # w_g [W/kg per m²] on (h − h_c(v))² (our choice: weak, the gap breathes)
    centre_gap_m: float = spec(2.0, ge=0.0)  # s_c [m] of h_c(v) (our choice: the humans' IDM s0, Treiber 2000)
    centre_time_gap_s: float = spec(1.5, ge=0.0)  # T_c [s] of h_c(v) (our choice: 0.5 s above the IDM's T = 1 s)
    max_gap_m: float = spec(60.0, gt=0.0)  # s_max [m] of the soft ceiling (our choice: room for a jam's swing)
    max_time_gap_s: float = spec(3.0, ge=0.0)  # T_max [s] of the soft ceiling (our choice)
    band_penalty: float = spec(5.0, gt=0.0)  # ρ_band [W/kg per m beyond the ceiling] (our choice)
    terminal_speed_weight: float = spec(5.0, ge=0.0)  # w_vT [J/kg per (m/s)²] (our choice)
    terminal_gap_weight: float = spec(0.1, ge=0.0)  # w_gT [J/kg per m²] (our choice)
    window_s: float = spec(38.0, gt=0.0)  # the own-speed average of v_ref [s] (Stern et al. 2018 §3.2's PI: 38 s)
    # the gap catch-up of v_ref (Stern et al. 2018 §3.2's PI with saturation adds up to v_catch = 1 m/s while the
    # gap is large): v_ref = U + clip(k (h̄ − h_t(U)), −v_c, v_c), h̄ the mean measured gap over window_s,
    # h_t(U) = s_t + T_t U; in steady state h̄ = h_t: an integral action that sets the ring's speed
    catch_gain_per_s: float = spec(0.1, ge=0.0)  # k [1/s] (our choice, seeds 0–2; 0: off, v_ref = U)
    # the base of v_ref: (1 − β) U + β U_l, U_l the mean of the predecessor's measured speed over window_s (the same
    # window); U, the car's own mean, makes v_ref = U + catch an integrator of the catch-up (its speed drifts while
    # the catch-up is not 0), so with the windowed gap h̄ the loop is two integrators and a 19 s lag: behind steady
    # drivers it swings (SUMO's Krauss ring: a 75 s cycle); U_l does not move with the car's own speed
    base_predecessor_share: float = spec(0.0, ge=0.0, le=1.0)  # β (our choice; 0: U, as before)
    target_gap_m: float = spec(8.0, ge=0.0)  # s_t [m] (our choice, seed 0: on the calibrated ring the car
    # settles near 3.9 m/s with a 16 m gap, where a smooth car leaves little wave behind it, when it gets out of
    # the jam it starts in: on 1 of the unseen seeds 10–19; docs/guide/studies.md)
    target_time_gap_s: float = spec(2.0, ge=0.0)  # T_t [s] (our choice: 72 m at 30 m/s, a cautious gap on a road)
    catch_max_mps: float = spec(1.0, ge=0.0)  # v_c [m/s] (Stern et al. 2018 §3.2: v_catch = 1 m/s)
    # the catch-up's upper saturation alone: clip(k (h̄ − h_t), −v_c, v_c⁺), so the car gives back a gap it collected
    # in a wave more slowly than it collects one (our choice; 0: v_c⁺ = v_c, symmetric, as before)
    catch_rise_max_mps: float = spec(0.0, ge=0.0)  # v_c⁺ [m/s] (our choice; 0: off)
    # a wave buffer in the catch-up's target: h_t = s_t + T_t U + c σ_l, σ_l the std of the predecessor's measured
    # speed over window_s (a wave of speed std σ and period P needs a gap swing of about √2 σ P/π: c ≈ 8 s at
    # the ring's 35 s); 0: off
    buffer_time_s: float = spec(4.0, ge=0.0)  # c [s] (our choice, seeds 0–2: 4 s against 8 s)
    # σ_l about its trend: the std of the predecessor's speeds about their least-squares line over the window, so a
    # start, a stop or a steady change of speed (a trend) opens no buffer and only an oscillation (a wave) does
    # (our choice; False: the plain std, as before). It is the σ_l of c σ_l, of the adaptive buffer and of the hold
    detrend_sigma: bool = spec(False, kind="bool")
    # an adaptive wave buffer b [m] added to h_t (h_t = s_t + T_t U + c σ_l + b): an integral action on the wave the
    # car sees, db/dt = g (σ_l − σ*), b within [0, b_max]: behind steady drivers (σ_l below σ*) it shrinks to 0 and
    # the car keeps the base gap s_t + T_t U; while a wave grows it opens the gap that absorbs it, until σ_l is back
    # at σ* (or b at b_max); so the base gap may be a human's and the wave sets the buffer (our design; Stern et al.
    # 2018's PI with saturation has a fixed target gap); g = 0: off, b = 0
    buffer_rate: float = spec(0.0, ge=0.0)  # g [m/s of buffer growth per m/s of σ_l above σ*] (our choice; 0: off)
    buffer_sigma_mps: float = spec(0.3, gt=0.0)  # σ* [m/s] (our choice)
    buffer_max_m: float = spec(20.0, ge=0.0)  # b_max [m] (our choice)
    # a speed band on v_ref (after the catch-up): v_ref ∈ [v_lo, v_hi], so the integral action cannot take the ring
    # below the speed where the humans behind the car amplify too much, nor above where their gaps leave the car too
    # little room (benchmarks/bench_wave_mpc.py --bound); 0: no bound
    min_ref_mps: float = spec(0.0, ge=0.0)  # v_lo [m/s] (our choice; 0: off)
    max_ref_mps: float = spec(0.0, ge=0.0)  # v_hi [m/s] (our choice; 0: off)
    # a latched speed hold (a ring setting: [ring.wave]): the car runs the catch-up above until its mean speed U, once
    # below hold_min_mps (the jam it must first leave by collecting it in its gap, which a floor on v_ref forbids), is
    # back at hold_min_mps; from that step on it holds v_ref within [hold_min_mps, hold_max_mps] (the catch-up's gain
    # and buffer then hold_gain_per_s and hold_buffer_time_s; 0, 0 and a point band: v_ref = hold_min_mps, a constant
    # speed, not chasing its gap). On a ring the car's long-run mean speed is the ring's, so holding it holds the ring
    # at a speed where the humans behind it amplify less (benchmarks/bench_wave_mpc.py --bound), the gap (its soft
    # floor and ceiling, the weak centring) only a constraint; 0: off (the default: every other use runs as before)
    hold_min_mps: float = spec(0.0, ge=0.0)  # v_lo of the hold [m/s] and the speed that latches it (our choice; 0: off)
    hold_max_mps: float = spec(0.0, ge=0.0)  # v_hi of the hold [m/s] (our choice; 0: no upper side)
    hold_gain_per_s: float = spec(0.0, ge=0.0)  # k while held [1/s] (our choice; 0: v_ref = clip(U, band))
    hold_buffer_time_s: float = spec(0.0, ge=0.0)  # c while held [s] (our choice)
    # the hold releases when U falls below hold_release_mps (a jam the floor would keep the car driving into: it must
    # slow down to collect it), and latches again when U is back at hold_min_mps; 0: it never releases
    hold_release_mps: float = spec(0.0, ge=0.0)  # [m/s] (our choice; 0: off)
    # ... and it holds only while the ring is calm: it latches only with σ_l <= hold_sigma_mps and releases when
    # σ_l > hold_sigma_mps (a wave grows that the car must collect in its gap); 0: off
    hold_sigma_mps: float = spec(0.0, ge=0.0)  # [m/s] (our choice; 0: off)
    # the follower term (leading cruise control: Wang, Zheng, Chen, Xu, Li 2022, IEEE T-ITS 23(8); DeeP-LCC,
    # Wang, Zheng, Li, Xu 2023, IEEE T-CST 31(6)): the car measures the vehicle behind it (a rear radar: its gap
    # h_f to the car and its speed v_f), predicts it over the horizon with a human model linearised at the
    # equilibrium at v_ref (``follower_law``) and penalises w_f (v_f − v_ref)² (and w_fT at the end): it shapes its
    # own motion so that the driver behind it stays at the reference speed (pulls it along instead of only holding
    # its own speed). 0 and 0: off (the problem is built without the follower states, as before the term)
    follower_speed_weight: float = spec(0.0, ge=0.0)  # w_f [W/kg per (m/s)²] (our choice; 0: off, the default: in
    # SUMO's IDM ring it made the spread worse; its merge stop, the law's NaN above v0, is fixed by the guards of
    # WaveMPC.usable_follower; docs/guide/studies.md). The calibrated
    # ring sets 300 (scenarios/ring_wave.toml's [ring.wave]): screened on its seeds 0–19 at 30, 100, 300, 1000
    # (speed-std ratio 0.172, 0.151, 0.146, 0.142 against 0.183 off), evaluated once on the fresh seeds 120–139
    # (0.144 against 0.167 off)
    follower_terminal_speed_weight: float = spec(0.0, ge=0.0)  # w_fT [J/kg per (m/s)²] (our choice; 0: off)
    # the rear radar's range for the term: a follower farther behind than this is no follower (its linearised law,
    # valid near the equilibrium gap, would predict an absurd acceleration; SUMO's merge: a follower 133-148 m behind
    # on the ramp); the term is also off while v_ref is above FOLLOWER_V0_SHARE of the law's desired speed v0,
    # where the law has no equilibrium (the merge's 23 m/s against the calibrated v0 = 16.35 m/s: NaN in the problem)
    follower_range_m: float = spec(60.0, gt=0.0)  # [m] (our choice: the gap ceiling's s_max; checked on the seen
    # SUMO merge seed 102 and calibrated-ring seeds 0-4, where it never acts; fresh: docs/guide/studies.md)
    # the human model of the prediction: the IDM with the calibrated ring population's median parameters
    # (aev_ocp.ring.humans.CALIBRATED["sugiyama_idm"], fitted to Sugiyama et al. 2008), no reaction time
    follower_law: IDM = spec(
        kind="instance",
        cls=IDM,
        default_factory=lambda: IDM(a_mps2=1.364, b_mps2=1.5, v0_mps=16.35, s0_m=2.0, T_s=0.716),
    )
    # the traffic problem's ω, heat, a², jerk terms and its soft gap floor (time_headway_s: T_min; ISO 15622
    # allows ACC time gaps from 0.8 s); its predecessor-speed and time-gap tracking weights are set to 0
    traffic: TrafficParams = spec(
        kind="instance", cls=TrafficParams, default_factory=lambda: TrafficParams(time_headway_s=0.8)
    )

    def __post_init__(self) -> None:
        validate_fields(self)
        if self.max_ref_mps > 0 and self.min_ref_mps > self.max_ref_mps:
            raise ParameterError(
                f"WaveParams: min_ref_mps = {self.min_ref_mps:g} m/s is above max_ref_mps = {self.max_ref_mps:g} "
                "m/s: the speed band of v_ref is empty"
            )
        if self.hold_max_mps > 0 and self.hold_min_mps > self.hold_max_mps:
            raise ParameterError(
                f"WaveParams: hold_min_mps = {self.hold_min_mps:g} m/s is above hold_max_mps = {self.hold_max_mps:g} "
                "m/s: the held speed band is empty"
            )
        if self.hold_release_mps > 0 and not self.hold_release_mps < self.hold_min_mps:
            raise ParameterError(
                f"WaveParams: hold_release_mps = {self.hold_release_mps:g} m/s must be below hold_min_mps = "
                f"{self.hold_min_mps:g} m/s (the hold would release as it latches)"
            )
        if self.hold_max_mps > 0 and self.hold_min_mps == 0:
            raise ParameterError(
                f"WaveParams: hold_max_mps = {self.hold_max_mps:g} m/s needs hold_min_mps > 0 (the speed that latches "
                "the hold)"
            )


def wave_problem(ev: EVParams, wp: WaveParams | None = None, dt: float = 0.1, name: str = "wave") -> ProblemBuilder:
    """The wave-damping problem (module docstring) as a builder in ``ev``'s model units: the traffic problem's
    states (h, v, V1, V2, S, a_prev) plus the own state ``v_ref`` [model speed], its controls plus ``slack_band``,
    stage parameters (v̄_l, v̂_l). ``dt`` [model time] is the MPC interval."""
    wp = wp or WaveParams()
    if not isinstance(wp, WaveParams):
        raise ParameterError(f"wave_problem: wp must be a WaveParams, got {type(wp).__name__}")
    tp = replace(wp.traffic, relative_speed_weight=0.0, gap_weight=0.0, terminal_gap_weight=0.0)
    pb = traffic_problem(ev, tp, dt, name=name)
    u = ev.units
    T = u.time_s
    v_ref = pb.state("v_ref")
    pb.set_der(v_ref, 0.0)
    h_m, v_ms, vr_ms = u.length_to_si(pb.x["h"]), u.speed_to_si(pb.x["v"]), u.speed_to_si(v_ref)
    h_c = wp.centre_gap_m + wp.centre_time_gap_s * v_ms
    pb.add_stage_cost(T * wp.speed_weight * (v_ms - vr_ms) ** 2, "speed_ref")
    pb.add_stage_cost(T * wp.gap_weight * (h_m - h_c) ** 2, "gap_centre")
    sig = pb.control("slack_band", 0.0, SLACK_MAX_M / u.length_m)
    sig_m = u.length_to_si(sig)
    pb.subject_to(h_m - sig_m - wp.max_time_gap_s * v_ms, -ca.inf, wp.max_gap_m, name="band_max")
    pb.add_stage_cost(T * (wp.band_penalty * sig_m + 1e-3 * sig_m**2), "penalty_band")
    pb.add_terminal_cost(wp.terminal_speed_weight * (v_ms - vr_ms) ** 2 + wp.terminal_gap_weight * (h_m - h_c) ** 2)
    if wp.follower_speed_weight > 0 or wp.follower_terminal_speed_weight > 0:
        add_follower(pb, wp, u)
    pb.meta.update({"wave": wp})
    return pb


#: the term predicts the follower only while v_ref <= this share of its law's v0 (at v0 the IDM's equilibrium gap is
#: infinite; at 0.9 v0 it is 1.9 times the gap s0 + T v: our choice)
FOLLOWER_V0_SHARE = 0.9

#: the follower states of the wave problem (its gap to the car [model length], its speed [model speed]) and the
#: switch of the follower term (1: a follower is measured, 0: none; constant over the horizon)
FOLLOWER_STATES = ("h_f", "v_f", "follower_on")


def follower_linearisation(law: IDM, v_star: Any) -> tuple[Any, Any, Any, Any]:
    """The human law linearised at its equilibrium at speed v* [m/s] (SI, numbers or CasADi expressions):
    (h*(v*) [m], ∂a/∂h [1/s²], ∂a/∂v [1/s], ∂a/∂v_l [1/s]), so a ≈ α_h (h − h*) + α_v (v − v*) + α_l (v_l − v*)
    (the linearised car-following model of Wang et al. 2022's leading cruise control). h* solves a(h*, v*, v*) = 0: h* = (s0 + v* T)/√(1 − (v*/v0)^δ)."""
    h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("v_l")
    acc = idm_accel(h, v, vl, law.a_mps2, law.b_mps2, law.v0_mps, law.s0_m, law.T_s, law.delta)
    jac = ca.Function("follower_jac", [h, v, vl], [ca.jacobian(acc, ca.vertcat(h, v, vl))])
    h_star = (law.s0_m + v_star * law.T_s) / ca.sqrt(1.0 - (v_star / law.v0_mps) ** law.delta)
    g = jac(h_star, v_star, v_star)
    return h_star, g[0], g[1], g[2]


def add_follower(pb: ProblemBuilder, wp: WaveParams, units: Units) -> None:
    """Add the follower (h_f, v_f) and its term to the wave problem ``pb`` (states ``v`` and ``v_ref``, model
    ``units``; module docstring and WaveParams' ``follower_*``): dh_f/dt = v − v_f, dv_f/dt = the law linearised at
    v* = v_ref (:func:`follower_linearisation`), cost w_f (v_f − v_ref)² while the own state ``follower_on`` is 1."""
    T = units.time_s
    v, v_ref = pb.x["v"], pb.x["v_ref"]
    h_f, v_f, on = (pb.state(n) for n in FOLLOWER_STATES)
    v_ms, vr_ms = units.speed_to_si(v), units.speed_to_si(v_ref)
    hf_m, vf_ms = units.length_to_si(h_f), units.speed_to_si(v_f)
    h_star, a_h, a_v, a_l = follower_linearisation(wp.follower_law, vr_ms)
    acc = a_h * (hf_m - h_star) + a_v * (vf_ms - vr_ms) + a_l * (v_ms - vr_ms)
    pb.set_der(h_f, v - v_f)
    pb.set_der(v_f, units.accel_from_si(acc))
    pb.set_der(on, 0.0)
    # (on (v_f − v_ref))², not on (v_f − v_ref)²: at on = 0 its Hessian then couples nothing (its cross terms carry the
    # factor on), so no follower leaves the car's solution that of the weight-0 problem (to round-off)
    e_f = on * (vf_ms - vr_ms)
    pb.add_stage_cost(T * wp.follower_speed_weight * e_f**2, "follower_speed")
    pb.add_terminal_cost(wp.follower_terminal_speed_weight * e_f**2)


@dataclass
class SpeedAverage:
    """The mean of the last ``n`` measured speeds (the own-speed estimate of the downstream average speed)."""

    n: int
    _buf: deque[float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.n, int) and self.n >= 1):
            raise ParameterError(f"SpeedAverage.n = {self.n!r} must be an integer >= 1")
        self._buf = deque(maxlen=self.n)

    def reset(self) -> None:
        """Forget every sample."""
        self._buf.clear()

    @property
    def value(self) -> float:
        """The mean of the window (NaN before the first sample)."""
        return float(np.mean(self._buf)) if self._buf else float("nan")

    def update(self, v: float) -> float:
        """Add one speed sample and return the mean of the window."""
        self._buf.append(float(v))
        return float(np.mean(self._buf))


def spread(samples: Sequence[float], detrend: bool = False) -> float:
    """The population std of ``samples`` [their unit]; ``detrend``: about their least-squares line over the sample
    index instead of their mean (a linear trend has spread 0)."""
    y = np.asarray(samples, dtype=float)
    if not detrend or y.size < 2:
        return float(np.std(y))
    x = np.arange(y.size, dtype=float) - 0.5 * (y.size - 1)
    r = y - y.mean()
    r = r - (x @ r) / (x @ x) * x
    return float(np.sqrt(np.mean(r * r)))


class WaveMPC(MPCPolicy):
    """The wave-damping MPC as a :class:`~aev_ocp.loop.Controller`: every step v_ref = the mean of its own
    measured speed over the last ``window_s`` (:class:`SpeedAverage`), then the policy's forecast, warm-started
    solve, safety filter and fallback (:class:`~aev_ocp.mpc.policy.MPCPolicy`). ``fallback_law``: the law applied
    when a solve fails (with the safe controller); ``predictor``: a forecast of the predecessor from the car's own
    measurements (default 'decaying-acceleration', the settings' default)."""

    def __init__(
        self,
        ev: EVParams,
        fallback_law: CarFollowingLaw,
        params: WaveParams | None = None,
        settings: MPCSettings | None = None,
        predictor: str | None = None,
    ) -> None:
        s = settings if settings is not None else MPCSettings()
        if not isinstance(s, MPCSettings):
            raise ParameterError(f"WaveMPC: settings must be an MPCSettings, got {type(s).__name__}")
        self.params = params if params is not None else WaveParams()
        pb = wave_problem(ev, self.params, s.dt)
        pred_name = predictor if predictor is not None else s.predictor
        if pred_name in ("oracle", "cooperative"):
            raise ParameterError(
                f"WaveMPC: predictor = {pred_name!r} is not allowed: the wave MPC forecasts from its own "
                "measurements (constant-velocity, constant-acceleration, decaying-acceleration)"
            )
        pred = make_predictor(pred_name, None, s.predictor_window, ev.units.time_s)
        super().__init__(s, ev, fallback_law, pred, formulation=problem_formulation(pb))
        self._filter = True  # every command through the safe bound, as the traffic MPC's
        self.name = WAVE_NAME
        self.units = ev.units
        dt_s = float(ev.units.time_to_si(s.dt))
        n_win = max(1, int(round(self.params.window_s / dt_s)))
        self.average = SpeedAverage(n_win)
        self.gap_average = SpeedAverage(n_win)  # the mean measured gap h̄ of the catch-up term
        self.predecessor_speeds = SpeedAverage(n_win)  # the predecessor's measured speeds (σ_l of the buffer)
        self.v_ref = float("nan")  # the last reference [model speed]
        self.buffer_m = 0.0  # the adaptive wave buffer b [m] (WaveParams.buffer_rate)
        self._dt_s = dt_s
        self.armed = False  # the mean speed U has been below WaveParams.hold_min_mps
        self.held = False  # the latched speed hold engaged (armed, then U >= hold_min_mps)
        # the problem predicts the follower (WaveParams.follower_*): fed from Observation.follower; a step without a
        # measured follower is the follower-less wave MPC's (built at the first such step, sharing the averages)
        self.with_follower = self.params.follower_speed_weight > 0 or self.params.follower_terminal_speed_weight > 0
        self._build = (ev, fallback_law, s, predictor)
        self._plain: WaveMPC | None = None
        self._plain_last = False  # the last step was the follower-less one's

    def reset(self) -> None:
        """Forget the warm start, the speed and gap averages and the latched hold."""
        super().reset()
        if self._plain is not None:
            self._plain.controller.reset()
        self._plain_last = False
        self.armed = self.held = False
        self.average.reset()
        self.gap_average.reset()
        self.predecessor_speeds.reset()
        self.v_ref = float("nan")
        self.buffer_m = 0.0

    def reference(self, h: float, v: float, lane_end: bool = False) -> float:
        """Add one measured gap h and own speed v [model units] to the averages and return v_ref [model speed]
        = U + clip(k (h̄ − s_t − T_t U − c σ_l), −v_c, v_c⁺) (U the mean own speed, h̄ the mean gap, σ_l the std of the
        predecessor's speed; v_c⁺ = v_c unless ``catch_rise_max_mps`` is set; WaveParams), then within the band
        [v_lo, v_hi] when set, and never below 0. Once the latched hold is engaged (``hold_min_mps``: from the first
        step with U >= hold_min_mps on) k and c are ``hold_gain_per_s`` and ``hold_buffer_time_s`` and v_ref is then
        clipped to [hold_min_mps, hold_max_mps]; the hold latches at the first step with U >= hold_min_mps after one
        with U < hold_min_mps, and releases at a step with U < hold_release_mps. ``lane_end``: h is the distance to
        the end of the car's lane, not a gap to a vehicle, and is not added to h̄ (h̄ of the gaps so far, h before
        the first)."""
        p, u = self.params, self.units
        U = self.average.update(v)
        if lane_end:
            h_bar = float(u.length_to_si(self.gap_average.value if self.gap_average._buf else h))
        else:
            h_bar = float(u.length_to_si(self.gap_average.update(h)))
        buf = self.predecessor_speeds._buf
        sigma_l = float(u.speed_to_si(spread(buf, p.detrend_sigma))) if buf else 0.0
        beta = p.base_predecessor_share
        if p.buffer_rate > 0:
            db = self._dt_s * p.buffer_rate * (sigma_l - p.buffer_sigma_mps)
            self.buffer_m = min(max(self.buffer_m + db, 0.0), p.buffer_max_m)
            if p.buffer_max_m > 0:  # the wave's share of the buffer takes the base back to the own mean
                beta *= 1.0 - self.buffer_m / p.buffer_max_m
        if beta > 0 and buf:
            U = (1.0 - beta) * U + beta * float(np.mean(buf))
        U_si = float(u.speed_to_si(U))
        if p.hold_min_mps > 0:
            self.armed = self.armed or U_si < p.hold_min_mps
            calm = p.hold_sigma_mps <= 0 or sigma_l <= p.hold_sigma_mps
            self.held = calm and ((self.held and U_si >= p.hold_release_mps) or (self.armed and U_si >= p.hold_min_mps))
        gain, c = (p.hold_gain_per_s, p.hold_buffer_time_s) if self.held else (p.catch_gain_per_s, p.buffer_time_s)
        h_t = p.target_gap_m + p.target_time_gap_s * U_si + c * sigma_l + self.buffer_m
        catch = gain * (h_bar - h_t)
        rise = p.catch_rise_max_mps if p.catch_rise_max_mps > 0 else p.catch_max_mps
        catch = min(max(catch, -p.catch_max_mps), rise)
        ref = U + float(u.speed_from_si(catch))
        if p.min_ref_mps > 0:
            ref = max(ref, float(u.speed_from_si(p.min_ref_mps)))
        if p.max_ref_mps > 0:
            ref = min(ref, float(u.speed_from_si(p.max_ref_mps)))
        if self.held:
            ref = max(ref, float(u.speed_from_si(p.hold_min_mps)))
            if p.hold_max_mps > 0:
                ref = min(ref, float(u.speed_from_si(p.hold_max_mps)))
        return max(0.0, ref)

    def own_states(self, obs: Observation) -> dict[str, float]:
        """The policy's own states plus v_ref [model speed] (:meth:`reference`, this step's measurements included).
        At the end of its lane (``obs.lane_end``) v_ref is the lane's speed limit (``obs.speed_limit``) when known: the
        car must merge into the next lane's traffic, as a driver accelerates along an acceleration lane (its
        braking-distance constraint to the lane's end still stops it there if it finds no gap); the lane's end is no
        predecessor, so neither its speed nor its distance enters the averages."""
        own = super().own_states(obs)
        fol = self.usable_follower(obs) if self.with_follower else None  # decided as command() did (the last v_ref)
        # (the end of a lane is no predecessor: its "speed" 0 is not the traffic's)
        if len(obs.meas_v) and not obs.lane_end:
            self.predecessor_speeds.update(float(obs.meas_v[-1]))
        v_ref = self.reference(float(obs.z[0]), float(obs.z[1]), obs.lane_end)
        if obs.lane_end and obs.merge_speed is not None:  # it must merge: at the speed that reaches a gap
            v_ref = float(obs.merge_speed)
        elif obs.lane_end and obs.speed_limit is not None:  # without one, it drives up to the road's speed
            v_ref = float(obs.speed_limit)
        self.v_ref = own["v_ref"] = v_ref
        if self.with_follower:
            if fol is None:  # no follower measured (command() hands such a step to without_follower()): term off
                own.update(h_f=float(obs.z[0]), v_f=float(obs.z[1]), follower_on=0.0)
            else:
                own.update(h_f=float(fol[0]), v_f=float(fol[1]), follower_on=1.0)
        return own

    def usable_follower(self, obs: Observation) -> np.ndarray | None:
        """The measured follower (its gap [model length], its speed [model speed]) if the term may use it, else None:
        none measured, its gap beyond ``follower_range_m``, or the step's speed (the last v_ref; the own measured
        speed before the first) above FOLLOWER_V0_SHARE of the follower law's v0 (v_ref moves by far less than the
        margin in one step)."""
        fol, u = obs.follower, self.units
        if fol is None or float(u.length_to_si(fol[0])) > self.params.follower_range_m:
            return None
        v_star = self.v_ref if np.isfinite(self.v_ref) else float(obs.z[1])
        if float(u.speed_to_si(v_star)) > FOLLOWER_V0_SHARE * self.params.follower_law.v0_mps:
            return None
        return fol

    def without_follower(self) -> "WaveMPC":
        """The wave MPC without the follower term (the follower weights 0: the problem without its states) that
        commands the steps without a measured follower, built at the first; it shares this one's averages."""
        if self._plain is None:
            ev, law, s, pred = self._build
            p = replace(self.params, follower_speed_weight=0.0, follower_terminal_speed_weight=0.0)
            self._plain = WaveMPC(ev, law, p, s, pred)
            self._plain.average, self._plain.gap_average = self.average, self.gap_average
            self._plain.predecessor_speeds = self.predecessor_speeds
        return self._plain

    def command(self, obs: Observation) -> Command:
        """The policy's command with v_ref in its info; with the follower term and no measured follower, the
        command of :meth:`without_follower` (so such a step is exactly the follower-less MPC's; a switch between the
        two forgets the warm start of the one taking over)."""
        if self.with_follower and self.usable_follower(obs) is None:
            plain = self.without_follower()
            if not self._plain_last:
                plain.controller.reset()
            plain.armed, plain.held, plain.buffer_m = self.armed, self.held, self.buffer_m
            cmd = plain.command(obs)
            self.armed, self.held, self.buffer_m = plain.armed, plain.held, plain.buffer_m
            self.v_ref, self._plain_last = plain.v_ref, True
            return cmd
        if self._plain_last:
            self.controller.reset()
            self._plain_last = False
        cmd = super().command(obs)
        cmd.info["v_ref_mps"] = float(self.units.speed_to_si(self.v_ref))
        cmd.info["buffer_m"] = self.buffer_m
        return cmd

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d["controller"] = WAVE_NAME
        d["wave"] = as_dict(self.params)
        return d


def sumo_controller(ev: EVParams) -> WaveMPC:
    """A new wave MPC for one SUMO vehicle (``controller = "aev_ocp.mpc.wave:sumo_controller"`` in ``[sumo]``):
    the default WaveParams and MPCSettings, the paper's proposed law (Proposed()) as its fallback."""
    from ..models.carfollowing import Proposed

    return WaveMPC(ev, Proposed())


def linear_gains(
    ev: EVParams,
    params: WaveParams | None = None,
    settings: MPCSettings | None = None,
    *,
    h_m: float,
    v_mps: float,
    dh_m: float = 0.5,
    dv_mps: float = 0.25,
) -> dict[str, float]:
    """The converged first move a = f(h, v, v_l) of the wave problem at a steady state (gap h_m [m], speed v_mps
    [m/s], predecessor and v_ref at v_mps, a_prev = 0) as secant gains over ±dh_m, ±dv_mps (central differences of
    IPOPT solves, tol 1e-10): f_h [1/s²], f_v [1/s] (at fixed Δv = v_l − v, v_ref held) and f_Δv [1/s], as
    :mod:`aev_ocp.stability.mixed` takes them, and a0 [m/s²] the move at the point itself. Secant, not tangent:
    the battery-power epigraph makes the first move piecewise linear with a dead band around a = 0 (a small
    deviation is cheaper to coast through than to correct), where the tangent gains are 0; the secant gains over
    the deviations of a forming wave are the ones that decide whether it grows. The follower term is left out (its
    weights 0: the theory's car reacts to its predecessor only)."""
    s = (settings or MPCSettings()).with_(solver="ipopt", tol=1e-10, codegen=False)
    params = replace(params or WaveParams(), follower_speed_weight=0.0, follower_terminal_speed_weight=0.0)
    pb = wave_problem(ev, params, s.dt)
    ctl = MPCController(s, ev, formulation=problem_formulation(pb))
    u, N = ev.units, s.N
    z_cell = np.array([0.0, 0.0, float(ev.cell.soc0)])

    def first(h: float, v: float, vl: float) -> float:
        ctl.reset()
        z0 = np.concatenate([[float(u.length_from_si(h)), float(u.speed_from_si(v))], z_cell])
        vlm = np.full(N, float(u.speed_from_si(vl)))
        sol = ctl.solve(z0, vlm, vlm, own={"a_prev": 0.0, "v_ref": float(u.speed_from_si(v_mps))})
        if not sol.success:
            raise ParameterError(f"linear_gains: the wave problem failed at h = {h:g} m, v = {v:g} m/s: {sol.status}")
        return float(u.accel_to_si(sol.a[0]))

    if not (dh_m > 0 and dv_mps > 0 and h_m > dh_m and v_mps > dv_mps):
        raise ParameterError(
            f"linear_gains: need 0 < dh_m < h_m and 0 < dv_mps < v_mps, got {dh_m}, {h_m}, {dv_mps}, {v_mps}"
        )
    dh, dv = float(dh_m), float(dv_mps)
    f_h = (first(h_m + dh, v_mps, v_mps) - first(h_m - dh, v_mps, v_mps)) / (2 * dh)
    f_dv = (first(h_m, v_mps, v_mps + dv) - first(h_m, v_mps, v_mps - dv)) / (2 * dv)
    f_v = (first(h_m, v_mps + dv, v_mps + dv) - first(h_m, v_mps - dv, v_mps - dv)) / (2 * dv)
    return {"f_h_per_s2": f_h, "f_v_per_s": f_v, "f_dv_per_s": f_dv, "a0_mps2": first(h_m, v_mps, v_mps)}


__all__ = [
    "FOLLOWER_V0_SHARE",
    "WAVE_NAME",
    "SpeedAverage",
    "WaveMPC",
    "WaveParams",
    "linear_gains",
    "sumo_controller",
    "wave_problem",
]
