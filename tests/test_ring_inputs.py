"""A ring's inputs: its start (order, overlaps, speeds up to v_max), the human drivers' ranges, the budget of
integration cuts, the compiled ring's cancel flag and the ring command's options. Every physical nonsense is one
line naming the key and the allowed range, before any integration."""

from __future__ import annotations

import ctypes
import re
import subprocess
import sys

import numpy as np
import pytest

from aev_ocp.control import ControlSequence
from aev_ocp.limits import MAX_RING_CUTS, check_ring_cuts
from aev_ocp.models.carfollowing import OVM
from aev_ocp.params import EVParams, ParameterError
from aev_ocp.ring.run import human_ring
from aev_ocp.ring.scenario import parse_ring_scenario
from aev_ocp.ring.simulate import RingInitial, RingRoad, RingSimulator, start_problem, uniform_flow
from aev_ocp.scenarios import ScenarioError

N, LENGTH_M = 7, 123.0


def _doc(**ring: object) -> dict[str, object]:
    base: dict[str, object] = {"length_m": LENGTH_M, "vehicles": N, "t_end_s": 17.0, "noise_mps2": 0.13, "seed": 3}
    base.update(ring)
    return {"name": "r", "ring": base}


def _front_to_back(n: int = N, length: float = LENGTH_M) -> list[float]:
    """Equal spacing, vehicle 0 in front: positions decrease along the list (mod the ring)."""
    return [(-(i * length / n)) % length for i in range(n)]


# ------------------------------------------------------------------------------------------------ the start
def test_start_problem_accepts_front_to_back_and_refuses_back_to_front() -> None:
    x = _front_to_back()
    assert start_problem(LENGTH_M, 5.0, 31.7, x, [6.1] * N) is None
    key, why = start_problem(LENGTH_M, 5.0, 31.7, x[::-1], [6.1] * N) or ("", "")
    # listed back to front every car "sees" a gap of almost the whole ring: the distances add up to (n - 1) L
    assert key == "positions_m" and "front to back" in why and f"{(N - 1) * LENGTH_M:.6g} m" in why
    # one car swapped with its neighbour: no overlap, but the order goes round twice
    y = list(x)
    y[2], y[3] = y[3], y[2]
    assert start_problem(LENGTH_M, 5.0, 31.7, y, [6.1] * N)[0] == "positions_m"  # type: ignore[index]


@pytest.mark.parametrize(
    "speed, ok", [(0.0, True), (31.7, True), (31.7000001, False), (1e300, False), (-0.01, False), (np.nan, False)]
)
def test_start_speeds_on_inside_and_outside_v_max(speed: float, ok: bool) -> None:
    v = [6.1] * N
    v[4] = speed
    bad = start_problem(LENGTH_M, 5.0, 31.7, _front_to_back(), v)
    assert (bad is None) == ok
    if not ok:
        assert bad is not None and bad[0] == "speeds_mps" and "[0, 31.7] m/s" in bad[1] and "vehicle 5" in bad[1]


def test_ring_initial_back_to_front_refused_in_the_file_and_in_the_api() -> None:
    x = _front_to_back()
    ini = {"positions_m": x[::-1], "speeds_mps": [4.3] * N}
    with pytest.raises(ScenarioError, match=r"g.toml: ring.initial.positions_m = .* must list the vehicles front to"):
        parse_ring_scenario(_doc(initial=ini), "g.toml")
    ring = RingRoad(LENGTH_M, tuple([OVM()] * N))
    with pytest.raises(ParameterError, match=r"RingInitial.positions_m is not allowed: must list the vehicles"):
        RingSimulator(ring, None).run(RingInitial(tuple(x[::-1]), tuple([4.3] * N)), 3.0)
    # the same ring in the right order is accepted by both
    sc = parse_ring_scenario(_doc(initial={"positions_m": x, "speeds_mps": [4.3] * N}), "g.toml")
    assert sc.spec.positions_m == tuple(x)


