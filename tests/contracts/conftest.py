"""The contracts (layers, CLI error style, independent checks, the architecture) share the helpers of tests/."""

from __future__ import annotations

import sys
from pathlib import Path

TESTS = str(Path(__file__).resolve().parents[1])
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)  # cli_helpers, cell_oracle, ... (pytest puts only this folder on the path)
