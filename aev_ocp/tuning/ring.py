"""The ring in the tuning: one AEV among the calibrated human drivers of a ring scenario
(:data:`RING_SCENARIO`), every ring controller of :data:`RING_TABLE` tuned with the same budget of closed-loop
evaluations on :data:`TRAIN_SEEDS`, then each controller at its default and tuned run on :data:`HELDOUT_SEEDS`
(seeds the tuning never saw) and reported as the mean with a 95 % t interval over those seeds, with paired verdicts.

A ring seed draws the drivers (their parameters and reaction times) and their acceleration noise
(:mod:`aev_ocp.ring.humans`). Every run is a task of the study layer (``kind = "ring"``,
:func:`aev_ocp.study.traffic.run_point`: one AEV, vehicle 1, under the controller; the other 21 drivers as the
seed draws them), run in this process, on the process pool or on Dask, kept in the store ``<out>/points/``.

Objective: the fleet's battery energy per distance [kWh/100 km] over the metrics window (``ring.metrics_from_s`` to
the end, :func:`aev_ocp.ring.field.field_metrics`), mean over the training seeds. Constraints (each ≤ 0): no run
ends on an event or fails; on every training seed the fleet's mean speed is at least :data:`SPEED_SHARE` of the
all-human ring's on the same seed (an AEV may not buy energy by slowing the whole ring down: the flow would drop with
it). The all-human runs on the training seeds are the constraint's reference; they are run once, are no
controller's trial and count in no budget.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..params import ParameterError, echo
from .core import PENALTY_KWH_PER_100KM, Evaluator, Param, Space, Tuner, check_budget, tune_rounds

#: The ring the controllers are tuned and tested on: the shipped calibrated ring (22 drivers on 230 m).
RING_SCENARIO = "ring_calibrated"
#: Training seeds (the tuning sees only these) and held-out seeds (the report's), disjoint.
TRAIN_SEEDS = (1, 2)
HELDOUT_SEEDS = tuple(range(11, 21))
#: Share of the all-human ring's mean speed the ring with the AEV must keep (our choice: a 5 % loss of flow at most;
#: every default controller keeps at least 95.7 % on the training seeds, so the bound binds only a controller that
#: slows the whole ring, e.g. FollowerStopper at a low desired speed).
SPEED_SHARE = 0.95
#: Controllers run at their defaults only, beside the tuned ones (the wave MPC: being reworked elsewhere, not tuned).
UNTUNED = ("wave-mpc",)
#: The constraints of a ring trial, in order.
RING_CONSTRAINTS = ("events", "mean_speed")
#: Metrics of the ring tables (SI; lower is better except the mean speed).
RING_METRICS = ("battery_energy_kWh_per_100km", "mean_speed_mps", "speed_std_mps", "braking_events_per_veh_km")
#: FollowerStopper's Δx⁰ and d ratios, kept when its first band is tuned (Stern et al. 2018 §3.1: 4.5, 5.25, 6 m;
#: 1.5, 1.0, 0.5 m/s²)
FS_DX0_M = (4.5, 5.25, 6.0)
FS_D_MPS2 = (1.5, 1.0, 0.5)

_RING_SCALES = (
    Param("h_scale_m", 2.0, 20.0, "the OV function's length scale ℓ: sets the equilibrium gap, ℓ V⁻¹(v/u)"),
    Param("v_scale_mps", 2.0, 15.0, "the OV function's speed scale u: V∞·u is the law's top speed"),
)
#: What is tuned on the ring, SI, with bounds (our choice: around the ring's defaults, the OV scales at ring speeds,
#: 2–5 m/s, not motorway ones; each controller 3–4 parameters).
RING_TABLE: dict[str, Space] = {
    "proposed": Space(
        "proposed",
        "law",
        "proposed",
        (
            Param(
                "kappa_per_m", 1e-4, 5e-2, "weight of the κ term κ/ℓ (the deceleration against a closing speed)", True
            ),
            Param("eps_m2ps2", 1e-6, 1.0, "smoothing ε u² of the κ term at zero relative speed", True),
            *_RING_SCALES,
        ),
    ),
    "ovfl": Space(
        "ovfl",
        "law",
        "ovfl",
        (
            Param("alpha_per_s", 0.1, 5.0, "relaxation rate α u/ℓ towards the optimal velocity", True),
            Param("beta_m2ps", 10.0, 2000.0, "follow-the-leader gain β ℓ u on (v_l − v)/h²", True),
            *_RING_SCALES,
        ),
    ),
    "idm": Space(
        "idm",
        "law",
        "idm",
        (
            Param("T_s", 0.5, 3.0, "desired time gap T"),
            Param("a_mps2", 0.3, 3.0, "maximum acceleration a"),
            Param("b_mps2", 0.5, 4.0, "comfortable deceleration b"),
            Param("s0_m", 1.0, 6.0, "standstill gap s0"),
        ),
    ),
    "followerstopper": Space(
        "followerstopper",
        "followerstopper",
        "followerstopper",
        (
            Param("r_fraction", 0.5, 1.2, "desired speed r as a share of the ring's uniform-flow speed"),
            Param("dx01_m", 2.0, 10.0, "first band Δx⁰₁ (Δx⁰₂, Δx⁰₃ at the paper's ratios 5.25/4.5, 6/4.5)"),
            Param("d1_mps2", 0.5, 4.0, "first band's deceleration d₁ (d₂, d₃ at the paper's 2/3, 1/3)"),
            Param("tau_s", 0.2, 2.0, "time constant τ of the speed loop tracking the commanded speed"),
        ),
    ),
    "mpc": Space(
        "mpc",
        "mpc",
        "mpc",
        (
            Param("accel_weight", 0.5, 60.0, "w_a [W/kg per (m/s²)²]: cost of acceleration (currents)", True),
            Param("gap_weight", 0.002, 0.2, "w_g [W/kg per m²]: cost of the gap's distance from h_des(v)", True),
            Param("target_time_gap_s", 0.5, 3.5, "T_des: time gap of the desired gap h_des = s_0 + T_des v"),
        ),
    ),
}
#: The all-human reference runs (no controller, no parameters).
HUMAN = Space("human", "human", "", ())


def check_ring_controllers(controllers: Sequence[str]) -> tuple[list[Space], list[str]]:
    """(tuned spaces, untuned controller names) of ``controllers``; ParameterError naming an unknown or repeated
    one."""
    known = [*RING_TABLE, *UNTUNED]
    if isinstance(controllers, str) or not controllers:
        raise ParameterError(
            f"ring tuning: controllers = {echo(controllers)} is not allowed: must be a list of {known}"
        )
    if len(set(controllers)) != len(controllers):
        raise ParameterError(f"ring tuning: controllers = {echo(list(controllers))} names a controller twice")
    for c in controllers:
        if c not in known:
            raise ParameterError(f"ring tuning: unknown controller {c!r}: known are {known}")
    return [RING_TABLE[c] for c in controllers if c in RING_TABLE], [c for c in controllers if c in UNTUNED]


def check_seeds(train: Sequence[int], held: Sequence[int]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The training and held-out seeds: whole numbers ≥ 0, at least 1 and 2 of them, no seed in both; ParameterError
    naming the list otherwise."""
    out = []
    for name, seeds, least in (("train_seeds", train, 1), ("heldout_seeds", held, 2)):
        if isinstance(seeds, str) or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) for s in seeds):
            raise ParameterError(f"ring tuning: {name} = {echo(seeds)} is not allowed: must be whole numbers >= 0")
        if len(seeds) < least or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
            raise ParameterError(
                f"ring tuning: {name} = {echo(list(seeds))} is not allowed: must be at least {least} distinct whole "
                "numbers >= 0" + (" (an interval needs 2 seeds)" if least == 2 else "")
            )
        out.append(tuple(int(s) for s in seeds))
    both = sorted(set(out[0]) & set(out[1]))
    if both:
        raise ParameterError(f"ring tuning: seeds {both} are both training and held-out seeds: held-out means unseen")
    return out[0], out[1]