def test_ring_initial_speed_above_the_top_speed_names_v_max() -> None:
    x = _front_to_back()
    doc = _doc(initial={"positions_m": x, "speeds_mps": [4.3] * (N - 1) + [1e300]})
    with pytest.raises(ScenarioError, match=r"g.toml: ring.initial.speeds_mps = .*\[0, 62.5\] m/s \(limits.v_max_mps"):
        parse_ring_scenario(doc, "g.toml")
    doc["limits"] = {"v_max_mps": 41.3}  # the file's own top speed is the bound
    doc["ring"]["initial"]["speeds_mps"] = [4.3] * (N - 1) + [41.4]  # type: ignore[index]
    with pytest.raises(ScenarioError, match=r"\[0, 41.3\] m/s"):
        parse_ring_scenario(doc, "g.toml")
    doc["ring"]["initial"]["speeds_mps"] = [4.3] * (N - 1) + [41.3]  # type: ignore[index]
    assert parse_ring_scenario(doc, "g.toml").spec.speeds_mps[-1] == 41.3  # type: ignore[index]
    ring = RingRoad(LENGTH_M, tuple([OVM()] * N))
    with pytest.raises(ParameterError, match=r"RingInitial.speeds_mps is not allowed: .*\[0, 62.5\] m/s"):
        RingSimulator(ring, None).run(RingInitial(tuple(x), tuple([4.3] * (N - 1) + [1e300])), 3.0)


@pytest.mark.parametrize("kw", [{"shift_m": -1e9}, {"shift_m": 12.6}, {"shift_m": np.inf}, {"speed_dip_mps": -0.2}])
def test_uniform_flow_refuses_a_shift_outside_the_gap(kw: dict[str, float]) -> None:
    ring = RingRoad(LENGTH_M, tuple([OVM()] * N))  # spacing 17.57 m, gap 12.57 m between 5 m cars
    with pytest.raises(ParameterError, match=f"uniform_flow {next(iter(kw))}"):
        uniform_flow(ring, speed_mps=4.0, **kw)
    assert uniform_flow(ring, speed_mps=4.0, shift_m=12.5).positions_m[0] == pytest.approx(LENGTH_M - 12.5)


# ------------------------------------------------------------------------------------------ human drivers
@pytest.mark.parametrize(
    "ring, key",
    [
        ({"idm": {"a_mps2": 1e300}}, "ring.idm.a_mps2"),
        ({"idm": {"b_mps2": 10.01}}, "ring.idm.b_mps2"),
        ({"idm": {"T_s": 11.0}}, "ring.idm.T_s"),
        ({"human": "ovm", "ovm": {"alpha_per_s": 1e6}}, "ring.ovm.alpha_per_s"),
        ({"noise_mps2": 12.0}, "ring.noise_mps2"),
    ],
)
def test_human_parameters_beyond_physics_are_refused(ring: dict[str, object], key: str) -> None:
    with pytest.raises(ScenarioError, match=rf"g.toml: {key} = .* is not allowed: must be a finite number"):
        parse_ring_scenario(_doc(**ring), "g.toml")


def test_human_parameters_on_their_bounds_are_accepted() -> None:
    sc = parse_ring_scenario(_doc(idm={"a_mps2": 10.0, "b_mps2": 10.0, "T_s": 10.0, "s0_m": 50.0}), "g.toml")
    assert sc.spec.human_params["a_mps2"] == 10.0 and sc.spec.human_params["s0_m"] == 50.0


# -------------------------------------------------------------------------------------- integration cuts
def test_cut_budget_on_inside_and_outside() -> None:
    t_end = 3.7 * MAX_RING_CUTS / 1e6  # cuts = t_end / dt
    assert check_ring_cuts(t_end, {"noise_dt_s": 3.7e-6}) == pytest.approx(MAX_RING_CUTS, rel=1e-9)
    assert check_ring_cuts(t_end, {"noise_dt_s": 3.8e-6}) < MAX_RING_CUTS
    with pytest.raises(ParameterError, match=r"noise_dt_s = 3.6e-06 s .* more than the 1000000"):
        check_ring_cuts(t_end, {"noise_dt_s": 3.6e-6})
    with pytest.raises(ParameterError, match="must be a finite number of seconds > 0"):
        check_ring_cuts(t_end, {"dt": 0.0})


