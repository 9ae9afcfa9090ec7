"""Compare two studies' summary.json, value for value, apart from what measures time.

Usage::

    python benchmarks/compare_summaries.py OLD/results/smoke/summary.json NEW/results/smoke/summary.json

Prints every path whose value differs (``timings_s`` and the ``time_s`` of SMC steps are
left out: they measure the machine, not the result) and exits 1 when any does. Used for
issue 37's proof that the one driver, the one solve path and the one launch path left the
studies' results bit for bit as they were.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

IGNORED = ("timings_s", "time_s")


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """The paths at which ``a`` and ``b`` differ (floats compared exactly)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k in IGNORED:
                continue
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'new' if k in b else 'old'}")
            else:
                out += differences(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items against {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {str(a)[:80]!s} -> {str(b)[:80]!s}"]


def main(argv: list[str]) -> int:
    old, new = (json.loads(Path(p).read_text()) for p in argv[1:3])
    diff = differences(old, new)
    print("\n".join(diff) if diff else "equal (apart from timings)")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