# ----------------------------------------------------------------------------- the ring and a parameter set in it


@dataclass(frozen=True)
class RingSet:
    """The ring task set: the scenario's document and file, training and held-out seeds, horizon ``t_end_s`` [s]
    (None: the scenario's) and its density [1/km]."""

    document: dict[str, Any]
    file: str
    train_seeds: tuple[int, ...]
    heldout_seeds: tuple[int, ...]
    t_end_s: float | None
    density_per_km: float


def ring_set(
    scenario: str | Path = RING_SCENARIO,
    train_seeds: Sequence[int] = TRAIN_SEEDS,
    heldout_seeds: Sequence[int] = HELDOUT_SEEDS,
    t_end_s: float | None = None,
) -> RingSet:
    """The ring task set of a ring scenario file (default :data:`RING_SCENARIO`)."""
    from ..ring.scenario import load_ring_scenario

    train, held = check_seeds(train_seeds, heldout_seeds)
    sc = load_ring_scenario(scenario)
    if t_end_s is not None and not (isinstance(t_end_s, (int, float)) and 0 < t_end_s <= sc.spec.t_end_s):
        raise ParameterError(
            f"ring tuning: t_end_s = {echo(t_end_s)} is not allowed: must be in (0, {sc.spec.t_end_s:g}] s "
            "(ring.t_end_s)"
        )
    doc = copy.deepcopy(sc.document or {})
    return RingSet(doc, str(sc.source or scenario), train, held, t_end_s, sc.density_per_km)


