"""loop.History (issue 40): the closed loops' measured times and speeds, read every step as an array without copying
the whole history (np.asarray of a growing list made a long run quadratic)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aev_ocp.loop import History


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(allow_nan=False, width=64), max_size=300), st.integers(1, 7))
def test_every_view_equals_the_list_it_replaces(values: list[float], capacity: int) -> None:
    """Each view is bit for bit np.asarray of the list so far, and a view taken earlier never changes (growth past
    the capacity included: 300 values from a capacity of 1 double the buffer 9 times)."""
    h, seen = History(capacity), []
    for k, x in enumerate(values):
        h.append(x)
        seen.append(h.view())
        assert len(h) == k + 1
    for k, v in enumerate(seen):
        ref = np.asarray(values[: k + 1])
        assert v.dtype == ref.dtype and np.array_equal(v, ref) and v.tobytes() == ref.tobytes()


def test_a_view_is_read_only() -> None:
    h = History(2)
    for x in (0.25, 1.5, -3.75):
        h.append(x)
    v = h.view()
    with pytest.raises(ValueError):
        v[0] = 9.0
    assert v.tolist() == [0.25, 1.5, -3.75]
