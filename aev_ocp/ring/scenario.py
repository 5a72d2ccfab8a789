"""The ``[ring]`` scenario form: a ring road, its drivers, its AEVs and its start, in SI keys.

A ring scenario file has ``name``, ``description``, the vehicle tables every scenario knows (``[units]``,
``[vehicle]``, ``[cell]``, ``[pack]``, ``[limits]``: every vehicle carries that EV and battery), an optional
``[mpc]`` (the MPC's solver settings and formulation, when an AEV runs "mpc"; a measured predictor only) and
``[ring]`` (registered with the scenario loader, :func:`aev_ocp.scenarios.register_section`):

* ``length_m`` [m] or ``density_per_km`` [1/km] (one of them), ``vehicles`` (how many), ``vehicle_length_m`` [m]
  (default 5), ``t_end_s`` [s], ``dt_out_s`` [s] (default 0.5), ``metrics_from_s`` [s] (fleet metrics from this
  time on; default the second half);
* the human drivers: ``human = "idm" | "ovm"`` with ``[ring.idm]`` (``a_mps2``, ``b_mps2``, ``v0_mps``, ``s0_m``,
  ``T_s``; defaults :data:`aev_ocp.ring.laws.IDM_SI`) or ``[ring.ovm]`` (``alpha_per_s``; V(h) the paper's),
  ``heterogeneity`` (each human's parameters scaled by independent factors uniform in [1 − h, 1 + h]),
  ``noise_mps2`` [m/s²], ``noise_dt_s`` [s] and ``seed`` (the seeded acceleration noise);
* ``[ring.aev]`` (optional): ``vehicles`` (1-based vehicle numbers driven by an AEV), ``controllers`` (one run per
  name, :data:`aev_ocp.ring.laws.AEV_CONTROLLERS`), ``r_fraction`` (FollowerStopper's desired speed as a share of
  the uniform-flow speed, default 0.85), ``all_human`` (also run the ring with no AEV first, default true);
* ``[ring.sweep]`` (optional, instead of ``[ring.aev]``): ``aevs`` (numbers of AEVs, spread evenly around the
  ring: vehicles round(j n / k) + 1), ``density_per_km`` or ``length_m`` (an array: the rings; default the one
  of ``[ring]``), ``controllers`` (default ["followerstopper"]) and ``r_fraction``: one run per ring, AEV count
  and controller (the AEV count 0, all human, once per ring);
* ``[ring.followerstopper]`` (optional): FollowerStopper's SI constants ``dx0_m`` (its three Δx⁰ [m], increasing),
  ``d_mps2`` (its three d [m/s²]) and ``tau_s`` (its speed loop [s]); defaults Stern et al. 2018 and
  :data:`aev_ocp.ring.laws.SPEED_LOOP_S`. An AEV law's own coefficients come from ``[carfollowing]`` and its
  sub-tables (``[carfollowing.idm]``: the IDM's SI ``T_s``, ``a_mps2``, …);
* ``[ring.wave]`` (optional, with a "wave-mpc" controller): the wave MPC's :class:`aev_ocp.mpc.wave.WaveParams`
  fields in SI (e.g. ``target_gap_m``, ``target_time_gap_s``; not ``traffic``), the others at their defaults;
* or, instead of ``human`` and its tables, ``population`` (a calibrated human population by name,
  :data:`aev_ocp.ring.humans.CALIBRATED`: heterogeneous seeded drivers with reaction times and noise) with an
  optional ``[ring.calibration]`` stating its fit (source, fitted and their values, statistics, target, tolerance, achieved,
  residual, seeds, validation_seeds, validation_achieved; checked, not used to run);
* the start: ``[ring.perturbation]`` (uniform flow, then ``vehicle`` (1-based, default 1) moved back ``shift_m``
  [m] (default 2) and slowed by ``speed_dip_mps`` [m/s] (default 0)), or ``[ring.initial]`` with ``positions_m``
  and ``speeds_mps`` (one per vehicle; vehicle i − 1 ahead of vehicle i).

Errors are one line naming the file and the key (``ring_x.toml: ring.aev.vehicles = [30] is not allowed: ...``).
``aev-ocp ring FILE`` runs it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from ..limits import check_ring_cuts, check_ring_size
from ..params import CarFollowingParams, Check, EVParams, ParameterError, echo, field_checks, spec, validate_fields
from ..scenarios import (
    ScenarioError,
    TableReader,
    find_scenario,
    read_scenario_doc,
    register_section,
    standalone_header,
)
from ..scenarios.followers import _carfollowing
from .laws import AEV_CONTROLLERS, IDM_SI, RING_PREDICTORS
from .simulate import start_problem

HUMAN_MODELS = ("idm", "ovm")
#: The ranges of a human driver's parameters (SI, unit in the name). Upper bounds: 10 m/s² is about 1 g, the tyre-road
#: friction limit of acceleration and braking (and of the noise's spread, RingSpec.noise_mps2); a time gap of 10 s and
#: a standstill gap of 50 m are far beyond any driver (Treiber & Kesting 2013, Traffic Flow Dynamics, Table 11.2:
#: T = 0.8-2 s, s0 = 1-5 m); 100 m/s is above every road's limit; an OVM relaxation rate of 10 1/s is a 0.1 s
#: response, faster than a human's reaction.
HUMAN_CHECKS: dict[str, Check] = {
    "a_mps2": Check(gt=0, le=10.0),
    "b_mps2": Check(gt=0, le=10.0),
    "v0_mps": Check(gt=0, le=100.0),
    "s0_m": Check(ge=0, le=50.0),
    "T_s": Check(gt=0, le=10.0),
    "alpha_per_s": Check(gt=0, le=10.0),
}
OVM_ALPHA_PER_S = 1.0  # the paper's OVM α = 2 (model, 1/T) at T = 2 s: 1 1/s
MAX_RING_T_END_S = 36_000.0  # the longest ring run a scenario may ask for [s]: 10 h of traffic (our bound)
#: the keys of [ring] and [ring.sweep] that are not fields of RingSpec: the density gives the length
DENSITY_PER_KM = Check(gt=0)
#: ring.human: the model of the human drivers (a calibrated population may state another, e.g. 'bandoftl')
HUMAN = Check("choice", choices=HUMAN_MODELS)
#: [ring.perturbation] vehicle: a 1-based vehicle number (RingSpec.perturbed_vehicle is 0-based; at most ring.vehicles)
VEHICLE_NUMBER = Check("integer", ge=1)
_TOP = ("name", "description", "units", "vehicle", "cell", "pack", "limits", "carfollowing", "mpc", "ring")


@dataclass(frozen=True)
class RingSpec:
    """The validated ``[ring]`` table (SI). Each key's type, range and unit are declared once, beside its field
    (:func:`aev_ocp.params.spec`): the scenario reader and the Python API check the same declarations; the rules
    between keys (dt_out_s <= t_end_s, metrics_from_s < t_end_s, the vehicles fit on the ring, …) are
    :func:`validate_ring_table`'s."""

    # (defaults: the ring of Sugiyama et al. 2008, New J. Phys. 10:033001, 22 cars on 230 m, that Stern et al. 2018
    # drove again, over the 600 s of the shipped ring scenarios; a [ring] table must give them: _REQUIRED)
    length_m: float = spec(230.0, gt=0)
    vehicles: int = spec(22, kind="integer", ge=2)
    t_end_s: float = spec(600.0, gt=0, le=MAX_RING_T_END_S)
    vehicle_length_m: float = spec(5.0, ge=0)  # the ring benchmarks of Wu et al. 2017 (Flow), as RingRoad
    dt_out_s: float = spec(0.5, gt=0)  # at most t_end_s
    metrics_from_s: float | None = spec(None, ge=0, optional=True)  # before t_end_s; None: the second half
    human: str = spec("idm", kind="instance", cls=str)  # ring.human (HUMAN), or a calibrated population's model
    human_params: dict[str, float] = spec(kind="instance", cls=dict, default_factory=dict)
    heterogeneity: float = spec(0.0, ge=0, lt=1)
    noise_mps2: float = spec(0.1, ge=0, le=10.0)  # aev_ocp.ring.run.NOISE_MPS2; at most 1 g (HUMAN_CHECKS)
    noise_dt_s: float = spec(0.5, gt=0)
    seed: int = spec(0, kind="integer", ge=0)
    aev_vehicles: tuple[int, ...] = spec((), kind="instance", cls=tuple)  # 0-based
    controllers: tuple[str, ...] = spec((), kind="instance", cls=tuple)
    r_fraction: float = spec(
        0.85, gt=0, le=1.5
    )  # FollowerStopper's r as a share of the uniform speed (experiments.stern)
    all_human: bool = spec(True, kind="bool")
    perturbed_vehicle: int = spec(0, kind="integer", ge=0)  # 0-based
    shift_m: float = spec(2.0, ge=0)  # below the mean gap
    speed_dip_mps: float = spec(0.0, ge=0)
    positions_m: tuple[float, ...] | None = spec(None, kind="instance", cls=tuple, optional=True)
    speeds_mps: tuple[float, ...] | None = spec(None, kind="instance", cls=tuple, optional=True)
    sweep_aevs: tuple[int, ...] = spec((), kind="instance", cls=tuple)  # [ring.sweep]: AEV counts
    sweep_length_m: tuple[float, ...] = spec((), kind="instance", cls=tuple)  # [ring.sweep]: ring lengths [m]
    #: a calibrated human population (aev_ocp.ring.humans.CALIBRATED) instead of human
    population: str | None = spec(None, kind="instance", cls=str, optional=True)
    #: [ring.calibration]: what the population was fitted to (stated)
    calibration: dict[str, Any] | None = spec(None, kind="instance", cls=dict, optional=True)
    #: [ring.followerstopper]: the keyword arguments of FollowerStopper.from_si (empty: its defaults)
    followerstopper: dict[str, Any] = spec(kind="instance", cls=dict, default_factory=dict)
    #: [ring.wave]: WaveParams fields of the ring's wave-MPC cars (empty: WaveParams' defaults)
    wave: dict[str, Any] = spec(kind="instance", cls=dict, default_factory=dict)

    def __post_init__(self) -> None:
        validate_fields(self)


