"""The safety suite's cases, all in SI, as one Python table (:func:`suite_cases`).

Families (Euro NCAP AEB car-to-car rear test protocol style; the NCAP speeds, our gaps where NCAP sets none):

* ``CCRb`` — car-to-car rear braking: ego and lead both at 50 km/h, gap 12 m or 40 m, the lead braking at
  −2 or −6 m/s² from t = 0 until it stops (Euro NCAP CCRb: 50 km/h, 12 / 40 m, −2 / −6 m/s²).
* ``CCRs`` — stationary target: the ego approaches a standing car at 10, 20, 30, 40, 50 km/h, starting at a
  time-to-collision of 4 s (gap = 4 s × v_ego; our choice, NCAP starts 4 s before impact too).
* ``CCRm`` — slower moving target: the lead at 20 km/h constant, the ego at 30 … 70 km/h, starting at a
  time-to-collision of 4 s (gap = 4 s × closing speed).
* ``cut-in`` — a car cuts in: **modelled as the new predecessor appearing at t = 0 at the given gap** (the
  ego had no reason to hold a gap to it before), at the ego's speed or 5 m/s slower, keeping its speed or
  braking at −3, −6, −9 m/s² from t = 0; gaps 5, 8, 12, 20 m, ego speeds 15, 20, 25 m/s.

Every case runs in the drive-cycle scenarios' units L = 15 m, U = 17 m/s (scenarios/udds_platoon.toml): the
laws' top speed V∞·U = 33.4 m/s lies above every case's speed, and the MPC's dt = 0.1 model = 88 ms.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..params import ParameterError, Units, echo

KMH = 1.0 / 3.6  # m/s per km/h (exact)
CASE_UNITS = Units(15.0, 17.0)  # the drive-cycle scenarios' units (scenarios/udds_platoon.toml)
START_TTC_S = 4.0  # CCRs / CCRm start: time-to-collision 4 s (our choice, as NCAP's test start)
FAMILIES = ("CCRb", "CCRs", "CCRm", "cut-in")


@dataclass(frozen=True)
class SafetyCase:
    """One case, SI: the ego at v_ego_mps a gap_m behind a lead at v_lead_mps that brakes at a_lead_mps2 (≤ 0)
    from t_brake_s on until it stops; the run lasts t_end_s [s]."""

    family: str
    name: str
    v_ego_mps: float
    gap_m: float
    v_lead_mps: float
    a_lead_mps2: float = 0.0
    t_brake_s: float = 0.0
    t_end_s: float = 10.0

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


def _t_end(v_lead: float, a_lead: float, t_brake: float) -> float:
    """Long enough for both cars to settle: 4 s after the lead stops, at least 8 s, at most 15 s (our choice)."""
    stop = t_brake + v_lead / -a_lead if a_lead < 0 else 0.0
    return float(min(max(stop + 4.0, 8.0), 15.0))


def suite_cases(quick: bool = False) -> list[SafetyCase]:
    """Every case of the suite (module docstring); ``quick``: two per family and 3 s long (a smoke run)."""
    cases: list[SafetyCase] = []
    v50 = 50 * KMH
    for gap in (12.0, 40.0):
        for a in (-2.0, -6.0):
            cases.append(
                SafetyCase("CCRb", f"CCRb_50kmh_{gap:g}m_{a:g}mps2", v50, gap, v50, a, 0.0, _t_end(v50, a, 0.0))
            )
    for kmh in (10, 20, 30, 40, 50):
        v = kmh * KMH
        cases.append(SafetyCase("CCRs", f"CCRs_{kmh}kmh", v, START_TTC_S * v, 0.0, 0.0, 0.0, 8.0))
    for kmh in (30, 40, 50, 60, 70):
        v, vl = kmh * KMH, 20 * KMH
        cases.append(SafetyCase("CCRm", f"CCRm_{kmh}kmh", v, START_TTC_S * (v - vl), vl, 0.0, 0.0, 10.0))
    for v in (15.0, 20.0, 25.0):
        for dv in (0.0, 5.0):
            for gap in (5.0, 8.0, 12.0, 20.0):
                for a in (0.0, -3.0, -6.0, -9.0):
                    vl = v - dv
                    cases.append(
                        SafetyCase(
                            "cut-in",
                            f"cutin_{v:g}mps_lead{vl:g}mps_{gap:g}m_{a:g}mps2",
                            v,
                            gap,
                            vl,
                            a,
                            0.0,
                            _t_end(vl, a, 0.0),
                        )
                    )
    if quick:
        keep = {
            "CCRb_50kmh_12m_-6mps2",
            "CCRb_50kmh_40m_-2mps2",
            "CCRs_30kmh",
            "CCRs_50kmh",
            "CCRm_50kmh",
            "CCRm_70kmh",
            "cutin_25mps_lead25mps_5m_-9mps2",
            "cutin_20mps_lead20mps_8m_-6mps2",
        }
        cases = [
            SafetyCase(c.family, c.name, c.v_ego_mps, c.gap_m, c.v_lead_mps, c.a_lead_mps2, c.t_brake_s, 3.0)
            for c in cases
            if c.name in keep
        ]
    return cases