def _scenario(rs: RingSet) -> Any:
    from ..ring.scenario import parse_ring_scenario

    return parse_ring_scenario(rs.document, rs.file, Path(rs.file) if Path(rs.file).is_file() else None)


def ring_defaults(space: Space, rs: RingSet) -> dict[str, float]:
    """The controller's tuned parameters as the ring scenario runs it, SI."""
    from ..models.carfollowing import make_law

    sc = _scenario(rs)
    if space.kind == "mpc":
        from ..ocp.formulation import traffic_formulation

        form = sc.mpc.formulation if sc.mpc is not None else traffic_formulation()
        return {p.name: float(getattr(form.traffic, p.name)) for p in space.params}
    if space.kind == "followerstopper":
        fs = sc.spec.followerstopper
        return {
            "r_fraction": float(sc.spec.r_fraction),
            "dx01_m": float(fs.get("dx0_m", FS_DX0_M)[0]),
            "d1_mps2": float(fs.get("d_mps2", FS_D_MPS2)[0]),
            "tau_s": float(fs.get("tau_s", _speed_loop_s())),
        }
    law = make_law(space.law, sc.cf, **sc.law_overrides.get(space.law, {}))
    si = law.si_coefficients() if hasattr(law, "si_coefficients") else {}
    return {p.name: float(si[p.name]) if p.name in si else float(getattr(law, p.name)) for p in space.params}


def _speed_loop_s() -> float:
    from ..ring.laws import SPEED_LOOP_S

    return SPEED_LOOP_S


