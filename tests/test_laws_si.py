"""Laws in SI (issue 33.1) and Treiber's IDM (issue 34.3): a law's SI behaviour does not depend on the model units
it is simulated in; the paper's laws at their own scales are the paper's expressions untouched."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.models.carfollowing import (
    IDM,
    IDM_TREIBER,
    OVFL,
    OVM,
    CarFollowingLaw,
    IDMModelUnits,
    Proposed,
    make_law,
)
from aev_ocp.params import CarFollowingParams, ParameterError, Units

pytestmark = pytest.mark.quick

scale = st.floats(0.7, 40.0)
unit = st.floats(0.3, 50.0)


def _ov_si(h: float, v: float, vl: float, c: dict[str, float], kind: str) -> float:
    """The OV-type laws written again in SI from their SI coefficients (a second form of the same law)."""
    ell, u = c["h_scale_m"], c["v_scale_mps"]
    V = u * (math.tanh(h / ell - 2.0) + math.tanh(2.0))  # the OV function in m/s
    a = c["alpha_per_s"] * (V - v)
    if kind != "ovm":
        a += c["beta_m2ps"] * (vl - v) / h**2
    if kind == "proposed":
        dv2 = (vl - v) ** 2
        a -= c["kappa_per_m"] * v**2 * dv2 / (dv2 + c["eps_m2ps2"])
    return a


@settings(max_examples=60, deadline=None)
@given(
    ell=scale,
    u=st.floats(2.0, 30.0),
    L=unit,
    U=unit,
    h=st.floats(2.0, 80.0),
    v=st.floats(0.0, 30.0),
    dv=st.floats(-6.0, 6.0),
    kind=st.sampled_from(["ovm", "ovfl", "proposed"]),
)
def test_ov_laws_in_any_units_are_the_same_si_law(
    ell: float, u: float, L: float, U: float, h: float, v: float, dv: float, kind: str
) -> None:
    law = make_law(kind, CarFollowingParams(alpha=1.7, beta=2.6, kappa=0.047, eps=3e-4, h_scale_m=ell, v_scale_mps=u))
    units = Units(L, U)
    vl = max(v + dv, 0.0)
    model = float(law.in_units(units).accel(h / L, v / U, vl / U)) * units.accel_mps2
    si = float(law.accel_si(h, v, vl))
    by_hand = _ov_si(h, v, vl, law.si_coefficients(), kind)  # type: ignore[attr-defined]
    tol = 1e-9 * (1.0 + abs(by_hand))
    assert model == pytest.approx(by_hand, abs=tol)
    assert si == pytest.approx(by_hand, abs=tol)


@pytest.mark.parametrize("law", [OVM(1.3), OVFL(1.9, 2.7), Proposed(2.0, 3.0, 0.03, 1e-6)])
def test_scales_equal_to_the_units_give_the_paper_expression_bit_for_bit(law: CarFollowingLaw) -> None:
    for L, U in ((10.0, 5.0), (15.0, 17.0), (2.5, 5.0)):
        coeffs = {k: getattr(law, k) for k in ("alpha", "beta", "kappa", "eps") if hasattr(law, k)}
        own = type(law)(**coeffs, h_scale_m=L, v_scale_mps=U)
        bound = own.in_units(Units(L, U))
        assert bound.model_units is None  # type: ignore[attr-defined]
        pts = np.array([[0.37, 1.3, 2.9], [0.21, 1.1, 0.4], [0.9, 1.75, 1.9]])
        for h, v, vl in pts.T:
            assert float(bound.accel(h, v, vl)) == float(law.accel(h, v, vl))  # exactly, not approximately


def test_ov_equilibrium_gap_closed_form_against_bisection() -> None:
    law = Proposed(h_scale_m=12.5, v_scale_mps=7.5)
    for v in (0.4, 3.45, 8.1, 13.2):
        closed = law.equilibrium_gap_m(v)
        assert closed == pytest.approx(CarFollowingLaw.equilibrium_gap_m(law, v), rel=1e-10)
        assert float(law.accel_si(closed, v, v)) == pytest.approx(0.0, abs=1e-12)


def test_law_scales_are_checked() -> None:
    with pytest.raises(ParameterError, match="h_scale_m"):
        OVFL(h_scale_m=0.0)
    with pytest.raises(ParameterError, match="v_scale_mps"):
        Proposed(v_scale_mps=float("nan"))
    with pytest.raises(ParameterError, match="model_units"):
        OVM(model_units=3.0)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="no SI meaning"):
        IDMModelUnits().accel_si(10.0, 5.0, 5.0)


# ----------------------------------------------------------------------------- IDM (Treiber)
def test_idm_defaults_are_treiber_and_kestings() -> None:
    law = IDM()
    assert (law.a_mps2, law.b_mps2, law.s0_m, law.T_s, law.delta) == (1.0, 1.5, 2.0, 1.0, 4)
    assert law.v0_mps == pytest.approx(120 / 3.6)
    assert {k: getattr(law, k) for k in IDM_TREIBER} == IDM_TREIBER
    assert make_law("idm") == law


@settings(max_examples=40, deadline=None)
@given(L=unit, U=unit, h=st.floats(1.0, 90.0), v=st.floats(0.0, 32.0), vl=st.floats(0.0, 32.0))
def test_idm_by_hand_in_si_and_in_any_units(L: float, U: float, h: float, v: float, vl: float) -> None:
    a, b, v0, s0, T = 1.0, 1.5, 120 / 3.6, 2.0, 1.0
    s_star = s0 + v * T + v * (v - vl) / (2 * math.sqrt(a * b))
    by_hand = a * (1 - (v / v0) ** 4 - (s_star / h) ** 2)
    units = Units(L, U)
    law = IDM()
    assert float(law.accel(h, v, vl)) == pytest.approx(by_hand, rel=1e-12, abs=1e-12)
    got = float(law.in_units(units).accel(h / L, v / U, vl / U)) * units.accel_mps2
    assert got == pytest.approx(by_hand, rel=1e-10, abs=1e-10 * (1 + abs(by_hand)))


def test_idm_equilibrium_gap_closed_form_against_bisection() -> None:
    law = IDM(T_s=1.4, s0_m=2.3)
    for v in (0.0, 3.45, 17.2, 29.0):
        closed = law.equilibrium_gap_m(v)
        assert closed == pytest.approx(CarFollowingLaw.equilibrium_gap_m(law, v), rel=1e-10)
    assert law.equilibrium_gap_m(0.0) == 2.3  # standstill: s0
    with pytest.raises(ParameterError, match="v0"):
        law.equilibrium_gap_m(law.v0_mps)


def test_idm_in_model_units_is_the_old_conversion() -> None:
    """The ring's humans: IDM given units equals the model-unit IDM with converted parameters (same numbers)."""
    units = Units(10.0, 5.0)
    si = IDM(a_mps2=1.0, b_mps2=1.5, v0_mps=30.0, s0_m=2.0, T_s=1.0).in_units(units)
    old = IDMModelUnits(
        a_max=units.accel_from_si(1.0),
        b=units.accel_from_si(1.5),
        v0=units.speed_from_si(30.0),
        s0=units.length_from_si(2.0),
        T_h=units.time_from_si(1.0),
    )
    for h, v, vl in ((0.6, 0.7, 0.65), (1.3, 1.1, 1.4), (0.25, 0.2, 0.0)):
        assert float(si.accel(h, v, vl)) == float(old.accel(h, v, vl))


