"""Battery life through BLAST-Lite (aev_ocp.life): the daily schedule and the wrapper against BLAST-Lite itself."""

from __future__ import annotations

import builtins
import math

import numpy as np
import pytest

from aev_ocp import life
from aev_ocp.params import ParameterError

T_DRIVE = np.linspace(0.0, 300.0, 601)
SOC_DRIVE = 0.83 - 0.0127 * (T_DRIVE / 300.0) ** 1.3  # a 300 s drive using 1.27 % of the charge
TEMP_DRIVE = 306.4 + 2.1 * np.sin(T_DRIVE / 47.0) ** 2  # K


def test_daily_profile_closes_the_day() -> None:
    sch = life.DailySchedule(trip_start_h=(7.5, 12.25, 18.0), charge_start_h=21.0, charge_C=0.37, sample_s=2.5)
    p = life.daily_profile(T_DRIVE, SOC_DRIVE, TEMP_DRIVE, 301.2, sch)
    t, s, T = p["Time_s"], p["SOC"], p["Temperature_C"]
    assert t[0] == 0.0 and t[-1] == 86400.0 and np.all(np.diff(t) > 0)
    assert s[0] == pytest.approx(0.83) and s[-1] == pytest.approx(0.83)  # charged back
    assert np.min(s) == pytest.approx(0.83 - 3 * 0.0127, abs=1e-12)  # three drives
    assert np.max(T) == pytest.approx(np.max(TEMP_DRIVE) - 273.15, abs=0.05) and T[0] == pytest.approx(301.2 - 273.15)
    k = np.searchsorted(t, 12.25 * 3600.0)  # the second drive starts at 12:15 with the SOC the first left
    assert s[k] == pytest.approx(0.83 - 0.0127, abs=1e-12)
    # charging: 3 × 1.27 % at 0.37C takes 3·0.0127/0.37 h
    j = np.where(t == 21.0 * 3600.0)[0][0]
    assert t[j + 1] - t[j] == pytest.approx(3 * 0.0127 / 0.37 * 3600.0)


def test_daily_profile_errors() -> None:
    with pytest.raises(ParameterError, match="trip_start_h"):
        life.DailySchedule(trip_start_h=(9.0, 8.0))
    with pytest.raises(ParameterError, match="charge_start_h"):
        life.DailySchedule(trip_start_h=(8.0, 23.0), charge_start_h=22.0)
    with pytest.raises(ParameterError, match="does not fit"):
        life.daily_profile(
            np.linspace(0, 7200.0, 50),
            np.linspace(0.8, 0.7, 50),
            np.full(50, 300.0),
            300.0,
            life.DailySchedule(trip_start_h=(8.0, 9.0)),
        )


def test_without_blast_lite_one_line_install_hint(monkeypatch: pytest.MonkeyPatch) -> None:
    real = builtins.__import__

    def no_blast(name: str, *a, **k):  # type: ignore[no-untyped-def]
        if name == "blast" or name.startswith("blast."):
            raise ImportError("no blast")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_blast)
    with pytest.raises(ParameterError) as exc:
        life.blast_model("LFP")
    assert str(exc.value) == "battery life needs NREL's BLAST-Lite: pip install '.[life]' in the aev_ocp checkout"
    assert not life.blast_available()


@pytest.mark.parametrize("chem", ["LFP", "NCA", "NMC"])
def test_toolkit_equals_blast_lite_called_directly(chem: str) -> None:
    blast_models = pytest.importorskip(
        "blast.models", reason="BLAST-Lite not installed (pip install '.[life]' in the checkout)"
    )
    prof = life.daily_profile(T_DRIVE, SOC_DRIVE, TEMP_DRIVE, 303.9)
    years = 1.3
    got = life.battery_life(prof, chem, years)
    direct = getattr(blast_models, life.BLAST_MODELS[chem])()
    direct.simulate_battery_life({k: v.copy() for k, v in prof.items()}, threshold_time=years)
    yrs = np.asarray(direct.stressors["t_days"]) / 365.0
    q = np.asarray(direct.outputs["q"])
    assert got["model"] == life.BLAST_MODELS[chem]
    assert got["capacity_1y"] == np.interp(1.0, yrs, q) and yrs[-1] >= 1.3
    if "r" in direct.outputs:
        assert got["resistance_1y"] == np.interp(1.0, yrs, np.asarray(direct.outputs["r"])) > 1.0
    assert math.isnan(got["capacity_5y"]) and math.isnan(got["capacity_10y"])  # not simulated that far
    assert 0.7 < got["capacity_1y"] < 1.0
    if q.min() >= 0.8:
        assert got["years_to_80pct"] == math.inf
    else:
        k = int(np.argmax(q < 0.8))
        assert yrs[k - 1] <= got["years_to_80pct"] <= yrs[k]


def test_hotter_pack_ages_faster() -> None:
    pytest.importorskip("blast", reason="BLAST-Lite not installed (pip install '.[life]' in the checkout)")
    cool = life.battery_life(life.daily_profile(T_DRIVE, SOC_DRIVE, TEMP_DRIVE - 10, 293.2), "LFP", 1.2)
    hot = life.battery_life(life.daily_profile(T_DRIVE, SOC_DRIVE, TEMP_DRIVE + 10, 313.2), "LFP", 1.2)
    assert hot["capacity_1y"] < cool["capacity_1y"]
