"""The bases of every exception and warning aev_ocp raises on purpose.

Each exception class of the package derives from :class:`AevOcpError` and keeps the built-in base it always had
(``class ParameterError(AevOcpError, ValueError)``), so ``except aev_ocp.AevOcpError`` catches whatever the toolkit
refuses or fails at while ``except ValueError`` callers keep working. Each warning category derives from
:class:`AevOcpWarning` beside its built-in category. The one exception that is not an ``Exception`` is
:class:`aev_ocp.interrupts.Interrupted` (a ``KeyboardInterrupt``: Ctrl-C must pass ``except Exception``).
tests/contracts/test_errors.py lists every exception class of the package and checks its base.
"""

from __future__ import annotations


class AevOcpError(Exception):
    """Base of every aev_ocp exception (bad input, a refused file, a failed section, a time limit, ...)."""


class AevOcpWarning(Warning):
    """Base of every aev_ocp warning category."""