def ring_document(space: Space, values: Mapping[str, float] | None, rs: RingSet) -> dict[str, Any]:
    """The ring scenario's document with vehicle 1 under ``space``'s controller and ``values`` (SI; None: the
    scenario's own settings) written where the ring reads them: an OV-type law's ``[carfollowing]`` (dimensionless
    coefficients at its scales), the IDM's ``[carfollowing.idm]``, FollowerStopper's ``ring.aev.r_fraction`` and
    ``[ring.followerstopper]``, the MPC's ``[mpc]``."""
    doc = copy.deepcopy(rs.document)
    if not values:
        return doc
    ring = doc.setdefault("ring", {})
    for k in values:
        space.param(k)  # unknown names are refused, by name
    v = {k: float(x) for k, x in values.items()}
    if space.kind == "mpc":
        doc["mpc"] = {**doc.get("mpc", {}), **v}
    elif space.kind == "followerstopper":
        d = {**ring_defaults(space, rs), **v}
        ring.setdefault("aev", {})["r_fraction"] = d["r_fraction"]
        ring["followerstopper"] = {
            "dx0_m": [d["dx01_m"] * x / FS_DX0_M[0] for x in FS_DX0_M],
            "d_mps2": [d["d1_mps2"] * x / FS_D_MPS2[0] for x in FS_D_MPS2],
            "tau_s": d["tau_s"],
        }
    elif space.law == "idm":
        cf = doc.setdefault("carfollowing", {})
        cf["idm"] = {**cf.get("idm", {}), **v}
    else:
        doc["carfollowing"] = _ov_table(space, v, rs)
    return doc


def _ov_table(space: Space, values: Mapping[str, float], rs: RingSet) -> dict[str, Any]:
    """``[carfollowing]`` setting an OV-type law's SI ``values`` (its untuned coefficients kept in SI when the
    scales move), as dimensionless coefficients at its scales (the other sub-tables kept)."""
    from ..scenarios.followers import SI_COEFFICIENTS

    sc = _scenario(rs)
    from ..models.carfollowing import make_law

    ov: Any = make_law("proposed", sc.cf)
    si = {**ov.si_coefficients(), **values}  # every OV coefficient in SI
    ell, u = si["h_scale_m"], si["v_scale_mps"]
    keep = {k: x for k, x in (rs.document.get("carfollowing") or {}).items() if isinstance(x, dict)}
    table: dict[str, Any] = {**keep, "h_scale_m": ell, "v_scale_mps": u}
    for key, (coeff, convert) in SI_COEFFICIENTS.items():
        table[coeff] = convert(si[key], ell, u)
    return table


def ring_task(space: Space, values: Mapping[str, float] | None, seed: int, index: int, rs: RingSet) -> Any:
    """The study task of one ring run: ``space``'s controller (HUMAN: no AEV) with ``values`` on seed ``seed``."""
    from ..study.traffic import _task

    doc = ring_document(space, values, rs)
    k = 0 if space.kind == "human" else 1
    v = {"density_per_km": float(rs.density_per_km), "aevs": k, "seed": int(seed), "t_end_s": rs.t_end_s}
    return _task("ring", index, doc, rs.file, v, "human" if k == 0 else space.label)