# ----------------------------------------------------------------------------- scenarios: [units] changes nothing
def _with_units(doc: dict, L: float, U: float) -> dict:
    d = copy.deepcopy(doc)
    d["units"] = {"length_m": L, "speed_mps": U}
    return d


def _same_si(law_a: CarFollowingLaw, ua: Units, law_b: CarFollowingLaw, ub: Units) -> None:
    for h, v, vl in ((7.5, 3.45, 3.1), (21.0, 8.2, 9.0), (4.1, 1.2, 0.0)):
        a = float(law_a.accel(ua.length_from_si(h), ua.speed_from_si(v), ua.speed_from_si(vl))) * ua.accel_mps2
        b = float(law_b.accel(ub.length_from_si(h), ub.speed_from_si(v), ub.speed_from_si(vl))) * ub.accel_mps2
        assert b == pytest.approx(a, rel=1e-10, abs=1e-12)


@pytest.mark.parametrize("name", ["proposed", "ovfl", "idm"])
def test_sumo_ring_and_merge_laws_do_not_depend_on_units(name: str) -> None:
    from aev_ocp.sumo.run import make_controller_factory
    from aev_ocp.sumo.scenario import load_sumo_scenario, parse_sumo_scenario

    for shipped in ("sumo_ring", "sumo_merge"):
        sc = load_sumo_scenario(shipped).with_point(controller=name)
        other = parse_sumo_scenario(_with_units(sc.document, 7.3, 11.9), "x.toml").with_point(controller=name)
        law_a, _ = make_controller_factory(sc)  # how the SUMO run builds its law
        law_b, _ = make_controller_factory(other)
        assert law_a is not None and law_b is not None
        _same_si(law_a, sc.ev.units, law_b, other.ev.units)
        if name != "idm":
            eq = law_a.equilibrium_gap_m(8.0)
            assert law_b.equilibrium_gap_m(8.0) == pytest.approx(eq, rel=1e-12)


