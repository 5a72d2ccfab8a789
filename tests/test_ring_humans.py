"""Calibrated human drivers on rings (issue 36.1): reaction times in the ring simulator against an independent
piecewise-exact integration, the Bando-FTL law, seeded heterogeneous populations, the jam wave's speed on a
synthetic wave, the calibration by simulation recovering known parameters, and the calibrated ring's jam."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from aev_ocp.calibration import calibrate_by_simulation
from aev_ocp.params import ParameterError
from aev_ocp.ring.humans import (
    SUGIYAMA_TARGETS,
    HumanPopulation,
    calibrated_ring,
    jam_statistics,
    population_ring,
    wave_speed_mps,
    within_tolerance,
)
from aev_ocp.ring.laws import BandoFTL, PISaturation, idm_si
from aev_ocp.ring.simulate import RingInitial, RingOptions, RingRoad, RingSimulator, uniform_flow


def _idm(a: float, v0: float, T: float) -> object:
    from aev_ocp.params import EVParams

    return idm_si(EVParams().units, a_mps2=a, b_mps2=1.5, v0_mps=v0, s0_m=2.0, T_s=T)


def _reference(L, ell, laws_si, delays, ddt, x0, v0, t_end):
    """Independent delayed ring: every ddt each driver's SI law on the state it saw at t + ddt/2 − τ (linear
    between updates, the initial state before 0), held; the motion between updates is exact (constant
    accelerations: speeds linear, positions quadratic)."""
    n = len(laws_si)
    x, v = np.array(x0, float), np.array(v0, float)
    hist_x, hist_v = [x.copy()], [v.copy()]
    steps = int(round(t_end / ddt))
    for k in range(steps):
        a = np.zeros(n)
        for i in range(n):
            tq = min(max(k + 0.5 - delays[i] / ddt, 0.0), float(k))
            j0 = int(math.floor(tq))
            w = tq - j0
            j1 = min(j0 + 1, k)
            xs = (1 - w) * hist_x[j0] + w * hist_x[j1]
            vs = (1 - w) * hist_v[j0] + w * hist_v[j1]
            p = (i - 1) % n
            gap = (xs[p] - xs[i]) % L - ell
            a[i] = laws_si[i](gap, vs[i], vs[p])
        x = x + v * ddt + 0.5 * a * ddt * ddt
        v = v + a * ddt
        hist_x.append(x.copy())
        hist_v.append(v.copy())
    return x, v


def test_reaction_times_match_an_independent_piecewise_exact_integration() -> None:
    """Three IDM drivers with reaction times 0.35, 0.8 and 1.25 s (one below, one above the 0.5 s ring buffer
    rows...) on a 60 m ring, no noise: positions and speeds after 20 s agree with the reference to 1e-6."""
    from aev_ocp.params import EVParams

    ev = EVParams()
    params = [(1.2, 13.0, 1.1), (0.9, 15.0, 0.8), (1.4, 12.0, 1.4)]
    laws = [_idm(*p) for p in params]

    def si(a, v0, T):
        return lambda h, v, vl: (
            a * (1 - (v / v0) ** 4 - ((2.0 + v * T + v * (v - vl) / (2 * math.sqrt(a * 1.5))) / h) ** 2)
        )

    delays = (0.35, 0.8, 1.25)
    L, ell = 60.0, 5.0
    ring = RingRoad(L, tuple(laws), ell, ev, delay_s=delays, delay_dt_s=0.1)
    x0 = (40.0, 22.0, 3.0)
    v0 = (6.0, 4.5, 5.2)
    res = RingSimulator(ring, RingOptions(rtol=1e-11, atol=1e-11, method="compiled")).run(RingInitial(x0, v0), 20.0)
    assert res.status == "ok"
    assert np.min(res.speed_mps) > 0.5  # the speed floor never acts: the reference has none
    xr, vr = _reference(L, ell, [si(*p) for p in params], delays, 0.1, x0, v0, 20.0)
    x = res.positions_m(wrap=False)[-1]
    np.testing.assert_allclose(res.speed_mps[-1], vr, atol=1e-6)
    np.testing.assert_allclose(x, xr, atol=1e-6)
    # the same ring without reaction times drives measurably differently (the delay acts)
    res0 = RingSimulator(dataclasses.replace(ring, delay_s=None), RingOptions(rtol=1e-11, atol=1e-11)).run(
        RingInitial(x0, v0), 20.0
    )
    assert np.max(np.abs(res0.speed_mps[-1] - vr)) > 1e-2


def test_uniform_flow_stays_uniform_with_reaction_times() -> None:
    """An equilibrium is one whatever the drivers' reaction times: identical delayed IDM drivers at the uniform
    speed keep it (to 1e-9 m/s) for 60 s."""
    ring = RingRoad(300.0, tuple([_idm(1.0, 15.0, 1.2)] * 8), 5.0, delay_s=(0.7,) * 8)
    res = RingSimulator(ring, RingOptions(rtol=1e-10, atol=1e-10)).run(uniform_flow(ring), 60.0)
    assert np.ptp(res.speed_mps) < 1e-9


def test_reaction_time_errors_name_the_field() -> None:
    laws = tuple([_idm(1.0, 15.0, 1.0)] * 4)
    with pytest.raises(ParameterError, match="delay_s needs 4"):
        RingRoad(100.0, laws, delay_s=(0.5, 0.5))
    with pytest.raises(ParameterError, match="delay_s"):
        RingRoad(100.0, laws, delay_s=(0.5, -0.1, 0.5, 0.5))
    with pytest.raises(ParameterError, match="delay_s"):
        RingRoad(100.0, laws, delay_s=(0.5, 5.01, 0.5, 0.5))
    with pytest.raises(ParameterError, match="sampled controller"):
        RingRoad(100.0, (PISaturation(),) + laws[1:], delay_s=(0.5, 0.0, 0.0, 0.0))
    with pytest.raises(ParameterError, match="delay_dt_s"):
        RingRoad(100.0, laws, delay_dt_s=0.0)


def test_bando_ftl_against_hand_values() -> None:
    """v̇ = α (V(h) − v) + β (v_l − v)/h² at h = 7.3 m, v = 4.1, v_l = 5.6 m/s with α = 0.6, β = 18, h_st = 2.2,
    v_max = 11: by hand; its equilibrium gap inverts V; SI and model units agree."""
    law = BandoFTL(alpha_per_s=0.6, beta_m2ps=18.0, h_st_m=2.2, v_max_mps=11.0)
    t2 = math.tanh(2.0)
    V = 11.0 * (math.tanh(7.3 / 2.2 - 2.0) + t2) / (1 + t2)
    want = 0.6 * (V - 4.1) + 18.0 * 1.5 / 7.3**2
    assert float(law.accel(7.3, 4.1, 5.6)) == pytest.approx(want, rel=1e-12)
    h = law.equilibrium_gap_m(6.2)
    assert float(law.accel(h, 6.2, 6.2)) == pytest.approx(0.0, abs=1e-12)
    from aev_ocp.params import Units

    u = Units(length_m=10.0, speed_mps=5.0)
    m = law.in_units(u)
    assert float(m.accel(0.73, 0.82, 1.12)) * u.accel_mps2 == pytest.approx(want, rel=1e-12)
    with pytest.raises(ParameterError, match="v_max"):
        law.equilibrium_gap_m(11.0)


def test_population_draws_are_seeded_lognormal_and_paired() -> None:
    pop = HumanPopulation("idm", {"v0_mps": 14.0, "T_s": 0.9}, delay_s=0.6, spread_cv=0.15, delay_cv=0.25)
    d1, t1 = pop.draw(4000, seed=7)
    d2, t2 = pop.draw(4000, seed=7)
    assert d1 == d2 and t1 == t2
    assert pop.draw(5, seed=8)[0] != d1[:5]
    # lognormal: log-median at the stated median, log-spread sqrt(log(1 + cv²)) (3 standard errors)
    logs = np.log([d["T_s"] for d in d1])
    s = math.sqrt(math.log1p(0.15**2))
    assert abs(float(np.mean(logs)) - math.log(0.9)) < 3 * s / math.sqrt(4000)
    assert float(np.std(logs)) == pytest.approx(s, rel=0.05)
    assert float(np.median(t1)) == pytest.approx(0.6, rel=0.03)
    # an AEV replaces one human and leaves the others' draws (and reaction times) as they were
    r0 = population_ring(pop, 230.0, 22, seed=3)
    r1 = population_ring(pop, 230.0, 22, seed=3, aevs={0: PISaturation()})
    assert r1.vehicles[1:] == r0.vehicles[1:] and r1.delay_s[1:] == r0.delay_s[1:]
    assert r1.delay_s[0] == 0.0 and not r1.human[0]
    with pytest.raises(ParameterError, match="not idm parameters"):
        HumanPopulation("idm", {"v_max_mps": 10.0})
    with pytest.raises(ParameterError, match="model"):
        HumanPopulation("gipps", {})


def test_wave_speed_of_a_synthetic_travelling_wave() -> None:
    """v_i(t) = v̄ + A sin(ω (t − i Δ)): the wave passes one vehicle per Δ = 1.37 s; on a ring of 22 over 230 m
    at v̄ = 2.3 m/s it moves over the ground at c = v̄ − (L/n)/Δ."""
    t = np.arange(0.0, 300.0, 0.1)
    n, L, vbar, lag = 22, 230.0, 2.3, 1.37
    omega = 2 * math.pi / (n * lag)
    v = vbar + 2.0 * np.sin(omega * (t[:, None] - np.arange(n)[None, :] * lag))
    c = wave_speed_mps(t, v, L)
    assert c == pytest.approx(vbar - (L / n) / lag, abs=0.02)
    assert math.isnan(wave_speed_mps(t, np.full((t.size, n), 3.0), L))


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_calibration_by_simulation_recovers_known_parameters() -> None:
    """Synthetic target: the mean speeds of 5 identical IDM drivers (v0 = 13.4 m/s, T = 1.35 s) on rings of 80 m
    and 160 m after 60 s; the fit from v0 = 10, T = 0.8 recovers both parameters."""
    from aev_ocp.ring.simulate import uniform_speed_mps

    def stats(p: dict[str, float]) -> dict[str, float]:
        out = {}
        for L in (80.0, 160.0):
            ring = RingRoad(L, tuple([_idm(1.0, p["v0_mps"], p["T_s"])] * 5), 5.0)
            res = RingSimulator(ring, RingOptions(rtol=1e-8, atol=1e-8, dt_out_s=1.0)).run(
                uniform_flow(ring, speed_mps=0.8 * uniform_speed_mps(ring)), 60.0
            )
            out[f"v{int(L)}"] = float(np.mean(res.speed_mps[-10:]))
        return out

    truth = {"v0_mps": 13.4, "T_s": 1.35}
    target = stats(truth)
    fit = calibrate_by_simulation(
        stats,
        {"v0_mps": 10.0, "T_s": 0.8},
        {"v0_mps": (5.0, 25.0), "T_s": (0.3, 3.0)},
        target,
        dict.fromkeys(target, 0.01),
        max_evaluations=80,
        xtol=1e-5,
    )
    assert fit.params["v0_mps"] == pytest.approx(13.4, rel=2e-3)
    assert fit.params["T_s"] == pytest.approx(1.35, rel=2e-3)
    assert max(abs(r) for r in fit.residuals.values()) < 1e-3
    with pytest.raises(ParameterError, match="same parameters"):
        calibrate_by_simulation(stats, {"v0_mps": 10.0}, {"T_s": (0.3, 3.0)}, target, dict.fromkeys(target, 1.0))


@pytest.mark.parametrize(("population", "max_collisions"), [("sugiyama_idm", 0), ("sugiyama_bandoftl", 1)])
def test_calibrated_sugiyama_ring_matches_its_targets_on_unseen_seeds(population: str, max_collisions: int) -> None:
    """The calibrated all-human Sugiyama ring (seeds 11, 12, 13: not the calibration's 101–103) jams as
    Sugiyama et al. 2008 report: wave ≈ −20 km/h, drivers leaving the jam at ≈ 40 km/h, stopping in it — each
    mean over the completed runs within the stated tolerance. The IDM drivers never collide; the Bando-FTL drivers
    (no reaction time, their braking saturating at the car's −8 m/s²) collide in seed 13 (1 of 12 seeds, 4–15)."""
    rows, collisions = [], 0
    for seed in (11, 12, 13):
        ring = calibrated_ring(seed=seed, population=population)
        res = RingSimulator(ring, RingOptions(rtol=1e-6, atol=1e-6, dt_out_s=0.1)).run(
            uniform_flow(ring, shift_m=2.0), 600.0
        )
        if res.status != "ok":
            assert res.status == "collision"
            collisions += 1
            continue
        rows.append(jam_statistics(res))
    assert collisions <= max_collisions
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    ok = within_tolerance(mean, SUGIYAMA_TARGETS)
    assert all(ok.values()), (mean, ok)


@pytest.mark.parametrize("name", ["ring_calibrated", "ring_calibrated_bandoftl"])
def test_the_calibrated_scenario_states_the_fit_the_code_uses(name: str) -> None:
    """scenarios/ring_calibrated.toml (and its packaged copy): the fitted values are the code's population, the
    residuals are achieved − target, the targets are SUGIYAMA_TARGETS; its rings carry the drivers' reaction
    times; a calibrated population beside human keys or a stray [ring.calibration] is refused naming the key."""
    import tomllib
    from pathlib import Path

    import aev_ocp
    from aev_ocp.ring.humans import calibrated_population
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario, parse_ring_scenario
    from aev_ocp.scenarios import ScenarioError

    root = Path(aev_ocp.__file__).parent  # the package as installed (editable or not)
    repo = (Path(__file__).resolve().parents[1] / "scenarios" / f"{name}.toml").read_text()  # the checkout's file
    assert (root / "scenario_files" / f"{name}.toml").read_text() == repo
    sc = load_ring_scenario(name)
    cal = sc.spec.calibration
    pop = calibrated_population(sc.spec.population)
    assert cal["values"] == [pytest.approx(pop.params[k], rel=1e-12) for k in cal["fitted"]]
    assert cal["target"] == [pytest.approx(SUGIYAMA_TARGETS[k][0], abs=2e-3) for k in cal["statistics"]]
    assert cal["tolerance"] == [pytest.approx(SUGIYAMA_TARGETS[k][1], abs=2e-3) for k in cal["statistics"]]
    for a, t, r in zip(cal["achieved"], cal["target"], cal["residual"]):
        assert r == pytest.approx(a - t, abs=2e-3)
    for a, t, tol in zip(cal["validation_achieved"], cal["target"], cal["tolerance"]):
        assert abs(a - t) <= tol
    ring, _ = build_ring(sc, None)
    assert ring.delay_s is not None
    assert (min(ring.delay_s) > 0) == (pop.delay_s > 0) and max(ring.delay_s) <= 5.0 * max(pop.delay_s, 1e-9)
    assert ring.noise_mps2 == pop.noise_mps2
    ring1, _ = build_ring(sc, "followerstopper")
    assert ring1.delay_s[0] == 0.0 and ring1.vehicles[1:] == ring.vehicles[1:]
    doc = tomllib.loads(repo)
    doc["ring"]["human"] = "idm"
    with pytest.raises(ScenarioError, match="ring.human"):
        parse_ring_scenario(doc, "x.toml")
    doc = tomllib.loads(repo)
    del doc["ring"]["population"]
    with pytest.raises(ScenarioError, match="ring.calibration"):
        parse_ring_scenario(doc, "x.toml")


def test_rings_of_one_structure_build_their_functions_and_c_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A ring of the same laws and car as an earlier one, with other coefficients (what a calibration simulates
    over and over), builds no CasADi function and no C source again (aev_ocp.ring.simulate._STRUCTURES) and runs
    as the same ring built afresh (the kept structures emptied), to the bit; a heavier car (1873 kg against the
    default 1752 kg: its battery side differs) builds its own."""
    from aev_ocp.params import EVParams
    from aev_ocp.ring import simulate as rs

    monkeypatch.setattr(rs, "_STRUCTURES", {})
    built: list[str] = []
    for name in ("_vehicle_function", "_source"):
        real = getattr(rs.RingSimulator, name)

        def counted(self: Any, *a: Any, _real: Any = real, _name: str = name) -> Any:
            built.append(_name)
            return _real(self, *a)

        monkeypatch.setattr(rs.RingSimulator, name, counted)

    def ring(v0: float, T: float, ev: EVParams | None = None) -> RingRoad:
        return RingRoad(95.0, (_idm(1.1, v0, T), _idm(0.9, v0 + 0.6, T)) * 3, 5.0, ev=ev or EVParams())

    def run(sim: RingSimulator) -> Any:
        return sim.run(uniform_flow(sim.ring, shift_m=1.3), 25.0)

    opts = RingOptions(rtol=1e-8, atol=1e-8, dt_out_s=0.5)
    RingSimulator(ring(12.2, 1.4), opts)
    first = list(built)
    assert first.count("_vehicle_function") == 1 and first.count("_source") == 1  # one IDM template
    other = ring(10.7, 1.75)
    kept = RingSimulator(other, opts)
    assert built == first and kept.method == "compiled"
    monkeypatch.setattr(rs, "_STRUCTURES", {})
    fresh = RingSimulator(other, opts)
    assert built == first * 2
    a, b = run(kept), run(fresh)
    assert a.status == b.status == "ok"
    np.testing.assert_array_equal(a.speed_mps, b.speed_mps)
    np.testing.assert_array_equal(a.gap_m, b.gap_m)
    np.testing.assert_array_equal(a.energy_J, b.energy_J)
    ev = EVParams()
    heavy = dataclasses.replace(ev, vehicle=dataclasses.replace(ev.vehicle, mass_kg=1873.0))
    h = RingSimulator(ring(10.7, 1.75, heavy), opts)
    assert built == first * 3 and h.funcs is not kept.funcs
    hr = run(h)
    assert hr.status == "ok" and np.all(hr.energy_J[-1] > 1.02 * a.energy_J[-1])  # the heavier car's battery works more
