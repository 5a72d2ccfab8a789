"""Compile once (issue 40 item 1): the platoon cascade's generated C does not depend on the numbers of a scenario
(the leader's speed or recorded table, the g split, the vehicle's cell, limits and thermal fields are run-time
inputs), so scenarios that differ only in parameters share one compiled library; with the parameters as inputs
the results are bit for bit those of the library with the numbers compiled in, and they follow the numbers
(CVODES, an independent integrator, agrees for each). Compilations are counted with
:func:`aev_ocp.compiled.compilations`, never timed."""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

import aev_ocp.compiled as B
import aev_ocp.simulate as S
from aev_ocp.models.carfollowing import Proposed
from aev_ocp.models.leader import ConstantSpeed, PaperLeader, SpeedTrace, drive_cycle
from aev_ocp.params import CellParams, EVParams, Units, UNLIMITED

pytestmark = pytest.mark.skipif(B.compiler() is None, reason="needs a C compiler")


def _ev(r_s: float) -> EVParams:
    return EVParams(cell=dataclasses.replace(CellParams(), R_s_ohm=r_s), limits=UNLIMITED)


def _run(leader, kappa: float, r_s: float, method: str = "auto"):
    law = Proposed(alpha=2.3, beta=2.7, kappa=kappa, eps=1e-6)
    return S.simulate_platoon(
        leader, [law, law], [1.4, 1.25], [0.9, 1.05], 6.0, ev=_ev(r_s), dt_out=0.05, rtol=1e-9, atol=1e-9, method=method
    )


