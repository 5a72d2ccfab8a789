"""SUMO's battery stepping (aev_ocp/sumo/run.py ``_battery`` on aev_ocp/models/battery_step.py, recorded by ``_result``)
against the plant's own battery (aev_ocp.models.ego.battery_side: the cell ODE, its current, its heat) integrated
by SciPy on the same speed trace (SUMO's ballistic update: the acceleration held over each step), sample by sample:
the current at every sample (the current of the step that starts there), SOC, V1, V2 and the cumulative pack heat,
for a vehicle present from the start and one that departs later (starting at rest at soc0). No SUMO process: the
loop's calls are made here in its order (the state read at t, then the battery over the step just made)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp.models.ego import battery_side
from aev_ocp.params import EVParams
from aev_ocp.sumo.run import _battery, _result, _Track

EV = EVParams()
U = EV.units
DT = 0.1
K = 260
T = np.arange(K) * DT


def _speed(t: np.ndarray, late: bool) -> np.ndarray:
    """A trace with accelerating, cruising, braking to a stop and starting again [m/s]."""
    if late:
        return np.clip(3.0 + 2.3 * np.sin(0.41 * t) + 0.9 * t, 0.0, None)
    v = 7.9 + 4.1 * np.sin(0.27 * t) + 1.3 * np.sin(1.9 * t)
    v[(t > 14.0) & (t < 16.5)] = 0.0
    return np.clip(v, 0.0, None)


def _side() -> ca.Function:
    v, a, V1, V2, S = (ca.SX.sym(s) for s in ("v", "a", "V1", "V2", "S"))
    b = battery_side(v, a, V1, V2, S, EV)
    return ca.Function("side", [v, a, V1, V2, S], [ca.vertcat(b["dV1"], b["dV2"], b["dS"], b["Q_pack"]), b["I"]])


def _reference(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V1, V2, S, pack ∫Q [J]) at every sample and the current [A per cell] at every sample with the step's
    acceleration, the plant's battery on v(t) = v_k + a_k (t − t_k) by SciPy (rtol 1e-11)."""
    side = _side()
    y = np.array([0.0, 0.0, EV.cell.soc0, 0.0])
    ys, cur = [y.copy()], []
    for k in range(v.size - 1):
        a = (v[k + 1] - v[k]) / DT
        am = float(U.accel_from_si(a))

        def f(t: float, yy: np.ndarray, v0: float = float(v[k]), a_si: float = a, am: float = am) -> np.ndarray:
            d, _ = side(U.speed_from_si(v0 + a_si * t), am, yy[0], yy[1], yy[2])
            return np.asarray(d).ravel()

        cur.append(float(side(U.speed_from_si(v[k]), am, y[0], y[1], y[2])[1]))
        y = solve_ivp(f, (0.0, DT), y, method="DOP853", rtol=1e-11, atol=1e-13).y[:, -1]
        ys.append(y.copy())
    return np.array(ys), np.array(cur)


def _run() -> dict[str, _Track]:
    """Two tracks stepped as the loop does: 'a' from the first step, 'b' departing at sample 60."""
    tracks = {
        "a": _Track("a", "car", "r", False, "sumo", 2.5, 0.0),
        "b": _Track("b", "car", "r", False, "sumo", 2.5, 60 * DT),
    }
    va, vb = _speed(T, False), _speed(T[60:] - T[60], True)
    for k in range(K):
        live = [tracks["a"]] + ([tracks["b"]] if k >= 60 else [])
        for tr in live:
            v = va[k] if tr.vid == "a" else vb[k - 60]
            tr.t_s.append(float(T[k]))
            tr.v.append(float(v))
            tr.odo.append(0.0)
            tr.gap.append(31.0)
            tr.v_lead.append(float(v))
            tr.lane.append("e_0")
        _battery(EV, live, DT)
    return tracks


@pytest.fixture(scope="module")
def tracks() -> dict[str, _Track]:
    return _run()


#: tolerances (V [V], S [-], heat relative to the run's, current [A]): 'b' is smooth (RK4's O(Δt⁵) per step);
#: 'a' stops abruptly and its power changes sign inside steps (the η switch): one RK4 step across a kink is only
#: first order there, 1e-7 V and 2e-4 of the heat over the run (a one-sample shift of the current is 24 A)
TOL = {"a": (2e-7, 1e-8, 5e-4, 1e-7), "b": (1e-10, 1e-12, 1e-8, 1e-10)}


@pytest.mark.parametrize("vid", ["a", "b"])
def test_sumo_battery_equals_the_plants_battery_sample_by_sample(tracks, vid: str) -> None:
    tol_v, tol_s, tol_q, tol_i = TOL[vid]
    tr = tracks[vid]
    v = np.asarray(tr.v)
    ref, cur = _reference(v)
    r = _result(tr, EV, 100.0, DT, 1)
    n = v.size
    assert r.t.size == n
    np.testing.assert_allclose(r.V1[:, 0], ref[:, 0], rtol=0, atol=tol_v)
    np.testing.assert_allclose(r.V2[:, 0], ref[:, 1], rtol=0, atol=tol_v)
    np.testing.assert_allclose(r.S[:, 0], ref[:, 2], rtol=0, atol=tol_s)
    np.testing.assert_allclose(r.heat_J[:, 0], ref[:, 3], rtol=0, atol=tol_q * ref[-1, 3])
    # the current at sample k is the current at the start of the step from k (not the step before or after)
    np.testing.assert_allclose(r.current_A[: n - 1, 0], cur, rtol=0, atol=tol_i)
    assert np.max(np.abs(np.diff(cur))) > 1e3 * tol_i  # the trace moves the current: a one-sample shift shows
    assert r.S[0, 0] == EV.cell.soc0 and r.V1[0, 0] == 0.0  # a departing vehicle starts at rest at soc0
