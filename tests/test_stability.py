"""String stability (issue 14): the linear analysis against closed forms and an independent second
method, the measured attenuation against sup|G|, the proposed law's departure from its linearisation,
the CLI and the report section."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.cli import main
from aev_ocp.models.carfollowing import (
    IDM,
    IDMModelUnits,
    LAW_REGISTRY,
    OVFL,
    OVM,
    TANH2,
    CarFollowingLaw,
    Proposed,
    optimal_velocity,
    register_law,
)
from aev_ocp.stability import LinearizedLaw, PerturbedLeader, analyse, measure, transfer
from aev_ocp.stability.run import stability_map, study_metrics
from aev_ocp.params import Units
from aev_ocp.stability.linear import impulse_response

speeds = st.floats(0.2, 1.9)  # inside the range of V, (tanh2 − 1, 1 + tanh2) = (−0.036, 1.964)
coef = st.floats(0.05, 6.0)


def v_inv(v: float) -> float:
    return 2.0 + math.atanh(v - TANH2)


def v_prime(h: float) -> float:
    return 1.0 - math.tanh(h - 2.0) ** 2


@dataclass(frozen=True)
class FVD(CarFollowingLaw):
    """A user's law (full velocity difference model): v̇ = a (V(h) − v) + lam (v_l − v)."""

    a: float = 0.7
    lam: float = 0.4
    name = "fvd_test"

    def accel(self, h: Any, v: Any, v_l: Any) -> Any:
        return self.a * (optimal_velocity(h) - v) + self.lam * (v_l - v)


@settings(max_examples=25, deadline=None)
@given(alpha=coef, v=speeds)
def test_ovm_criterion_is_bandos(alpha: float, v: float) -> None:
    lin = analyse(OVM(alpha), v)
    h = v_inv(v)
    assert lin.h_star == pytest.approx(h, abs=1e-9)
    assert lin.criterion == pytest.approx(alpha**2 / 2 - alpha * v_prime(h), rel=1e-9, abs=1e-10)
    if abs(alpha - 2 * v_prime(h)) > 1e-6:
        assert lin.string_stable == (alpha >= 2 * v_prime(h))


@settings(max_examples=25, deadline=None)
@given(alpha=coef, beta=coef, kappa=st.floats(0.0, 0.5), eps=st.floats(1e-8, 1e-2), v=speeds)
def test_ovfl_and_proposed_criterion_closed_form(alpha: float, beta: float, kappa: float, eps: float, v: float) -> None:
    h = v_inv(v)
    closed = alpha**2 / 2 + alpha * beta / h**2 - alpha * v_prime(h)  # f_v = −α at fixed Δv
    for law in (OVFL(alpha, beta), Proposed(alpha, beta, kappa, eps)):
        lin = analyse(law, v)
        assert lin.criterion == pytest.approx(closed, rel=1e-9, abs=1e-10)
        assert (lin.f_h, lin.f_v, lin.f_dv) == pytest.approx((alpha * v_prime(h), -alpha, beta / h**2), rel=1e-9)
        assert lin.locally_stable


def test_idm_equilibrium_and_partials_against_finite_differences() -> None:
    law = IDMModelUnits(a_max=1.3, b=1.7, v0=2.1, s0=0.15, T_h=0.9)
    v = 1.37
    h = (law.s0 + v * law.T_h) / math.sqrt(1 - (v / law.v0) ** 4)  # closed form at Δv = 0
    lin = analyse(law, v)
    assert lin.h_star == pytest.approx(h, rel=1e-11)
    f = lambda hh, vv, vl: float(law.function(hh, vv, vl))  # noqa: E731
    d = 1e-6
    fh = (f(h + d, v, v) - f(h - d, v, v)) / (2 * d)
    fdv = (f(h, v, v + d) - f(h, v, v - d)) / (2 * d)
    fv = (f(h, v + d, v + d) - f(h, v - d, v - d)) / (2 * d)  # Δv held at 0
    assert (lin.f_h, lin.f_v, lin.f_dv) == pytest.approx((fh, fv, fdv), rel=1e-6)


