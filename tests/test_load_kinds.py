"""Every output kind loads back with aev_ocp.load (ring runs and experiments, the safety suite, the stability
analyses, SUMO fleet runs): each written by a short real run, loaded, its numbers compared with the run that wrote
them or recomputed from the loaded arrays, and ``.plot()`` a matplotlib Figure; a damaged or unknown manifest is
one LoadError naming the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import same_numbers as _same
from matplotlib.figure import Figure

import aev_ocp
from aev_ocp.cli import main
from aev_ocp.saved import KINDS, MANIFEST, SIM_ARRAYS, LoadError


def _figure(obj) -> None:
    import matplotlib.pyplot as plt

    fig = obj.plot()
    assert isinstance(fig, Figure) and fig.axes
    plt.close(fig)


# ----------------------------------------------------------------------------- ring
def test_ring_experiment_round_trip(tmp_path: Path) -> None:
    """The Stern ring all-human and with a FollowerStopper (30 s) saved and loaded: every run's arrays equal the
    run's, and the fleet metrics recomputed from the loaded trajectories equal the saved ones."""
    from aev_ocp.ring.run import fleet_metrics, stern
    from aev_ocp.ring.outputs import save_ring_output

    direct = stern(["followerstopper"], t_end_s=30.0, seed=3)
    save_ring_output(tmp_path, direct, {"experiment": "stern", "t_end_s": 30.0, "seed": 3})
    out = aev_ocp.load(tmp_path)
    assert [r.label for r in out.runs] == ["all human", "followerstopper"]
    for got, want in zip(out.runs, direct):
        for name in SIM_ARRAYS:
            np.testing.assert_array_equal(getattr(got.result.sim, name), getattr(want.result.sim, name), err_msg=name)
        np.testing.assert_array_equal(got.result.distance, want.result.distance)
        np.testing.assert_array_equal(got.result.energy_J, want.result.energy_J)
        assert got.result.ring.length_m == want.result.ring.length_m
        assert [got.result.ring.is_human(i) for i in range(22)] == [want.result.ring.is_human(i) for i in range(22)]
        np.testing.assert_array_equal(got.result.positions_m(), want.result.positions_m())
        recomputed = fleet_metrics(got.result)  # from the loaded arrays alone
        assert _same(
            json.loads(json.dumps(aev_ocp.results.to_jsonable(recomputed))), {k: got.fleet[k] for k in recomputed}
        )
    assert not out.runs[1].result.ring.is_human(0) and out.runs[0].result.ring.is_human(0)
    saved = json.loads((tmp_path / "ring.json").read_text())
    assert [r["label"] for r in saved["runs"]] == [r.label for r in out.runs]
    label = out.runs[1].label
    assert aev_ocp.load(tmp_path, run=label).t_s[-1] == pytest.approx(30.0)
    with pytest.raises(LoadError, match="no run 'nope'"):
        aev_ocp.load(tmp_path, run="nope")
    with pytest.raises(LoadError, match="saved record"):  # a loaded ring is read, not run again
        out.runs[1].result.ring.vehicles[0].command(None)
    _figure(out)


def test_ring_round_trip_thinned_keeps_every_kth_sample_and_the_last(tmp_path: Path) -> None:
    """A ring run saved with at most 23 samples (reproduce stores its 600 s rings this way): the loaded arrays are
    the run's own samples 0, k, 2k, … and the last (k = ceil(n / 23)), distance and energy thinned alike, and the
    saved fleet metrics are the run's own (from every sample), not recomputed from the thinned copy."""
    import math

    from aev_ocp.ring.outputs import save_ring_output
    from aev_ocp.ring.run import stern

    direct = stern(["followerstopper"], t_end_s=17.5, seed=5)
    save_ring_output(tmp_path, direct, {"experiment": "stern"}, max_samples=23)
    out = aev_ocp.load(tmp_path)
    for got, want in zip(out.runs, direct):
        n = want.result.sim.t.shape[0]
        k = math.ceil(n / 23)
        idx = np.arange(0, n, k)
        idx = idx if idx[-1] == n - 1 else np.append(idx, n - 1)
        assert n > 23 and got.result.sim.t.shape[0] == idx.size < n
        for name in SIM_ARRAYS:
            want_a = np.asarray(getattr(want.result.sim, name))
            want_a = want_a[idx] if want_a.ndim and want_a.shape[0] == n else want_a
            np.testing.assert_array_equal(getattr(got.result.sim, name), want_a, err_msg=name)
        np.testing.assert_array_equal(got.result.distance, np.asarray(want.result.distance)[idx])
        np.testing.assert_array_equal(got.result.energy_J, np.asarray(want.result.energy_J)[idx])
        assert got.fleet == json.loads(json.dumps(aev_ocp.results.to_jsonable(want.fleet)))


