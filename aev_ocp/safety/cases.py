"""The safety suite's cases, all in SI, as one Python table (:func:`suite_cases`), each with its source, and the
two actuators every case is labelled and run with (:data:`ACTUATORS`).

Families (the Euro NCAP AEB Car-to-Car test protocol's rear-end tests, extended to motorway speed):

* ``CCRs`` — stationary target: the ego approaches a standing car at 10 … 80 km/h in 10 km/h steps (Euro NCAP
  CCRs) and at 100, 120, 130 km/h (ours: motorway speeds, the same geometry), starting at a time-to-collision of
  4 s (gap = 4 s × v_ego; NCAP starts its runs 4 s before the impact too).
* ``CCRm`` — slower moving target: the lead at 20 km/h constant, the ego at 30 … 80 km/h (Euro NCAP CCRm) and
  at 100, 120, 130 km/h (ours), starting at a time-to-collision of 4 s (gap = 4 s × closing speed).
* ``CCRb`` — car-to-car rear braking: ego and lead both at 50 km/h (Euro NCAP CCRb) or 100 km/h (ours), gap
  12 m or 40 m, the lead braking at −2 or −6 m/s² from t = 0 until it stops.
* ``lane-end`` — a standing obstacle (a lane end, a stopped car behind a crest) seen at 60 m or 150 m from
  100 km/h and at 150 m from 130 km/h (ours: 60 m is just beyond the stopping distance from 100 km/h at
  −8 m/s² with the declared actuator, 150 m a sight distance on a motorway).
* ``cut-in`` — a car cuts in: **modelled as the new predecessor appearing at t = 0 at the given gap** (the
  ego had no reason to hold a gap to it before), at the ego's speed or 20 km/h slower, keeping its speed, or
  braking at −6 or −9 m/s² from t = 0 (at gaps 8, 15 and 20 m in that order); the ego at 54, 100 and 130 km/h
  (ours: a lead braking at −9 m/s², harder than the ego can, makes the 20 m cases near the boundary).

Every case runs in the drive-cycle scenarios' units L = 15 m, U = 17 m/s (scenarios/udds_platoon.toml): the
laws' top speed V∞·U = 33.4 m/s lies below 120 and 130 km/h, so there the laws slow towards it on their own
(stated, not hidden), and the MPC's dt = 0.1 model = 88 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..params import ParameterError, Units, VehicleLimits, echo

KMH = 1.0 / 3.6  # m/s per km/h (exact)
CASE_UNITS = Units(15.0, 17.0)  # the drive-cycle scenarios' units (scenarios/udds_platoon.toml)
START_TTC_S = 4.0  # CCRs / CCRm start: time-to-collision 4 s (our choice, as NCAP's test start)
FAMILIES = ("CCRs", "CCRm", "CCRb", "lane-end", "cut-in")
NCAP = "Euro NCAP AEB Car-to-Car test protocol (v4.3, 2023)"
OURS_MOTORWAY = f"ours: {NCAP} geometry at motorway speed"


@dataclass(frozen=True)
class Actuator:
    """How the vehicle realises a commanded acceleration: a first-order lag lag_s [s] with its rate clipped to
    ±jerk_max_mps3 [m/s³] (None: no jerk limit), from a realised 0 at t = 0 (:mod:`aev_ocp.models.actuator`)."""

    name: str
    lag_s: float
    jerk_max_mps3: float | None
    source: str

    def limits(self, base: VehicleLimits | None = None) -> VehicleLimits:
        """``base`` (default :class:`VehicleLimits`' defaults: a_min −8 m/s², a_max 4 m/s²) with this actuator."""
        b = base or VehicleLimits()
        return VehicleLimits(b.a_min_mps2, b.a_max_mps2, self.jerk_max_mps3, self.lag_s, b.v_max_mps, True)

    @property
    def tau_s(self) -> float:
        """The actuator's time constant [s] as the plant runs it (VehicleLimits.actuator_tau_s; 0: ideal)."""
        lim = self.limits()
        return lim.actuator_tau_s if lim.has_actuator_state else 0.0


#: The paper's model: the command is realised at once.
IDEAL = Actuator("ideal", 0.0, None, "the paper's model: the command realised at once")
#: A passenger car's brakes: full braking (−8 m/s²) is reached through a jerk-limited ramp at 40 m/s³ to −4 m/s²
#: (0.1 s) and then the lag τ = 0.1 s: 90 % of it after 0.26 s, 95 % after 0.33 s — a braking build-up of
#: about 0.3 s. Sources: the brake build-up time ("Schwellzeit") of passenger-car hydraulic brakes in
#: emergency braking, 0.1–0.3 s, the range German accident reconstruction works with (the standard handbook is Burg &
#: Moser (eds.), Handbuch Verkehrsunfallrekonstruktion, 2nd ed., 2009; its page was not checked here: the range is
#: as practitioners' published summaries quote it, some giving 0.1–0.2 s for modern cars);
#: the first-order lag of an ACC's lower-level (brake/drive) controller, τ ≈ 0.1–0.5 s (Rajamani, Vehicle
#: Dynamics and Control, 2nd ed., 2012, ch. 5).
DECLARED = Actuator(
    "declared",
    0.1,
    40.0,
    "brake build-up ~0.3 s (accident reconstruction's 'Schwellzeit' of car brakes, 0.1–0.3 s); lower-level lag τ 0.1 s "
    "(Rajamani 2012, ch. 5); jerk ≤ 40 m/s³",
)
ACTUATORS = {a.name: a for a in (IDEAL, DECLARED)}


@dataclass(frozen=True)
class SafetyCase:
    """One case, SI: the ego at v_ego_mps a gap_m behind a lead at v_lead_mps that brakes at a_lead_mps2 (≤ 0)
    from t_brake_s on until it stops; the run lasts t_end_s [s]; source: where the case comes from."""

    family: str
    name: str
    v_ego_mps: float
    gap_m: float
    v_lead_mps: float
    a_lead_mps2: float = 0.0
    t_brake_s: float = 0.0
    t_end_s: float = 10.0
    source: str = "user"

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ParameterError(f"SafetyCase.family = {echo(self.family)} is not allowed: must be one of {FAMILIES}")
        for nm, ok in (
            ("v_ego_mps", self.v_ego_mps >= 0),
            ("gap_m", self.gap_m > 0),
            ("v_lead_mps", self.v_lead_mps >= 0),
            ("a_lead_mps2", self.a_lead_mps2 <= 0),
            ("t_brake_s", self.t_brake_s >= 0),
            ("t_end_s", self.t_end_s > 0),
        ):
            if not ok:
                raise ParameterError(f"SafetyCase {self.name}: {nm} = {echo(getattr(self, nm))} is not allowed")


def _t_end(v_ego: float, v_lead: float, a_lead: float, t_brake: float) -> float:
    """Long enough for both cars to settle (our choice): 2.5 s after the later of the lead's stop and the ego's
    stop at −8 m/s² (with its build-up), at least 6 s, at most 12 s."""
    stop_l = t_brake + v_lead / -a_lead if a_lead < 0 else (0.0 if v_lead == 0 else 6.0)
    stop_e = 0.4 + v_ego / 8.0 if v_lead == 0 or a_lead < 0 else 4.0
    return float(min(max(max(stop_l, stop_e) + 2.5, 6.0), 12.0))


def _case(family: str, name: str, v: float, gap: float, vl: float, a: float, source: str) -> SafetyCase:
    return SafetyCase(family, name, v, gap, vl, a, 0.0, _t_end(v, vl, a, 0.0), source)


#: The quick subset (a smoke run, 3 s each): names of :func:`suite_cases`.
QUICK = (
    "CCRs_50kmh",
    "CCRs_100kmh",
    "CCRm_80kmh",
    "CCRb_50kmh_12m_-6mps2",
    "CCRb_100kmh_40m_-6mps2",
    "laneend_100kmh_60m",
    "cutin_100kmh_lead100kmh_15m_-6mps2",
    "cutin_130kmh_lead110kmh_20m_-9mps2",
)


#: The representative subset ``aev-ocp reproduce`` runs (full length; ``aev-ocp safety`` runs every case): each
#: family, Euro NCAP's CCRs at 50 and 80 km/h and every motorway CCRs (100, 120, 130 km/h: the bare proposed law and
#: OVFL collide from 80 km/h on, their top speed V∞·U = 33.4 m/s being no reason to brake), the fastest slower-
#: target case, both NCAP-speed and motorway braking leads, the nearest and the fastest lane end, and the two
#: cut-ins the suite's text discusses (a lead braking at −6 m/s², one at −9 m/s², harder than the ego can).
REPRODUCE = (
    "CCRs_50kmh",
    "CCRs_80kmh",
    "CCRs_100kmh",
    "CCRs_120kmh",
    "CCRs_130kmh",
    "CCRm_80kmh",
    "CCRm_130kmh",
    "CCRb_50kmh_12m_-6mps2",
    "CCRb_100kmh_40m_-6mps2",
    "laneend_100kmh_60m",
    "laneend_130kmh_150m",
    "cutin_100kmh_lead100kmh_15m_-6mps2",
    "cutin_130kmh_lead110kmh_20m_-9mps2",
)


def reproduce_cases() -> list[SafetyCase]:
    """The cases of :data:`REPRODUCE`, full length, in the suite's order (``aev-ocp reproduce``'s subset)."""
    return [c for c in suite_cases() if c.name in REPRODUCE]


def suite_cases(quick: bool = False) -> list[SafetyCase]:
    """Every case of the suite (module docstring), each with its source; ``quick``: :data:`QUICK`, 3 s long."""
    cases: list[SafetyCase] = []
    for kmh in (10, 20, 30, 40, 50, 60, 70, 80, 100, 120, 130):
        v = kmh * KMH
        cases.append(
            _case("CCRs", f"CCRs_{kmh}kmh", v, START_TTC_S * v, 0.0, 0.0, NCAP if kmh <= 80 else OURS_MOTORWAY)
        )
    vl = 20 * KMH
    for kmh in (30, 40, 50, 60, 70, 80, 100, 120, 130):
        v = kmh * KMH
        src = NCAP if kmh <= 80 else OURS_MOTORWAY
        cases.append(_case("CCRm", f"CCRm_{kmh}kmh", v, START_TTC_S * (v - vl), vl, 0.0, src))
    for kmh in (50, 100):
        v = kmh * KMH
        for gap in (12.0, 40.0):
            for a in (-2.0, -6.0):
                src = NCAP if kmh == 50 else OURS_MOTORWAY
                cases.append(_case("CCRb", f"CCRb_{kmh}kmh_{gap:g}m_{a:g}mps2", v, gap, v, a, src))
    for kmh, gap in ((100, 60.0), (100, 150.0), (130, 150.0)):
        src = "ours: a standing obstacle / lane end at motorway speed"
        cases.append(_case("lane-end", f"laneend_{kmh}kmh_{gap:g}m", kmh * KMH, gap, 0.0, 0.0, src))
    for kmh in (54, 100, 130):
        for dkmh in (0, 20):
            for gap, a in ((8.0, 0.0), (15.0, -6.0), (20.0, -9.0)):
                v, vl = kmh * KMH, (kmh - dkmh) * KMH
                name = f"cutin_{kmh}kmh_lead{kmh - dkmh}kmh_{gap:g}m_{a:g}mps2"
                cases.append(_case("cut-in", name, v, gap, vl, a, "ours: the new predecessor appears at t = 0"))
    if quick:
        cases = [
            SafetyCase(c.family, c.name, c.v_ego_mps, c.gap_m, c.v_lead_mps, c.a_lead_mps2, c.t_brake_s, 3.0, c.source)
            for c in cases
            if c.name in QUICK
        ]
    return cases