@dataclass(frozen=True)
class RingRun:
    """One run of a ring scenario: its label, the ring's length [m], the 0-based AEV vehicles and their
    controller (None: all human)."""

    label: str
    length_m: float
    aevs: tuple[int, ...]
    controller: str | None


@dataclass(frozen=True)
class RingScenario:
    """A ring scenario: name, description, the EV every vehicle carries, the [ring] spec, the [mpc] config (or
    None) and the TOML document it came from."""

    name: str
    spec: RingSpec
    ev: EVParams
    mpc: Any = None
    description: str = ""
    source: Path | None = None
    document: dict[str, Any] | None = field(default=None, compare=False, repr=False)
    cf: CarFollowingParams = field(default_factory=CarFollowingParams)  # the AEV laws' coefficients and scales
    law_overrides: dict[str, dict[str, float]] = field(default_factory=dict)  # [carfollowing.<law>] sub-tables

    @property
    def density_per_km(self) -> float:
        """Vehicles per km."""
        return 1000.0 * self.spec.vehicles / self.spec.length_m


_CHECKS = field_checks(RingSpec)
_REQUIRED = ("length_m", "vehicles", "t_end_s")  # keys a [ring] table must give (no default in a file)
_DEFAULTS = {f.name: f.default for f in fields(RingSpec) if f.default is not MISSING and f.name not in _REQUIRED}


