"""The ring's linear analysis (aev_ocp/stability/ring.py) reports the most unstable mode's wavelength and wave
speed: checked against the linearised ring itself, not the mode formula. The full Jacobian of the whole ring
(CasADi, :func:`ring_jacobian`, no Fourier analysis) is exponentiated (SciPy ``expm``) from that mode's real
pattern; the crest of the gap pattern is followed in road coordinates (vehicle i at −i s + v* t, its pattern
a cos(θ i) + b sin(θ i)), and its speed and the pattern's period along the road are measured. Sugiyama's ring
(22 IDM cars on 230 m) also against the experiment: its jam travels backwards at about 20 km/h."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from aev_ocp.models.carfollowing import OVM
from aev_ocp.params import EVParams, VehicleLimits
from aev_ocp.ring.laws import idm_si
from aev_ocp.stability.ring import ring_jacobian, ring_stability

EV = EVParams()
CASES = [
    (idm_si(EV.units), 22, 230.0, EV),  # Sugiyama et al. 2008
    (idm_si(EV.units, T_s=1.3), 17, 263.0, EV),
    (OVM(alpha=1.3), 31, 470.0, EV),
    (idm_si(EV.units), 40, 330.0, EV),  # the most unstable mode k = 3: three waves on the ring
    (idm_si(EV.units, T_s=0.9), 60, 600.0, EV),
    (idm_si(EV.units), 13, 187.0, EVParams(limits=VehicleLimits(lag_s=0.35))),  # actuator lag: cubic modes
]


def _measured(law, n: int, length_m: float, ev: EVParams) -> tuple[float, float, float]:
    """(wave speed [m/s], wavelength [m], growth [1/s]) of the most unstable pattern of the linearised ring."""
    J = ring_jacobian(law, n, length_m, ev=ev)
    lam, W = np.linalg.eig(J)
    # the growing oscillatory mode (k = 0's modes are real): largest real part among complex eigenvalues
    cand = [j for j in range(lam.size) if abs(lam[j].imag) > 1e-9]
    j = max(cand, key=lambda q: lam[q].real)
    x0 = np.real(W[:, j]) * 1e-3
    eta0 = x0[:n]
    theta = float(np.angle(W[1, j] / W[0, j]))  # the pattern's phase step from vehicle to vehicle
    rs = ring_stability(law, n, length_m, ev=ev)
    s, v_star = length_m / n, rs.v_star_mps
    idx = np.arange(n)

    def crest(t: float) -> float:
        eta = (expm(J * t) @ x0)[:n] if t > 0 else eta0
        c = np.sum(eta * np.exp(-1j * theta * idx))  # η_i ≈ Re(c e^{iθi}) / (n/2): its phase locates the crest
        i_crest = -np.angle(c) / theta  # the vehicle index (continuous) where θ i + arg c = 0
        return -i_crest * s + v_star * t, abs(c)

    dt = 0.05
    (x_a, a_a), (x_b, a_b) = crest(0.0), crest(dt)
    return (x_b - x_a) / dt, 2 * math.pi * s / abs(theta), math.log(a_b / a_a) / dt


@pytest.mark.parametrize("law, n, length_m, ev", CASES)
def test_wave_speed_and_wavelength_equal_the_linearised_rings(law, n, length_m, ev) -> None:
    rs = ring_stability(law, n, length_m, ev=ev)
    if n >= 40:
        assert rs.most_unstable_k > 1  # a shorter wave than the ring
    c, wl, growth = _measured(law, n, length_m, ev)
    assert rs.growth_rate_per_s == pytest.approx(growth, rel=1e-6, abs=1e-9)
    assert rs.wavelength_m == pytest.approx(wl, rel=1e-9)
    assert rs.wavelength_m == pytest.approx(length_m / min(rs.most_unstable_k, n - rs.most_unstable_k), rel=1e-12)
    assert rs.wave_speed_mps == pytest.approx(c, rel=1e-8)


def test_sugiyamas_jam_travels_backwards_at_about_20_km_h() -> None:
    rs = ring_stability(idm_si(EV.units), 22, 230.0, ev=EV)
    assert rs.wavelength_m == pytest.approx(230.0)  # one jam on the ring (k = 1)
    assert -7.0 < rs.wave_speed_mps < -4.0  # Sugiyama et al. 2008: about −20 km/h = −5.6 m/s
    assert rs.wave_speed_mps < rs.v_star_mps
