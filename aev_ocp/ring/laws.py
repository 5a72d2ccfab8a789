"""Human-driver and wave-dampening laws for rings, with their published constants (SI in, model units out).

* :func:`idm_si`: the Intelligent Driver Model (Treiber, Hennecke & Helbing 2000, Phys. Rev. E 62:1805) from SI
  parameters, the toolkit's SI :class:`~aev_ocp.models.carfollowing.IDM` given a scenario's model units.
* :class:`FollowerStopper`: Stern et al. 2018 (Transportation Research Part C 89:205–221, "Dissipation of
  stop-and-go waves via control of autonomous vehicles: field experiments"), §3.1: a commanded speed from the gap
  Δx and the relative speed Δv = v_l − v, tracked by the car's speed loop (modelled as a first-order lag τ).
* :class:`PISaturation`: the same paper, §3.2, "PI with saturation": a sampled controller (it keeps the mean of
  its own past speeds and its last command), so it is a :class:`~aev_ocp.control.Controller`.

The constants (FollowerStopper Δx⁰ = 4.5, 5.25, 6.0 m and d = 1.5, 1.0, 0.5 m/s²; PI: g_l = 7 m, g_u = 30 m,
v_catch = 1 m/s, γ = 2 m, Δx_s = max(2Δv, 4 m), β = 1 − α/2, a 38 s speed average) are those of the paper as
reproduced in public re-implementations (the Flow project's FollowerStopper/PISaturation controllers), checked
against each other; the paper's own text was not available here. The speed loop τ is our modelling choice
(the field car's cruise controller is not published): :data:`SPEED_LOOP_S`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from ..control import Command, Observation
from ..models.carfollowing import IDM, CarFollowingLaw, register_law
from ..params import CarFollowingParams, EVParams, ParameterError, Units

#: τ [s] of the speed loop that tracks a commanded speed: a = (v_cmd − v)/τ. Our choice (Stern et al. 2018 drove
#: a production car's velocity controller, not published); 0.6 s is a typical ACC speed-loop time constant.
SPEED_LOOP_S = 0.6

#: IDM (Treiber et al. 2000, Table 1 city-traffic values as used for ring roads in the Flow benchmarks,
#: Wu et al. 2017): a = 1 m/s², b = 1.5 m/s², v0 = 30 m/s, T = 1 s, s0 = 2 m, δ = 4.
IDM_SI = {"a_mps2": 1.0, "b_mps2": 1.5, "v0_mps": 30.0, "s0_m": 2.0, "T_s": 1.0}


def idm_si(
    units: Units, a_mps2: float = 1.0, b_mps2: float = 1.5, v0_mps: float = 30.0, s0_m: float = 2.0, T_s: float = 1.0
) -> IDM:
    """The IDM with SI parameters (defaults :data:`IDM_SI`) in the model units ``units``
    (:class:`~aev_ocp.models.carfollowing.IDM` given ``units``)."""
    for name, val in (("a_mps2", a_mps2), ("b_mps2", b_mps2), ("v0_mps", v0_mps), ("s0_m", s0_m), ("T_s", T_s)):
        ok = isinstance(val, (int, float)) and math.isfinite(val) and (val >= 0 if name == "s0_m" else val > 0)
        if not ok:
            raise ParameterError(
                f"idm: {name} = {val!r} is not allowed: must be a finite number {'>= 0' if name == 's0_m' else '> 0'}"
            )
    law = IDM(a_mps2=float(a_mps2), b_mps2=float(b_mps2), v0_mps=float(v0_mps), s0_m=float(s0_m), T_s=float(T_s))
    return replace(law, model_units=units)


#: The Bando-FTL human driver (Bando et al. 1995's optimal velocity plus a follow-the-leader term) with the Flow
#: project's BandoFTLController defaults (flow/controllers/car_following_models.py: α = 0.5 1/s, β = 20 m²/s,
#: h_st = 2 m, v_max = 32 m/s); the ring's calibrated drivers refit v_max and h_st (aev_ocp.ring.humans)
BANDO_FTL_SI = {"alpha_per_s": 0.5, "beta_m2ps": 20.0, "h_st_m": 2.0, "v_max_mps": 32.0}
_TANH2 = math.tanh(2.0)


@dataclass(frozen=True)
class BandoFTL(CarFollowingLaw):
    """Bando-FTL in SI: v̇ = α (V(h) − v) + β (v_l − v)/h², V(h) = v_max (tanh(h/h_st − 2) + tanh 2)/(1 + tanh 2)
    (h the bumper-to-bumper gap [m]); evaluated in SI unless given model units (:meth:`in_units`)."""

    alpha_per_s: float = 0.5  # Flow's BandoFTLController default (BANDO_FTL_SI)
    beta_m2ps: float = 20.0  # same
    h_st_m: float = 2.0  # same
    v_max_mps: float = 32.0  # same
    model_units: Units | None = None
    name = "bandoftl"
    has_si: ClassVar[bool] = True
    _positive = ("alpha_per_s", "h_st_m", "v_max_mps")
    _nonnegative = ("beta_m2ps",)

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        u = self.model_units
        if u is not None:
            h, v, v_l = u.length_to_si(h), u.speed_to_si(v), u.speed_to_si(v_l)
        V = self.v_max_mps * (ca.tanh(h / self.h_st_m - 2.0) + _TANH2) / (1.0 + _TANH2)
        a = self.alpha_per_s * (V - v) + self.beta_m2ps * (v_l - v) / (h * h)
        return a if u is None else u.accel_from_si(a)

    def in_units(self, units: Units) -> "CarFollowingLaw":
        if not isinstance(units, Units):
            raise ParameterError(f"BandoFTL.in_units: units must be a Units, got {type(units).__name__}")
        return replace(self, model_units=units)

    def equilibrium_gap_m(self, v_mps: float) -> float:
        """V⁻¹(v) = h_st (2 + atanh(v (1 + tanh 2)/v_max − tanh 2)) [m] for 0 ≤ v < v_max."""
        v = float(v_mps)
        if not 0.0 <= v < self.v_max_mps:
            raise ParameterError(
                f"BandoFTL: no equilibrium gap at v = {v!r} m/s: must be in [0, v_max = {self.v_max_mps!r})"
            )
        return self.h_st_m * (2.0 + math.atanh(v * (1.0 + _TANH2) / self.v_max_mps - _TANH2))


register_law("bandoftl", BandoFTL)


def follower_stopper_speed(
    gap: Any, v: Any, v_l: Any, r: Any, dx0: tuple[Any, Any, Any], d: tuple[Any, Any, Any]
) -> Any:
    """FollowerStopper's commanded speed (Stern et al. 2018, eqs. of §3.1), any consistent units:
    Δx_k = Δx⁰_k + Δv₋²/(2 d_k), Δv₋ = min(v_l − v, 0), v̄ = min(max(v_l, 0), r), and
    v_cmd = 0 (Δx ≤ Δx₁); v̄ (Δx − Δx₁)/(Δx₂ − Δx₁) (≤ Δx₂); v̄ + (r − v̄)(Δx − Δx₂)/(Δx₃ − Δx₂) (≤ Δx₃); r beyond."""
    dvm = ca.fmin(v_l - v, 0)
    x1, x2, x3 = (dx0[k] + dvm * dvm / (2 * d[k]) for k in range(3))
    vb = ca.fmin(ca.fmax(v_l, 0), r)
    return ca.if_else(
        gap <= x1,
        0,
        ca.if_else(
            gap <= x2, vb * (gap - x1) / (x2 - x1), ca.if_else(gap <= x3, vb + (r - vb) * (gap - x2) / (x3 - x2), r)
        ),
    )


@dataclass(frozen=True)
class FollowerStopper(CarFollowingLaw):
    """Stern et al. 2018's FollowerStopper in model units: v̇ = (v_cmd(h, v, v_l) − v)/tau
    (:func:`follower_stopper_speed`). Build it from SI with :meth:`from_si`."""

    r: float = 1.3  # desired speed [model speed]; the experimenter's choice in the paper (set per run)
    dx1: float = 0.45  # Δx⁰₁ = 4.5 m at L = 10 m (Stern et al. 2018 §3.1)
    dx2: float = 0.525  # Δx⁰₂ = 5.25 m (same)
    dx3: float = 0.6  # Δx⁰₃ = 6.0 m (same)
    d1: float = 0.6  # d₁ = 1.5 m/s² at U²/L = 2.5 m/s² (same)
    d2: float = 0.4  # d₂ = 1.0 m/s² (same)
    d3: float = 0.2  # d₃ = 0.5 m/s² (same)
    tau: float = 0.3  # SPEED_LOOP_S at T = 2 s
    name = "followerstopper"
    _nonnegative = ("r",)
    _positive = ("dx1", "dx2", "dx3", "d1", "d2", "d3", "tau")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.dx1 < self.dx2 < self.dx3:
            raise ParameterError(
                f"FollowerStopper: dx1 < dx2 < dx3 is required, got {self.dx1}, {self.dx2}, {self.dx3}"
            )

    @classmethod
    def from_si(
        cls,
        units: Units,
        r_mps: float,
        tau_s: float = SPEED_LOOP_S,
        dx0_m: tuple[float, float, float] = (4.5, 5.25, 6.0),
        d_mps2: tuple[float, float, float] = (1.5, 1.0, 0.5),
    ) -> "FollowerStopper":
        """From SI (defaults: Stern et al. 2018 §3.1; r_mps the desired speed [m/s])."""
        lx = [float(units.length_from_si(x)) for x in dx0_m]
        dd = [float(units.accel_from_si(x)) for x in d_mps2]
        return cls(
            r=float(units.speed_from_si(r_mps)),
            dx1=lx[0],
            dx2=lx[1],
            dx3=lx[2],
            d1=dd[0],
            d2=dd[1],
            d3=dd[2],
            tau=float(units.time_from_si(tau_s)),
        )

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        vc = follower_stopper_speed(h, v, v_l, self.r, (self.dx1, self.dx2, self.dx3), (self.d1, self.d2, self.d3))
        return (vc - v) / self.tau


register_law("followerstopper", FollowerStopper)


@dataclass
class PISaturation:
    """Stern et al. 2018's "PI with saturation" (§3.2) as a sampled :class:`~aev_ocp.control.Controller`.

    Every dt: U = mean of the own speed over the last ``window_s``; v_target = U + v_catch·clip((Δx − g_l)/(g_u − g_l));
    Δx_s = max(2 Δv, 4 m) (Δv = v_l − v); α = clip((Δx − Δx_s)/γ); β = 1 − α/2;
    v_cmd ← β (α v_target + (1 − α) v_l) + (1 − β) v_cmd; the acceleration held over dt is (v_cmd − v)/τ.
    All settings SI; ``units`` converts the observation (model units) and the command.
    """

    units: Units = field(default_factory=Units)
    dt_s: float = 0.1  # control period [s] (the field controller ran at 10–20 Hz; 10 Hz here)
    window_s: float = 38.0  # averaging window of U [s] (Stern et al. 2018 §3.2)
    g_l_m: float = 7.0  # (same)
    g_u_m: float = 30.0  # (same)
    v_catch_mps: float = 1.0  # (same)
    gamma_m: float = 2.0  # (same)
    dx_s_min_m: float = 4.0  # Δx_s = max(2 Δv, 4 m) (same)
    tau_s: float = SPEED_LOOP_S  # speed loop (our choice, see SPEED_LOOP_S)
    name: str = "pi-saturation"
    _hist: Any = field(default=None, init=False, repr=False)
    _v_cmd: float | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        for k in ("dt_s", "window_s", "g_u_m", "gamma_m", "tau_s"):
            x = getattr(self, k)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
                raise ParameterError(f"PISaturation.{k} = {x!r} is not allowed: must be a finite number > 0")
        if not self.g_u_m > self.g_l_m:
            raise ParameterError(f"PISaturation: g_u_m = {self.g_u_m} must exceed g_l_m = {self.g_l_m}")
        self.reset()

    @property
    def dt(self) -> float:
        """The control period [model time]."""
        return float(self.units.time_from_si(self.dt_s))

    def reset(self) -> None:
        """Forget the speed history and the last command."""
        self._hist = deque(maxlen=max(1, int(round(self.window_s / self.dt_s))))
        self._v_cmd = None

    def command(self, obs: Observation) -> Command:
        u = self.units
        gap, v, vl = (
            float(u.length_to_si(obs.z[0])),
            float(u.speed_to_si(obs.z[1])),
            float(u.speed_to_si(obs.meas_v[-1])),
        )
        self._hist.append(v)
        U = float(np.mean(self._hist))
        clip = lambda x: min(max(x, 0.0), 1.0)  # noqa: E731
        v_target = U + self.v_catch_mps * clip((gap - self.g_l_m) / (self.g_u_m - self.g_l_m))
        dx_s = max(2.0 * (vl - v), self.dx_s_min_m)
        alpha = clip((gap - dx_s) / self.gamma_m)
        beta = 1.0 - 0.5 * alpha
        prev = v if self._v_cmd is None else self._v_cmd
        self._v_cmd = beta * (alpha * v_target + (1.0 - alpha) * vl) + (1.0 - beta) * prev
        a = (self._v_cmd - v) / self.tau_s
        return Command(float(u.accel_from_si(a)), info={"v_cmd_mps": self._v_cmd})

    def describe(self) -> dict[str, Any]:
        return {
            "controller": self.name,
            "dt_s": self.dt_s,
            "window_s": self.window_s,
            "g_l_m": self.g_l_m,
            "g_u_m": self.g_u_m,
            "v_catch_mps": self.v_catch_mps,
            "gamma_m": self.gamma_m,
            "tau_s": self.tau_s,
        }


#: AEV controllers by name (:func:`make_aev`)
AEV_CONTROLLERS = ("followerstopper", "pi-saturation", "proposed", "ovfl", "mpc", "wave-mpc")
#: predictors a ring MPC may use: forecasts from its own measurements of the predecessor (a ring has no
#: prescribed leader, so no 'oracle'; 'cooperative' would need the predecessor's plan)
RING_PREDICTORS = ("decaying-acceleration", "constant-velocity", "constant-acceleration")


def ring_mpc(
    ev: EVParams,
    settings: Any = None,
    predictor: str | None = None,
    formulation: Any = None,
    cf: CarFollowingParams | None = None,
) -> Any:
    """The toolkit's MPC as a ring AEV: :class:`aev_ocp.mpc.policy.MPCPolicy` with ``settings`` (default
    ``MPCSettings()``), ``formulation`` (default the traffic formulation: its 2 m gap floor, every command
    through the safety filter) and a forecast of the predecessor from the AEV's own measurements (``predictor``, one of
    :data:`RING_PREDICTORS`; default the settings' 'decaying-acceleration'). Fallback law: the proposed law
    (coefficients and scales ``cf``, default CarFollowingParams(); in the ring's units, the same SI law)."""
    from ..mpc.policy import MPCPolicy
    from ..mpc.predictors import make_predictor
    from ..mpc.settings import MPCSettings
    from ..ocp.formulation import traffic_formulation

    s = settings if settings is not None else MPCSettings()
    if not isinstance(s, MPCSettings):
        raise ParameterError(f"ring: mpc settings must be an MPCSettings, got {type(s).__name__}")
    name = predictor if predictor is not None else s.predictor
    if name not in RING_PREDICTORS:
        raise ParameterError(
            f"ring: mpc predictor = {name!r} is not allowed on a ring: must be one of "
            f"{RING_PREDICTORS} (forecasts from the AEV's own measurements)"
        )
    pred = make_predictor(name, None, s.predictor_window, ev.units.time_s)
    fallback = _law("proposed", ev, cf)
    return MPCPolicy(s, ev, fallback, pred, formulation=formulation or traffic_formulation())


def _law(name: str, ev: EVParams, cf: CarFollowingParams | None, **own: float) -> CarFollowingLaw:
    """A registered law with the coefficients and scales ``cf`` (default CarFollowingParams()) and its own
    coefficients ``own``, in ``ev``'s model units (the same SI law whatever the units)."""
    from ..models.carfollowing import make_law

    base = cf if cf is not None else CarFollowingParams()
    return make_law(name, replace(base, model_units=ev.units), **own)


def make_aev(
    name: str,
    ev: EVParams,
    r_mps: float,
    mpc: Any = None,
    cf: CarFollowingParams | None = None,
    own: dict[str, dict[str, Any]] | None = None,
) -> Any:
    """An AEV controller by name: 'followerstopper' (desired speed r_mps), 'pi-saturation', 'proposed' (the
    paper's law), 'ovfl', 'mpc' (:func:`ring_mpc`; ``mpc`` an optional (settings, formulation) pair, default
    MPCSettings() and the traffic formulation), 'wave-mpc' (:class:`aev_ocp.mpc.wave.WaveMPC`, the wave-damping
    MPC; the pair's settings if given, its own formulation), or any registered law name. Laws take their coefficients and
    scales from ``cf`` (default CarFollowingParams()) and run in ``ev``'s units with the same SI behaviour. ``own``:
    {name: keyword arguments} of a law's own coefficients (a scenario's ``[carfollowing.<law>]``, e.g. the IDM's SI
    ``T_s``), of FollowerStopper's :meth:`FollowerStopper.from_si` (``tau_s``, ``dx0_m``, ``d_mps2``) and, under
    'wave-mpc', the wave MPC's :class:`~aev_ocp.mpc.wave.WaveParams` fields (a scenario's ``[ring.wave]``)."""
    mine = dict((own or {}).get(name.lower(), {}))
    key = name.lower()
    if key == "mpc":
        s, f = mpc if mpc is not None else (None, None)
        return ring_mpc(ev, s, None, f, cf)
    if key == "wave-mpc":  # the wave-damping MPC (aev_ocp.mpc.wave); [mpc]'s solver settings when given
        from ..mpc.wave import WaveMPC, WaveParams

        s, _ = mpc if mpc is not None else (None, None)
        return WaveMPC(ev, _law("proposed", ev, cf), WaveParams(**mine) if mine else None, settings=s)
    if key == "followerstopper":
        return FollowerStopper.from_si(ev.units, r_mps, **mine)
    if key == "pi-saturation":
        return PISaturation(units=ev.units)
    return _law(key, ev, cf, **mine)
