"""The followers of a platoon scenario: [carfollowing] (the coefficients, and per-law sub-tables) and [platoon]
(how many followers, their laws, initial gaps and speeds)."""

from __future__ import annotations

import dataclasses
from typing import Callable

from ..models.carfollowing import LAW_REGISTRY, CarFollowingLaw, make_law
from ..models.leader import LeaderProfile
from ..overrides import SI_TWINS
from ..params import CarFollowingParams, ParameterError, Units
from .tables import ScenarioError, TableReader, _params


#: [carfollowing] keys in SI: {key: (the dimensionless coefficient, SI value -> coefficient at scales ℓ [m], u [m/s])}
SI_COEFFICIENTS: dict[str, tuple[str, Callable[[float, float, float], float]]] = {
    "alpha_per_s": ("alpha", lambda x, ell, u: x * ell / u),
    "beta_m2ps": ("beta", lambda x, ell, u: x / (ell * u)),
    "kappa_per_m": ("kappa", lambda x, ell, u: x * ell),
    "eps_m2ps2": ("eps", lambda x, ell, u: x / (u * u)),
}


def _carfollowing(r: TableReader, sub_tables: bool = True) -> tuple[CarFollowingParams, dict[str, dict[str, float]]]:
    """[carfollowing]: ``calibrated`` (optional: a calibrated set by name or path, aev_ocp.calibration; the table's
    own keys override it), the OV-type laws' coefficients (dimensionless: alpha, beta, kappa, eps; or in SI:
    alpha_per_s, beta_m2ps, kappa_per_m, eps_m2ps2, converted with the law's scales), their scales h_scale_m [m]
    and v_scale_mps [m/s], and (``sub_tables``) a sub-table per law with its own coefficients."""
    coeffs = {f.name for f in dataclasses.fields(CarFollowingParams)} - {"model_units"}
    calibrated: dict[str, float] = {}
    if r.has("calibrated"):  # a calibrated set (aev_ocp.calibration): its parameters, then the table's keys
        from ..calibration import load as load_calibration

        name = r.string("calibrated")
        try:
            _, cal = load_calibration(name)
        except ParameterError as exc:
            raise r.error("calibrated", name, str(exc)) from None
        calibrated = {k: float(v) for k, v in cal["params"].items() if k in coeffs}
    cf_table = {**calibrated, **{k: v for k, v in r.table.items() if k in coeffs}}
    si = {k: v for k, v in r.table.items() if k in SI_COEFFICIENTS}
    cf = _params(CarFollowingParams, TableReader(cf_table, r.path, r.file))
    r._seen.update(k for k in cf_table if k in r.table)
    if si:
        kw: dict[str, float] = {}
        for key in si:
            coeff, convert = SI_COEFFICIENTS[key]
            if coeff in cf_table:
                raise r.error(key, si[key], f"give {r.key_path(coeff)} (dimensionless) or {key} (SI), not both")
            kw[coeff] = convert(
                r.number(key, ge=0 if coeff != "eps" else None, gt=0 if coeff == "eps" else None),
                cf.h_scale_m,
                cf.v_scale_mps,
            )
        try:
            cf = dataclasses.replace(cf, **kw)
        except ParameterError as exc:
            raise ScenarioError(f"{r.file}: {r.path}: {exc}") from None
    overrides: dict[str, dict[str, float]] = {}
    for key, value in r.table.items():
        if key in coeffs or key in SI_COEFFICIENTS or key == "calibrated":
            continue
        if not sub_tables or key.lower() not in LAW_REGISTRY:
            raise r.error(
                key,
                value,
                f"unknown key: allowed are {sorted(coeffs | set(SI_COEFFICIENTS))}"
                + (f" or a sub-table named after a law, one of {sorted(LAW_REGISTRY)}" if sub_tables else ""),
            )
        sub = r.sub(key, required=True)
        ov = {k: sub.number(k) for k in list(sub.table)}
        try:
            make_law(key, cf, **ov)
        except (TypeError, ParameterError) as exc:
            raise ScenarioError(f"{r.file}: {sub.path}: invalid coefficients for law {key!r}: {exc}") from None
        overrides[key.lower()] = ov
    return cf, overrides


def _per_vehicle(r: TableReader, n: int, list_key: str, values: list[float] | None) -> list[float] | None:
    if values is not None and len(values) != n:
        raise r.error(list_key, values, f"needs exactly {n} values, one per follower (platoon.followers = {n})")
    return values


_INITIAL_SPEEDS: dict[LeaderProfile, float] = {}


def _initial_speed(leader: LeaderProfile) -> float:
    """The leader's speed at t = 0 [model speed]. Sampling a leader builds its CasADi Function (~1 ms); a study
    parses a new but equal leader (a frozen dataclass) at each of its points, so equal leaders share the value."""
    try:
        v = _INITIAL_SPEEDS.get(leader)
    except TypeError:  # a leader holding arrays is not hashable: sampled each time
        return float(leader.speed_np(0.0)[0])
    if v is None:
        if len(_INITIAL_SPEEDS) >= 1024:
            _INITIAL_SPEEDS.clear()
        v = _INITIAL_SPEEDS[leader] = float(leader.speed_np(0.0)[0])
    return v


