"""Benchmark: the full search of the surrogate's discrete choices, serial against its
candidates fitted on forked processes (``fit_from_config(..., threads=k)``).

For each problem of ``bench_active.py`` (``--problems``), a Sobol design of ``--n`` points
(its log-likelihood values, the bound known) is searched ``--repeats`` times with each
``--threads`` value; the script prints the wall and CPU seconds (CPU: this process's and
its forked children's) per search, their medians, the speed-up against one thread, and
whether every search chose the same surrogate bit for bit (kernel, output, frame, inputs,
hyperparameters, Cholesky factor).

    python benchmarks/bench_search_threads.py --problems sloppy4d,hetero7d --n 100,200 \\
        --threads 1,2 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _key(gp) -> tuple:
    return (gp.kernel, gp.warped, gp.rotation is None, gp.log_offset is None,
            gp.variance, tuple(np.ravel(gp.lengthscale)), gp.nugget, gp.chol.tobytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", default="sloppy4d,hetero7d")
    ap.add_argument("--n", default="100,200", help="design size per problem (comma-separated)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="results/bench_search_threads")
    args = ap.parse_args()

    import bench_active as ba

    from bayescalib.inference.design import sobol_design
    from bayescalib.inference.gp.selection import fit_from_config, search_size, surrogate_settings

    cfg = surrogate_settings()
    problems = args.problems.split(",")
    sizes = [int(v) for v in args.n.split(",")]
    if len(sizes) == 1:
        sizes *= len(problems)
    threads = [int(v) for v in args.threads.split(",")]
    print(f"machine: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    print("| problem | n | candidates | threads | wall s (median) | CPU s (median) | "
          "speed-up (wall) | same surrogate |")
    print("|---|---|---|---|---|---|---|---|")
    for name, n in zip(problems, sizes, strict=True):
        prob = ba.make_problem(name, Path(args.out), False)
        X = sobol_design(prob.bounds, n, 0)
        y = prob.loglik(X)
        m = search_size(cfg, prob.bounds)
        times: dict[int, tuple[float, float]] = {}
        keys = set()
        for k in threads:
            walls, cpus = [], []
            for _ in range(args.repeats):
                t0, c0 = time.perf_counter(), _cpu()
                gp = fit_from_config(X, y, cfg, prob.bounds, bound=prob.B, threads=k)
                walls.append(time.perf_counter() - t0)
                cpus.append(_cpu() - c0)
                keys.add(_key(gp))
            times[k] = (statistics.median(walls), statistics.median(cpus))
        base = times[threads[0]][0]
        for k in threads:
            w, c = times[k]
            print(f"| {name} | {n} | {m} | {k} | {w:.2f} | {c:.2f} | {base / w:.2f} | "
                  f"{'yes' if len(keys) == 1 else 'NO'} |", flush=True)
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
