"""An independent model of the 2-RC cell for tests: its equations written out for SciPy's ``solve_ivp``, with the
delivered energy E and the heat Q as two extra states, under a current held over each interval."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from scipy.integrate import solve_ivp

from aev_ocp.models.battery import ocv_function
from aev_ocp.params import CellParams

CELL = CellParams()
OCV = ocv_function()


def cell_rhs(I: float) -> Callable[[float, Sequence[float]], list[float]]:
    """d/dt (V1, V2, S, E, Q) [V, V, 1, J, J] of the default cell at a held current I [A]."""

    def f(_t: float, y: Sequence[float]) -> list[float]:
        V1, V2, S = y[:3]
        VT = float(OCV(S)) - V1 - V2 - CELL.R_s_ohm * I
        return [
            -V1 / CELL.tau1_s + I / CELL.C1_F,
            -V2 / CELL.tau2_s + I / CELL.C2_F,
            -I / (3600 * CELL.capacity_Ah),
            I * VT,
            I * (V1 + V2) + CELL.R_s_ohm * I**2,
        ]

    return f


def resim_cell(t: np.ndarray, I: np.ndarray, y0: Sequence[float], rtol: float, atol: float) -> np.ndarray:
    """(V1, V2, S, E, Q) at t[-1] from y0 at t[0], with I[k] [A] held over [t[k], t[k+1]] [s]."""
    y = np.asarray(y0, float)
    for k in range(I.size):
        y = solve_ivp(cell_rhs(I[k]), (t[k], t[k + 1]), y, rtol=rtol, atol=atol).y[:, -1]
    return y