def _platoon(
    r: TableReader,
    leader: LeaderProfile,
    cf: CarFollowingParams,
    overrides: dict[str, dict[str, float]],
    compare: tuple[str, ...] = (),
    size: Callable[[int], None] | None = None,
    units: Units | None = None,
) -> tuple[tuple[CarFollowingLaw, ...], list[float], list[float]]:
    laws_known = sorted(LAW_REGISTRY)
    if r.has("laws") and r.has("law"):
        raise r.error("laws", r.table["laws"], "give either platoon.law (all followers) or platoon.laws, not both")
    if r.has("laws"):
        names = r.strings("laws", choices=laws_known)
        n = r.integer("followers", len(names), ge=1)
        if len(names) != n:
            raise r.error("laws", names, f"needs exactly {n} names, one per follower")
        if size is not None:
            size(n)
        if compare:  # a mixed platoon never runs when compare is set: say so instead of ignoring it
            raise r.error(
                "laws",
                r.table["laws"],
                f"cannot be combined with compare = {list(compare)}, which runs "
                "the whole platoon once per compared law; remove one of them",
            )
    else:
        n = r.integer("followers", ge=1)
        law_name = r.string("law", "proposed", choices=laws_known)
        if compare and r.has("law") and law_name not in compare:
            raise r.error(
                "law",
                r.table["law"],
                f"is never run: compare = {list(compare)} runs the whole platoon "
                f"once per compared law; add {law_name!r} to compare, or remove compare",
            )
        if size is not None:
            size(n)  # refuse an oversized platoon before building anything of its size
        names = [law_name] * n
    laws = tuple(make_law(nm, cf, **overrides.get(nm, {})) for nm in names)

    # initial gaps (each key or its SI twin, e.g. gap0_first or gap0_first_m [m])
    u = units if units is not None else Units()
    tw = SI_TWINS["platoon"]
    for g in ("gap0", "gaps0", "gap0_first", "gap0_others"):
        r._twin(g)  # a key and its SI twin together: an error naming both
    whole = [k for k in ("gap0", "gap0_m", "gaps0", "gaps0_m") if r.has(k)]
    part = [k for k in ("gap0_first", "gap0_first_m", "gap0_others", "gap0_others_m") if r.has(k)]
    if len(whole) > 1 or (whole and part):
        other = (whole[1:] + part)[0]
        raise r.error(
            other,
            r.table[other],
            f"give one of platoon.gap0 (every follower), platoon.gaps0 (one per "
            f"follower) or gap0_first/gap0_others (each also in m as *_m); "
            f"{r.key_path(whole[0])} is given too",
        )
    if r.has_quantity("gaps0"):
        gaps = _per_vehicle(r, n, tw["gaps0"][0] if r.has(tw["gaps0"][0]) else "gaps0", r.quantities("gaps0", u, gt=0))
    elif r.has_quantity("gap0"):
        gaps = [r.quantity("gap0", u, gt=0)] * n
    else:
        if not part:
            raise ScenarioError(
                f"{r.file}: {r.path}: the initial gaps are missing: give gap0_first (model length) "
                "or gap0_first_m [m] (and optionally gap0_others / gap0_others_m), gap0 / gap0_m "
                "(every follower) or gaps0 / gaps0_m (one per follower)"
            )
        first = r.quantity("gap0_first", u, gt=0)
        others = r.quantity("gap0_others", u, first, gt=0)
        gaps = [first] + [others] * (n - 1)

    # initial speeds (speed0 / speeds0 or their SI twins speed0_mps / speeds0_mps [m/s])
    r._twin("speed0"), r._twin("speeds0")  # a key and its SI twin together: an error naming both
    given = [k for k in ("speed0", "speed0_mps", "speed0_factor", "speeds0", "speeds0_mps") if r.has(k)]
    if len(given) != 1:
        raise ScenarioError(
            f"{r.file}: {r.path}: give exactly one of speed0 (model speed) or speed0_mps [m/s], "
            f"speed0_factor (× the leader's initial speed) or speeds0 / speeds0_mps (one per "
            f"follower); got {given or 'none'}"
        )
    if given[0].startswith("speeds0"):
        speeds = _per_vehicle(r, n, given[0], r.quantities("speeds0", u, ge=0))
    elif given[0].startswith("speed0") and given[0] != "speed0_factor":
        speeds = [r.quantity("speed0", u, ge=0)] * n
    else:
        v_l0 = _initial_speed(leader)
        speeds = [r.number("speed0_factor", ge=0) * v_l0] * n
    r.finish()
    assert gaps is not None and speeds is not None
    return laws, gaps, speeds