def ring_summary(result: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """The numbers of one ring run (a study task's result) that the tuning reads, SI."""
    m = (result.get("metrics") or [{}])[0]
    status = result.get("status", "error")
    row: dict[str, Any] = {"seed": int(seed), "status": status, "message": result.get("message", "")}
    for k in RING_METRICS + ("throughput_veh_per_h", "heat_pack_J_per_km"):
        x = m.get(k, math.nan)
        row[k] = float(x) if isinstance(x, (int, float)) and x is not None else math.nan
    return row


def ring_evaluator(
    folder: Path, rs: RingSet, executor: str, workers: int | None, scheduler: str | None, progress: Any
) -> Evaluator:
    """An :class:`~aev_ocp.tuning.core.Evaluator` whose cases are ring seeds."""
    return Evaluator(
        folder,
        executor,
        workers,
        scheduler,
        progress,
        task_of=lambda space, values, seed, index: ring_task(space, values, seed, index, rs),
        summary_of=ring_summary,
    )


# ----------------------------------------------------------------------------- scoring


def ring_score(
    runs: Sequence[Mapping[str, Any]], human: Sequence[Mapping[str, Any]], share: float = SPEED_SHARE
) -> tuple[float, list[float]]:
    """(objective [kWh/100 km], constraints :data:`RING_CONSTRAINTS`, each feasible when ≤ 0) of one parameter set's
    runs on the training seeds, ``human`` the all-human runs on the same seeds in the same order (module doc): the
    mean fleet energy (:data:`~aev_ocp.tuning.core.PENALTY_KWH_PER_100KM` if a run failed or ended on an event);
    the runs that did; the largest shortfall [m/s] of the mean speed below ``share`` × the all-human one."""
    if len(runs) != len(human) or not runs:
        raise ParameterError(
            f"ring_score: {len(runs)} runs against {len(human)} all-human runs: need one each per seed"
        )
    bad = sum(1 for r in runs if r["status"] != "ok")
    e = [float(r["battery_energy_kWh_per_100km"]) for r in runs]
    ok = bad == 0 and all(math.isfinite(x) for x in e)
    obj = float(np.mean(e)) if ok else PENALTY_KWH_PER_100KM
    short = []
    for r, h in zip(runs, human):
        need = share * float(h["mean_speed_mps"])
        got = float(r["mean_speed_mps"])
        short.append(need - got if math.isfinite(need) and math.isfinite(got) else 0.0)
    return obj, [float(bad), max(short)]


# ----------------------------------------------------------------------------- the tuning run


#: Files of a ring tuning folder.
RING_FILES = ("ring.md", "ring.json", "ring_runs.csv", "ring_trials.csv")


@dataclass
class RingTuningOutput:
    """What :func:`run_ring_tuning` wrote: the folder, its files, the held-out table's rows and everything saved."""

    folder: Path
    files: list[Path]
    rows: list[dict[str, Any]]
    result: dict[str, Any]


@dataclass(frozen=True)
class RingRun:
    """One ring tuning, for its files: the task set, the tuned spaces and the untuned controllers, their tuners,
    defaults and best sets, the all-human training runs, the held-out runs ({(controller, set): runs in seed order}),
    the budget, seed, batch, the closed-loop evaluations per controller while tuning and the command line."""

    rs: RingSet
    spaces: Sequence[Space]
    untuned: Sequence[str]
    tuners: Mapping[str, Tuner]
    defaults: Mapping[str, Mapping[str, float]]
    best: Mapping[str, Any]
    human_train: Sequence[Mapping[str, Any]]
    held: Mapping[tuple[str, str], Sequence[Mapping[str, Any]]]
    budget: int
    seed: int
    batch: int
    evals: Mapping[str, int]
    command: str | None


def run_ring_tuning(
    controllers: Sequence[str] = (*RING_TABLE, *UNTUNED),
    budget: int = 16,
    out: str | Path | None = None,
    *,
    scenario: str | Path = RING_SCENARIO,
    train_seeds: Sequence[int] = TRAIN_SEEDS,
    heldout_seeds: Sequence[int] = HELDOUT_SEEDS,
    t_end_s: float | None = None,
    seed: int = 1,
    batch: int = 4,
    executor: str = "pool",
    workers: int | None = None,
    scheduler: str | None = None,
    progress_stream: Any = None,
    command: str | None = None,
) -> RingTuningOutput:
    """Tune each ring controller (:data:`RING_TABLE`) with ``budget`` trials on the training seeds (each trial one
    run per seed; :data:`UNTUNED` ones run at their defaults), then run every controller at its default and tuned,
    and the all-human ring, on the held-out seeds; write :data:`RING_FILES` into ``out`` (default
    results/tune_ring). executor, workers, scheduler: as :func:`aev_ocp.study.runner.execute`."""
    from ..results import claim_output_dir, output_lock
    from ..study.runner import check_executor
    from .cycles import check_seed

    spaces, untuned = check_ring_controllers(list(controllers))
    budget, batch, seed = check_budget(budget), check_budget(batch, "batch"), check_seed(seed)
    check_executor(executor, workers, scheduler)
    rs = ring_set(scenario, train_seeds, heldout_seeds, t_end_s)
    folder = Path(out) if out is not None else Path("results") / "tune_ring"
    with output_lock(folder):
        claim_output_dir(folder, "tune", "ring tuning", None, list(RING_FILES))
        ev = ring_evaluator(folder, rs, executor, workers, scheduler, progress_stream)
        (human_train,) = ev.run([(HUMAN, None, rs.train_seeds)], name="tune ring: all human")
        ev.counts.clear()  # the reference runs count in no controller's budget
        defaults = {s.label: ring_defaults(s, rs) for s in spaces}
        tuners = {s.label: Tuner(s.params, defaults[s.label], budget, seed) for s in spaces}
        tune_rounds(
            spaces,
            tuners,
            batch,
            lambda pairs, rnd: ev.run([(s, v, rs.train_seeds) for s, v in pairs], name=f"tune ring round {rnd}"),
            lambda runs: ring_score(runs, human_train),
        )
        evals = dict(ev.counts)
        best = {s.label: tuners[s.label].best() for s in spaces}
        jobs: list[tuple[Space, Mapping[str, float] | None, Sequence[int]]] = [(HUMAN, None, rs.heldout_seeds)]
        keys = [("human", "all human")]
        for s in spaces:
            b = best[s.label]
            jobs += [(s, None, rs.heldout_seeds), (s, b.values if b is not None else None, rs.heldout_seeds)]
            keys += [(s.label, "default"), (s.label, "tuned")]
        for c in untuned:
            jobs.append((Space(c, "untuned", c, ()), None, rs.heldout_seeds))
            keys.append((c, "default"))
        final = ev.run(jobs, name="tune ring: held-out seeds")
        run = RingRun(
            rs,
            spaces,
            untuned,
            tuners,
            defaults,
            best,
            human_train,
            dict(zip(keys, final)),
            budget,
            seed,
            batch,
            evals,
            command,
        )
        return write_ring(folder, run)


# ----------------------------------------------------------------------------- the tables


def _stat(runs: Sequence[Mapping[str, Any]], metric: str) -> dict[str, Any]:
    """Mean and 95 % t interval of ``metric`` over the runs that ended 'ok' (n kept)."""
    from ..intervals import summarize

    x = [float(r[metric]) for r in runs if r["status"] == "ok" and math.isfinite(float(r[metric]))]
    if len(x) < 2:
        return {"mean": float(np.mean(x)) if x else None, "lo": None, "hi": None, "n": len(x)}
    iv = summarize(x)
    return {"mean": iv.mean, "lo": iv.lo, "hi": iv.hi, "n": iv.n}


def _paired(a: Sequence[Mapping[str, Any]], b: Sequence[Mapping[str, Any]], metric: str) -> dict[str, Any] | None:
    """The paired difference a − b of ``metric`` on the seeds both ended 'ok', its 95 % interval and the verdict for
    a ('better'/'worse' when the interval excludes 0, else 'tie'; higher is better for the mean speed only)."""
    from ..intervals import difference, verdict

    bb = {r["seed"]: r for r in b if r["status"] == "ok"}
    pairs = [(float(r[metric]), float(bb[r["seed"]][metric])) for r in a if r["status"] == "ok" and r["seed"] in bb]
    if len(pairs) < 2:
        return None
    d = difference([p[0] for p in pairs], [p[1] for p in pairs], paired=True)
    return {"mean": d.mean, "lo": d.lo, "hi": d.hi, "n": len(pairs), "verdict": verdict(d, metric != "mean_speed_mps")}


def held_rows(run: RingRun) -> list[dict[str, Any]]:
    """One row per (controller, set) on the held-out seeds: each metric's mean and interval, the energy's paired
    difference to the all-human ring and (tuned rows) to the same controller's default."""
    human = run.held[("human", "all human")]
    rows = []
    for (ctrl, which), runs in run.held.items():
        none = which == "tuned" and run.best.get(ctrl) is None
        row: dict[str, Any] = {"controller": ctrl, "set": "tuned = default (no feasible trial)" if none else which}
        row["seeds"] = len(runs)
        row["failed"] = sum(1 for r in runs if r["status"] != "ok")
        row["budget_trials"] = run.budget if ctrl in run.tuners else 0
        row["closed_loop_evaluations"] = run.evals.get(ctrl, 0)
        for m in RING_METRICS:
            row[m] = _stat(runs, m)
        e = "battery_energy_kWh_per_100km"
        row["energy_vs_human"] = _paired(runs, human, e) if ctrl != "human" else None
        row["energy_vs_default"] = _paired(runs, run.held[(ctrl, "default")], e) if which == "tuned" else None
        row["speed_std_vs_human"] = _paired(runs, human, "speed_std_mps") if ctrl != "human" else None
        rows.append(row)
    return rows


def _iv(s: Mapping[str, Any] | None, fmt: str = ".4g") -> str:
    from ..study.seeds import interval_text

    if s is None:
        return "–"
    text = interval_text(s["mean"], s["lo"], s["hi"], fmt)
    return text + (f" {s['verdict']}" if s.get("verdict") else "")


def _what_tuned(run: RingRun) -> list[list[str]]:
    from .core import _fmt

    rows = []
    for s in run.spaces:
        b = run.best[s.label]
        for p in s.params:
            tuned = _fmt(b.values[p.name], 4) if b is not None else "no feasible trial"
            bounds = f"[{_fmt(p.lo)}, {_fmt(p.hi)}]" + (" log" if p.log else "")
            rows.append([s.label, p.name, p.meaning, bounds, _fmt(run.defaults[s.label][p.name], 4), tuned])
    for c in run.untuned:
        rows.append([c, "–", "not tuned: run at its defaults", "–", "defaults", "–"])
    return rows


def _train_rows(run: RingRun) -> list[list[str]]:
    from .core import _fmt

    rows = []
    for s in run.spaces:
        recs = run.tuners[s.label].records
        b = run.best[s.label]
        d = recs[0]
        feas = sum(r.feasible for r in recs)
        rows.append(
            [
                s.label,
                f"{run.budget} / {run.evals.get(s.label, 0)}",
                f"{_fmt(d.objective, 4)}" + ("" if d.feasible else " (infeasible)"),
                _fmt(b.objective, 4) if b is not None else "–",
                f"#{b.number}" if b is not None else "–",
                f"{feas}/{len(recs)}",
            ]
        )
    return rows


def ring_markdown(run: RingRun, rows: Sequence[Mapping[str, Any]]) -> str:
    """``ring.md``: the task set, objective, budget, what was tuned, the training result and the held-out table."""
    from ..report import markdown_table

    rs = run.rs
    n_tr = len(rs.train_seeds)
    t_end = f"{rs.t_end_s:g} s" if rs.t_end_s is not None else "the scenario's horizon"
    head = ["controller", "set", "trials / evaluations", "failed", "energy kWh/100 km", "mean speed m/s"]
    head += ["speed std m/s", "braking /veh-km", "energy − all human", "energy: tuned − default"]
    table = [
        [
            r["controller"],
            r["set"],
            f"{r['budget_trials']} / {r['closed_loop_evaluations']}",
            f"{r['failed']}/{r['seeds']}",
            *(_iv(r[m]) for m in RING_METRICS),
            _iv(r["energy_vs_human"], "+.3g"),
            _iv(r["energy_vs_default"], "+.3g"),
        ]
        for r in rows
    ]
    return "\n".join(
        [
            "# Equal tuning effort on the ring: each controller at its default and tuned",
            "",
            f"Command: `{run.command}`" if run.command else "",
            "",
            f"Ring: {Path(rs.file).name}, one AEV (vehicle 1) among the calibrated drivers, {t_end}. Training seeds "
            f"{list(rs.train_seeds)}; held-out seeds {list(rs.heldout_seeds)}.",
            f"Budget: {run.budget} trials per controller × {n_tr} training seeds = {run.budget * n_tr} closed-loop "
            f"evaluations per controller (trial 0 is the default); optuna TPE, seed {run.seed}, {run.batch} trials per "
            "controller per study execution. The all-human runs on the training seeds are the constraint's reference "
            "and count in no budget.",
            "Objective: the fleet's battery energy [kWh/100 km] over the metrics window, mean over the training seeds. "
            f"Feasible: no run ends on an event, and on every training seed the mean speed is ≥ {SPEED_SHARE:g} × the "
            "all-human ring's on that seed.",
            "",
            "## What was tuned",
            "",
            markdown_table(["controller", "parameter (SI)", "meaning", "bounds", "default", "tuned"], _what_tuned(run)),
            "",
            "## On the training seeds",
            "",
            markdown_table(
                ["controller", "trials / evaluations", "default", "tuned", "best trial", "feasible trials"],
                _train_rows(run),
            ),
            "",
            "Objective kWh/100 km (mean over the training seeds).",
            "",
            "## On the held-out seeds",
            "",
            markdown_table(head, table),
            "",
            "Mean over the held-out seeds [95 % t interval]; failed: runs that ended on an event (left out). Differences "
            "are paired by seed, mean [95 % interval], with the verdict for the row: better/worse only when the "
            "interval excludes 0, else tie.",
            "",
        ]
    )


def write_ring(folder: Path, run: RingRun) -> RingTuningOutput:
    """Write :data:`RING_FILES` into ``folder``, atomically."""
    from ..results import to_jsonable, write_atomic, write_json
    from .write import csv_text

    rows = held_rows(run)
    runs_rows = [
        {"controller": c, "set": w, **{k: v for k, v in r.items()}} for (c, w), runs in run.held.items() for r in runs
    ]
    trials = [
        {
            "controller": s.label,
            "trial": rec.number,
            "objective_kWh_per_100km": rec.objective,
            "feasible": rec.feasible,
            **{f"violation_{k}": v for k, v in zip(RING_CONSTRAINTS, rec.constraints)},
            **rec.values,
        }
        for s in run.spaces
        for rec in run.tuners[s.label].records
    ]
    result = {
        "command": run.command,
        "scenario": run.rs.file,
        "train_seeds": list(run.rs.train_seeds),
        "heldout_seeds": list(run.rs.heldout_seeds),
        "t_end_s": run.rs.t_end_s,
        "budget_trials": run.budget,
        "closed_loop_evaluations_per_controller": run.budget * len(run.rs.train_seeds),
        "evaluations": dict(run.evals),
        "speed_share": SPEED_SHARE,
        "seed": run.seed,
        "batch": run.batch,
        "sampler": "optuna TPESampler (multivariate, constrained), seed fixed",
        "controllers": {
            s.label: {
                "defaults": dict(run.defaults[s.label]),
                "tuned": dict(run.best[s.label].values) if run.best[s.label] is not None else None,
                "best_trial": run.best[s.label].number if run.best[s.label] is not None else None,
                "tuned_document": ring_document(s, run.best[s.label].values, run.rs) if run.best[s.label] else None,
            }
            for s in run.spaces
        },
        "untuned": list(run.untuned),
        "human_train": list(run.human_train),
        "rows": rows,
    }
    files = [
        write_atomic(folder / "ring.md", ring_markdown(run, rows)),
        write_json(folder / "ring.json", to_jsonable(result)),
        write_atomic(folder / "ring_runs.csv", csv_text(runs_rows)),
        write_atomic(folder / "ring_trials.csv", csv_text(trials)),
    ]
    return RingTuningOutput(folder, files, rows, result)
