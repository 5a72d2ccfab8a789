"""Exact replay of a speed trace: one vehicle driven exactly on a drive cycle or a recorded trace, and its battery.

The trace's samples are joined linearly (constant acceleration between two samples, as the EPA cycles and FASTSim
define them), so the motion is known in closed form; the battery side (the powertrain of ``ev.vehicle``, the 2-RC
cell of ``ev.cell`` in the pack ``ev.pack``) is integrated over each interval by CVODES with every integral as a
state: battery energy ∫P_b dt, where it went (traction, regeneration, friction brakes, powertrain losses, auxiliary
load; :func:`aev_ocp.models.powertrain.powertrain_flows`), pack heat ∫Q and ∫Q_irr, the cell's charge throughput
∫|I| dt and the distance. One CasADi Function (the interval's integrator accumulated over the whole trace) is built
per vehicle and trace length and called once.

Battery energy is *the* energy of the toolkit: ∫P_b dt at the pack's terminals [J], reported per km
(Wh/km, J/km) and per 100 km (kWh/100 km).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import casadi as ca
import numpy as np

from .models.ego import battery_side
from .models.leader import CYCLES, load_cycle_si, read_trace_csv
from .models.powertrain import powertrain_flows
from .models.vehicle import wheel_power_W
from .params import POWERTRAINS, EVParams, ParameterError, VehicleParams, check_declared
from .params import CellParams

#: The integrals carried by the replay, after the cell states V1, V2 [V], S [-] (all in J but the last two).
INTEGRALS = ("battery", "traction", "regen", "friction", "loss", "aux", "heat", "heat_irr", "charge_As", "distance_m")
#: CVODES tolerances of the replay: relative, absolute (states: V, -, J, A s, m).
RTOL, ATOL = 1e-10, 1e-8
J_PER_KWH = 3.6e6


def default_ev() -> EVParams:
    """The replay's vehicle by default: FASTSim's 2022 Tesla Model 3 RWD as FASTSim simulates it
    (:meth:`aev_ocp.params.VehicleParams.model3`) with the toolkit's cell and pack."""
    return EVParams(vehicle=VehicleParams.model3())


@dataclass(frozen=True)
class ReplayResult:
    """One vehicle's exact replay of a speed trace. Arrays are at the trace's samples (K,); totals in SI.

    battery_energy_J: ∫P_b dt at the pack terminals [J]; the flows (traction_J, regen_J, friction_J, loss_J,
    aux_J) say where it went (battery = traction + loss + aux − regen); heat_pack_J, heat_irr_pack_J: pack ∫Q,
    ∫Q_irr [J]; charge_throughput_Ah: the pack's ∫|I_pack| dt [Ah]; soc: the cell's state of charge [-]."""

    name: str
    powertrain: str
    t_s: np.ndarray
    speed_mps: np.ndarray
    soc: np.ndarray
    current_A: np.ndarray  # per cell, at the samples
    distance_m: float
    battery_energy_J: float
    traction_J: float
    regen_J: float
    friction_J: float
    loss_J: float
    aux_J: float
    heat_pack_J: float
    heat_irr_pack_J: float
    charge_throughput_Ah: float
    status: str = "ok"
    events: list[str] = field(default_factory=list)
    ev: EVParams = field(default_factory=EVParams)

    @property
    def duration_s(self) -> float:
        """Length of the trace [s]."""
        return float(self.t_s[-1] - self.t_s[0])

    def per_km(self, x: float) -> float:
        """x per km of the trace (nan when it does not move)."""
        return x / (self.distance_m / 1000.0) if self.distance_m > 0 else math.nan

    def summary(self) -> dict[str, Any]:
        """The numbers a user reads, SI with units in the names: battery energy (J/km, Wh/km, kWh/100 km), its
        flows per km, pack heat, charge throughput (Ah/km), SOC, peak current and the status."""
        e = self.battery_energy_J
        return {
            "trace": self.name,
            "powertrain": self.powertrain,
            "status": self.status,
            "duration_s": self.duration_s,
            "distance_m": self.distance_m,
            "battery_energy_J": e,
            "battery_energy_J_per_km": self.per_km(e),
            "battery_energy_Wh_per_km": self.per_km(e) / 3600.0,
            "battery_energy_kWh_per_100km": self.per_km(e) * 100.0 / J_PER_KWH,
            "traction_J_per_km": self.per_km(self.traction_J),
            "regen_J_per_km": self.per_km(self.regen_J),
            "friction_brake_J_per_km": self.per_km(self.friction_J),
            "powertrain_loss_J_per_km": self.per_km(self.loss_J),
            "aux_J_per_km": self.per_km(self.aux_J),
            "heat_pack_J_per_km": self.per_km(self.heat_pack_J),
            "heat_irr_pack_J_per_km": self.per_km(self.heat_irr_pack_J),
            "charge_throughput_Ah_per_km": self.per_km(self.charge_throughput_Ah),
            "soc_start": float(self.soc[0]),
            "soc_end": float(self.soc[-1]),
            "delta_soc": float(self.soc[-1] - self.soc[0]),
            "max_abs_current_A": float(np.max(np.abs(self.current_A))),
            "cell_current_limit_A": self.ev.cell.max_current_A,
        }


