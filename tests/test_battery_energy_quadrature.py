"""A platoon's battery energy ∫P_b dt is the plant's own quadrature (issue 35): the compiled cascade integrates it
on its steps (outside the error norm, so nothing else changes), the CVODES plant as an error-controlled quadrature.
Checked against SciPy's solve_ivp with an energy state, and against the trapezoid of P_b on a fine grid.

Measured (table1's platoon, 3 followers, t ∈ [0, 10] model, rtol = atol = 1e-10; errors against SciPy relative to
the gross ∫|P_b| dt, constant η and map powertrain): cascade ≤ 4.2e-7, CVODES ≤ 5e-9, the trapezoid on the 0.1 output
grid up to 8.9e-4 (the proposed law's ε term switches within one sample), on a 0.001 grid up to 2.6e-5. Tolerances
stated below: cascade 2e-6, CVODES 5e-8, fine trapezoid 1e-4.
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp import VehicleParams, load_scenario, simulate_platoon
from aev_ocp.metrics import battery_energy_J
from aev_ocp.plant import battery_power_integrand

T_END = 10.0
N_FOLLOWERS = 3


def _scenario(powertrain: str):
    s = load_scenario("table1")
    ev = s.ev if powertrain == "constant" else dataclasses.replace(s.ev, vehicle=VehicleParams.model3())
    return s, ev


def _run(s, ev, method: str, dt_out: float | None = None):
    n = N_FOLLOWERS
    return simulate_platoon(
        s.leader,
        list(s.laws[:n]),
        s.gaps0[:n],
        s.speeds0[:n],
        T_END,
        ev=ev,
        dt_out=dt_out or s.dt_out,
        rtol=s.rtol,
        atol=s.atol,
        method=method,
    )


def scipy_battery_energy(s, ev) -> tuple[np.ndarray, np.ndarray]:
    """∫P_b dt and ∫|P_b| dt [J] per follower from SciPy's DOP853 on (h, v, E, E_abs) of the whole platoon (the laws
    and P_b from their own CasADi expressions, the leader's speed from its own function), split at the leader's
    breakpoints. The gross ∫|P_b| dt scales the tolerances: traction and regeneration cancel in the net."""
    n, law = N_FOLLOWERS, s.laws[0]
    # the whole right-hand side as one CasADi Function of (t, y): one call per evaluation (issue 40: three calls, the
    # law's, P_b's and the leader's speed, cost 3x the time in the calls' overhead; the same expressions)
    t, y = ca.SX.sym("t"), ca.SX.sym("y", 4 * n)
    H, V = y[:n], y[n : 2 * n]
    VL = ca.vertcat(s.leader.speed(t), V[:-1])
    A = law.accel(H, V, VL)
    P = ev.units.time_s * battery_power_integrand(V, A, ev)
    f = ca.Function("rhs", [t, y], [ca.vertcat(VL - V, A, P, ca.fabs(P))])

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        return np.asarray(f(t, y)).ravel()

    cuts = sorted({0.0, T_END, *(b for b in s.leader.breakpoints if 0.0 < b < T_END)})
    y = np.concatenate([s.gaps0[:n], s.speeds0[:n], np.zeros(2 * n)])
    for a, b in zip(cuts[:-1], cuts[1:]):
        y = solve_ivp(rhs, (a, b), y, method="DOP853", rtol=1e-11, atol=1e-9).y[:, -1]
    return y[2 * n : 3 * n], y[3 * n :]


@pytest.mark.parametrize("powertrain", ["constant", "map"])
def test_battery_energy_is_the_plants_quadrature(powertrain: str) -> None:
    s, ev = _scenario(powertrain)
    ref, gross = scipy_battery_energy(s, ev)
    assert np.all(gross > 2e4)  # tens of kJ per follower through the battery (the net is smaller: regeneration)
    casc, cv = _run(s, ev, "cascade"), _run(s, ev, "cvodes")
    for r in (casc, cv):
        assert r.status == "ok" and r.battery_energy_J is not None and r.battery_energy_J.shape == r.speed.shape
        assert np.all(r.battery_energy_J[0] == 0.0)
    got_c, got_v = casc.battery_energy_J[-1], cv.battery_energy_J[-1]
    err_c, err_v = np.abs(got_c - ref) / gross, np.abs(got_v - ref) / gross
    assert np.all(err_c < 2e-6)  # integrated on the cascade's steps, not error-controlled
    assert np.all(err_v < 5e-8)  # CVODES, error-controlled
    # the metrics read it (kWh/100 km from the same J)
    m = casc.metrics()[0]
    assert m["battery_energy_J"] == got_c[0]
    # the trapezoid of P_b on the samples: a second method, converging to the same number as the grid shrinks
    trap = lambda r: np.array([battery_energy_J(dataclasses.replace(r, battery_energy_J=None), i) for i in range(3)])  # noqa: E731
    coarse, fine = trap(casc), trap(_run(s, ev, "cascade", dt_out=0.001))
    assert np.all(np.abs(fine - ref) / gross < 1e-4)
    assert np.max(np.abs(got_c - ref)) < 0.05 * np.max(np.abs(coarse - ref))  # the quadrature beats the trapezoid


def test_battery_energy_does_not_depend_on_the_output_grid() -> None:
    """The cascade's steps do not depend on the samples, so neither does its quadrature (to rounding in the dense
    output's last sample); the trapezoid does."""
    s, ev = _scenario("constant")
    a, b = _run(s, ev, "cascade"), _run(s, ev, "cascade", dt_out=s.dt_out / 4)
    np.testing.assert_allclose(a.battery_energy_J[-1], b.battery_energy_J[-1], rtol=1e-13)
    np.testing.assert_allclose(a.battery_energy_J, b.battery_energy_J[::4], rtol=1e-12, atol=1e-6)
