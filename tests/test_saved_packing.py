"""Packed arrays in saved outputs (format version 2, issue 40): float64 trajectories stored as int64 differences in
byte planes load back bit for bit, take fewer bytes than the plain arrays, and version 1 folders still load."""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import aev_ocp
from aev_ocp.models.carfollowing import OVFL, Proposed
from aev_ocp.models.leader import ConstantSpeed
from aev_ocp.saved import (
    ARRAYS,
    FORMAT_VERSION,
    MANIFEST,
    PACK_MIN_SIZE,
    SIM_ARRAYS,
    LoadError,
    pack_array,
    save_output,
    unpack_array,
)
from aev_ocp.simulate import simulate_platoon


@settings(max_examples=60, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        hnp.array_shapes(min_dims=1, max_dims=3, min_side=1, max_side=9),
        elements=st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True, width=64),
    )
)
def test_pack_unpack_is_bit_for_bit(a: np.ndarray) -> None:
    planes = pack_array(a)
    assert planes.dtype == np.uint8 and planes.shape == (8, a.size)
    assert unpack_array(planes, a.shape).tobytes() == a.tobytes()  # NaN payloads, -0.0, subnormals included


def test_unpack_refuses_planes_of_another_size() -> None:
    planes = pack_array(np.linspace(0.3, 7.1, 12).reshape(4, 3))
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        unpack_array(planes, (4, 4))


@pytest.fixture(scope="module")
def runs() -> dict[str, aev_ocp.results.SimulationResult]:
    return {
        law.name: simulate_platoon(ConstantSpeed(1.3), [law] * 3, [0.8, 2.1, 2.4], [1.7, 1.45, 1.5], 6.0, dt_out=0.01)
        for law in (Proposed(), OVFL())
    }


def test_saved_runs_are_packed_smaller_and_load_bit_for_bit(runs, tmp_path: Path) -> None:  # noqa: ANN001
    save_output(tmp_path, "simulate", runs)
    m = json.loads((tmp_path / MANIFEST).read_text())
    assert m["format_version"] == FORMAT_VERSION == 2 and m["packed_encoding"] == "int64-delta-byteplanes"
    n = runs["proposed"].t.size
    assert n >= PACK_MIN_SIZE and m["packed"]["proposed/gap"] == [n, 3] and m["packed"]["ovfl/t"] == [n]
    loaded = aev_ocp.load_all(tmp_path)
    for label, r in runs.items():
        for name in SIM_ARRAYS:
            assert getattr(loaded[label], name).tobytes() == np.asarray(getattr(r, name)).tobytes(), (label, name)
    with np.load(tmp_path / ARRAYS) as z:  # the arrays as the file holds them: plain floats would take more
        plain = {k: unpack_array(z[k], tuple(m["packed"][k])) if k in m["packed"] else z[k] for k in z.files}
    buf = io.BytesIO()
    np.savez_compressed(buf, **plain)
    assert (tmp_path / ARRAYS).stat().st_size < 0.8 * len(buf.getvalue())


def test_a_version_1_folder_still_loads(runs, tmp_path: Path) -> None:  # noqa: ANN001
    save_output(tmp_path, "simulate", runs)
    m = json.loads((tmp_path / MANIFEST).read_text())
    with np.load(tmp_path / ARRAYS) as z:
        plain = {k: unpack_array(z[k], tuple(m["packed"][k])) if k in m["packed"] else z[k] for k in z.files}
    buf = io.BytesIO()
    np.savez_compressed(buf, **plain)  # version 1 wrote every array as is
    (tmp_path / ARRAYS).write_bytes(buf.getvalue())
    for key in ("packed", "packed_encoding"):
        del m[key]
    m.update(format_version=1, arrays_sha256=hashlib.sha256(buf.getvalue()).hexdigest())
    (tmp_path / MANIFEST).write_text(json.dumps(m))
    r = aev_ocp.load(tmp_path, "ovfl")
    np.testing.assert_array_equal(r.speed, runs["ovfl"].speed)
    np.testing.assert_array_equal(r.S, runs["ovfl"].S)


@pytest.mark.parametrize(
    ("field", "value", "word"),
    [("packed_encoding", "zstd", "packed_encoding"), ("packed", {"proposed/gap": [7, 3]}, "proposed/gap")],
)
def test_a_damaged_packing_record_is_a_load_error(runs, tmp_path: Path, field: str, value: object, word: str) -> None:  # noqa: ANN001
    save_output(tmp_path, "simulate", runs)
    m = json.loads((tmp_path / MANIFEST).read_text())
    m[field] = {**m[field], **value} if isinstance(value, dict) else value
    (tmp_path / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(LoadError, match=word):
        aev_ocp.load(tmp_path)
