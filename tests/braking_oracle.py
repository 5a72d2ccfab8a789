"""An independent model of the braking manoeuvre for tests: the ego braking at a_min from t = 0 through its actuator
(lag τ, its rate clipped to ±J when a jerk limit is given, as the plant's) behind a lead that brakes at a_l from t_b,
both stopping at rest, integrated by SciPy's ``solve_ivp`` piece by piece.

The right-hand side is smooth between its switches (the ramp's end where the rate (a_min − a)/τ reaches −J, the ego's
stop, the lead's braking start at t_b and its stop); each switch is an event (or a breakpoint) of one solve, and the
next piece starts there with the new right-hand side, so no step straddles a kink. The minimum gap is at a piece's end
or where the closing speed v − v_l changes sign (an event too). (The tests integrated across the switches with 0.2 and
0.5 ms steps before: 0.5–3.6 s per case, the same numbers to 1.5e-7; issue 40.)"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def scipy_min_gap(
    v0: float,
    g0: float,
    vl0: float,
    al: float,
    tb: float,
    am: float,
    tau: float,
    t_end: float,
    jm: float | None = None,
) -> float:
    """The smallest gap h [m] on [0, t_end] [s]: ego speed v0 [m/s] braking at am [m/s²] through the lag tau [s]
    (tau = 0: at am from t = 0) with its rate clipped to ±jm [m/s³] (None: no jerk limit); gap g0 [m]; lead speed
    vl0 [m/s], braking at al [m/s²] from tb [s]. The ego's acceleration starts at 0 (at am when tau = 0)."""
    ramp = tau > 0 and jm is not None and (am - 0.0) / tau < -jm  # the rate limit binds first (J τ < |a_min|)
    ego_moving, lead_moving, lead_braking = v0 > 0, vl0 > 0, tb <= 0.0
    t, y = 0.0, np.array([g0, v0, 0.0 if tau > 0 else am, vl0])
    h_min = g0

    def f(t: float, y: np.ndarray) -> list[float]:
        _h, v, a, vl = y
        rate = 0.0 if tau == 0 else -float(jm or 0.0) if ramp else (am - a) / tau
        return [vl - v, a if ego_moving else 0.0, rate, al if lead_braking and lead_moving else 0.0]

    def ramp_ends(t: float, y: np.ndarray) -> float:
        return (am - y[2]) / tau + float(jm or 0.0) if ramp else 1.0

    def ego_stops(t: float, y: np.ndarray) -> float:
        return y[1] if ego_moving else 1.0

    def lead_stops(t: float, y: np.ndarray) -> float:
        return y[3] if lead_braking and lead_moving else 1.0

    def closing_ends(t: float, y: np.ndarray) -> float:
        return y[3] - y[1]

    for ev in (ramp_ends, ego_stops, lead_stops):
        ev.terminal = True  # type: ignore[attr-defined]
    while t < t_end:
        stop = min(tb, t_end) if not lead_braking else t_end
        sol = solve_ivp(
            f, (t, stop), y, events=(ramp_ends, ego_stops, lead_stops, closing_ends), rtol=1e-11, atol=1e-12
        )
        assert sol.success, sol.message  # (a failed solve would restart at its last step for ever)
        h_min = min(h_min, float(sol.y[0].min()), *(float(e[0]) for e in sol.y_events[3]))
        t, y = float(sol.t[-1]), sol.y[:, -1].copy()
        if sol.status == 1:  # a switch: the next piece's right-hand side
            if sol.t_events[0].size:
                ramp = False
            if sol.t_events[1].size:
                ego_moving, y[1] = False, 0.0
            if sol.t_events[2].size:
                lead_moving, y[3] = False, 0.0
        elif not lead_braking:
            lead_braking = True
    return h_min
