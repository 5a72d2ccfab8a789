"""The paper's claims, checked with two independent integrators."""

from __future__ import annotations

import numpy as np

from aev_ocp.claims import compare_laws, paper_platoon_check, random_cases, theorem41_summary
from aev_ocp.models import PaperLeader
from aev_ocp.reference import simulate_reference


def test_theorem41_fails_for_follower5_of_the_paper_platoon() -> None:
    """Both CVODES (aev_ocp) and SciPy's DOP853 (reference) find ω(proposed) > ω(OVFL) for follower 5."""
    r = paper_platoon_check()
    gaps, speeds = np.array([0.3] + [3.5] * 4), np.full(5, 1.87)
    cascade = compare_laws(PaperLeader(), list(gaps), list(speeds), 70.0, method="cascade")
    ref = {k: simulate_reference(k, gaps, speeds, 70.0, battery=False)["omega"] for k in ("proposed", "ovfl")}
    np.testing.assert_allclose(r["omega_proposed"], ref["proposed"], atol=1e-6)
    np.testing.assert_allclose(r["omega_ovfl"], ref["ovfl"], atol=1e-6)
    np.testing.assert_allclose(cascade["omega_proposed"], ref["proposed"], atol=1e-6)
    np.testing.assert_allclose(cascade["omega_ovfl"], ref["ovfl"], atol=1e-6)
    assert r["violating_followers"] == [5]
    assert ref["proposed"][4] - ref["ovfl"][4] > 1e-3  # far above the integration error
    # the proof's step "the OVFL follower is never slower" fails for every follower
    assert r["followers_faster_under_proposed"] == [1, 2, 3, 4, 5]


def test_random_counterexample_confirmed_by_scipy() -> None:
    cases = random_cases(12, seed=2025)
    s = theorem41_summary(cases)
    assert s["n_completed"] == 12 and s["n_violating_theorem"] >= 1
    bad = next(c for c in cases if c.violates and c.leader == "constant")
    v_l = bad.leader_speed
    from aev_ocp.params import CarFollowingParams

    p = CarFollowingParams(kappa=bad.kappa)
    ref = {
        k: simulate_reference(
            k,
            np.array([bad.gap0]),
            np.array([bad.speed0]),
            70.0,
            battery=False,
            leader_speed=lambda t: v_l,
            breakpoints=(),
            p=p,
        )["omega"][0]
        for k in ("proposed", "ovfl")
    }
    np.testing.assert_allclose([ref["proposed"], ref["ovfl"]], [bad.omega_proposed, bad.omega_ovfl], atol=1e-6)
    assert ref["proposed"] > ref["ovfl"] + 1e-5