@settings(max_examples=25, deadline=None)
@given(alpha=st.floats(0.2, 3.0), beta=st.floats(0.0, 3.0), v=speeds)
def test_max_gain_and_band_against_a_dense_grid(alpha: float, beta: float, v: float) -> None:
    lin = analyse(OVFL(alpha, beta), v)
    w = np.concatenate([np.linspace(0.0, 5.0, 40001), [lin.omega_max_gain]])
    grid_max = float(np.abs(transfer(lin.f_h, lin.f_v, lin.f_dv, w)).max())
    assert lin.max_gain == pytest.approx(grid_max, rel=1e-7)
    assert lin.max_gain >= grid_max - 1e-12
    if lin.unstable_band and lin.criterion < -1e-6:
        edge = lin.unstable_band[1]
        assert lin.gain(0.98 * edge) > 1 > lin.gain(1.02 * edge)
        assert lin.max_gain > 1 and 0 < lin.omega_max_gain < edge
    elif not lin.unstable_band:
        assert np.all(lin.gain(w[1:-1]) <= 1 + 1e-12)


def test_closed_form_sup_gain_of_ovm_at_the_inflection() -> None:
    # OVM, α = 1, at h* = 2 (V' = 1): C = −1/2, |G|² = 1/((1 − ω²)² + ω²), max 4/3 at ω² = 1/2
    lin = analyse(OVM(1.0), TANH2)
    assert lin.criterion == pytest.approx(-0.5, rel=1e-12)
    assert lin.max_gain == pytest.approx(2 / math.sqrt(3), rel=1e-12)
    assert lin.omega_max_gain == pytest.approx(math.sqrt(0.5), rel=1e-12)
    assert lin.unstable_band == pytest.approx((0.0, 1.0))


def test_impulse_response_and_peak_gain_against_scipy() -> None:
    signal = pytest.importorskip("scipy.signal")
    for law, v in ((OVFL(2.0, 3.0), 1.7), (OVM(1.0), 0.8), (OVM(2.0), 0.5), (IDM(), 1.1)):
        lin = analyse(law, v)
        t = np.linspace(0, 60, 12001)
        num = [lin.f_dv, lin.f_h] if lin.f_dv else [lin.f_h]
        sys_ = signal.lti(num, [1.0, lin.f_dv - lin.f_v, lin.f_h])
        _, g = signal.impulse(sys_, T=t)
        assert impulse_response(lin.f_h, lin.f_v, lin.f_dv, t) == pytest.approx(g, abs=1e-8)
        ref = float(np.sum(0.5 * (np.abs(g[1:]) + np.abs(g[:-1])) * np.diff(t)))
        assert lin.peak_gain == pytest.approx(ref, abs=5e-5)
    assert analyse(OVFL(2.0, 3.0), 1.7).peak_gain == pytest.approx(1.0, abs=1e-12)  # real poles, g > 0


def test_measured_sinusoid_attenuation_matches_sup_gain() -> None:
    """Second method: a small sinusoid at the argmax frequency grows by sup|G| per vehicle (unstable OVM),
    and a string-stable law attenuates it by |G(iω)|."""
    lin = analyse(OVM(1.0), TANH2)
    att = measure(OVM(1.0), TANH2, 1e-6, kind="sine", omega=lin.omega_max_gain, n_followers=30, lin=lin)
    steps = np.asarray(att.harmonic[1:]) / np.asarray(att.harmonic[:-1])
    assert att.status == "ok"
    assert np.median(steps) == pytest.approx(lin.max_gain, rel=2e-3)
    assert att.ratio_harmonic == pytest.approx(lin.max_gain, rel=2e-3)
    assert not att.string_stable_measured
    lin2 = analyse(OVFL(2.0, 3.0), 1.3)
    w = 0.83
    att2 = measure(OVFL(2.0, 3.0), 1.3, 1e-5, kind="sine", omega=w, n_followers=20, lin=lin2)
    assert att2.ratio_harmonic == pytest.approx(float(lin2.gain(w)), rel=2e-3)
    assert att2.string_stable_measured


def test_proposed_law_departs_from_its_linearisation_above_eps_over_kappa_v2() -> None:
    law = Proposed()
    lin = analyse(law, 1.7)
    ref = measure(LinearizedLaw.of(lin), 1.7, 1e-4, n_followers=8, lin=lin)
    small = measure(law, 1.7, 3e-6, n_followers=8, lin=lin)
    big = measure(law, 1.7, 1e-3, n_followers=8, lin=lin)
    ovfl = measure(OVFL(), 1.7, 1e-3, n_followers=8)
    lin_profile = np.asarray(ref.peak) / ref.amplitude
    assert np.asarray(small.peak) / small.amplitude == pytest.approx(lin_profile, rel=0.03)
    assert np.asarray(ovfl.peak) / ovfl.amplitude == pytest.approx(lin_profile, rel=0.01)
    assert big.peak[1] > 5 * big.amplitude  # follower 1 dips far more than the leader
    assert not big.string_stable_measured and small.string_stable_measured


