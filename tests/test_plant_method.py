"""The plant's CVODES method (aev_ocp.plant.NONSTIFF): Adams–Moulton with functional iteration, an interval it fails
on retried with BDF and Newton iteration. Checked against SciPy's Radau on the same equations written out here."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aev_ocp.models.carfollowing import OVM
from aev_ocp.models.leader import ConstantSpeed, PaperLeader
from aev_ocp.params import EVParams
from aev_ocp.plant import NONSTIFF, Plant

V_LEAD = 1.3  # leader speed [model]
H0, V0 = 1.1, 0.9  # initial gap and speed [model]
T1 = 0.37  # interval end [model time]


def _run(plant: Plant, a: float, b: float, x: np.ndarray) -> tuple[bool, list, list]:
    q = np.zeros(plant.nq)
    out = ([np.array([a])], [x[:, None]], [q[:, None]], [plant.samples(np.array([a]), x[:, None])])
    events: list = []
    return plant.advance(a, b, x, q, None, out, events), out, events


def _radau(plant: Plant, x0: np.ndarray) -> np.ndarray:
    """The state at T1 by SciPy's Radau (for stiff problems) at rtol 1e-11 on the plant's own right-hand side (its
    law, after the vehicle's acceleration bounds), from x0 at t = 0."""
    dae = plant._dae
    f = ca.Function("rhs", [dae["t"], dae["x"], dae["p"]], [dae["ode"]])

    def rhs(s: float, y: np.ndarray) -> np.ndarray:
        return np.asarray(f(s, y, [0.0, 1.0])).ravel()

    sol = solve_ivp(rhs, (0.0, T1), x0, method="Radau", rtol=1e-11, atol=1e-12)
    assert sol.success
    return sol.y[:, -1]


def test_the_plant_integrates_with_adams_and_functional_iteration() -> None:
    p = Plant(PaperLeader(), [None], EVParams())
    assert (
        {k: p._int_opts[k] for k in NONSTIFF}
        == NONSTIFF
        == {
            "linear_multistep_method": "adams",
            "nonlinear_solver_iteration": "functional",
        }
    )
    assert "linear_multistep_method" not in p._stiff_opts  # the fallback: CVODES's default BDF with Newton


def test_an_interval_the_nonstiff_method_cannot_take_is_integrated_by_bdf() -> None:
    """A stiff law (OVM with α = 2000: a time constant of 5e-4 model time) within a step budget that Adams with
    functional iteration exceeds (about 790 steps) and BDF with Newton does not (about 570): the interval ends in one
    piece, integrated by BDF, equal bit for bit to the fallback integrator's own result and to Radau within 1e-8."""
    law = OVM(alpha=2000.0)
    p = Plant(ConstantSpeed(V_LEAD), [law], battery=False, max_num_steps=680)
    x0 = p.initial_state([H0], [V0])
    ok, out, events = _run(p, 0.0, T1, x0)
    assert ok and events == [] and p.stiff_retries == 1
    assert len(out[0]) == 2 and out[0][-1][-1] == T1  # one piece: not subdivided
    x1 = out[1][-1][:, -1]
    direct = np.asarray(p.stiff(x0=x0, p=[0.0, T1])["xf"]).ravel()
    np.testing.assert_array_equal(x1, direct)
    np.testing.assert_allclose(x1, _radau(p, x0), rtol=0, atol=1e-8)
    with pytest.raises(RuntimeError):  # the non-stiff integrator alone cannot: what the fallback is for
        p.integrator(x0=x0, p=[0.0, T1])


def test_a_nonstiff_interval_needs_no_fallback_and_agrees_with_radau() -> None:
    law = OVM(alpha=2.7)  # a law's usual stiffness (the paper's α = 2)
    p = Plant(ConstantSpeed(V_LEAD), [law], battery=False)
    x0 = p.initial_state([H0], [V0])
    ok, out, _ = _run(p, 0.0, T1, x0)
    assert ok and p.stiff_retries == 0
    np.testing.assert_allclose(out[1][-1][:, -1], _radau(p, x0), rtol=0, atol=1e-9)