@lru_cache(maxsize=16)
def _interval(ev: EVParams) -> tuple[ca.Function, ca.Function]:
    """(step, probe): step(x, p = (v0 [m/s], a [m/s²], dt [s])) -> x at the interval's end (CVODES, normalised time);
    probe(x, v [m/s], a [m/s²]) -> (I [A per cell], disc [V²])."""
    u = ev.units
    x = ca.SX.sym("x", 3 + len(INTEGRALS))
    p = ca.SX.sym("p", 3)
    s = ca.SX.sym("s")
    v0, a, dt = p[0], p[1], p[2]
    v = v0 + a * dt * s
    b = battery_side(u.speed_from_si(v), u.accel_from_si(a), x[0], x[1], x[2], ev)
    f = powertrain_flows(wheel_power_W(v, a, ev.vehicle), ev.vehicle)
    rates = [
        b["dV1"],
        b["dV2"],
        b["dS"],
        b["P_b"],
        f["traction"],
        f["regen"],
        f["friction"],
        f["loss"],
        f["aux"],
        b["Q_pack"],
        b["Q_irr_pack"],
        ca.fabs(b["I"]),
        v,
    ]
    dae = {"x": x, "p": p, "t": s, "ode": dt * ca.vertcat(*rates)}
    opts = {"abstol": ATOL, "reltol": RTOL, "max_num_steps": 100_000, "disable_internal_warnings": True}
    F = ca.integrator("replay_interval", "cvodes", dae, 0.0, 1.0, opts)
    step = ca.Function("replay_step", [x, p], [F(x0=x, p=p)["xf"]], ["x", "p"], ["x_next"])
    vv, aa = ca.SX.sym("v"), ca.SX.sym("a")
    bp = battery_side(u.speed_from_si(vv), u.accel_from_si(aa), x[0], x[1], x[2], ev)
    probe = ca.Function("replay_probe", [x, vv, aa], [bp["I"], bp["disc"]], ["x", "v", "a"], ["I", "disc"])
    return step, probe