def test_user_law_everywhere(tmp_path: Path) -> None:
    register_law("fvd_test", FVD)
    try:
        lin = analyse(FVD(), 1.2)
        h = v_inv(1.2)
        assert lin.criterion == pytest.approx(0.7**2 / 2 + 0.4 * 0.7 - 0.7 * v_prime(h), rel=1e-9)
        row = study_metrics(FVD(0.5, 0.1), 1.2, amplitude=1e-4, n_followers=6)
        assert row["string_stable"] == (0.6**2 / 2 + 0.1 * 0.6 - 0.5 * v_prime(h) >= 0)  # f_v = −(a + lam) + lam
        m = stability_map(FVD(), 1.2, "a", [0.2, 0.6, 1.4], "lam", [0.0, 0.3])
        assert m["criterion"].shape == (2, 3)
        assert m["criterion"][1, 2] == pytest.approx(1.4**2 / 2 + 0.3 * 1.4 - 1.4 * v_prime(h), rel=1e-9)
        rc = main(
            [
                "stability",
                "--law",
                "fvd_test",
                "--set",
                "carfollowing.fvd_test.a=0.9",
                "--speed-model",
                "1.2",
                "--linear-only",
                "--no-plots",
                "--out",
                str(tmp_path),
            ]
        )
        assert rc == 0
        doc = json.loads((tmp_path / "stability.json").read_text())
        assert doc["law"]["a"] == 0.9 and doc["speeds"][0]["measured"] == []
    finally:
        LAW_REGISTRY.pop("fvd_test", None)


