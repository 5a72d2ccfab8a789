"""CasADi Functions called from NumPy on bound buffers: the same numbers as ``fn(...)``, without the conversion of
every argument and result to and from DM that costs ~20 µs per call (most of a small Function's time; a closed loop,
a root search or a per-step battery update calls one tens of thousands of times).

:class:`BufferedCall` binds NumPy buffers to a Function once (CasADi's ``Function.buffer``); :class:`ColumnCall`
evaluates a Function of column-vector inputs over n columns at once, as ``fn(*matrices)`` with n columns does
(CasADi's repeated evaluation), on ``fn.map(n)``; :func:`column_call` keeps one per Function in this process.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from .params import remember


class BufferedCall:
    """``fn`` evaluated on numpy buffers bound once (CasADi's ``Function.buffer``): the same evaluation as
    ``fn(...)``, without converting every argument and result to and from DM on each call (a closed loop calls the
    plant's integrator and its output map once or twice per sample). ``args[i]`` / ``res[i]`` hold input / output
    i's nonzeros, column-major; calling returns False when the evaluation failed (then call ``fn`` itself, which
    raises the Function's own error)."""

    def __init__(self, fn: ca.Function) -> None:
        self.fn = fn
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._fb, self._eval = fn.buffer()
        # (the type stub asks for a size in bytes too; the binding takes it from the buffer itself)
        for i, a in enumerate(self.args):
            if a.size:
                self._fb.set_arg(i, a.data)  # type: ignore[call-arg]
        for i, r in enumerate(self.res):
            if r.size:
                self._fb.set_res(i, r.data)  # type: ignore[call-arg]

    def __call__(self) -> bool:
        try:
            self._eval()
        except RuntimeError:
            return False
        return int(self._fb.ret()) == 0


class ColumnCall:
    """``fn`` (dense column-vector inputs and outputs) over n columns from NumPy: ``call(*args)`` returns each output
    as a (rows, n) array, equal to ``fn(*args)`` with every argument given as a (rows, n) matrix. An argument is a
    (rows, n) array, n values of a one-row input (any shape), or one column (rows values, a scalar for one row) that
    every column shares. ``fn.map(n)`` on bound buffers is built once per n (the last ``sizes_kept`` kept)."""

    def __init__(self, fn: ca.Function, sizes_kept: int = 8) -> None:
        for kind, n_io, sp in (("input", fn.n_in(), fn.sparsity_in), ("output", fn.n_out(), fn.sparsity_out)):
            for i in range(n_io):
                if not (sp(i).is_dense() and sp(i).size2() == 1):
                    raise ValueError(
                        f"ColumnCall: {fn.name()}'s {kind} {i} is {sp(i).size1()}x{sp(i).size2()}"
                        f"{'' if sp(i).is_dense() else ' sparse'}: must be a dense column"
                    )
        self.fn = fn
        self.rows_in = [fn.size1_in(i) for i in range(fn.n_in())]
        self.rows_out = [fn.size1_out(i) for i in range(fn.n_out())]
        self.sizes_kept = int(sizes_kept)
        self._maps: dict[int, BufferedCall] = {}
        self._scalars = all(r == 1 for r in self.rows_in)  # every input one row: :meth:`scalar`'s fast path

    def _columns(self, args: tuple[Any, ...]) -> int:
        """The column count n the arguments ask for (1 when every one is a single column)."""
        n = 1
        for x, r in zip(args, self.rows_in):
            size = np.size(x)
            if size != r:
                cols = size // r if r and size % r == 0 else -1
                if cols < 1 or (n != 1 and cols != n):
                    raise ValueError(
                        f"ColumnCall: {self.fn.name()}: an argument of {size} values for an input of {r} rows "
                        f"(n = {n} columns so far)"
                    )
                n = cols
        return n

    def _buffers(self, n: int) -> BufferedCall:
        f = self._maps.get(n)
        if f is None:
            f = remember(self._maps, n, BufferedCall(self.fn.map(n)), self.sizes_kept)
        return f

    def scalar(self, *args: float) -> float:
        """The first output's first entry at one column of scalar arguments (every input one row): a law's
        acceleration at (h, v, v_l), the cheapest call (about 3 µs)."""
        f = self._maps.get(1)
        if f is None or not self._scalars or len(args) != len(self.rows_in):
            return float(self(*args)[0][0, 0])
        for buf, x in zip(f.args, args):
            buf[0] = x
        if not f():
            return float(self(*args)[0][0, 0])  # raises the Function's own error
        return float(f.res[0][0])

    def __call__(self, *args: Any) -> list[np.ndarray]:
        if len(args) != len(self.rows_in):
            raise TypeError(f"ColumnCall: {self.fn.name()} takes {len(self.rows_in)} arguments, got {len(args)}")
        n = self._columns(args)
        f = self._buffers(n)
        for i, (buf, x, r) in enumerate(zip(f.args, args, self.rows_in)):
            a = np.asarray(x, dtype=float)
            if a.shape == (r, n):
                buf[:] = a.ravel(order="F")
            elif a.size == r * n and (r == 1 or n == 1):
                buf[:] = a.ravel()
            elif a.size == r:  # one column shared by every column
                buf.reshape(n, r)[:] = a.ravel()
            else:
                raise ValueError(
                    f"ColumnCall: {self.fn.name()}: argument {i} has shape {a.shape}: must be ({r}, {n}), "
                    f"{r} values (one column for all) or n values of a one-row input"
                )
        if not f():  # the Function's own error (or, should it pass, its result)
            mats = [buf.reshape(n, r).T for buf, r in zip(f.args, self.rows_in)]
            return [np.asarray(y, dtype=float).reshape(r, n) for y, r in zip(f.fn(*mats), self.rows_out)]
        return [res.reshape(n, r).T.copy() for res, r in zip(f.res, self.rows_out)]


#: column_call's ColumnCall per Function in this process, by the Function's id (the entry holds the Function, so the
#: id names it as long as the entry lives); the last FUNCTIONS_KEPT kept
_CALLS: dict[int, tuple[ca.Function, ColumnCall]] = {}
FUNCTIONS_KEPT = 64


def column_call(fn: ca.Function) -> ColumnCall:
    """The :class:`ColumnCall` of ``fn``, built once per Function object in this process."""
    hit = _CALLS.get(id(fn))
    if hit is not None and hit[0] is fn:
        return hit[1]
    return remember(_CALLS, id(fn), (fn, ColumnCall(fn)), FUNCTIONS_KEPT)[1]
