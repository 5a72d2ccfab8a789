"""Linear stability of mixed rings (aev_ocp.stability.mixed) against independent constructions: the Fourier modes of
identical rings, the CasADi Jacobian of the full nonlinear ring, the per-mode transcendental equation with delay."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from aev_ocp.params import ParameterError
from aev_ocp.stability.ring import mode_eigenvalues
from aev_ocp.stability import mixed as M

RING_M, N, CAR_M, VMAX = 230.0, 22, 4.7, 33.0


def idm(a=1.3, b=1.7, v0=27.0, s0=2.1, T=1.2) -> ca.Function:
    """Treiber's IDM in SI, written out here (not the package's class)."""
    h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl")
    s_star = s0 + v * T + v * (v - vl) / (2 * math.sqrt(a * b))
    return ca.Function("idm", [h, v, vl], [a * (1 - (v / v0) ** 4 - (s_star / h) ** 2)])


def ovfl(alpha=0.55, beta=21.0, vmax=13.0, hs=8.0, hc=11.0) -> ca.Function:
    """An OV + follow-the-leader law in SI (Bando's tanh OV function scaled to hs, hc, vmax)."""
    h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl")
    V = 0.5 * vmax * (ca.tanh((h - hc) / hs) + math.tanh(hc / hs))
    return ca.Function("ovfl", [h, v, vl], [alpha * (V - v) + beta * (vl - v) / h**2])


def full_jacobian_eigs(accels, gaps, v, lags=None):
    """Eigenvalues of the Jacobian of the full nonlinear ring (CasADi AD on the whole system)."""
    n = len(accels)
    lags = lags or [0.0] * n
    h, vv, a = ca.SX.sym("h", n), ca.SX.sym("v", n), ca.SX.sym("a", n)
    rhs, x, x0 = [], [h, vv], [np.asarray(gaps), np.full(n, v)]
    hd = [vv[(i - 1) % n] - vv[i] for i in range(n)]
    f = [accels[i](h[i], vv[i], vv[(i - 1) % n]) for i in range(n)]
    vd = [a[i] if lags[i] > 0 else f[i] for i in range(n)]
    ad = [(f[i] - a[i]) / lags[i] for i in range(n) if lags[i] > 0]
    rhs = ca.vertcat(*hd, *vd, *ad)
    if ad:
        x.append(ca.vertcat(*[a[i] for i in range(n) if lags[i] > 0]))
        x0.append(np.zeros(len(ad)))
    X = ca.vertcat(*x)
    J = np.array(ca.Function("J", [X], [ca.jacobian(rhs, X)])(np.concatenate(x0)))
    lam = np.linalg.eigvals(J)
    lam = np.delete(lam, np.argmin(np.abs(lam)))
    return lam[np.argsort(-lam.real)]


def _match(a: np.ndarray, b: np.ndarray, tol: float) -> None:
    """Every eigenvalue of a has one in b within tol."""
    for x in a:
        assert np.min(np.abs(b - x)) < tol, (x, b[:6])


@pytest.mark.parametrize("lag_s", [0.0, 0.37])
def test_identical_ring_equals_its_fourier_modes(lag_s):
    law = idm()
    r = M.analyse_mixed_ring([law] * N, RING_M, CAR_M, VMAX, lags_s=lag_s)
    _, lin = M.linearise([law] * N, RING_M, [CAR_M] * N, VMAX, [lag_s] * N)
    p = lin[0]
    modes = np.concatenate(
        [mode_eigenvalues(p.f_h_per_s2, p.f_v_per_s, p.f_dv_per_s, 2 * np.pi * k / N, lag_s) for k in range(1, N)]
    )
    assert r.growth_rate_per_s == pytest.approx(modes.real.max(), abs=1e-12)
    _match(np.array([complex(*e) for e in r.eigenvalues_per_s]), modes, 1e-10)
    assert r.exact and r.residual < 1e-10
    # the equilibrium fills the ring with the uniform gap
    assert r.gaps_m[0] == pytest.approx(RING_M / N - CAR_M, rel=1e-12)


@pytest.mark.parametrize("lags", [None, "mixed"])
def test_mixed_ring_equals_the_full_jacobian(lags):
    human, aev = idm(), ovfl()
    acc = [aev if i in (3, 14) else human for i in range(N)]
    lag = None if lags is None else [0.0 if i in (3, 14) else 0.43 for i in range(N)]
    r = M.analyse_mixed_ring(acc, RING_M, CAR_M, VMAX, lags_s=lag or 0.0)
    # the equilibrium: every law holds v*, the spacings fill the ring
    for f, h in zip(acc, r.gaps_m):
        assert abs(float(f(h, r.v_star_mps, r.v_star_mps))) < 1e-9
    assert sum(r.gaps_m) + N * CAR_M == pytest.approx(RING_M, rel=1e-12)
    assert r.gaps_m[3] != pytest.approx(r.gaps_m[0], rel=1e-3)  # two different laws, two different gaps
    lam = full_jacobian_eigs(acc, r.gaps_m, r.v_star_mps, lag)
    ours = np.array([complex(*e) for e in r.eigenvalues_per_s])
    _match(ours, lam, 1e-9)
    assert r.growth_rate_per_s == pytest.approx(lam[0].real, abs=1e-10)


def _mode_root_with_delay(p: M.LinearVehicle, theta: float, guess: complex) -> complex:
    """Newton on one Fourier mode's transcendental equation λ² e^{λT} + (f_Δv w − f_v) λ + f_h w = 0."""
    w = 1 - np.exp(-1j * theta)
    lam = guess
    for _ in range(100):
        e = np.exp(lam * p.delay_s)
        g = lam * lam * e + (p.f_dv_per_s * w - p.f_v_per_s) * lam + p.f_h_per_s2 * w
        dg = (2 * lam + p.delay_s * lam * lam) * e + p.f_dv_per_s * w - p.f_v_per_s
        lam = lam - g / dg
    return lam


def test_delay_roots_solve_the_exact_equation_whatever_the_pade_order():
    human = idm()
    acc = [human] * 12
    rs = [M.analyse_mixed_ring(acc, 110.0, CAR_M, VMAX, delays_s=0.31, pade_order=k) for k in (2, 5, 9)]
    assert all(not r.exact and r.residual < 1e-9 for r in rs)
    lead = [complex(*r.eigenvalues_per_s[0]) for r in rs]
    assert abs(lead[0] - lead[2]) < 1e-9 and abs(lead[1] - lead[2]) < 1e-9
    # identical delayed vehicles: the lead root is a root of one mode's own equation
    _, lin = M.linearise(acc, 110.0, [CAR_M] * 12, VMAX, delays_s=[0.31] * 12)
    roots = [_mode_root_with_delay(lin[0], 2 * np.pi * k / 12, lead[2]) for k in range(1, 12)]
    assert min(abs(r - lead[2]) for r in roots) < 1e-9
    # the delay destabilises: the same ring without it grows slower
    assert rs[0].growth_rate_per_s > M.analyse_mixed_ring(acc, 110.0, CAR_M, VMAX).growth_rate_per_s


def test_min_aev_count_is_the_first_stable_count():
    human, aev = idm(T=0.9), ovfl(alpha=0.9, beta=35.0)
    m, growth = M.min_aev_count(human, aev, N, RING_M, CAR_M, VMAX)
    assert m is not None and m >= 1 and len(growth) == m + 1
    assert growth[0] > 0 and growth[m] < 0 and all(g >= 0 for g in growth[:m])
    for k, g in enumerate(growth):  # each entry is the analysis of that placement
        idx = set(M.even_placement(N, k))
        acc = [aev if i in idx else human for i in range(N)]
        assert g == pytest.approx(M.analyse_mixed_ring(acc, RING_M, CAR_M, VMAX).growth_rate_per_s, abs=1e-12)


def damper(c: float, alpha: float = 2.0, vmax: float = 13.0, hs: float = 8.0, hc: float = 11.0) -> ca.Function:
    """An AEV law whose gain c damps the speed difference to its predecessor (a linear, Cui et al. 2017-like AEV)."""
    h, v, vl = ca.SX.sym("h"), ca.SX.sym("v"), ca.SX.sym("vl")
    V = 0.5 * vmax * (ca.tanh((h - hc) / hs) + math.tanh(hc / hs))
    return ca.Function("damper", [h, v, vl], [alpha * (V - v) + c * (vl - v)])


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_min_aev_gain_on_inside_and_outside():
    human = idm(T=1.25)  # a mildly unstable human ring that one damping AEV can stabilise
    assert M.analyse_mixed_ring([human] * N, RING_M, CAR_M, VMAX).growth_rate_per_s > 0
    # the bisection's default tolerance (1e-6 relative) is 10 times finer than the edge checked below (1e-5)
    k = M.min_aev_gain(human, damper, [5], N, RING_M, CAR_M, VMAX, (0.3, 6.0))
    assert k is not None and 0.3 < k < 6.0

    def growth(c):
        acc = [damper(c) if i == 5 else human for i in range(N)]
        return M.analyse_mixed_ring(acc, RING_M, CAR_M, VMAX).growth_rate_per_s

    assert growth(k) < 0 < growth(k * (1 - 1e-5))
    assert M.min_aev_gain(human, damper, [5], N, RING_M, CAR_M, VMAX, (0.3, 0.99 * k)) is None
    assert M.min_aev_gain(human, damper, [5], N, RING_M, CAR_M, VMAX, (1.01 * k, 6.0)) == 1.01 * k


def test_even_placement():
    assert M.even_placement(22, 0) == []
    assert M.even_placement(22, 1) == [0]
    assert M.even_placement(22, 3) == [0, 7, 14]
    assert M.even_placement(5, 5) == [0, 1, 2, 3, 4]
    with pytest.raises(ParameterError, match="6 AEVs do not fit among 5"):
        M.even_placement(5, 6)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"length_m": N * CAR_M}, "must exceed the vehicles' total length"),
        ({"length_m": N * CAR_M + 1.0}, "too short"),
        ({"length_m": 1e6}, "too long"),
        ({"lags_s": [0.1] * 3}, "lags_s has 3 entries for 22 vehicles"),
        ({"lags_s": -0.2}, "lag_s = -0.2 is not allowed"),
        ({"pade_order": 0, "delays_s": 0.2}, "pade_order = 0 is not allowed"),
    ],
)
def test_bad_rings_are_refused_with_the_field(kw, match):
    args = {"length_m": RING_M, "lags_s": 0.0}
    args.update(kw)
    with pytest.raises(ParameterError, match=match):
        M.analyse_mixed_ring([idm()] * N, args.pop("length_m"), CAR_M, VMAX, **args)


