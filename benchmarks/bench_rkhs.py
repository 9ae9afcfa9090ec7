"""Throughput of the RKHS surface-current norm (bayescalib.measures.currents).

Cases
-----
* 2D: a 66-segment model curve (the paper's interface resolution) against a
  2000-segment observed curve, cells as given (no resampling) -- and the same
  pair after the default resampling to sigma_W / 4 (what a study evaluates).
* 3D: two concentric spheres with 20480 triangles each (icosphere level 5),
  sigma_W = 0.05 mm on a unit sphere (edge ~0.035 mm), dense (every pair
  evaluated) and with the default kernel truncation at 11.9 sigma_W (exact to
  double precision).

Throughput is reported as kernel pair evaluations per second, counting the
pairs of the three terms of eq:surfcurrontriang as a naive double sum would,
``n1^2 + n1 n2 + n2^2`` (symmetry of the self terms and truncation make the
implementation evaluate fewer). Each figure is the median wall time of
``--repeats`` runs; CPU always, CUDA as well when torch sees a GPU.

Usage::

    python benchmarks/bench_rkhs.py [--repeats 3] [--skip-dense] [--threads 1]
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _interface_shapes import arc, icosphere

from bayescalib.measures.currents import current, rkhs_squared


def timed(fn, repeats):
    times, value = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, value


def report(label, n1, n2, med, times, value):
    pairs = n1 * n1 + n1 * n2 + n2 * n2
    d2 = value[0] - 2 * value[1] + value[2]
    print(
        f"{label:58s} n1={n1:6d} n2={n2:6d}  median {med:8.3f} s  "
        f"{pairs / med / 1e6:10.1f} Mpairs/s  (runs: {', '.join(f'{t:.2f}' for t in times)}; D={math.sqrt(max(d2, 0)):.6g})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-dense", action="store_true", help="skip the dense 3D runs")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads during the computation (default 1)")
    args = ap.parse_args()

    import torch

    th = args.threads
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    print(f"torch {torch.__version__}, CPU threads {th}, devices {devices}")

    # ---------------------------------------------------------------- 2D
    model = arc(0.4, 67)  # 66 segments
    obs = arc(0.41, 2001)  # 2000 segments
    c1, a1 = current(model, 0.005, math.inf)
    c2, a2 = current(obs, 0.005, math.inf)
    for backend in ("numpy", "torch"):
        med, ts, v = timed(lambda backend=backend: rkhs_squared(c1, a1, c2, a2, 0.005, backend=backend, device="cpu", threads=th), args.repeats)
        report(f"2D 66 vs 2000 segments, {backend} cpu float64", len(c1), len(c2), med, ts, v)
    r1, b1 = current(model, 0.005)
    r2, b2 = current(obs, 0.005)
    for dev in devices:
        med, ts, v = timed(lambda dev=dev: rkhs_squared(r1, b1, r2, b2, 0.005, backend="torch", device=dev, threads=th), args.repeats)
        report(f"2D resampled to sigma_W/4 (sigma_W=0.005), torch {dev}", len(r1), len(r2), med, ts, v)

    # ---------------------------------------------------------------- 3D
    s1, s2 = icosphere(1.0, 5), icosphere(1.02, 5)
    x, a = s1.centres, s1.current
    y, b = s2.centres, s2.current
    sw = 0.05
    for dev in devices:
        for dtype in ("float32", "float64"):
            med, ts, v = timed(
                lambda dev=dev, dtype=dtype: rkhs_squared(x, a, y, b, sw, backend="torch", device=dev, dtype=dtype, threads=th),
                args.repeats,
            )
            report(f"3D spheres, truncated 11.9 sigma_W, torch {dev} {dtype}", len(x), len(y), med, ts, v)
            if not args.skip_dense:
                med, ts, v = timed(
                    lambda dev=dev, dtype=dtype: rkhs_squared(x, a, y, b, sw, backend="torch", device=dev, dtype=dtype, truncate=None, threads=th),
                    args.repeats,
                )
                report(f"3D spheres, dense, torch {dev} {dtype}", len(x), len(y), med, ts, v)


if __name__ == "__main__":
    main()