# ----------------------------------------------------------------------------- stability
def test_stability_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``aev-ocp stability --law ovfl`` at two speeds, 8 followers: the linear analyses rebuilt from the loaded
    document equal analyse() here, and the measured attenuations equal the saved tables."""
    from aev_ocp.models import make_law
    from aev_ocp.stability.linear import analyse

    argv = ["stability", "--law", "ovfl", "--speed-model", "1.3", "--speed-model", "1.7", "--amplitude-model", "0.07"]
    assert main([*argv, "--followers", "8", "--no-plots", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    out = aev_ocp.load(tmp_path)
    assert out.kind == "stability" and out.law == "ovfl"
    law = make_law("ovfl")
    lins = out.linear()
    assert [x.v_star for x in lins] == [1.3, 1.7]
    for got in lins:
        want = analyse(law, got.v_star)
        assert got.criterion == want.criterion and got.f_h == want.f_h and got.poles == want.poles
        np.testing.assert_array_equal(got.gain(np.array([0.3, 1.7])), want.gain(np.array([0.3, 1.7])))
    meas = out.measured()
    assert list(meas) == ["v* = 1.3", "v* = 1.7"]
    saved = json.loads((tmp_path / "stability.json").read_text())
    for (label, atts), entry in zip(meas.items(), saved["speeds"]):
        assert len(atts) == 1 and atts[0].amplitude == 0.07
        assert atts[0].ratio_peak == entry["measured"][0]["ratio_peak"]
        assert atts[0].peak == entry["measured"][0]["peak_model"]
    _figure(out)


def test_ring_stability_round_trips(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--ring 12`` and ``--ring 12 --aev``: the loaded eigenvalues equal a direct analysis."""
    from aev_ocp.models import make_law
    from aev_ocp.params import EVParams
    from aev_ocp.stability.ring import ring_stability

    a, b = tmp_path / "ring", tmp_path / "mixed"
    assert (
        main(["stability", "--law", "ovm", "--ring", "12", "--spacing-m", "13.5", "--linear-only", "--out", str(a)])
        == 0
    )
    argv = ["stability", "--law", "ovm", "--ring", "12", "--spacing-m", "13.5", "--linear-only", "--aev", "proposed"]
    assert main([*argv, "--aev-count", "2", "--out", str(b)]) == 0
    capsys.readouterr()
    ring = aev_ocp.load(a)
    assert ring.kind == "ring_stability" and ring.law == "ovm"
    want = ring_stability(make_law("ovm"), 12, 12 * 13.5, 5.0, EVParams())
    assert ring.document["growth_rate_per_s"] == want.growth_rate_per_s
    assert ring.eigenvalues_per_s() == [lam for mode in want.modes for lam in mode]
    mixed = aev_ocp.load(b / MANIFEST)
    assert mixed.kind == "mixed_ring_stability" and mixed.law == "ovm+proposed"
    doc = json.loads((b / "mixed_ring_stability.json").read_text())
    assert (
        mixed.eigenvalues_per_s() == doc["eigenvalues_per_s"]
        and mixed.document["aev_positions"] == doc["aev_positions"]
    )
    _figure(ring)
    _figure(mixed)


