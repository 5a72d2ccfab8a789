"""The compiled simulators' speed-ups keep every number (issue 40, item 6).

The ring (aev_ocp/c/ring.c) and the cascade (aev_ocp/c/cascade.c) are built with -O3 for the native CPU, contraction
off and no semantic interposition (aev_ocp.compiled.exact_tuned_flags): their runs must equal, to the bit, the
same source built without those flags (plain -O2 for generic x86-64, where no fused multiply-add exists), so a run's
numbers depend neither on the machine's CPU nor on how the compiler vectorised a loop. The restructured ring (one
pass per stage, the predecessor's stage speed recomputed where it is read, the battery's stages per vehicle) is
checked against CVODES and a SciPy twin in tests/test_ring.py and tests/test_ring_integrator.py; the cascade's
sample table (quantity × vehicle rows, no transpose) against CVODES in tests/test_simulate.py and here with an event
behind the first vehicle (the vehicles ahead are integrated again to the event time)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import aev_ocp.ring.simulate as RS
import aev_ocp.simulate as S
from aev_ocp.compiled import exact_tuned_flags
from aev_ocp.models import OVFL, OVM, PaperLeader, Proposed
from aev_ocp.params import EVParams, SimOptions
from aev_ocp.ring.laws import FollowerStopper, idm_si
from aev_ocp.ring.simulate import RingOptions, RingRoad, RingSimulator, uniform_flow

EV = EVParams()
pytestmark = pytest.mark.skipif(not exact_tuned_flags(), reason="the compiler cannot name the native CPU")


def _ring_run(monkeypatch: pytest.MonkeyPatch, tuned: bool) -> RS.RingResult:
    if not tuned:
        monkeypatch.setattr(RS, "exact_tuned_flags", lambda: ())
    monkeypatch.setattr(RS, "_BUILT", {})  # build (or load from the cache) the library of these flags
    laws = [idm_si(EV.units, T_s=1.0 + 0.05 * i) for i in range(11)] + [FollowerStopper.from_si(EV.units, 5.1)]
    ring = RingRoad(150.0, tuple(laws), ev=EV, noise_mps2=0.2, seed=7)
    init = uniform_flow(ring, speed_mps=5.9, shift_m=2.2, vehicle=4, speed_dip_mps=0.9)
    res = RingSimulator(ring, RingOptions(rtol=1e-6, atol=1e-6, dt_out_s=0.5, method="compiled")).run(init, 40.0)
    monkeypatch.undo()
    assert res.status == "ok" and res.stats["method"] == "compiled"
    return res


def test_tuned_ring_equals_the_plain_build_to_the_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    a, b = _ring_run(monkeypatch, True), _ring_run(monkeypatch, False)
    assert a.stats["steps"] == b.stats["steps"] and a.stats["rejected"] == b.stats["rejected"]
    for name in ("gap", "speed", "accel", "omega", "V1", "V2", "S", "current_A", "heat_J"):
        np.testing.assert_array_equal(getattr(a.sim, name), getattr(b.sim, name), err_msg=name)
    np.testing.assert_array_equal(a.energy_J, b.energy_J)
    np.testing.assert_array_equal(a.distance, b.distance)


def _platoon_run(monkeypatch: pytest.MonkeyPatch, tuned: bool, ev: EVParams = EV) -> S.SimulationResult:
    if not tuned:
        monkeypatch.setattr(S, "exact_tuned_flags", lambda: ())
    laws = [Proposed(), OVFL(), OVM(alpha=1.5), Proposed(kappa=0.1)]
    sim = S.PlatoonSimulator(PaperLeader(), laws, ev=ev, options=SimOptions(dt_out=0.05, method="cascade"))
    res = sim.run(np.array([0.3, 3.5, 3.1, 2.9]), np.full(4, 1.87), 30.0)
    monkeypatch.undo()
    return res


def test_tuned_cascade_equals_the_plain_build_to_the_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    a, b = _platoon_run(monkeypatch, True), _platoon_run(monkeypatch, False)
    for name in ("t", "gap", "speed", "accel", "omega", "S", "current_A", "heat_J", "int_jerk2", "battery_energy_J"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert [s["nsteps"] for s in a.solver_stats] == [s["nsteps"] for s in b.solver_stats]


def test_cascade_table_at_an_event_behind_the_first_vehicle_equals_cvodes() -> None:
    """The third follower starts 0.15 behind its predecessor and faster, with a sluggish OVM: it collides first (at
    t ≈ 0.23). The vehicles ahead are then integrated again to the collision time and their rows at the event are
    read from that second table; every row of the run's last sample (and the samples before) must agree with
    CVODES."""
    laws = [Proposed(), Proposed(kappa=0.3), OVM(alpha=0.3)]
    gaps, speeds = np.array([3.0, 3.5, 0.15]), np.array([1.87, 1.87, 2.6])
    res = {
        m: S.PlatoonSimulator(PaperLeader(), laws, options=SimOptions(dt_out=0.05, method=m)).run(gaps, speeds, 70.0)
        for m in ("cascade", "cvodes")
    }
    a, b = res["cascade"], res["cvodes"]
    assert [(e.kind, e.vehicle) for e in a.events] == [(e.kind, e.vehicle) for e in b.events] == [("collision", 2)]
    assert a.t.size == b.t.size and a.t[-1] == pytest.approx(b.t[-1], abs=1e-8)
    for name in ("gap", "speed", "accel", "S", "omega", "current_A", "heat_J"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-6, atol=1e-7, err_msg=name)
    assert a.gap[-1, 2] == pytest.approx(0.0, abs=1e-8) and np.all(a.gap[-1, :2] > 1.0)


def test_equal_laws_are_probed_once_and_differing_bits_are_not_merged(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[object] = []
    orig = S._law_template
    monkeypatch.setattr(S, "_law_template", lambda law: (calls.append(law), orig(law))[1])
    laws = [Proposed(kappa=0.25) for _ in range(40)] + [Proposed(kappa=0.5)]
    out = S._law_templates(laws)
    assert len(calls) == 2 and len(out) == 41
    assert out[0] is out[39] and out[40][2] != out[0][2]
    calls.clear()
    signed = [Proposed(kappa=0.0), Proposed(kappa=-0.0)]  # equal as numbers, different bits
    typed = [dataclasses.replace(Proposed(), kappa=1.0), dataclasses.replace(Proposed(), kappa=1)]  # float vs int
    out = S._law_templates(signed + typed)
    assert len(calls) == 4
    assert np.signbit(out[1][2]).any() and not np.signbit(out[0][2]).any()


def _mpc_loop(monkeypatch: pytest.MonkeyPatch, tuned: bool, hessian: str) -> tuple[str, np.ndarray, list[np.ndarray]]:
    """The §9 closed loop (one follower behind the Table 1 leader) on the compiled MPC step, N = 8: the library,
    the applied accelerations and each step's plan with its multipliers."""
    import aev_ocp.compiled as B
    from aev_ocp.control import ClosedLoop
    from aev_ocp.mpc import MPCVehicle
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.ocp.formulation import s9_formulation

    if not tuned:
        monkeypatch.setattr(B, "exact_tuned_flags", lambda: ())
    s = MPCSettings(N=8, rti_hessian=hessian, predictor="oracle", solver="rti", qp_solver="riccati", codegen=True)
    loop = ClosedLoop(PaperLeader(), [MPCVehicle(s, formulation=s9_formulation())])
    c = loop.ctrl[0].controller  # type: ignore[union-attr]
    assert c.compiled_step is not None
    plans: list[np.ndarray] = []
    solve = c.solve

    def rec(*a: object, **kw: object) -> object:
        out = solve(*a, **kw)
        x, lam_g, lam_x, _ = c.compiled_step.solution()
        plans.append(np.concatenate([x, lam_g, lam_x]))
        return out

    c.solve = rec
    r = loop.run([0.3], [1.87], 6.0)
    monkeypatch.undo()
    return str(c.compiled_step.lib._name), np.asarray(r.accel), plans


@pytest.mark.parametrize("hessian", ["exact", "projected"])
def test_tuned_mpc_step_equals_the_plain_build_to_the_bit(monkeypatch: pytest.MonkeyPatch, hessian: str) -> None:
    """The compiled MPC step (aev_ocp/c/mpc_step.c, ocp_qp.c and the generated CasADi C) is built with the tuned
    flags too: every plan, multiplier and applied acceleration of a closed loop equals the plain build's."""
    (lib_t, a_t, p_t), (lib_p, a_p, p_p) = _mpc_loop(monkeypatch, True, hessian), _mpc_loop(monkeypatch, False, hessian)
    assert lib_t != lib_p  # two builds (the flags are part of the cache key)
    assert len(p_t) == len(p_p) > 50
    np.testing.assert_array_equal(a_t, a_p)
    for k, (x, y) in enumerate(zip(p_t, p_p, strict=True)):
        np.testing.assert_array_equal(x, y, err_msg=f"step {k}")