def _declared(
    r: TableReader, key: str, check: Check | None = None, *, lt: float | None = None, le: float | None = None
) -> Any:
    """``key`` of ``r``'s table checked against its declaration (RingSpec's field ``key`` unless ``check``), with
    an upper bound ``lt``/``le`` that another key sets (e.g. ``le=t_end_s``); absent: the field's default (required
    without one)."""
    c = check or _CHECKS[key]
    if lt is not None or le is not None:
        c = dataclasses.replace(c, lt=c.lt if lt is None else lt, le=c.le if le is None else le)
    return r.declared(key, c, _DEFAULTS[key]) if key in _DEFAULTS and check is None else r.declared(key, c)


def _scenario_error(r: TableReader, exc: ParameterError) -> ScenarioError:
    return ScenarioError(f"{r.file}: {exc}")


def validate_ring_table(r: TableReader) -> RingSpec:
    """Validator of the ``[ring]`` table (registered with the scenario loader): every key against its declaration
    (:class:`RingSpec`), then the rules between keys, each error naming the file and the key."""
    kw: dict[str, Any] = {}
    n, length, ell = _ring_geometry(r, kw)
    _ring_times(r, kw, n)
    _ring_humans(r, kw)
    kw["seed"] = _declared(r, "seed")
    if r.has("aev"):
        _ring_aev(r.sub("aev"), kw, n)
    if r.has("sweep"):
        length = _ring_sweep(r, kw, n, ell, length)
    if r.has("followerstopper"):
        kw["followerstopper"] = _followerstopper_table(r.sub("followerstopper"))
    if r.has("wave"):
        kw["wave"] = _wave_table(r.sub("wave"), kw.get("controllers", ()))
    _ring_start(r, kw, n, length, ell)
    r.finish()
    return RingSpec(**kw)