def test_cli_writes_json_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(
        [
            "stability",
            "--law",
            "ovfl",
            "--set",
            "carfollowing.ovfl.beta=2.5",
            "--speed-mps",
            "5.5",
            "--speed-mps",
            "8",
            "--amplitude-mps",
            "5e-4",
            "--amplitude-mps",
            "1.5",
            "--followers",
            "6",
            "--out",
            str(tmp_path),
        ]
    )  # the paper's units: 1.1 and 1.6 model speed, A = 1e-4 and 0.3
    assert rc == 0
    doc = json.loads((tmp_path / "stability.json").read_text())
    assert [e["v_star_model"] for e in doc["speeds"]] == pytest.approx([1.1, 1.6], rel=1e-15)
    for e in doc["speeds"]:
        for key in (
            "criterion_model",
            "string_stable",
            "max_gain",
            "unstable_band_model",
            "measured",
            "linear_prediction",
        ):
            assert key in e
        assert [m["amplitude_model"] for m in e["measured"]] == pytest.approx([1e-4, 0.3], rel=1e-15)
        assert e["measured"][0]["agrees_with_linear"] is True  # OVFL at A = 1e-4 is in its linear range
        h = e["h_star_model"]
        assert e["criterion_model"] == pytest.approx(2 + 2 * 2.5 / h**2 - 2 * v_prime(h), rel=1e-9)
    for name in ("gain.png", "stable_region.png", "attenuation.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert "criterion C" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, field",
    [
        (["--law", "nope"], "--law"),
        (["--law", "ovm", "--set", "carfollowing.ovm.gamma=1"], "gamma"),
        (["--law", "ovm", "--set", "carfollowing.ovm.alpha=x"], "carfollowing.ovm.alpha"),
        (["--law", "ovm", "--set", "carfollowing.ovfl.beta=1"], "--law"),
        (["--law", "proposed", "--set", "carfollowing.proposed.eps=0"], "eps"),
        (["--law", "ovm", "--speed-mps", "12.5", "--linear-only"], "v* = 12.5 m/s (2.5 model speed)"),
        (["--law", "ovm", "--speed-model", "2.5", "--linear-only"], "--speed-model"),
        (["--law", "ovm", "--speed-mps", "nan"], "--speed-mps"),
        (["--law", "ovm", "--speed-mps", "-8"], "--speed-mps"),
        (["--law", "ovm", "--amplitude-mps", "15"], "--amplitude-mps: amplitude 15 m/s (3 model speed)"),
        (["--law", "ovm", "--duration-s", "0"], "--duration-s"),
        (["--law", "ovm", "--omega-model", "inf"], "--omega-model"),
        (["--law", "ovm", "--units-speed-mps", "0"], "--units-speed-mps"),
        (["--law", "ovm", "--units-length-m", "nan"], "--units-length-m"),
        (["--law", "ovm", "--followers", "0"], "--followers"),
        (["--law", "mpc", "--predictor", "psychic"], "--predictor"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(
    argv: list[str], field: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["stability", *argv, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("aev-ocp: error: ") and field in err[0]
    assert "Traceback" not in err[0] and "casadi" not in err[0].lower()


def test_perturbed_leader_is_consistent() -> None:
    for ld in (
        PerturbedLeader(1.3, 0.4, "sine", omega=1.7, t_start=0.5),
        PerturbedLeader(1.3, 0.4, "pulse", duration=3.0, t_start=0.5),
    ):
        t = np.random.default_rng(7).uniform(0.01, 5.9, 300)
        t = t[np.min(np.abs(t[:, None] - np.array([0.5, 3.5])[None, :]), axis=1) > 2e-3]  # away from the kinks
        d = 1e-4
        assert (ld.position(t + d) - ld.position(t - d)) / (2 * d) == pytest.approx(ld.speed_np(t), abs=1e-7)
        a = np.array([float(ld.accel(tt)) for tt in t])
        assert a == pytest.approx((ld.speed_np(t + d) - ld.speed_np(t - d)) / (2 * d), abs=1e-6)
    with pytest.raises(Exception, match="amplitude"):
        PerturbedLeader(0.5, 0.6, "pulse")


def test_mpc_platoon_measured_through_the_closed_loop() -> None:
    """The MPC platoon (2 followers, short horizon, interpreted RTI): the dip is seen and attenuated."""
    from aev_ocp.mpc.settings import MPCSettings
    from aev_ocp.stability import measure_mpc

    st_ = MPCSettings(N=15, solver="rti", codegen=False)
    att, base = measure_mpc(
        1.5, 0.05, n_followers=2, predictor="cooperative", duration=2.0, t_start=0.5, t_end=5.0, settings=st_
    )
    assert att.status == "ok" and base.status == "ok"
    assert att.peak[0] == pytest.approx(0.05, rel=1e-3)
    assert 0 < att.peak[2] < att.peak[1] < att.peak[0]


# ----------------------------------------------------------------------------- SI options and columns (issue 20)
L_M, U_MPS = 13.0, 7.0  # distinct, non-special units: T = 13/7 s
T_S = L_M / U_MPS


def _run(tmp_path: Path, name: str, args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    out = tmp_path / name
    assert (
        main(
            [
                "stability",
                "--law",
                "ovfl",
                "--set",
                "carfollowing.ovfl.beta=2.6",
                "--followers",
                "3",
                "--units-length-m",
                str(L_M),
                "--units-speed-mps",
                str(U_MPS),
                "--no-plots",
                "--out",
                str(out),
                *args,
            ]
        )
        == 0
    )
    return json.loads((out / "stability.json").read_text()), capsys.readouterr().out


@pytest.mark.parametrize(
    "si, model",
    [
        (
            ["--speed-mps", "9.1", "--amplitude-mps", "0.0217", "--kind", "sine", "--omega-rad-per-s", "0.7"],
            ["--speed-model", "1.3", "--amplitude-model", "0.0031", "--kind", "sine", "--omega-model", str(0.7 * T_S)],
        ),
        (
            ["--speed-mps", "10.5", "--amplitude-mps", "0.35", "--duration-s", "5.2"],
            ["--speed-model", "1.5", "--amplitude-model", "0.05", "--duration-model", "2.8"],
        ),
    ],
)
def test_si_options_equal_the_model_options_after_conversion(
    si: list[str], model: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, out_a = _run(tmp_path, "si", si, capsys)
    b, out_b = _run(tmp_path, "model", model, capsys)
    ea, eb = a["speeds"][0], b["speeds"][0]
    assert a["units"] == {"length_m": L_M, "speed_mps": U_MPS, "time_s": pytest.approx(T_S, rel=1e-15)}
    v = float(model[1])
    assert ea["v_star_model"] == pytest.approx(v, rel=1e-14) and ea["v_star_mps"] == pytest.approx(float(si[1]))
    # the same run: every model-unit number equal, whichever twin was given
    for key in ("h_star_model", "criterion_model", "f_h_model", "f_v_model", "f_dv_model"):
        assert ea[key] == pytest.approx(eb[key], rel=1e-9)
    ma, mb = ea["measured"][0], eb["measured"][0]
    for key in (
        "amplitude_model",
        "omega_model",
        "duration_model",
        "t_end_model",
        "ratio_peak",
        "ratio_l2",
        "max_step_l2",
    ):
        assert ma[key] == pytest.approx(mb[key], rel=1e-9), key
    assert ma["peak_model"] == pytest.approx(mb["peak_model"], rel=1e-7)
    # the SI columns are the model columns converted with L = 13 m, U = 7 m/s (time unit 13/7 s)
    h = ea["h_star_model"]
    assert ea["criterion_model"] == pytest.approx(2 + 2 * 2.6 / h**2 - 2 * v_prime(h), rel=1e-9)  # closed form
    assert ea["h_star_m"] == pytest.approx(13.0 * h, rel=1e-14)
    assert ea["criterion_per_s2"] == pytest.approx(ea["criterion_model"] * 49.0 / 169.0, rel=1e-14)
    assert ea["f_dv_per_s"] == pytest.approx(ea["f_dv_model"] * 7.0 / 13.0, rel=1e-14)
    assert ma["amplitude_mps"] == pytest.approx(7.0 * ma["amplitude_model"], rel=1e-14)
    assert ma["omega_rad_per_s"] == pytest.approx(ma["omega_model"] * 7.0 / 13.0, rel=1e-14)
    assert ma["duration_s"] == pytest.approx(ma["duration_model"] * 13.0 / 7.0, rel=1e-14)
    assert ma["t_end_s"] == pytest.approx(ma["t_end_model"] * 13.0 / 7.0, rel=1e-14)
    assert ma["peak_mps"] == pytest.approx([7.0 * x for x in ma["peak_model"]], rel=1e-14)
    assert ma["l2_m_per_sqrt_s"] == pytest.approx([7.0 * math.sqrt(13.0 / 7.0) * x for x in ma["l2_model"]], rel=1e-14)
    if "--omega-rad-per-s" in si:
        assert ma["omega_rad_per_s"] == pytest.approx(0.7, rel=1e-14)
    else:
        assert ma["duration_s"] == pytest.approx(5.2, rel=1e-14)
    # printed: SI first, the model value in parentheses
    assert f"v* = {float(si[1]):g} m/s ({v:g})" in out_a and f"m ({h:.6g})" in out_a
    assert f"A = {float(si[3]):.4g} m/s ({float(model[3]):g})" in out_a
    assert out_a.splitlines()[0] == out_b.splitlines()[0]


@pytest.mark.parametrize(
    "si, model",
    [
        ("--speed-mps", "--speed-model"),
        ("--amplitude-mps", "--amplitude-model"),
        ("--omega-rad-per-s", "--omega-model"),
        ("--duration-s", "--duration-model"),
    ],
)
def test_both_twins_given_is_an_error_naming_both(
    si: str, model: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["stability", "--law", "ovm", si, "0.3", model, "0.2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and si in err[0] and model in err[0]
    assert not (tmp_path / "stability.json").exists()


@pytest.mark.parametrize("old", ["--speed", "--amplitude", "--omega", "--duration"])
def test_unitless_option_names_are_refused(old: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stability", "--law", "ovm", old, "1.1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{old}-model" in err and old in err


def _dimensionless_or_si(key: str) -> bool:
    return (
        key
        in {
            "label",
            "kind",
            "n_followers",
            "status",
            "law",
            "string_stable",
            "locally_stable",
            "max_gain",
            "peak_gain",
            "agrees_with_linear",
            "string_stable_measured",
            "measured",
            "linear_prediction",
        }
        or key.startswith(("ratio_", "max_step_"))
        or key.endswith(("_mps", "_m", "_s", "_per_s", "_per_s2", "_rad_per_s", "_m_per_sqrt_s"))
    )


def test_written_columns_lead_with_si_and_suffix_the_model_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    doc, _ = _run(tmp_path, "cols", ["--speed-mps", "9.8", "--amplitude-mps", "0.07"], capsys)
    e = doc["speeds"][0]
    for table in (e, e["measured"][0], e["linear_prediction"], doc["experiment"]):
        keys = [k for k in table if k != "sizes"]
        model = [k for k in keys if k.endswith("_model")]
        assert model and all(_dimensionless_or_si(k) for k in keys if k not in model), keys
        first_model = keys.index(model[0])
        assert all(k.endswith("_model") for k in keys[first_model:] if k not in ("measured", "linear_prediction"))
        assert keys[0] in ("v_star_mps", "label", "kind")
    assert list(e)[:2] == ["v_star_mps", "h_star_m"]
    assert e["measured"][0]["v_star_mps"] == pytest.approx(9.8)
    row = study_metrics(OVFL(2.0, 3.0), 1.4, amplitude=1e-3, n_followers=3, units=Units(13.0, 7.0))
    assert list(row)[1:3] == ["v_star_mps", "h_star_m"] and row["v_star_mps"] == pytest.approx(9.8)
    assert row["amplitude_mps"] == pytest.approx(7e-3) and row["amplitude_model"] == 1e-3
    assert row["criterion_per_s2"] == pytest.approx(row["criterion_model"] * 49.0 / 169.0, rel=1e-14)
