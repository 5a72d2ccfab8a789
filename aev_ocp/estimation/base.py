"""The estimator protocol, its estimate, and the model both shipped estimators share.

An :class:`Estimator` turns one vehicle's :class:`~aev_ocp.estimation.sensors.Measurement` stream into an
:class:`Estimate` of what the controllers need (SI): the cell's SOC, V1, V2, the gap and the predecessor's speed
and acceleration. Plug your own in wherever ``estimator=`` is accepted (an object with ``name``, ``reset``,
``update`` and ``describe``).

:class:`EstimationModel` is the discrete model of both shipped estimators, built with CasADi from the same
description as the controller's (:func:`aev_ocp.models.battery.cell_derivatives` and
:func:`~aev_ocp.models.battery.terminal_voltage` of the 2-RC cell, with the model's CellParams): states
x = (S, V1 [V], V2 [V], h [m], v_l [m/s], a_l [m/s²], v [m/s] own speed, ρ0, ρ1, κ1, ρ2, κ2), the last five the
cell's parameters as scales of the model's (R0 = ρ0·R0, R1 = ρ1·R1, C1 = C1/κ1, R2 = ρ2·R2, C2 = C2/κ2: slow
random walks, learnt from the voltage's response to the current: a resistance or capacitance mismatch stays out of
the SOC); inputs u = (I [A per cell], a [m/s²], the acceleration the car applied last), outputs y = (cell terminal
voltage [V], h [m], v_l [m/s], v [m/s]); one RK4 step of length dt_s with u held; the predecessor's acceleration is
a Singer process (da_l/dt = −a_l/τ_a, τ_a = :data:`LEAD_ACCEL_TAU_S`), the own speed follows the applied
acceleration (dv/dt = a).

What 60 s of driving can and cannot tell on the flat LFP plateau (docs/guide/realism.md has the numbers): R0, R1,
C1 are observable (the voltage's response to current steps within seconds); C2 and R2 partly (V2 grows with the
charge and relaxes over τ2 ≈ 100 s); the capacity not at all (60 s move the SOC by < 1 %, and on the plateau that
is < 0.5 mV); an OCV offset not at all: it is indistinguishable from an SOC error, 1/OCV'(S) ≈ 2 % SOC per mV at
S = 0.8 on the shipped cell.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import casadi as ca
import numpy as np

from ..models import battery
from ..params import EVParams, ParameterError
from .sensors import Measurement, Sensors

#: τ_a [s] of the predecessor's acceleration (Singer model): drivers hold an acceleration for a few seconds
#: (the same 2 s as the MPC's decaying-acceleration predictor, aev_ocp.mpc.predictors.DECAY_TIME_S)
LEAD_ACCEL_TAU_S = 2.0
#: σ_a [m/s²] of the predecessor's acceleration (Singer model): urban and US06 drive cycles stay within ±3 m/s²
#: with an RMS of ~0.5-1 m/s² (EPA UDDS/US06 speed traces); 1 m/s² is used
LEAD_ACCEL_SIGMA_MPS2 = 1.0
#: σ [V] of the OCV curve as a model of the real cell (hysteresis, temperature, ageing): LFP cells show a few mV of
#: hysteresis in the 20-90 % plateau (Roscher & Sauer, J. Power Sources 196 (2011) 331); 0.5 mV is kept for
#: the part an estimator cannot model (the hysteresis itself is not modelled)
OCV_MODEL_SIGMA_V = 0.5e-3
#: the model's own process-noise rates [state²/s] of S, V1, V2, h, v_l (a_l: the Singer model): SOC drift from
#: a ~1 % capacity error at a few amperes, V1/V2 at 0.1 mV/√s (the RC model's error: a 2-RC fit leaves ~1 mV of
#: unmodelled polarisation over a minute of driving; 0.1 mV/√s lets V1/V2 absorb it instead of the SOC: on seeded
#: draws of the declared mismatch at true SOC 0.35/0.55/0.8 the largest SOC error after 60 s fell from 0.83 % at
#: 0.02 mV/√s to 0.54 %, at 0.5 mV/√s the learnt R1 scale blurs by ~0.12), h and v_l at 0.01 /√s
OWN_NOISE_RATES = ((1e-6) ** 2, (1e-4) ** 2, (1e-4) ** 2, 1e-4, 1e-4)
#: rate [m²/s³] of the own speed's process noise: the applied acceleration is not the realised one (the actuator's
#: lag and saturation, road grade, wind): ~0.3 m/s² over a 0.2 s step -> 0.3² × 0.2 ... taken as 0.05 m²/s³
OWN_SPEED_NOISE_RATE = 0.05
#: the cell's parameters the estimators learn, as scales of their model's values (random-walk states after the
#: motion states): the ohmic resistance R0 = ρ0·R0, the RC branches' resistances R1 = ρ1·R1, R2 = ρ2·R2 and
#: their capacitances C1 = C1/κ1, C2 = C2/κ2 (κ multiplies 1/C, so each branch's dV/dt is linear in it)
PARAM_NAMES = ("rho0", "rho1", "kappa1", "rho2", "kappa2")
#: σ of each initial scale: the cell-to-cell and ageing spread of the 2-RC parameters, ±20 % (the mismatch the
#: issue declares for R0/R1/R2, C1/C2; LFP cells of one batch spread by ~5-10 % in resistance and more after
#: ageing, Dubarry et al., J. Power Sources 196 (2011) 10328)
PARAM_SCALE_SIGMA = 0.2
#: random-walk rate [1/s] of each scale: the resistances fall ~3 %/K with temperature (Arrhenius, E_a ≈ 20-30
#: kJ/mol) and a pack warms by well under 1 K/min on a drive cycle (the thermal plant: ~0.1 K/min on US06), i.e.
#: ≲ 0.05 %/s: a random walk of 3e-4/√s spreads 0.2 % over 60 s and lets a scale follow that drift
PARAM_SCALE_RATE = 3e-4
#: the scales are kept in [PARAM_SCALE_MIN, PARAM_SCALE_MAX] by the measurement update (a guard: a scale near 0
#: would make an RC branch's time constant vanish)
PARAM_SCALE_MIN, PARAM_SCALE_MAX = 0.3, 3.0
#: σ [V] of V1 and V2 at the start: a car starts after a rest, and the RC voltages relax with τ1 ≈ 4 s and τ2 ≈ 100 s
#: (CellParams); after a 10-minute park V2 keeps e^-6 ≈ 0.25 % of its value, ≲ 0.05 mV of the ≲ 20 mV a drive
#: leaves (R2·I at a few amperes per cell): 0.1 mV is kept
RC_REST_SIGMA_V = 1e-4
NX = 7 + len(PARAM_NAMES)  # states of the estimation model
STATE_NAMES = ("S", "V1", "V2", "h", "v_l", "a_l", "v", *PARAM_NAMES)
#: indices of the battery's states (S, V1, V2 and the scales) and of the motion states (h, v_l, a_l, v): the two
#: parts do not interact (their covariance stays block-diagonal)
BATTERY = (0, 1, 2, *range(7, NX))
MOTION = (3, 4, 5, 6)


class ScaledCell:
    """``cell`` with R_s, R1, R2 times ρ0, ρ1, ρ2 and C1, C2 divided by κ1, κ2 (numbers or CasADi expressions);
    every other attribute (capacity, OCV table) is the cell's: passed where the battery model reads a CellParams."""

    def __init__(self, cell: Any, rho0: Any, rho1: Any, kappa1: Any, rho2: Any, kappa2: Any) -> None:
        self.base = cell
        self.R_s_ohm, self.R1_ohm, self.R2_ohm = rho0 * cell.R_s_ohm, rho1 * cell.R1_ohm, rho2 * cell.R2_ohm
        self.C1_F, self.C2_F = cell.C1_F / kappa1, cell.C2_F / kappa2

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