def _ring_geometry(r: TableReader, kw: dict[str, Any]) -> tuple[int, float, float]:
    """(vehicles, length [m], vehicle length [m]): the length given or from the density; the vehicles must fit."""
    n = _declared(r, "vehicles")
    kw["vehicles"] = n
    if r.has("length_m") == r.has("density_per_km"):
        raise ScenarioError(
            f"{r.file}: {r.key_path('length_m')} / {r.key_path('density_per_km')}: give exactly one "
            "(the ring's length [m] or its density [vehicles per km])"
        )
    if r.has("length_m"):
        length = _declared(r, "length_m")
    else:
        length = 1000.0 * n / _declared(r, "density_per_km", DENSITY_PER_KM)
    ell = _declared(r, "vehicle_length_m")
    if n * ell >= length:
        key = "length_m" if r.has("length_m") else "density_per_km"
        raise r.error(
            key,
            r.table[key],
            f"{n} vehicles of {ell:g} m do not fit on a ring of {length:g} m "
            "(need length > vehicles × vehicle_length_m)",
        )
    kw.update(length_m=length, vehicle_length_m=ell)
    return n, length, ell


def _ring_times(r: TableReader, kw: dict[str, Any], n: int) -> None:
    """t_end_s, dt_out_s (at most t_end_s; the run's size within the budget) and metrics_from_s (before t_end_s)."""
    kw["t_end_s"] = _declared(r, "t_end_s")
    kw["dt_out_s"] = _declared(r, "dt_out_s", le=kw["t_end_s"])
    try:  # the budget ($AEV_OCP_MAX_MEMORY_GB) when the file is read, naming its keys
        keys = (r.key_path("vehicles"), r.key_path("t_end_s"), r.key_path("dt_out_s"))
        check_ring_size(n, kw["t_end_s"], kw["dt_out_s"], keys)
    except ParameterError as exc:
        raise _scenario_error(r, exc) from None
    if r.has("metrics_from_s"):
        kw["metrics_from_s"] = _declared(r, "metrics_from_s", lt=kw["t_end_s"])


def _ring_humans(r: TableReader, kw: dict[str, Any]) -> None:
    """The human drivers: a calibrated population (with its stated fit), or a model with its parameters, spread
    and noise; the noise's integration cuts within the budget."""
    if r.has("population"):
        from .humans import CALIBRATED

        kw["population"] = r.string("population", choices=sorted(CALIBRATED))
        for other in ("human", "heterogeneity", "noise_mps2", "noise_dt_s", *HUMAN_MODELS):
            if r.has(other):
                raise r.error(
                    other, r.table[other], "a calibrated ring.population states its drivers, their noise and spread"
                )
        pop = CALIBRATED[kw["population"]]
        kw.update(human=pop.model, human_params=dict(pop.params), noise_mps2=pop.noise_mps2)
        kw["noise_dt_s"] = pop.noise_dt_s
        if r.has("calibration"):
            kw["calibration"] = _calibration_table(r.sub("calibration"))
    elif r.has("calibration"):
        raise r.error(
            "calibration", r.table["calibration"], "states a calibrated ring.population's fit: give ring.population"
        )
    human = r.declared("human", HUMAN, "idm") if kw.get("population") is None else kw["human"]
    kw["human"] = human
    for other in HUMAN_MODELS:
        if other != human and r.has(other):
            raise r.error(other, r.table[other], f"sets the {other.upper()}, but ring.human = {human!r}")
    if kw.get("population") is None:
        hp = r.sub(human)
        defaults = IDM_SI if human == "idm" else {"alpha_per_s": OVM_ALPHA_PER_S}
        kw["human_params"] = {k: hp.declared(k, HUMAN_CHECKS[k], v) for k, v in defaults.items()}
        hp.finish(allowed_hint=list(defaults))
        for key in ("heterogeneity", "noise_mps2", "noise_dt_s"):
            kw[key] = _declared(r, key)
    if kw["noise_mps2"] > 0:
        try:  # the integration cuts the noise makes, before any is built
            check_ring_cuts(kw["t_end_s"], {r.key_path("noise_dt_s"): kw["noise_dt_s"]})
        except ParameterError as exc:
            raise _scenario_error(r, exc) from None