@pytest.mark.parametrize("controller", ["proposed", "ovfl", "idm"])
def test_ring_laws_do_not_depend_on_units(controller: str) -> None:
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario, parse_ring_scenario

    sc = load_ring_scenario("ring_stern")
    other = parse_ring_scenario(_with_units(sc.document or {}, 3.7, 13.0), "x.toml")
    ra, _ = build_ring(sc, controller, aevs=(0,))
    rb, _ = build_ring(other, controller, aevs=(0,))
    for i in (0, 3):  # the AEV and a human (IDM)
        _same_si(ra.vehicles[i], sc.ev.units, rb.vehicles[i], other.ev.units)


def test_platoon_laws_do_not_depend_on_units() -> None:
    import aev_ocp

    sc = aev_ocp.load_scenario("udds_platoon")
    other = sc.with_overrides({"units.length_m": 6.1, "units.speed_mps": 23.0})
    for name in ("proposed", "ovfl"):
        _same_si(sc.law(name), sc.units, other.law(name), other.units)


@pytest.mark.parametrize("name", ["proposed", "ovfl", "idm"])
def test_safety_suite_laws_do_not_depend_on_units(name: str) -> None:
    from aev_ocp.safety.cases import CASE_UNITS, suite_cases
    from aev_ocp.safety.run import _law

    case = suite_cases()[7]
    other = Units(6.3, 21.0)
    _same_si(_law(name, case, CASE_UNITS), CASE_UNITS, _law(name, case, other), other)
    if name != "idm":  # at the suite's own units the law is the paper's expression, as before (bit for bit)
        old = {"proposed": Proposed(), "ovfl": OVFL()}[name]  # the paper's law in model units, as the suite had it
        new = _law(name, case, CASE_UNITS)
        for h, v, vl in ((0.41, 0.93, 1.07), (1.9, 1.2, 0.6)):
            assert float(new.function(h, v, vl)) == float(old.function(h, v, vl))