@dataclass(frozen=True)
class Estimate:
    """What an estimator believes (SI): SOC [-], V1, V2 [V], gap [m], predecessor speed [m/s] and acceleration
    [m/s²], own speed [m/s] (NaN: not estimated, the measured one is used); ``std``: 1-σ of each (the order of
    :data:`STATE_NAMES`; empty when unknown)."""

    soc: float
    V1_V: float
    V2_V: float
    gap_m: float
    lead_speed_mps: float
    lead_accel_mps2: float
    speed_mps: float = float("nan")
    std: tuple[float, ...] = ()


@runtime_checkable
class Estimator(Protocol):
    """A state estimator of one vehicle, called once per controller step."""

    name: str

    def reset(self, first: Measurement) -> Estimate:
        """Start from the first measurement of a run; the estimate after it."""

    def update(self, y: Measurement) -> Estimate:
        """Take the measurement at y.t_s and return the estimate."""

    def describe(self) -> dict[str, Any]:
        """Settings, for results."""


def soc_from_rest_voltage(v_cell: float, cell: Any = None) -> float:
    """SOC [-] whose OCV equals ``v_cell`` [V] (``cell``'s OCV table inverted, default the shipped one; clipped to
    [0, 1]): a BMS's start-up guess after a rest (the shipped LFP cell's OCV is very flat between 40 and 90 %)."""
    s, o = battery.ocv_table(cell)
    return float(np.interp(v_cell, o, s))