def _trace(trace: Any) -> tuple[str, np.ndarray, np.ndarray]:
    """(name, times [s], speeds [m/s]) of a cycle name, a CSV path (columns time_s, speed_mps) or a pair of arrays."""
    if isinstance(trace, str) and trace.lower() in CYCLES:
        t, v = load_cycle_si(trace)
        return trace.lower(), np.asarray(t, float), np.asarray(v, float)
    if isinstance(trace, (str, Path)):
        path = Path(trace)
        if not path.is_file():
            raise ParameterError(
                f"replay: trace {str(trace)!r} is neither a shipped cycle ({', '.join(CYCLES)}) nor a CSV file"
            )
        t, v = read_trace_csv(path, time_column="time_s", speed_column="speed_mps", max_gap_s=None, label=path.name)
        return path.stem, np.asarray(t, float), np.asarray(v, float)
    try:
        t_in, v_in = trace
        t, v = np.asarray(t_in, float).ravel(), np.asarray(v_in, float).ravel()
    except (TypeError, ValueError):
        raise ParameterError(
            "replay: trace must be a cycle name, a CSV path or a pair (times_s, speeds_mps) of arrays"
        ) from None
    if t.size != v.size or t.size < 2:
        raise ParameterError(f"replay: times_s and speeds_mps need the same length ≥ 2, got {t.size} and {v.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ParameterError("replay: times_s and speeds_mps must be finite")
    if np.any(np.diff(t) <= 0):
        raise ParameterError("replay: times_s must be strictly increasing")
    if np.any(v < 0):
        raise ParameterError(f"replay: speeds_mps must be ≥ 0, got {float(v.min()):g} m/s")
    return "trace", t, v


def replay(
    trace: str | Path | tuple[Sequence[float], Sequence[float]],
    ev: EVParams | None = None,
    powertrain: str | None = None,
    soc0: float | None = None,
) -> ReplayResult:
    """Drive one vehicle exactly on ``trace`` (a shipped cycle 'udds', 'hwfet', 'us06', a CSV file with columns
    time_s, speed_mps, or a pair (times [s], speeds [m/s])) and integrate its battery.

    ev: the vehicle (default :func:`default_ev`, FASTSim's Model 3 with the map powertrain); powertrain: 'map' or
    'constant' (the paper's η switch) to override ``ev.vehicle.powertrain``; soc0: the cell's initial state of
    charge (default ``ev.cell.soc0``). The cell starts at rest (V1 = V2 = 0)."""
    ev = default_ev() if ev is None else ev
    if powertrain is not None:
        if powertrain not in POWERTRAINS:
            raise ParameterError(f"replay: powertrain = {powertrain!r} is not allowed: must be one of {POWERTRAINS}")
        ev = dataclasses.replace(ev, vehicle=dataclasses.replace(ev.vehicle, powertrain=powertrain))
    s0 = ev.cell.soc0 if soc0 is None else float(check_declared(CellParams, "soc0", soc0, "replay"))
    name, t, v = _trace(trace)
    lim = ev.limits
    if lim.enabled and float(v.max()) > lim.v_max_mps:
        k = int(np.argmax(v > lim.v_max_mps))
        raise ParameterError(
            f"replay: trace {name}: speed_mps = {float(v[k]):g} at t = {float(t[k]):g} s is above the vehicle's top "
            f"speed limits.v_max_mps = {lim.v_max_mps:g} m/s"
        )
    dt = np.diff(t)
    a = np.diff(v) / dt
    # no tyre grips beyond the friction limit |a_min| (0.8 g), either way: a jump of the trace is not a drive (the
    # battery's check at the samples would miss the interval's demand and report nonsense with status ok)
    a_grip = abs(lim.a_min_mps2)
    if lim.enabled and float(np.abs(a).max()) > a_grip * (1 + 1e-12):
        k = int(np.argmax(np.abs(a) > a_grip * (1 + 1e-12)))
        raise ParameterError(
            f"replay: trace {name}: speed_mps goes from {float(v[k]):g} to {float(v[k + 1]):g} m/s between t = "
            f"{float(t[k]):g} and {float(t[k + 1]):g} s, an acceleration of {float(a[k]):.4g} m/s^2, beyond the "
            f"tyre-road friction limit |limits.a_min_mps2| = {a_grip:g} m/s^2"
        )
    step, probe = _interval(ev)
    x0 = np.zeros(3 + len(INTEGRALS))
    x0[2] = s0
    P = np.vstack([v[:-1], a, dt])
    try:
        X = np.asarray(step.mapaccum("replay", dt.size)(x0, P))
    except RuntimeError as exc:  # CVODES gave up (a demand far outside the cell's range)
        reason = str(exc).rsplit(":", 1)[-1].strip()[:120]
        raise ParameterError(
            f"replay: trace {name}: the battery's integration failed ({reason}); check the trace's speeds and "
            "accelerations (speed_mps, time_s)"
        ) from None
    X = np.hstack([x0[:, None], X])
    a_at = np.append(a, a[-1])  # the acceleration of the interval that starts at each sample (the last: its own)
    I, disc = (np.asarray(o).ravel() for o in probe.map(t.size)(X, v[None, :], a_at[None, :]))
    events: list[str] = []
    if np.any(disc < 0):
        k = int(np.argmax(disc < 0))
        events.append(f"infeasible_current at t = {t[k]:g} s: the cell cannot deliver the power demand")
    S = X[2]
    if np.any((S < 0) | (S > 1)):
        k = int(np.argmax((S < 0) | (S > 1)))
        events.append(f"soc_out_of_range at t = {t[k]:g} s: S = {S[k]:.6g}")
    q = dict(zip(INTEGRALS, X[3:, -1].tolist()))
    return ReplayResult(
        name=name,
        powertrain=ev.vehicle.powertrain,
        t_s=t,
        speed_mps=v,
        soc=S,
        current_A=I,
        distance_m=q["distance_m"],
        battery_energy_J=q["battery"],
        traction_J=q["traction"],
        regen_J=q["regen"],
        friction_J=q["friction"],
        loss_J=q["loss"],
        aux_J=q["aux"],
        heat_pack_J=q["heat"],
        heat_irr_pack_J=q["heat_irr"],
        charge_throughput_Ah=q["charge_As"] * ev.pack.n_parallel / 3600.0,
        status=events[0].split(" ", 1)[0] if events else "ok",
        events=events,
        ev=ev,
    )