def test_characteristic_derivative_matches_finite_differences():
    rng = np.random.default_rng(7)
    veh = [
        M.LinearVehicle(*rng.uniform([0.05, -0.6, 0.2], [0.9, -0.05, 1.4]), lag_s=lag, delay_s=dl)
        for lag, dl in [(0.0, 0.0), (0.37, 0.0), (0.0, 0.29), (0.41, 0.23), (0.13, 0.61)]
    ]
    for lam in rng.normal(size=6) * 0.7 + 1j * rng.normal(size=6) * 0.9:
        f, df = M.characteristic(veh, lam)
        h = 1e-6
        fd = (M.characteristic(veh, lam + h)[0] - M.characteristic(veh, lam - h)[0]) / (2 * h)
        assert abs(df - fd) < 1e-6 * max(1.0, abs(df))
        # and χ itself is Π D − Π N, from the vehicles' own D and N
        assert abs(f - (np.prod([p.D(lam) for p in veh]) - np.prod([p.N(lam) for p in veh]))) < 1e-12 * max(1, abs(f))


def test_si_accel_of_an_si_law_ignores_the_units_and_a_model_law_needs_them():
    from aev_ocp.models.carfollowing import OVFL, LAW_REGISTRY
    from aev_ocp.params import Units

    law = OVFL(h_scale_m=9.3, v_scale_mps=4.7)
    a = M.si_accel(law)
    b = M.si_accel(law, Units(13.0, 7.0))  # an SI law: the units change nothing
    for h, v, vl in [(7.1, 3.3, 3.9), (15.2, 6.1, 5.4)]:
        assert float(a(h, v, vl)) == pytest.approx(float(law.accel_si(h, v, vl)), rel=1e-14)
        assert float(b(h, v, vl)) == float(a(h, v, vl))
    model_law = LAW_REGISTRY.get("idm_model")
    if model_law is not None:
        with pytest.raises(ParameterError, match="written in model units: give its units"):
            M.si_accel(model_law())


