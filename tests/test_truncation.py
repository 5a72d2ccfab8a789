"""Cuts at a distance and at a time (aev_ocp/truncation.py) on runs built here in closed form (a held acceleration
per sample interval: positions are exact quadratics): a run that stands still exactly at the cut distance (the
first arrival, not a later sample of the standstill), repeated distances in a study profile, cuts exactly at a
sample (no extra point) and inside an interval (the time from the quadratic's root, the state from the exact
kinematics)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aev_ocp.params import EVParams
from aev_ocp.results import SimulationResult
from aev_ocp.truncation import (
    equal_profile_views,
    time_at_distance,
    truncate_at_distance,
    truncate_at_time,
)

EV = EVParams()
DT = 0.5
#: held accelerations [model] of the intervals: braking to a stop at sample 10, standing still for samples 10-15,
#: then starting again
A = np.array([-0.3] * 10 + [0.0] * 6 + [0.23] * 14)
V0, X0 = 1.5, 3.7


def _run() -> SimulationResult:
    K = A.size + 1
    t = np.arange(K) * DT
    v, x = np.empty(K), np.empty(K)
    v[0], x[0] = V0, X0
    for k in range(K - 1):
        v[k + 1] = v[k] + A[k] * DT
        x[k + 1] = x[k] + v[k] * DT + 0.5 * A[k] * DT**2
    assert abs(v[10]) < 1e-12 and np.all(v[10:16] == v[10])
    v[10:16] = 0.0
    gap = np.full(K, 4.1)
    col = lambda y: np.asarray(y, float)[:, None]  # noqa: E731
    S = 0.8 - 1e-4 * t  # linear in t: the interpolants are exact
    heat = 31.0 * (x - X0) + 2.0 * t  # grows while standing too (relaxing RC voltages)
    zeros = np.zeros((K, 1))
    accel = np.append(A, A[-1])
    return SimulationResult(
        t=t,
        leader_speed=v.copy(),
        leader_position=x + gap,
        gap=col(gap),
        speed=col(v),
        accel=col(accel),
        V1=zeros,
        V2=zeros,
        S=col(S),
        current_A=zeros,
        omega=zeros,
        heat_J=col(heat),
        heat_irr_J=col(0.5 * heat),
        int_ovm_err2=zeros,
        int_rel_speed2=zeros,
        int_jerk2=zeros,
        controllers=["test"],
        ev=EV,
        jerk_sampled=True,
    )


RUN = _run()
X = RUN.positions()[:, 0]
D = X - X[0]


def test_a_run_standing_at_the_cut_distance_is_cut_where_it_arrived() -> None:
    stop = float(D[10])
    assert np.all(D[10:16] == stop)  # repeated distances
    assert time_at_distance(RUN, 0, stop) == RUN.t[10]
    cut = truncate_at_distance(RUN, 0, float(EV.units.length_to_si(stop)))
    assert cut.t[-1] == RUN.t[10] and cut.t.size == 11
    assert cut.speed[-1, 0] == 0.0 and cut.S[-1, 0] == RUN.S[10, 0]


@pytest.mark.parametrize("k", [1, 4, 9, 17, 29])
def test_a_cut_exactly_at_a_sample_adds_no_point(k: int) -> None:
    assert time_at_distance(RUN, 0, float(D[k])) == RUN.t[k]
    cut = truncate_at_time(RUN, float(RUN.t[k]))
    assert cut.t.size == k + 1 and cut.t[-1] == RUN.t[k]
    np.testing.assert_array_equal(cut.speed, RUN.speed[: k + 1])
    np.testing.assert_array_equal(cut.heat_J, RUN.heat_J[: k + 1])


@pytest.mark.parametrize("k, frac", [(2, 0.37), (9, 0.81), (16, 0.13), (22, 0.59)])
def test_a_cut_inside_an_interval_is_the_quadratics_root(k: int, frac: float) -> None:
    """distance x_k + v_k τ + a_k τ²/2: the time from the root, and speed, position, S exact there."""
    tau = frac * DT
    v_k, a_k = float(RUN.speed[k, 0]), float(A[k])
    dist = float(D[k]) + v_k * tau + 0.5 * a_k * tau * tau
    t_cut = time_at_distance(RUN, 0, dist)
    root = (-v_k + math.sqrt(v_k * v_k + 2 * a_k * (dist - D[k]))) / a_k if a_k else (dist - D[k]) / v_k
    assert t_cut == pytest.approx(RUN.t[k] + root, abs=1e-12)
    cut = truncate_at_time(RUN, t_cut)
    assert cut.t.size == k + 2
    assert cut.speed[-1, 0] == pytest.approx(v_k + a_k * root, abs=1e-12)
    assert cut.positions()[-1, 0] == pytest.approx(X[k] + dist - D[k], abs=1e-12)
    assert cut.S[-1, 0] == pytest.approx(0.8 - 1e-4 * t_cut, abs=1e-15)
    assert cut.accel[-1, 0] == a_k  # the held command


def test_profiles_with_a_standstill_take_the_heat_at_the_first_arrival() -> None:
    """A study's profile of a run that stands still exactly at the shortest run's final distance: the heat there is
    the heat when it arrived, not after standing (which grew by 12 J)."""
    d = [0.0, 40.0, 80.0, 120.0, 120.0, 120.0, 160.0]
    q = [0.0, 400.0, 800.0, 1200.0, 1206.0, 1212.0, 1600.0]
    standing = {"distance_m": d, "t_s": [0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0], "heat_pack_J": q}
    short = {"distance_m": [0.0, 60.0, 120.0], "t_s": [0.0, 6.0, 12.0], "heat_pack_J": [0.0, 700.0, 1300.0]}
    v = equal_profile_views({"standing": standing, "short": short})
    assert v["distance"]["cut_m"] == 120.0
    row = v["distance"]["runs"]["standing"]
    assert row["heat_pack_J"] == 1200.0 and row["heat_pack_J_per_km"] == pytest.approx(1200.0 / 0.12, rel=1e-15)
    assert v["distance"]["runs"]["short"]["rank"] == 2 and row["rank"] == 1
    # the common time 12 s: both at a sample; between samples linear
    assert v["time"]["cut_s"] == 12.0
    assert v["time"]["runs"]["standing"]["heat_pack_J"] == 1200.0
    standing2 = {**standing, "t_s": [0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 30.0]}
    long = {"distance_m": [0.0, 90.0, 200.0], "t_s": [0.0, 9.0, 14.0], "heat_pack_J": [0.0, 950.0, 2100.0]}
    v2 = equal_profile_views({"standing": standing2, "long": long})
    assert v2["time"]["cut_s"] == 14.0
    assert v2["time"]["runs"]["standing"]["heat_pack_J"] == pytest.approx(1203.0, abs=1e-12)  # 12 → 16 s halfway