def test_noise_every_microsecond_is_refused_before_the_grid_is_built() -> None:
    with pytest.raises(ScenarioError, match=r"g.toml: ring: ring.noise_dt_s = 1e-06 s over t_end_s = 17 s"):
        parse_ring_scenario(_doc(noise_dt_s=1e-6), "g.toml")
    assert parse_ring_scenario(_doc(noise_dt_s=1e-6, noise_mps2=0.0), "g.toml").spec.noise_dt_s == 1e-6  # no noise
    ring = human_ring(230.0, seed=2)
    ring = RingRoad(ring.length_m, ring.vehicles, ring.vehicle_length_m, ring.ev, None, 0.13, 1e-6, 2)
    with pytest.raises(ParameterError, match=r"noise_dt_s = 1e-06 s over t_end_s = 20 s"):
        RingSimulator(ring, None).run(uniform_flow(ring), 20.0)


def test_a_user_controller_sampled_every_50_ns_is_refused() -> None:
    ev = EVParams()
    dt = 5e-8 / ev.units.time_s  # model time
    ring = RingRoad(LENGTH_M, (ControlSequence((0.0,), dt), *[OVM()] * (N - 1)), 5.0, ev, None, 0.0)
    with pytest.raises(ParameterError, match=r"the sampled controllers' dt = 5e-08 s over t_end_s = 2 s"):
        RingSimulator(ring, None).run(RingInitial(tuple(_front_to_back()), (3.0,) * N), 2.0)


# ------------------------------------------------------------------------------- the compiled cancel flag
def test_compiled_ring_stops_at_once_when_cancelled() -> None:
    """aevring_advance checks aevring_cancel before every step (as the cascade's aevsim_cancel): set, it returns -2
    without a step; clear, the same call integrates to t1."""
    ring = human_ring(230.0, seed=4)
    sim = RingSimulator(ring, None)
    if sim.method != "compiled":
        pytest.skip("no C compiler: the compiled ring is not built")
    lib = sim._lib
    assert lib is not None
    init = uniform_flow(ring, shift_m=1.3)
    n, nz = sim.n, sim.nz
    u = ring.ev.units
    z0 = np.zeros((n, nz))
    z0[:, 0] = u.length_from_si(np.full(n, ring.spacing_m - ring.vehicle_length_m))
    z0[:, 1] = u.speed_from_si(np.asarray(init.speeds_mps))
    z0[:, 4] = ring.ev.cell.soc0
    t1 = 7.3 / u.time_s
    ts = np.array([t1])

    def advance(z: np.ndarray) -> tuple[int, np.ndarray]:
        out, h, ev, stats = np.zeros((1, n, nz + sim.ny)), np.zeros(1), np.zeros(4), np.zeros(3, np.int64)
        brake = np.zeros((n, 4))  # the braking counters (ring.c), off: threshold below any acceleration
        args = (n, sim.law_of, sim.params, np.zeros(n), z, 0.0, t1, 1, ts, out, 1e-8, 1e-8, 10**7, h, ev, stats, 1)
        args += (brake, -1e300, 0.0, 0.0)
        return int(lib.aevring_advance(*args)), stats

    flag = ctypes.c_int.in_dll(lib, "aevring_cancel")
    try:
        flag.value = 1
        z = z0.copy()
        m, stats = advance(z)
        assert m == -2 and stats[0] == 0 and np.array_equal(z, z0)  # no step, state untouched
    finally:
        flag.value = 0
    z = z0.copy()
    m, stats = advance(z)
    assert m == 1 and stats[0] >= 1 and not np.array_equal(z, z0)