def _ring_aev(a: TableReader, kw: dict[str, Any], n: int) -> None:
    """``[ring.aev]``: the vehicles (1-based, distinct, at most ring.vehicles) AEVs drive and their controllers."""
    nums = a.numbers("vehicles", ge=1)
    if any(int(x) != x or x > n for x in nums):
        raise a.error("vehicles", a.table["vehicles"], f"must be vehicle numbers 1 … {n} (ring.vehicles)")
    if len(set(nums)) != len(nums):
        raise a.error("vehicles", a.table["vehicles"], "lists a vehicle twice")
    kw["aev_vehicles"] = tuple(sorted(int(x) - 1 for x in nums))
    kw["controllers"] = _distinct_controllers(a, None)
    kw["r_fraction"] = _declared(a, "r_fraction")
    kw["all_human"] = _declared(a, "all_human")
    a.finish()


def _distinct_controllers(t: TableReader, default: Any) -> tuple[str, ...]:
    """The table's ``controllers`` (AEV_CONTROLLERS, each once; ``default`` when absent, None: required)."""
    ctrls = (
        t.strings("controllers", choices=list(AEV_CONTROLLERS))
        if default is None
        else t.strings("controllers", default, choices=list(AEV_CONTROLLERS))
    )
    if len(set(ctrls)) != len(ctrls):
        raise t.error("controllers", t.table["controllers"], "names a controller twice; each runs once")
    return tuple(ctrls)


def _ring_sweep(r: TableReader, kw: dict[str, Any], n: int, ell: float, length: float) -> float:
    """``[ring.sweep]``: AEV counts × ring lengths × controllers; returns the shortest ring's length [m] (the
    perturbation must fit on every ring)."""
    if r.has("initial"):
        raise r.error(
            "sweep",
            r.table["sweep"],
            "a sweep starts every ring from uniform flow and [ring.perturbation]; [ring.initial] gives one ring's positions",
        )
    if r.has("aev"):
        raise r.error(
            "sweep",
            r.table["sweep"],
            "give [ring.aev] (one ring, AEVs at given vehicles) or [ring.sweep] (AEV counts × rings), not both",
        )
    sw = r.sub("sweep")
    counts = sw.numbers("aevs", ge=0)
    if any(int(x) != x or x > n for x in counts) or len(set(counts)) != len(counts):
        raise sw.error("aevs", sw.table["aevs"], f"must be distinct whole numbers of AEVs in 0 … {n}")
    if sw.has("length_m") and sw.has("density_per_km"):
        raise sw.error("length_m", sw.table["length_m"], "give length_m or density_per_km, not both")
    if sw.has("density_per_km"):
        lengths = [1000.0 * n / d for d in sw.numbers("density_per_km", gt=DENSITY_PER_KM.gt)]
        key = "density_per_km"
    else:
        lengths = sw.numbers("length_m", [length], gt=_CHECKS["length_m"].gt)
        key = "length_m"
    for L in lengths:
        if n * ell >= L:
            raise sw.error(key, sw.table[key], f"{n} vehicles of {ell:g} m do not fit on a ring of {L:g} m")
    kw.update(
        sweep_aevs=tuple(int(x) for x in counts),
        sweep_length_m=tuple(lengths),
        controllers=_distinct_controllers(sw, ["followerstopper"]),
        r_fraction=_declared(sw, "r_fraction"),
    )
    sw.finish()
    return min(lengths)


