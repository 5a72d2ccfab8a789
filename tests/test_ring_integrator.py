"""The compiled ring integrator's error control (aev_ocp/c/ring.c through RingSimulator) against a twin built on
SciPy's own Dormand–Prince 5(4) (``RK45``: the same tableau, the same step-size rule 0.9·err^(−1/5) within
[0.2, 10], no growth right after a rejection), with the error norm stated in ring.c's docstring written here,
max(RMS over the ring, largest per-vehicle RMS / local_factor) over the motion states (h, v): the accepted and
rejected steps must agree at two tolerances and at local factors 1 and 4 (a wrong norm, a dropped 1/n, a factor on
the wrong side change them). Then the errors against a DOP853 reference at rtol 1e-13: they scale with the
tolerance, and the step count with its fifth root (the method's order)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import RK45, solve_ivp

from aev_ocp.params import EVParams
from aev_ocp.ring.laws import idm_si
from aev_ocp.ring.simulate import RingOptions, RingRoad, RingSimulator, gaps_from_positions, uniform_flow

EV = EVParams()
U = EV.units
N = 24
T_H = np.array([1.0 + 0.013 * i for i in range(N)])  # IDM time headways [s], each vehicle its own
RING = RingRoad(N * 12.3, tuple(idm_si(U, T_s=float(t)) for t in T_H), ev=EV)
INIT = uniform_flow(RING, speed_mps=6.7, shift_m=2.9, vehicle=5, speed_dip_mps=1.1)
T_END_S = 24.0


def _rhs_model(_t: float, y: np.ndarray) -> np.ndarray:
    """The ring's motion in model units, y = (h_0, v_0, h_1, v_1, …): IDM (Treiber et al. 2000) written here in SI,
    a = 1.0 (1 − (v/30)⁴ − (s*/h)²), s* = 2 + v T + v (v − v_l)/(2 √(1.0 · 1.5))."""
    h, v = y[0::2] * U.length_m, y[1::2] * U.speed_mps
    vl = np.roll(v, 1)
    s_star = 2.0 + v * T_H + v * (v - vl) / (2.0 * np.sqrt(1.0 * 1.5))
    a = 1.0 * (1.0 - (v / 30.0) ** 4 - (s_star / h) ** 2)
    d = np.empty_like(y)
    d[0::2] = (vl - v) / U.speed_mps
    d[1::2] = a / U.accel_mps2
    return d


def _y0() -> np.ndarray:
    y = np.empty(2 * N)
    y[0::2] = gaps_from_positions(RING, INIT.positions_m) / U.length_m
    y[1::2] = np.asarray(INIT.speeds_mps) / U.speed_mps
    return y


class _RingNormRK45(RK45):
    """SciPy's RK45 with ring.c's error norm (its docstring): max(RMS over all, max per-vehicle RMS / factor)."""

    local_factor = 1.0

    def _estimate_error_norm(self, K, h, scale):  # type: ignore[no-untyped-def]
        e = (self._estimate_error(K, h) / scale).reshape(N, 2)
        per_vehicle = np.sqrt(np.mean(e * e, axis=1))
        return max(float(np.sqrt(np.mean(e * e))), float(per_vehicle.max()) / self.local_factor)


def _twin_steps(tol: float, factor: float) -> tuple[int, int]:
    cls = type("Twin", (_RingNormRK45,), {"local_factor": factor})
    solver = cls(_rhs_model, 0.0, _y0(), T_END_S / U.time_s, rtol=tol, atol=tol, first_step=1e-3)
    accepted = rejected = 0
    while solver.status == "running":
        solver.step()
        accepted += 1
    assert solver.status == "finished"
    rejected = solver.nfev // 6 - accepted  # six new stages per attempt (FSAL), one evaluation to start
    return accepted, rejected


def _compiled(tol: float, factor: float):  # type: ignore[no-untyped-def]
    opts = RingOptions(rtol=tol, atol=tol, dt_out_s=T_END_S / 4, method="compiled", local_factor=factor)
    res = RingSimulator(RING, opts).run(INIT, T_END_S)
    assert res.status == "ok" and res.stats["method"] == "compiled"
    return res


@pytest.mark.parametrize("factor", [1.0, 4.0])
@pytest.mark.parametrize("tol", [1e-5, 1e-8])
def test_steps_equal_a_scipy_twin_with_the_stated_error_norm(tol: float, factor: float) -> None:
    res = _compiled(tol, factor)
    acc, rej = _twin_steps(tol, factor)
    assert abs(res.stats["steps"] - acc) <= 1, (res.stats, acc, rej)
    assert abs(res.stats["rejected"] - rej) <= 1, (res.stats, acc, rej)


def test_a_larger_local_factor_takes_fewer_steps_and_lets_the_error_grow() -> None:
    """The perturbation sits in a few vehicles, so the per-vehicle term decides: factor 4 relaxes it."""
    tol = 1e-7
    ref = solve_ivp(_rhs_model, (0.0, T_END_S / U.time_s), _y0(), method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
    err = {}
    steps = {}
    for f in (1.0, 4.0):
        r = _compiled(tol, f)
        steps[f] = r.stats["steps"]
        err[f] = float(np.max(np.abs(r.speed_mps[-1] / U.speed_mps - ref[1::2])))
    assert steps[4.0] < steps[1.0]
    assert err[4.0] > err[1.0]


def test_error_scales_with_the_tolerance_and_steps_with_its_fifth_root() -> None:
    ref = solve_ivp(_rhs_model, (0.0, T_END_S / U.time_s), _y0(), method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
    out = {}
    for tol in (1e-6, 1e-10):
        r = _compiled(tol, 1.0)
        e_v = np.max(np.abs(r.speed_mps[-1] / U.speed_mps - ref[1::2]))
        e_h = np.max(np.abs(r.gap_m[-1] / U.length_m - ref[0::2]))
        out[tol] = (max(e_v, e_h), r.stats["steps"])
    (e1, n1), (e2, n2) = out[1e-6], out[1e-10]
    assert e1 < 50 * 1e-6 and e2 < 50 * 1e-10  # within a small multiple of the tolerance
    assert 1e2 < e1 / e2 < 1e5  # ~ the tolerance ratio 1e4
    assert n2 / n1 == pytest.approx(1e4**0.2, rel=0.25)  # order 5: steps ∝ tol^(−1/5)
