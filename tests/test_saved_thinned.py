"""Thinned trajectories (issue 40: reproduce's output under 60 MB): a long run saved with ``max_samples`` keeps every
k-th sample and the last, bit for bit; its manifest says how many of how many, and its saved metrics are those of
the whole run. A run at or under the limit is stored whole."""

from __future__ import annotations

import json

import numpy as np
import pytest

import aev_ocp
from aev_ocp.saved import MANIFEST, SIM_ARRAYS, save_output, stored_samples
from aev_ocp.scenarios import find_scenario, load_scenario


@pytest.mark.parametrize(
    ("n", "m", "want"),
    [
        (10, None, None),
        (10, 10, None),  # on the limit: whole
        (11, 10, [0, 2, 4, 6, 8, 10]),  # just above: every 2nd, the last is on the grid
        (12, 10, [0, 2, 4, 6, 8, 10, 11]),  # the last appended
        (31101, 4000, None),  # checked below by its properties
    ],
)
def test_stored_samples(n, m, want) -> None:
    idx = stored_samples(n, m)
    if n == 31101:
        assert idx is not None and idx[0] == 0 and idx[-1] == n - 1 and idx.size <= m + 1
        assert set(np.diff(idx[:-1])) == {8} and idx.size == 3889
    elif want is None:
        assert idx is None
    else:
        assert idx.tolist() == want


def test_a_thinned_run_holds_every_kth_sample_bit_for_bit(tmp_path) -> None:
    sc = load_scenario(find_scenario("table1")).replace(t_end=7.3)
    runs = sc.run()
    n = len(next(iter(runs.values())).t)
    m = n // 5 + 3  # an uneven stride: the last sample is appended
    save_output(tmp_path, "simulate", runs, max_samples=m)
    manifest = json.loads((tmp_path / MANIFEST).read_text())
    keep = stored_samples(n, m)
    assert keep is not None and keep[-1] == n - 1
    for label, r in runs.items():
        rec = manifest["runs"][label]
        assert rec["stored_samples"] == keep.size < n == rec["samples"]
        back = aev_ocp.load(tmp_path, run=label)
        for name in SIM_ARRAYS:
            full = np.asarray(getattr(r, name))
            np.testing.assert_array_equal(getattr(back, name), full[keep] if full.ndim and full.shape[0] == n else full)
        # the saved metrics are the whole run's (a thinned run's recomputed jerk would differ)
        assert rec["metrics"] == json.loads(json.dumps(aev_ocp.results.to_jsonable(r.metrics())))
    save_output(tmp_path / "whole", "simulate", runs, max_samples=n)
    assert "stored_samples" not in json.loads((tmp_path / "whole" / MANIFEST).read_text())["runs"][label]