def _ring_start(r: TableReader, kw: dict[str, Any], n: int, length: float, ell: float) -> None:
    """The start: ``[ring.initial]`` (every position and speed; in order, no overlaps) or ``[ring.perturbation]``
    (uniform flow with one vehicle moved back, less than the mean gap, and slowed)."""
    if r.has("perturbation") and r.has("initial"):
        raise r.error("initial", r.table["initial"], "give [ring.perturbation] or [ring.initial], not both")
    if r.has("initial"):
        ini = r.sub("initial")
        pos = ini.numbers("positions_m", min_len=n, ge=0)
        spd = ini.numbers("speeds_mps", min_len=n, ge=0)
        for key, vals in (("positions_m", pos), ("speeds_mps", spd)):
            if len(vals) != n:
                raise ini.error(key, ini.table[key], f"needs {n} values (ring.vehicles), got {len(vals)}")
        if any(x >= length for x in pos):
            raise ini.error("positions_m", ini.table["positions_m"], f"must lie in [0, {length:g}) m (the ring)")
        bad = start_problem(length, ell, math.inf, pos, spd)  # order and overlaps; the top speed: with [limits]
        if bad is not None:
            raise ini.error(bad[0], ini.table[bad[0]], bad[1])
        kw.update(positions_m=tuple(pos), speeds_mps=tuple(spd))
        ini.finish()
        return
    p = r.sub("perturbation")
    veh = p.declared("vehicle", VEHICLE_NUMBER, 1)
    if veh > n:
        raise p.error("vehicle", veh, f"must be a vehicle number 1 … {n} (ring.vehicles)")
    kw.update(
        perturbed_vehicle=veh - 1,
        shift_m=_declared(p, "shift_m", lt=length / n - ell),
        speed_dip_mps=_declared(p, "speed_dip_mps"),
    )
    p.finish()


def _followerstopper_table(f: TableReader) -> dict[str, Any]:
    """``[ring.followerstopper]``: the keyword arguments of :meth:`aev_ocp.ring.laws.FollowerStopper.from_si`."""
    from .laws import SPEED_LOOP_S

    out: dict[str, Any] = {}
    for key, default in (("dx0_m", [4.5, 5.25, 6.0]), ("d_mps2", [1.5, 1.0, 0.5])):  # Stern et al. 2018 §3.1
        vals = f.numbers(key, default, gt=0)
        if len(vals) != 3:
            raise f.error(key, f.table[key], "needs three values (the three bands of FollowerStopper)")
        if key == "dx0_m" and not vals[0] < vals[1] < vals[2]:
            raise f.error(key, f.table[key], "must increase (Δx⁰₁ < Δx⁰₂ < Δx⁰₃)")
        out[key] = tuple(float(x) for x in vals)
    out["tau_s"] = f.number("tau_s", SPEED_LOOP_S, gt=0, le=10.0)  # 10 s: far slower than any speed loop
    f.finish()
    return out


def _wave_table(w: TableReader, controllers: tuple[str, ...]) -> dict[str, Any]:
    """``[ring.wave]``: the :class:`aev_ocp.mpc.wave.WaveParams` fields (SI, range-checked as declared beside them;
    not ``traffic``) of the ring's "wave-mpc" cars, the others at their defaults. Only with a "wave-mpc" controller."""
    from ..mpc.wave import WAVE_NAME, WaveParams
    from ..scenarios.tables import read_declared

    if WAVE_NAME not in controllers:
        raise ScenarioError(
            f"{w.file}: [{w.path}] is given but no AEV runs {WAVE_NAME!r} (ring.aev.controllers or "
            f"ring.sweep.controllers = {list(controllers)}): it sets the wave MPC's parameters"
        )
    names = [f.name for f in fields(WaveParams) if f.name != "traffic"]
    out = read_declared(WaveParams, w, names)
    w.finish(allowed_hint=names)
    try:
        WaveParams(**out)
    except ParameterError as exc:
        raise ScenarioError(f"{w.file}: {w.path}: {exc}") from None
    return out


def _calibration_table(c: TableReader) -> dict[str, Any]:
    """``[ring.calibration]``: what a calibrated population was fitted to, as stated beside it (read and checked,
    not used to run): source, the statistics with their target, tolerance, the achieved means and residuals over
    the calibration seeds and over validation seeds, and the fitted parameters."""
    out: dict[str, Any] = {"source": c.string("source"), "fitted": c.strings("fitted")}
    out["values"] = c.numbers("values")
    if len(out["values"]) != len(out["fitted"]):
        raise c.error("values", c.table["values"], f"needs one value per fitted parameter ({len(out['fitted'])})")
    out["statistics"] = c.strings("statistics")
    k = len(out["statistics"])
    for key in ("target", "tolerance", "achieved", "residual", "validation_achieved"):
        vals = c.numbers(key)
        if len(vals) != k:
            raise c.error(key, c.table[key], f"needs one value per statistic ({k})")
        out[key] = vals
    for key in ("seeds", "validation_seeds"):
        out[key] = [int(x) for x in c.numbers(key, ge=0)]
    c.finish()
    return out