def test_ring_command_time_limit_and_seed_with_a_file(tmp_path) -> None:  # noqa: ANN001
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "aev_ocp.cli", "ring", *a], capture_output=True, text=True, timeout=600
    )
    p = run("ring_sugiyama", "--seed", "3", "--out", str(tmp_path / "s"))
    assert p.returncode == 2 and "--seed 3: a ring scenario file sets its seed with ring.seed" in p.stderr
    p = run("stern", "--penetration", "2", "--out", str(tmp_path / "p"))
    assert p.returncode == 2 and "--penetration applies to the sweep experiment only" in p.stderr
    # 10 h of Sugiyama's ring cannot finish in 0.2 s: stopped, exit 1, nothing written
    p = run("sugiyama", "--t-end-s", "36000", "--time-limit", "0.2", "--no-plots", "--out", str(tmp_path / "t"))
    assert p.returncode == 1 and "stopped by --time-limit 0.2 s" in p.stderr, p.stderr
    assert not (tmp_path / "t" / "ring.json").exists()


# ------------------------------------------------------------------------------- declared ranges of [ring]
def _edges(check) -> list[tuple[float, bool]]:  # noqa: ANN001
    """(value, accepted) on and beside each declared bound: a closed bound is accepted, an open one refused."""
    out = []
    step = 1 if check.kind == "integer" else None
    for bound, sign, strict in ((check.gt, 1, True), (check.ge, 1, False), (check.lt, -1, True), (check.le, -1, False)):
        if bound is None:
            continue
        d = step or max(abs(bound), 1.0) * 1e-6
        out += [(bound, not strict), (bound - sign * d, False), (bound + sign * d, True)]
    return [(int(v) if step else v, ok) for v, ok in out]


@pytest.mark.parametrize(
    "table, key",
    [
        ("", "vehicles"),
        ("", "t_end_s"),
        ("", "vehicle_length_m"),
        ("", "heterogeneity"),
        ("", "noise_mps2"),
        ("", "seed"),
        ("aev", "r_fraction"),
        ("perturbation", "speed_dip_mps"),
        ("idm", "T_s"),
        ("idm", "s0_m"),
    ],
)
def test_ring_keys_are_read_against_their_declared_range(table: str, key: str) -> None:
    """Each [ring] key is checked against the range declared once beside its RingSpec field (or HUMAN_CHECKS):
    on, just inside and just outside every bound; a refusal names the file, the key path and the value."""
    from aev_ocp.params import field_checks
    from aev_ocp.ring.scenario import HUMAN_CHECKS, RingSpec

    check = HUMAN_CHECKS[key] if table == "idm" else field_checks(RingSpec)[key]
    edges = _edges(check)
    assert edges, key
    for value, ok in edges:
        if table == "aev":
            doc = _doc(aev={"vehicles": [2], "controllers": ["proposed"], key: value})
        elif table:
            doc = _doc(**{table: {key: value}})
        else:
            doc = _doc(**{key: value})
        path = f"ring.{table}.{key}" if table else f"ring.{key}"
        if ok:
            sc = parse_ring_scenario(doc, "g.toml")
            got = (
                sc.spec.human_params[key]
                if table == "idm"
                else getattr(sc.spec, "r_fraction" if table == "aev" else key)
            )
            assert got == value, (key, value)
        else:
            with pytest.raises(ScenarioError, match="^" + re.escape(f"g.toml: {path} = ") + ".* is not allowed: "):
                parse_ring_scenario(doc, "g.toml")


def test_ring_spec_checks_its_declarations_from_python_too() -> None:
    """The Python API checks the same declarations (RingSpec built by hand, as a study's replace does)."""
    import dataclasses

    sc = parse_ring_scenario(_doc(), "g.toml")
    with pytest.raises(
        ParameterError, match=r"^RingSpec\.heterogeneity = 1\.0 is not allowed: must be a finite number in \[0, 1\)"
    ):
        dataclasses.replace(sc.spec, heterogeneity=1.0)
    assert dataclasses.replace(sc.spec, heterogeneity=0.999).heterogeneity == 0.999