def test_si_keys_of_carfollowing() -> None:
    from aev_ocp.scenarios.followers import _carfollowing
    from aev_ocp.scenarios.tables import ScenarioError, TableReader

    t = {"h_scale_m": 12.0, "v_scale_mps": 6.0, "alpha_per_s": 0.9, "beta_m2ps": 144.0, "kappa_per_m": 0.0025}
    cf, _ = _carfollowing(TableReader(t, "carfollowing", "f.toml"))
    law = make_law("proposed", cf)
    c = law.si_coefficients()  # type: ignore[attr-defined]
    assert (c["alpha_per_s"], c["beta_m2ps"], c["kappa_per_m"]) == pytest.approx((0.9, 144.0, 0.0025), rel=1e-14)
    with pytest.raises(ScenarioError, match="alpha_per_s"):
        _carfollowing(TableReader({"alpha": 2.0, "alpha_per_s": 1.0}, "carfollowing", "f.toml"))


# ----------------------------------------------------------------------------- calibration (issue 33.2)
def test_calibration_recovers_known_scales_from_a_synthetic_target() -> None:
    from aev_ocp.calibration import calibrate

    truth = Proposed(h_scale_m=13.7, v_scale_mps=7.9)
    v = [1.5, 3.0, 4.5, 6.0, 7.5, 9.0, 10.5]
    cal = calibrate("proposed", v, [truth.equilibrium_gap_m(x) for x in v])
    assert cal.params["h_scale_m"] == pytest.approx(13.7, rel=1e-6)
    assert cal.params["v_scale_mps"] == pytest.approx(7.9, rel=1e-6)
    idm = IDM(s0_m=2.6, T_s=1.35)
    cal = calibrate("idm", v, [idm.equilibrium_gap_m(x) for x in v])
    assert (cal.params["s0_m"], cal.params["T_s"]) == pytest.approx((2.6, 1.35), rel=1e-6)


@pytest.mark.parametrize("name", ["proposed_ring", "ovfl_ring", "idm_ring"])
def test_shipped_calibrations_meet_their_target_within_their_residual(name: str) -> None:
    from aev_ocp.calibration import RING_HUMANS, load

    law, doc = load(name)
    t = doc["target"]
    assert t["speed_mps"] == RING_HUMANS["speed_mps"] and t["gap_m"] == pytest.approx(RING_HUMANS["gap_m"])
    res = np.array([law.equilibrium_gap_m(v) - g for v, g in zip(t["speed_mps"], t["gap_m"])])
    assert np.max(np.abs(res)) <= doc["max_abs_m"] * (1 + 1e-9)
    assert float(np.sqrt(np.mean(res**2))) == pytest.approx(doc["rms_m"], rel=1e-9)


