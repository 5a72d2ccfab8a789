"""The compiled ring's OCV lookup (aev_ocp/c/ocv_lookup.h, exported as aevring_ocv) returns the model's piecewise cubic
(aev_ocp.models.battery.ocv_piecewise, evaluated by CasADi) to the bit: at random SOCs, on every breakpoint and its
two neighbouring doubles, outside [0, 1] on both sides (the end pieces extended, as the model), ±0, ±inf and NaN; for
the shipped A123 table (a uniform grid) and a non-uniform one. Inside [0, 1] both are the cell's B-spline (1e-12 V).
And the compiled ring's outputs (the cell current I, the discriminant) at its samples are the model's whole
right-hand side (the law's CasADi Function, with the piecewise OCV) at the same states, to the bit."""

from __future__ import annotations

import ctypes
import dataclasses

import casadi as ca
import numpy as np
import pytest

from aev_ocp.models import battery
from aev_ocp.params import EVParams
from aev_ocp.ring.laws import idm_si
from aev_ocp.ring.simulate import RingOptions, RingRoad, RingSimulator, uniform_flow

# a non-uniform table: spacings from 0.004 to 0.3, so the lookup's guess from the mean spacing walks several pieces
SOC = (0.0, 0.004, 0.03, 0.09, 0.2, 0.5, 0.61, 0.9, 0.97, 0.996, 1.0)
OCV_V = (2.61, 2.93, 3.08, 3.19, 3.24, 3.29, 3.31, 3.38, 3.47, 3.72, 3.95)
EVS = {"a123": EVParams(), "nonuniform": EVParams(cell=dataclasses.replace(EVParams().cell, ocv_soc=SOC, ocv_V=OCV_V))}


def _sim(ev: EVParams) -> RingSimulator:
    ring = RingRoad(4 * 12.3, tuple(idm_si(ev.units, T_s=1.0 + 0.17 * i) for i in range(4)), ev=ev)
    sim = RingSimulator(ring, RingOptions(rtol=1e-8, atol=1e-8, dt_out_s=0.7))
    if sim.method != "compiled":
        pytest.skip("no C compiler: the compiled ring is not built")
    return sim


def _lookup(sim: RingSimulator, S: np.ndarray) -> np.ndarray:
    S = np.ascontiguousarray(S, dtype=float)
    E = np.full_like(S, -1.0)
    ptr = ctypes.POINTER(ctypes.c_double)
    sim._lib.aevring_ocv(ctypes.c_int64(S.size), S.ctypes.data_as(ptr), E.ctypes.data_as(ptr))
    return E


@pytest.mark.parametrize("name", sorted(EVS))
def test_lookup_is_the_piecewise_cubic_to_the_bit(name: str) -> None:
    ev = EVS[name]
    sim = _sim(ev)
    grid = battery.ocv_table(ev.cell)[0]
    rng = np.random.default_rng(36)
    S = np.concatenate(
        [
            rng.uniform(-0.4, 1.4, 3000),  # inside and outside the table on both sides
            grid,
            np.nextafter(grid, -np.inf),
            np.nextafter(grid, np.inf),
            0.5 * (grid[1:] + grid[:-1]),
            [-0.0, -1e-300, 7.5, -3.25, np.inf, -np.inf, np.nan],
        ]
    )
    s = ca.SX.sym("S")
    model = np.asarray(ca.Function("ocv", [s], [battery.ocv_piecewise(s, ev.cell)])(ca.DM(S).T)).ravel()
    got = _lookup(sim, S)
    differ = ~((got == model) | (np.isnan(got) & np.isnan(model)))
    assert not differ.any(), (
        f"{differ.sum()} differ, first at S = {S[differ][:3]!r}: {got[differ][:3]} vs {model[differ][:3]}"
    )
    inside = np.isfinite(S) & (S >= 0) & (S <= 1)  # the cell's curve itself there: an independent oracle
    spline = np.asarray(battery.ocv_function(ev.cell)(ca.DM(S[inside]).T)).ravel()
    assert np.max(np.abs(got[inside] - spline)) < 1e-12


@pytest.mark.parametrize("name", sorted(EVS))
def test_compiled_ring_outputs_are_the_models_right_hand_side(name: str) -> None:
    sim = _sim(EVS[name])
    res = sim.run(uniform_flow(sim.ring, speed_mps=6.1, shift_m=2.3, vehicle=2, speed_dip_mps=1.4), 6.0)
    r = res.sim
    assert res.status == "ok" and len(r.t) > 5
    assert np.ptp(r.current_A) > 1.0 and np.ptp(r.current_A[-1]) > 0.01  # the outputs vary
    for k in range(len(r.t)):
        z = np.stack([r.gap[k], r.speed[k], r.V1[k], r.V2[k], r.S[k]], axis=1)  # model units, as the ring's state
        y = sim._outputs(z, np.zeros(sim.n))
        assert np.array_equal(r.current_A[k], y[:, 1]), k
        assert np.array_equal(r.accel[k], y[:, 0]), k


@pytest.mark.parametrize("name", sorted(EVS))
def test_piecewise_ocv_through_its_cached_function_is_the_written_out_expression(name: str) -> None:
    """ocv_piecewise of a dense SX (a scalar and a 3-vector) goes through a Function built once per table and shape:
    the values are those of the expression written out from Python, to the bit, at random SOCs inside and outside
    [0, 1], on the breakpoints and at ±inf; a second model reuses the Function."""
    cell = EVS[name].cell
    grid = battery.ocv_table(cell)[0]
    S = np.concatenate([np.random.default_rng(40).uniform(-0.3, 1.3, 600), grid, [np.inf, -np.inf]])
    for shape in ((1, 1), (3, 1)):
        s = ca.SX.sym("S", *shape)
        via = ca.Function("via", [s], [battery.ocv_piecewise(s, cell)])
        direct = ca.Function("direct", [s], [battery._ocv_piecewise_expression(s, cell, None)])
        X = ca.DM(np.resize(S, (shape[0], S.size)))
        a, b = np.asarray(via(X)), np.asarray(direct(X))
        assert a.shape == (shape[0], S.size) and np.array_equal(a, b)
    hits = battery._ocv_piecewise_function.cache_info().hits
    battery.ocv_piecewise(ca.SX.sym("T"), cell)
    assert battery._ocv_piecewise_function.cache_info().hits == hits + 1