def test_scenarios_differing_only_in_parameters_share_one_library(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    n0 = len(B.compilations())
    a = _run(ConstantSpeed(1.15), 0.03, 0.0121)
    assert B.compilations()[n0:] == ["aevsim"]
    b = _run(ConstantSpeed(0.85), 0.045, 0.0154)  # another leader speed, law coefficient and cell resistance
    assert B.compilations()[n0:] == ["aevsim"]  # the same library: nothing compiled again
    assert a.meta["integrator"] == b.meta["integrator"] == "cascade-dopri5"
    # the run-time numbers are really used: each run agrees with CVODES on its own parameters, not the other's
    for res, (v, kappa, r_s) in ((a, (1.15, 0.03, 0.0121)), (b, (0.85, 0.045, 0.0154))):
        ref = _run(ConstantSpeed(v), kappa, r_s, method="cvodes")
        np.testing.assert_allclose(res.gap, ref.gap, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(res.V1, ref.V1, rtol=1e-5, atol=1e-8)
    assert not np.allclose(a.gap, b.gap)


def test_recorded_leaders_of_different_lengths_share_one_library(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("AEV_OCP_CACHE", str(tmp_path / "cache"))
    n0 = len(B.compilations())
    units = Units(15.0, 17.0)
    for cycle in ("hwfet", "udds"):  # 766 and 1370 samples: one padded table length
        _run(drive_cycle(cycle, units), 0.03, 0.0121)
    assert B.compilations()[n0:] == ["aevsim"]


@pytest.mark.parametrize(
    "leader",
    [
        ConstantSpeed(0.37),
        PaperLeader(),
        PaperLeader(v0=1.3, amplitude=0.8),
        SpeedTrace((0.0, 1.5, 2.25, 7.0), (0.0, 0.6, 0.55, 1.3)),
    ],
)
def test_leader_as_runtime_input_is_bit_identical_to_compiled_in_numbers(leader) -> None:
    """aevsim_leader(t, q) with this leader's q gives exactly (==) speed(t) and its slope as compiled in, at the
    knots, just beside them and between them (the padded table holds the same intervals)."""
    f, q = S._leader_template(leader)
    assert q.size > 0  # a runtime input, not compiled in
    t = ca.SX.sym("t")
    v = leader.speed(t)
    ref = ca.Function("ref", [t], [ca.vertcat(v, ca.jacobian(v, t))])
    ts = np.concatenate([np.linspace(-0.5, 30.0, 613), [1.5, 2.25, 7.0, 1.5 - 1e-13, 2.25 + 1e-13, 20.0, 20.0 + 1e-12]])
    for x in ts:
        assert np.array_equal(np.asarray(f(x, q)), np.asarray(ref(x))), x


def test_a_parameter_that_would_change_the_rounding_stays_compiled_in() -> None:
    """The units and the vehicle's body enter products of several constants that CasADi folds when they are
    numbers: as inputs the right-hand side differs in the last bits, so they stay compiled in (the paper's
    numbers bit-identical); the cell's fields do not, so they are inputs."""
    sim = S.PlatoonSimulator(ConstantSpeed(0.5), [Proposed()], _ev(0.0121))
    chosen = {p[0] for p in S._EV_PATHS[(True, S._skeleton(sim.ev), S._law_template(sim.laws[0])[0])]}
    assert "cell" in chosen and "units" not in chosen and "vehicle" not in chosen


def _per_point_choice(sim: S.PlatoonSimulator) -> tuple[tuple[str, ...], ...]:
    """The fields the probe should choose, by its definition with one call per probe point and a compiled-in and a
    parameter function built for every candidate set: all fields if they give the compiled-in right-hand side bit
    for bit, else each top-level group that does, and nothing if those together do not."""
    _, make, law_values = S._law_template(sim.laws[0])
    n_par = max(1, len(law_values))
    law = np.concatenate([law_values, np.zeros(n_par - len(law_values))])
    every = S._float_paths(sim.ev)
    points = S.ev_probe_points(sim.battery, sim.ev.limits.has_actuator_state)

    def same(paths: list[tuple[str, ...]]) -> bool:
        if not paths:
            return False
        p = ca.SX.sym("p", n_par + len(paths))
        values = np.concatenate([law, [float(S._get(sim.ev, pth)) for pth in paths]])
        try:
            baked = sim._vehicle_function(make(p[:n_par]), 0, p)
            symbolic = sim._vehicle_function(make(p[:n_par]), 0, p, S._with_symbols(sim.ev, paths, p[n_par:]))
        except (TypeError, ValueError, RuntimeError, NotImplementedError, S.ParameterError, AttributeError):
            return False
        for u, x in points:
            for a, b in zip(baked(u, x, values), symbolic(u, x, values)):
                if not np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True):
                    return False
        return True

    if same(every):
        return tuple(every)
    groups = {g: [pth for pth in every if pth[0] == g] for g in dict.fromkeys(pth[0] for pth in every)}
    chosen = [pth for members in groups.values() if same(members) for pth in members]
    return tuple(chosen) if same(chosen) else ()


#: the groups chosen by (battery, limits on): never the units or the body (products CasADi folds), the limits only
#: where they are off (on, they reach float() and comparisons)
GROUPS_CHOSEN = {
    (True, False): {"cell", "limits", "thermal"},
    (True, True): {"cell", "thermal"},
    (False, False): {"cell", "limits", "thermal"},
}


@pytest.mark.parametrize(
    "ev, battery",
    [
        (_ev(0.0121), True),
        (EVParams(), True),  # the shipped limits: saturation and the speed range
        (EVParams(limits=dataclasses.replace(EVParams().limits, lag_s=0.23)), True),  # an actuator state
        (_ev(0.0173), False),
    ],
)
def test_the_batched_probe_chooses_what_its_definition_chooses_point_by_point(ev: EVParams, battery: bool) -> None:
    """The probe evaluates each function once over all its points (mapped) and builds the compiled-in one once for
    every candidate set: the same fields as the definition checked one point and one pair of functions at a time."""
    S._EV_PATHS.clear()
    sim = S.PlatoonSimulator(ConstantSpeed(0.5), [Proposed(alpha=2.3, kappa=0.61)], ev, battery=battery)
    chosen = S._EV_PATHS[(battery, S._skeleton(sim.ev), S._law_template(sim.laws[0])[0])]
    assert chosen and chosen == _per_point_choice(sim)
    assert {pth[0] for pth in chosen} == GROUPS_CHOSEN[(battery, sim.ev.limits.enabled)]


def test_s9_compiled_step_builds_its_cold_ipopt_only_when_a_cold_start_fails(monkeypatch) -> None:
    """§9's compiled rti step starts cold by itself (its regularised SQP) and hands over to the cold IPOPT only after
    a cold start that failed: the IPOPT is built then (not with the controller: reproduce's §9 controllers never ran
    it, and its NLP is ~10 s of gcc), before the step's clock starts, and gives the plan of a controller that built
    it up front (§9's interpreted rti path, whose cold start is that IPOPT)."""
    import aev_ocp.mpc.controller as C
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.ocp.formulation import s9_formulation

    # it counts no compilations: its libraries come from the environment's cache (issue 40: a cache of its own
    # compiled §9's mpc_step, ~7 s of gcc, in every run)
    s = MPCSettings(N=6, dt=0.2, solver="rti", qp_solver="riccati", codegen=False)  # NLP interpreted: no gcc for it
    c = C.MPCController(s, formulation=s9_formulation())
    assert c.compiled_step is not None and c._cold_ipopt is None
    z, vm, vh = np.array([1.3, 0.9, 0.0, 0.0, 0.8]), np.full(6, 0.95), np.full(6, 0.97)
    sol = c.solve(z, vm, vh)
    assert sol.success and sol.path != "ipopt-cold" and c._cold_ipopt is None  # a good cold start: no IPOPT
    c.warm = None
    c.compiled_step.reset()  # the next step is cold; its compiled cold start fails (planted: a failed QP)
    monkeypatch.setattr(C, "solve_compiled", lambda ctl, z0, p: ctl.failed("QP failed: planted", 0, 0.0, 0.0, "rti"))
    sol = c.solve(z, vm, vh)
    assert sol.success and sol.path == "ipopt-cold" and c._cold_ipopt is not None
    ref = C.MPCController(dataclasses.replace(s, qp_solver="hpipm"), formulation=s9_formulation())
    assert ref.compiled_step is None and ref._cold_ipopt is not None  # built with the controller
    r = ref.solve(z, vm, vh)
    assert r.success and r.path == "ipopt-cold"
    np.testing.assert_allclose(sol.X, r.X, rtol=0, atol=1e-7)  # IPOPT tolerance 1e-8 (numbers in vs as inputs)
    np.testing.assert_allclose(sol.a, r.a, rtol=0, atol=1e-7)
