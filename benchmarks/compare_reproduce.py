"""Compare every JSON file of two ``aev-ocp reproduce`` output folders, number by number.

    python benchmarks/compare_reproduce.py BASELINE_DIR NEW_DIR [--rtol 1e-9] [--atol 1e-9]

Numbers must agree to |a - b| <= atol + rtol·|b|; strings, booleans, keys and list lengths exactly. Fields that
measure time or the machine (wall-clock, CPU and solve times in s or ms, provenance) are skipped: their
names are matched by :data:`TIMING` (a model time such as ``collision_time_s`` is compared). Prints one line per difference (file, key path, both values) and exits 1
if there is any, 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import Any, Iterator

#: Keys whose values are timings or describe the run's machine, not its results.
#: ``arrays_sha256`` (a saved output's manifest) hashes float arrays bit for bit: no tolerance applies to it.
TIMING = re.compile(
    r"^(provenance|git_commit|platform|timings_s|solve_time_s|solver_time_s|arrays_sha256)$|wall|cpu"
    r"|(^|_)ms($|_)"
)


def differences(a: Any, b: Any, path: str, rtol: float, atol: float) -> Iterator[str]:
    """'path: a != b' for every difference between two JSON values (b is the baseline)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if TIMING.search(str(k)):
                continue
            if k not in a or k not in b:
                yield f"{path}.{k}: only in {'new' if k in a else 'baseline'}"
                continue
            yield from differences(a[k], b[k], f"{path}.{k}", rtol, atol)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{path}: length {len(a)} != {len(b)}"
            return
        for i, (x, y) in enumerate(zip(a, b)):
            yield from differences(x, y, f"{path}[{i}]", rtol, atol)
    elif (
        isinstance(a, (int, float))
        and isinstance(b, (int, float))
        and not isinstance(a, bool)
        and not isinstance(b, bool)
    ):
        fa, fb = float(a), float(b)
        if not (fa == fb or (math.isfinite(fa) and math.isfinite(fb) and abs(fa - fb) <= atol + rtol * abs(fb))):
            yield f"{path}: {a!r} != {b!r}"
    elif a != b:
        yield f"{path}: {a!r} != {b!r}"


def compare(base: Path, new: Path, rtol: float = 1e-9, atol: float = 1e-9) -> list[str]:
    """Every difference between the JSON files under ``base`` and ``new`` (a file missing on either side too)."""
    files = sorted(
        {p.relative_to(base) for p in base.rglob("*.json")} | {p.relative_to(new) for p in new.rglob("*.json")}
    )
    out: list[str] = []
    for rel in files:
        if not (base / rel).is_file() or not (new / rel).is_file():
            out.append(f"{rel}: only in {'new' if (new / rel).is_file() else 'baseline'}")
            continue
        a = json.loads((new / rel).read_text(encoding="utf-8"))
        b = json.loads((base / rel).read_text(encoding="utf-8"))
        out += [f"{rel}{d}" for d in differences(a, b, "", rtol, atol)]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("baseline", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-9)
    ap.add_argument("--atol", type=float, default=1e-9)
    args = ap.parse_args(argv)
    diffs = compare(args.baseline, args.new, args.rtol, args.atol)
    n = len(list(args.baseline.rglob("*.json")))
    for d in diffs:
        print(d)
    print(f"{n} JSON files of {args.baseline} compared with {args.new}: {len(diffs)} difference(s)")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