register_section("ring", validate_ring_table)


def parse_ring_scenario(doc: dict[str, Any], file: str = "<ring scenario>", source: Path | None = None) -> RingScenario:
    """Validate a parsed TOML document into a :class:`RingScenario` (errors name the file and key)."""
    top, name, description, ev = standalone_header(doc, file, source, _TOP, "ring")
    spec = validate_ring_table(top.sub("ring", required=True))
    v_max = ev.limits.v_max_mps
    if spec.speeds_mps is not None and max(spec.speeds_mps) > v_max:
        raise ScenarioError(
            f"{file}: ring.initial.speeds_mps = {echo(list(spec.speeds_mps))} is not allowed: every speed must be in "
            f"[0, {v_max:g}] m/s (limits.v_max_mps, the vehicle's top speed)"
        )
    mpc = None
    if "mpc" in doc:
        from ..mpc.scenario import validate_mpc_table

        mpc = validate_mpc_table(top.sub("mpc"))
        if mpc.vehicles is not None or mpc.follower_predictor is not None:
            raise ScenarioError(
                f"{file}: mpc.vehicles / mpc.follower_predictor do not apply to a ring: the MPC "
                'drives the vehicles of ring.aev.vehicles whose controller is "mpc"'
            )
        if mpc.settings.predictor not in RING_PREDICTORS:
            raise ScenarioError(
                f"{file}: mpc.predictor = {mpc.settings.predictor!r} is not allowed on a ring: must "
                f"be one of {list(RING_PREDICTORS)} (an AEV forecasts its predecessor from its "
                "own measurements)"
            )
    cf, own = _carfollowing(top.sub("carfollowing"))  # SI laws: [units] does not change them
    top.finish()
    return RingScenario(name, spec, ev, mpc, description, source, copy.deepcopy(doc), cf, own)


def load_ring_scenario(path: str | Path) -> RingScenario:
    """Read and validate a ring scenario file (a path, or a shipped name such as ``ring_stern``)."""
    try:
        p = find_scenario(path)
    except ScenarioError:
        from ..scenarios import shipped_scenarios

        raise ScenarioError(
            f"{path}: no such ring scenario file (shipped ring scenarios: "
            f"{', '.join(shipped_scenarios('ring')) or 'none found'})"
        ) from None
    file = str(path)
    doc = read_scenario_doc(p, file)
    if "ring" not in doc:
        raise ScenarioError(
            f"{file}: not a ring scenario (no [ring] table); run a platoon scenario with 'aev-ocp simulate'"
        )
    return parse_ring_scenario(doc, file, p)


def build_ring(
    sc: RingScenario, controller: str | None, length_m: float | None = None, aevs: tuple[int, ...] | None = None
) -> tuple[Any, Any]:
    """(RingRoad, RingInitial) of the scenario with its AEVs (default ``[ring.aev]``'s vehicles; 0-based) under
    ``controller`` (None: all human), on a ring of ``length_m`` [m] (default the scenario's)."""
    from .laws import idm_si
    from .simulate import RingInitial, RingRoad, uniform_flow
    from ..models.carfollowing import OVM

    s, ev = sc.spec, sc.ev
    length = s.length_m if length_m is None else float(length_m)
    on = s.aev_vehicles if aevs is None else tuple(aevs)
    if s.population is not None:
        return _build_population_ring(sc, controller, length, on)
    rng = np.random.default_rng(s.seed + 7919)  # the same draws as aev_ocp.ring.run.human_ring
    humans: list[Any] = []
    for _ in range(s.vehicles):
        f = 1 + s.heterogeneity * rng.uniform(-1, 1, 5) if s.heterogeneity > 0 else np.ones(5)
        if s.human == "idm":
            humans.append(idm_si(ev.units, *[v * fk for v, fk in zip(s.human_params.values(), f)]))
        else:
            # OVM humans: the paper's V(h) at the laws' scales (CarFollowingParams), alpha_per_s in SI
            hs, vs = sc.cf.h_scale_m, sc.cf.v_scale_mps
            ovm = OVM(alpha=float(s.human_params["alpha_per_s"] * f[0] * (hs / vs)), h_scale_m=hs, v_scale_mps=vs)
            humans.append(ovm.in_units(ev.units))
    base = RingRoad(
        length, tuple(humans), s.vehicle_length_m, ev, tuple([True] * s.vehicles), s.noise_mps2, s.noise_dt_s, s.seed
    )
    vehicles, human = list(humans), [True] * s.vehicles
    if controller is not None:
        for i, aev in _aevs(sc, controller, base, on).items():
            vehicles[i] = aev
            human[i] = False
    ring = RingRoad(length, tuple(vehicles), s.vehicle_length_m, ev, tuple(human), s.noise_mps2, s.noise_dt_s, s.seed)
    if s.positions_m is not None and s.speeds_mps is not None and length == s.length_m:
        init = RingInitial(s.positions_m, s.speeds_mps, None, "given positions and speeds")
    else:
        init = uniform_flow(base, shift_m=s.shift_m, vehicle=s.perturbed_vehicle, speed_dip_mps=s.speed_dip_mps)
    return ring, init