def test_calibrated_proposed_law_is_the_same_si_law_on_ring_sumo_and_platoon_whatever_units() -> None:
    """Done-when of issue 33: the calibrated proposed law, named by [carfollowing] calibrated, keeps the same
    equilibrium gap and SI acceleration on the ring, the SUMO ring and merge and a drive-cycle platoon under any
    [units]."""
    import aev_ocp
    from aev_ocp.calibration import load
    from aev_ocp.ring.scenario import build_ring, load_ring_scenario, parse_ring_scenario
    from aev_ocp.sumo.run import make_controller_factory
    from aev_ocp.sumo.scenario import load_sumo_scenario, parse_sumo_scenario

    ref, _ = load("proposed_ring")
    gaps = [ref.equilibrium_gap_m(v) for v in (3.45, 6.0)]
    laws: list[tuple[CarFollowingLaw, Units]] = []
    ring = load_ring_scenario("ring_sugiyama")
    for L, U in ((10.0, 5.0), (2.5, 5.0), (15.0, 17.0)):
        d = _with_units(ring.document or {}, L, U)
        d["carfollowing"] = {"calibrated": "proposed_ring"}
        sc = parse_ring_scenario(d, "r.toml")
        rr, _ = build_ring(sc, "proposed", aevs=(0,))
        laws.append((rr.vehicles[0], sc.ev.units))
    for shipped in ("sumo_ring", "sumo_merge"):
        base = load_sumo_scenario(shipped)
        for L, U in ((10.0, 15.0), (2.5, 5.0)):
            d = _with_units(base.document, L, U)
            d["carfollowing"] = {"calibrated": "proposed_ring"}
            s = parse_sumo_scenario(d, "s.toml").with_point(controller="proposed")
            law, _ = make_controller_factory(s)
            assert law is not None
            laws.append((law, s.ev.units))
    from aev_ocp.scenarios.tables import ScenarioWarning

    with pytest.warns(ScenarioWarning, match="v_scale_mps"):  # UDDS's 25 m/s is beyond a ring law's top speed
        pl = aev_ocp.load_scenario("udds_platoon").with_overrides(
            {
                "carfollowing.h_scale_m": None,
                "carfollowing.v_scale_mps": None,
                "carfollowing.calibrated": "proposed_ring",
            }
        )
    laws.append((pl.law("proposed"), pl.units))
    for law, u in laws:
        _same_si(ref.in_units(Units(1.0, 1.0)), Units(1.0, 1.0), law, u)
        for v, g in zip((3.45, 6.0), gaps):  # the equilibrium gap at the same speed, through the model-unit law
            assert float(law.accel(u.length_from_si(g), u.speed_from_si(v), u.speed_from_si(v))) == pytest.approx(
                0.0, abs=1e-9
            )


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"speed_mps": [5.0, 10.0, 1e300]}, "speed_mps = 1e\\+300 is not allowed"),  # was a CasADi RuntimeError
        ({"speed_mps": [[5.0, 10.0]], "gap_m": [[20.0, 30.0]]}, "speed_mps = .* at least 2 finite"),  # TypeError
        ({"speed_mps": ["a", "b"], "gap_m": [1.0, 2.0]}, "speed_mps"),  # ValueError before
        ({"speed_mps": [True, False], "gap_m": [20.0, 30.0]}, "speed_mps"),  # fitted bools before
        ({"free": "T_s"}, "free = 'T_s' must be a list"),  # said "no parameter 'T'" before
        ({"free": ["a_mps2"]}, "\\['a_mps2'\\] .* do not change its equilibrium gap"),  # a_mps2 = 1.2e5 before
        ({"free": ["s0_m", "s0_m"]}, "twice"),
    ],
)
def test_calibrate_refuses_bad_targets_and_free_parameters_by_name(kw: dict, match: str) -> None:
    from aev_ocp.calibration import calibrate

    args = {"speed_mps": [5.0, 10.0, 15.0], "gap_m": [21.0, 32.0, 43.0], **kw}
    with pytest.raises(ParameterError, match=match):
        calibrate("idm", args.pop("speed_mps"), args.pop("gap_m"), **args)


def test_calibration_at_the_top_speed_and_a_saved_set_with_quotes_round_trips(tmp_path) -> None:  # noqa: ANN001
    from aev_ocp.calibration import calibrate, load, save

    from aev_ocp.models.carfollowing import make_law

    truth = make_law("ovfl", None, h_scale_m=23.7, v_scale_mps=41.3)
    v = [4.0, 12.0, 62.5]  # on the top speed: allowed
    cal = calibrate("ovfl", v, [truth.equilibrium_gap_m(x) for x in v])
    assert cal.params["h_scale_m"] == pytest.approx(23.7, rel=1e-6) and cal.max_abs_m < 1e-6
    p = save(cal, tmp_path / "c.toml", target_name='my "fit"\nline', source="C:\\data")  # wrote broken TOML before
    law, doc = load(p)
    assert doc["target"]["name"] == 'my "fit"\nline' and doc["target"]["source"] == "C:\\data"
    assert law.h_scale_m == cal.law.h_scale_m
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfelaw")
    with pytest.raises(ParameterError, match="bin.toml: cannot read it"):  # UnicodeDecodeError before
        load(tmp_path / "bin.toml")
    with pytest.raises(ParameterError, match="cannot write it"):  # FileExistsError before
        save(cal, tmp_path / "bin.toml" / "x.toml")