class EstimationModel:
    """The discrete model of the estimators (see the module docstring) for a vehicle ``ev`` (its model) and
    ``sensors`` (their noise sets R and the input noise in Q); ``ocv_offset_V`` shifts the model's OCV."""

    def __init__(self, ev: EVParams, sensors: Sensors, ocv_offset_V: float = 0.0) -> None:
        self.ev, self.sensors, self.ocv_offset_V = ev, sensors, float(ocv_offset_V)
        cell, pack = ev.cell, ev.pack
        x, u, dt = ca.SX.sym("x", NX), ca.SX.sym("u", 2), ca.SX.sym("dt")

        def scaled(x: Any) -> Any:  # a ScaledCell, read where a CellParams is (as battery.cell_at)
            return ScaledCell(cell, *(x[k] for k in range(7, NX)))

        def f(x: Any, u: Any) -> Any:
            dV1, dV2, dS = battery.cell_derivatives(x[1], x[2], u[0], scaled(x))
            return ca.vertcat(
                dS, dV1, dV2, x[4] - x[6], x[5], -x[5] / LEAD_ACCEL_TAU_S, u[1], ca.SX.zeros(len(PARAM_NAMES))
            )

        k1 = f(x, u)
        k2 = f(x + dt / 2 * k1, u)
        k3 = f(x + dt / 2 * k2, u)
        k4 = f(x + dt * k3, u)
        xn = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        y = ca.vertcat(
            battery.terminal_voltage(ca.fmin(ca.fmax(x[0], 0.0), 1.0), x[1], x[2], u[0], scaled(x)) + self.ocv_offset_V,
            x[3],
            x[4],
            x[6],
        )
        self.F = ca.Function("est_F", [x, u, dt], [xn, ca.jacobian(xn, x), ca.jacobian(xn, u)])
        self.H = ca.Function("est_H", [x, u], [y, ca.jacobian(y, x)])
        self.f_sym, self.h_sym, self.x, self.u, self.dt = xn, y, x, u, dt
        ns, npar = pack.n_series, pack.n_parallel
        self.n_series, self.n_parallel = ns, npar
        # measurement noise of y: the pack voltage's per series cell plus the OCV table's own error, the radar's
        # gap and predecessor speed, the own speed
        self.R = np.diag(
            [
                sensors.variance("voltage") / ns**2 + OCV_MODEL_SIGMA_V**2,
                sensors.variance("gap") + 1e-6,
                sensors.variance("lead_speed") + 1e-6,
                sensors.variance("speed") + 1e-6,
            ]
        )
        # input noise: the pack current's per parallel cell (the applied acceleration is known; its error is in
        # OWN_SPEED_NOISE_RATE)
        self.Su = np.diag([sensors.variance("current") / npar**2, 0.0])

    def ekf_step(self, iterations: int) -> ca.Function:
        """One EKF step as ONE CasADi Function (x, P, u_prev, u, y, dt) -> (x⁺, P⁺): the time update over dt [s]
        with the inputs held (the cell current at its value at the interval's end: the command is held over the
        interval and the current sampled at its end belongs to it; the applied acceleration as the mean of the
        interval's two samples), then the measurement update, and the Joseph-form covariance. The
        battery's part (S, V1, V2, the scales; the cell voltage) and the motion part (h, v_l, a_l, v; gap and both
        speeds) do not interact and are updated separately (P stays block-diagonal); the battery's update is
        iterated ``iterations`` times (Gauss–Newton on h; SOC clamped to [0, 1], the scales to
        [PARAM_SCALE_MIN, PARAM_SCALE_MAX]). dt = 0: the update only."""
        if iterations < 1:
            raise ParameterError(f"ekf_step: iterations = {iterations!r} must be >= 1")
        x, P = ca.SX.sym("x", NX), ca.SX.sym("P", NX, NX)
        u0, u1, ym, dt = ca.SX.sym("u0", 2), ca.SX.sym("u1", 2), ca.SX.sym("y", 4), ca.SX.sym("dt")
        um = ca.vertcat(u1[0], 0.5 * (u0[1] + u1[1]))
        xp, A, B = self.F(x, um, dt)
        Q = self.process_noise_sx(dt, B)
        b, m = list(BATTERY), list(MOTION)
        Pb = A[b, b] @ P[b, b] @ A[b, b].T + Q[b, b]
        Pm = A[m, m] @ P[m, m] @ A[m, m].T + Q[m, m]
        hx = ca.Function("h", [self.x, self.u], [self.h_sym, ca.jacobian(self.h_sym, self.x)])
        R = ca.DM(self.R)
        # the battery: one scalar measurement (the cell voltage), iterated
        xb_p, xb = xp[b], xp[b]
        lo = ca.DM([0.0] + [-ca.inf] * 2 + [PARAM_SCALE_MIN] * len(PARAM_NAMES))
        hi = ca.DM([1.0] + [ca.inf] * 2 + [PARAM_SCALE_MAX] * len(PARAM_NAMES))
        Kb: Any = None
        Cb: Any = None
        for _ in range(iterations):
            xi = ca.SX(xp)
            xi[b] = xb
            yh, C = hx(xi, u1)
            Cb = C[0, b]
            Kb = Pb @ Cb.T / (Cb @ Pb @ Cb.T + R[0, 0])
            xb = ca.fmin(ca.fmax(xb_p + Kb @ (ym[0] - yh[0] - Cb @ (xb_p - xb)), lo), hi)
        IKC = ca.DM.eye(len(b)) - Kb @ Cb
        Pb_n = IKC @ Pb @ IKC.T + Kb @ R[0, 0] @ Kb.T
        # the motion: linear, three measurements (gap, predecessor speed, own speed), one update
        Cm = ca.DM([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
        Rm = R[1:, 1:]
        Km = ca.solve(Cm @ Pm @ Cm.T + Rm, Cm @ Pm).T
        xm = xp[m] + Km @ (ym[1:] - Cm @ xp[m])
        IKCm = ca.DM.eye(len(m)) - Km @ Cm
        Pm_n = IKCm @ Pm @ IKCm.T + Km @ Rm @ Km.T
        xn = ca.SX(xp)
        xn[b], xn[m] = xb, xm
        Pn = ca.SX(NX, NX)
        Pn[b, b], Pn[m, m] = Pb_n, Pm_n
        return ca.Function("ekf_step", [x, P, u0, u1, ym, dt], [xn, Pn])

    def process_noise_sx(self, dt: Any, Bu: Any) -> Any:
        """:meth:`process_noise` as a CasADi expression of dt [s] and B."""
        q_acc = LEAD_ACCEL_SIGMA_MPS2**2 * (1.0 - ca.exp(-2.0 * dt / LEAD_ACCEL_TAU_S))
        own = ca.diag(
            ca.vertcat(
                *(q * dt for q in OWN_NOISE_RATES),
                q_acc,
                OWN_SPEED_NOISE_RATE * dt,
                *([PARAM_SCALE_RATE**2 * dt] * len(PARAM_NAMES)),
            )
        )
        return Bu @ ca.DM(self.Su) @ Bu.T + own

    def inputs(self, y: Measurement) -> np.ndarray:
        """u = (cell current [A], applied acceleration [m/s²]) from a measurement."""
        return np.array([y.current_A / self.n_parallel, y.accel_cmd_mps2])

    def outputs(self, y: Measurement) -> np.ndarray:
        """The measured y = (cell voltage [V], gap [m], predecessor speed [m/s], own speed [m/s])."""
        return np.array([y.voltage_V / self.n_series, y.gap_m, y.lead_speed_mps, y.speed_mps])

    def process_noise(self, dt_s: float, Bu: np.ndarray) -> np.ndarray:
        """Q [per step] over dt_s: the input noise through B plus the model's own uncertainty (:data:`OWN_NOISE_RATES`,
        the Singer acceleration, the scales' random walk :data:`PARAM_SCALE_RATE`)."""
        return np.asarray(self.process_noise_sx(dt_s, ca.DM(Bu)))

    def initial(self, y: Measurement, soc0: float | None) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) from the first measurement: the gap and both speeds measured, a_l = 0, V1 = V2 = 0,
        SOC = ``soc0`` or the OCV inverted at the first voltage (rest assumed), with σ_S = 0.1 and
        σ_V1 = σ_V2 = :data:`RC_REST_SIGMA_V` (a car starts after a rest: the RC voltages have relaxed), every scale 1 with σ =
        :data:`PARAM_SCALE_SIGMA`."""
        if soc0 is not None and not (0.0 <= soc0 <= 1.0):
            raise ParameterError(f"estimator: soc0 = {soc0!r} is not allowed: must be in [0, 1]")
        v_cell = y.voltage_V / self.n_series + self.ev.cell.R_s_ohm * y.current_A / self.n_parallel
        s0 = soc_from_rest_voltage(v_cell - self.ocv_offset_V, self.ev.cell) if soc0 is None else soc0
        x0 = np.array([s0, 0.0, 0.0, y.gap_m, y.lead_speed_mps, 0.0, y.speed_mps, *([1.0] * len(PARAM_NAMES))])
        P0 = np.diag(
            [
                0.1**2,
                RC_REST_SIGMA_V**2,
                RC_REST_SIGMA_V**2,
                self.R[1, 1] + 0.01,
                self.R[2, 2] + 0.01,
                1.0,
                self.R[3, 3] + 0.01,
                *([PARAM_SCALE_SIGMA**2] * len(PARAM_NAMES)),
            ]
        )
        return x0, P0


def estimate_of(x: np.ndarray, P: np.ndarray | None = None) -> Estimate:
    """An :class:`Estimate` from a state vector (and its covariance)."""
    std = tuple(float(s) for s in np.sqrt(np.maximum(np.diag(P), 0.0))) if P is not None else ()
    return Estimate(float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), float(x[5]), float(x[6]), std)