# ----------------------------------------------------------------------------- safety
def test_safety_suite_round_trip(tmp_path: Path) -> None:
    """Two cases × the IDM and OVFL: the loaded rows equal the run's, its trajectories bit for bit."""
    from aev_ocp.safety.cases import suite_cases
    from aev_ocp.safety.report import write_outputs
    from aev_ocp.safety.run import run_suite

    cases = [c for c in suite_cases(quick=True)][:2]
    res = run_suite(cases, ["idm", "ovfl"], actuators=["ideal"], workers=1)
    write_outputs(res, tmp_path, plots=False)
    out = aev_ocp.load(tmp_path)
    assert len(out.rows) == 4
    for got, want in zip(out.rows, res.rows):
        assert _same(vars(got), json.loads(json.dumps(aev_ocp.results.to_jsonable(vars(want)))))
        assert got.failed == want.failed
    assert out.cases == res.cases and out.settings["controllers"] == ["idm", "ovfl"]
    assert set(out.runs) == set(res.runs)
    for case, by in res.runs.items():
        assert set(out.runs[case]) == set(by)
        for key, r in by.items():
            for name in SIM_ARRAYS:
                np.testing.assert_array_equal(getattr(out.runs[case][key], name), getattr(r, name), err_msg=name)
    _figure(out)


# ----------------------------------------------------------------------------- SUMO
@pytest.mark.skipif(not __import__("aev_ocp.sumo").sumo.sumo_available(), reason="SUMO is not installed")
def test_sumo_fleet_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``aev-ocp sumo sumo_ring`` (8 s): aev_ocp.load gives the fleet (a SumoRun) whose totals equal fleet.json's;
    run=<vehicle> gives that vehicle's SimulationResult."""
    assert main(["sumo", "sumo_ring", "--t-end-s", "8", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    run = aev_ocp.load(tmp_path)
    saved = json.loads((tmp_path / "fleet.json").read_text())
    assert _same(json.loads(json.dumps(aev_ocp.results.to_jsonable(run.fleet_totals()))), saved["fleet"])
    assert run.events == saved["events"]
    vid = next(v for v, c in run.controlled.items() if c)
    one = aev_ocp.load(tmp_path, run=vid)
    np.testing.assert_array_equal(one.gap, run.vehicles[vid].gap)
    _figure(run)


# ----------------------------------------------------------------------------- damaged manifests
def _stability_folder(tmp_path: Path) -> Path:
    out = tmp_path / "s"
    assert (
        main(["stability", "--law", "ovm", "--ring", "6", "--spacing-m", "20", "--linear-only", "--out", str(out)]) == 0
    )
    return out


def test_unknown_kind_names_the_file_and_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = _stability_folder(tmp_path)
    capsys.readouterr()
    m = json.loads((out / MANIFEST).read_text())
    assert m["kind"] in KINDS
    m["kind"] = "ring_stabilty"
    (out / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LoadError, match=rf"{MANIFEST}: kind = 'ring_stabilty' is not one of"):
        aev_ocp.load(out)


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (lambda m: m.pop("document"), r"manifest.json: field 'document' = None"),
        (
            lambda m: m.update(document_sha256="0" * 64),
            r"ring_stability.json: its SHA-256 differs from field 'document_sha256'",
        ),
        (lambda m: m.update(document="gone.json"), r"gone.json: missing \(field 'document'"),
    ],
)
def test_damaged_document_field_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str], edit, says: str) -> None:
    out = _stability_folder(tmp_path)
    capsys.readouterr()
    m = json.loads((out / MANIFEST).read_text())
    edit(m)
    (out / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LoadError, match=says):
        aev_ocp.load(out)


def test_a_document_without_its_field_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A document whose SHA-256 was updated after a key was removed: the missing field is named."""
    import hashlib

    out = _stability_folder(tmp_path)
    capsys.readouterr()
    doc = json.loads((out / "ring_stability.json").read_text())
    del doc["modes"]
    data = json.dumps(doc).encode()
    (out / "ring_stability.json").write_bytes(data)
    m = json.loads((out / MANIFEST).read_text())
    m["document_sha256"] = hashlib.sha256(data).hexdigest()
    (out / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LoadError, match=r"ring_stability.json: field 'modes' is missing"):
        aev_ocp.load(out)
    with pytest.raises(LoadError, match="has no labelled runs"):
        aev_ocp.load(out, run="x")