@pytest.mark.slow  # over 5 s of one core (measured under load, pytest --durations)
def test_the_stability_command_analyses_a_mixed_ring(tmp_path, capsys):
    import json

    from cli_helpers import one_error, run_cli

    out = tmp_path / "mixed"
    argv = ["stability", "--law", "idm", "--ring", "22", "--spacing-m", "10.45", "--aev", "ovfl"]
    rc, stdout, _ = run_cli([*argv, "--aev-count", "2", "--delay-s", "0.2", "--out", str(out)], capsys)
    assert rc == 0 and "fewest evenly spread ovfl cars" in stdout
    doc = json.loads((out / "mixed_ring_stability.json").read_text())
    from aev_ocp.models.carfollowing import make_law
    from aev_ocp.params import CarFollowingParams

    h, a = M.si_accel(make_law("idm", CarFollowingParams())), M.si_accel(make_law("ovfl", CarFollowingParams()))
    acc = [a if i in (0, 11) else h for i in range(22)]
    ref = M.analyse_mixed_ring(acc, 22 * 10.45, 5.0, 70.0, delays_s=[0.0 if i in (0, 11) else 0.2 for i in range(22)])
    assert doc["aev_positions"] == [0, 11]
    assert doc["growth_rate_per_s"] == pytest.approx(ref.growth_rate_per_s, rel=1e-9)
    m = doc["min_aev_count"]
    g = doc["growth_by_aev_count_per_s"]
    assert (m is None and all(x >= 0 for x in g)) or (g[m] < 0 and all(x >= 0 for x in g[:m]))
    for extra, what in [(["--aev-count", "23"], "--aev-count 23"), (["--delay-s", "-0.1"], "--delay-s -0.1")]:
        rc, _, err = run_cli([*argv, *extra, "--out", str(tmp_path / "bad")], capsys)
        assert rc == 2 and what in one_error(err)


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--aev-count", "3"], "error: --aev-count 3: only with --ring N --aev LAW"),  # silently ignored before
        (["--delay-s", "0.7"], "error: --delay-s 0.7: only with --ring N --aev LAW"),  # silently ignored before
        (["--aev", "mpc"], "error: --aev 'mpc': unknown law"),  # named --law and offered 'mpc' before
    ],
)
def test_mixed_ring_options_are_refused_by_their_own_name(tmp_path, capsys, extra, says) -> None:  # noqa: ANN001
    from aev_ocp.cli import main

    rc = main(
        [
            "stability",
            "--law",
            "ovm",
            "--ring",
            "22",
            "--spacing-m",
            "10",
            "--no-plots",
            "--out",
            str(tmp_path / "o"),
            *extra,
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and says in err and "or 'mpc'" not in err, err