def _aevs(sc: RingScenario, controller: str, base: Any, on: tuple[int, ...]) -> dict[int, Any]:
    """{0-based vehicle: its AEV controller} of the scenario (FollowerStopper's r from the all-human ``base``)."""
    from .laws import make_aev
    from .simulate import uniform_speed_mps

    try:
        r_mps = sc.spec.r_fraction * uniform_speed_mps(base)
    except ParameterError as exc:
        raise ScenarioError(f"{sc.source or sc.name}: {exc}") from None
    mpc = (sc.mpc.settings, sc.mpc.formulation) if sc.mpc is not None else None
    own = {**sc.law_overrides, "followerstopper": dict(sc.spec.followerstopper), "wave-mpc": dict(sc.spec.wave)}
    return {i: make_aev(controller, sc.ev, r_mps, mpc, sc.cf, own) for i in on}


def _build_population_ring(
    sc: RingScenario, controller: str | None, length: float, on: tuple[int, ...]
) -> tuple[Any, Any]:
    """build_ring for a calibrated ``ring.population`` (aev_ocp.ring.humans.population_ring: seeded draws,
    reaction times; an AEV replaces a driver and leaves the others' draws)."""
    from .humans import calibrated_population, population_ring
    from .simulate import RingInitial, uniform_flow

    s, ev = sc.spec, sc.ev
    assert s.population is not None
    pop = calibrated_population(s.population)
    base = population_ring(pop, length, s.vehicles, seed=s.seed, ev=ev, vehicle_length_m=s.vehicle_length_m)
    ring = base
    if controller is not None:
        aevs = _aevs(sc, controller, base, on)
        ring = population_ring(
            pop, length, s.vehicles, seed=s.seed, aevs=aevs, ev=ev, vehicle_length_m=s.vehicle_length_m
        )
    if s.positions_m is not None and s.speeds_mps is not None and length == s.length_m:
        return ring, RingInitial(s.positions_m, s.speeds_mps, None, "given positions and speeds")
    return ring, uniform_flow(base, shift_m=s.shift_m, vehicle=s.perturbed_vehicle, speed_dip_mps=s.speed_dip_mps)


def spread(k: int, n: int) -> tuple[int, ...]:
    """k AEV positions (0-based) spread evenly over n vehicles: round(j n / k), j = 0 … k − 1."""
    return tuple(sorted({int(round(j * n / k)) for j in range(k)})) if k else ()


def scenario_runs(sc: RingScenario) -> list[RingRun]:
    """The runs of a scenario: all human first when asked for, then one per AEV controller; with
    ``[ring.sweep]`` one per ring × AEV count × controller (count 0 once per ring)."""
    s = sc.spec
    if s.sweep_aevs:
        out = []
        for L in s.sweep_length_m:
            dens = 1000.0 * s.vehicles / L
            for k in s.sweep_aevs:
                for c in s.controllers[:1] if k == 0 else s.controllers:
                    out.append(
                        RingRun(
                            f"{dens:.4g}/km, {k} {'human' if k == 0 else c}",
                            L,
                            spread(k, s.vehicles),
                            None if k == 0 else c,
                        )
                    )
        return out
    runs = [RingRun("all human", s.length_m, (), None)] if (s.all_human or not s.controllers) else []
    return runs + [RingRun(c, s.length_m, s.aev_vehicles, c) for c in s.controllers]
