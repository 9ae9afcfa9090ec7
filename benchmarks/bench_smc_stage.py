"""The SMC stage's in-process cost, two source trees side by side (A/B).

Runs ``bayescalib.stages.smc.smc`` (the pipeline's SMC job: load the GP surrogate, run
adaptive-tempering SMC on its mean, write the particles) on one study's surrogate, with
the code of each tree in turn (a subprocess per run that imports the package from
``TREE/src``, one BLAS thread as the job servers run it), interleaved A, B, A, B, ...
so that both see the same load. Per tree: the median CPU time (user + system of the
process, imports excluded: the stage is timed after a warm-up call), the median wall
time, the tempering steps, the surrogate evaluations, and whether its particles,
weights and log-likelihoods are bitwise those of the first tree.

The surrogate: ``--results DIR`` a study's results folder (e.g. the python64 study of
``benchmarks/bench_pipeline.py --studies python64 --keep /tmp/bp``:
``/tmp/bp/python64_server/results/python64``), whose ``config.yaml`` settings are
rebuilt here as bench_pipeline builds them (``--study``). ``--results analytic``
instead runs ``run_smc`` with the study's SMC settings on a closed-form banana-shaped
log-likelihood over the python64 box (microseconds per batch): the time is then the
sampler's own bookkeeping (proposals, prior, acceptance, resampling), the part the
surrogate's threads do not share.

Usage::

    python benchmarks/bench_smc_stage.py --results DIR|analytic [--study python64]
        [--trees /work/main,/work/h_smc] [--repeats 3] [--threads 2]

Prints a table and a final one-line JSON summary. No assertions. On a shared machine
the CPU times are the figures to compare, the wall times grow with the load.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _child(tree: str, results: str, study: str, threads: int, out: str) -> None:
    """One timed SMC stage run (in the subprocess): JSON on stdout."""
    import resource
    import time

    import numpy as np

    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_pipeline import _stages, _study_config

    from bayescalib.inference.parameters import ParameterSpace
    from bayescalib.inference.posterior import read_particles_h5

    cfg = _study_config(Path(tree), study)
    measure = cfg["measures"][0]
    sur = Path(results) / measure / "surrogate.h5"

    def call() -> None:
        _stages().smc(sur, cfg["smc"], cfg["parameters"], out, threads=threads)

    if results == "analytic":
        from bayescalib.inference.posterior import write_particles_h5
        from bayescalib.inference.smc import smc_from_config

        space = ParameterSpace.from_config(cfg["parameters"])

        def banana(X: np.ndarray) -> np.ndarray:
            e = (X[:, 0] - 100.0) / 700.0
            n = (X[:, 1] + 0.8) / 1.25
            return (-0.5 * ((n - 0.25 - 0.8 * e**1.5) / 0.04) ** 2
                    - 0.5 * ((e - 0.4) / 0.2) ** 2)

        def call() -> None:  # the analytic case replaces the stage
            write_particles_h5(out, smc_from_config(banana, space, cfg["smc"]), space)

    call()  # warm-up: imports, first-call caches
    ru0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    call()
    ru1, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter() - t0
    res = read_particles_h5(out)
    print(json.dumps({"cpu_s": (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime),
                      "wall_s": wall, "n_steps": int(res.n_steps),
                      "n_evals": int(res.n_loglik_evals),
                      "digest": _digest(np, res)}))


def _digest(np, res) -> str:
    import hashlib

    h = hashlib.sha256()
    for a in (res.particles, res.weights, res.loglik):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", required=False)
    ap.add_argument("--study", default="python64")
    ap.add_argument("--trees", default=f"/work/main,{REPO}")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        tree, results, study, threads, out = a.child
        _child(tree, results, study, int(threads), out)
        return
    if not a.results:
        ap.error("--results is required")
    trees = [t for t in a.trees.split(",") if t]
    rows: dict[str, list[dict]] = {t: [] for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.repeats):
            for k, tree in enumerate(trees):
                env = {**os.environ, "PYTHONPATH": str(Path(tree) / "src"),
                       "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                       "MKL_NUM_THREADS": "1"}
                proc = subprocess.run(
                    [sys.executable, __file__, "--child", tree, a.results, a.study,
                     str(a.threads), str(Path(tmp) / f"p{k}_{r}.h5")],
                    env=env, check=True, capture_output=True, text=True)
                rows[tree].append(json.loads(proc.stdout.splitlines()[-1]))
    ref = trees[0]
    print(f"SMC stage on {a.results} ({a.study}), {a.threads} thread(s), {a.repeats} runs "
          f"per tree, load average {os.getloadavg()[0]:.2f} at the end")
    print(f"  {'tree':<28} {'CPU median':>11} {'wall median':>12} {'steps':>6} "
          f"{'evaluations':>12} {'bitwise = A':>12}")
    summary = {}
    for tree in trees:
        rr = rows[tree]
        cpu = statistics.median(x["cpu_s"] for x in rr)
        wall = statistics.median(x["wall_s"] for x in rr)
        same = all(x["digest"] == rows[ref][0]["digest"] for x in rr)
        summary[tree] = {"cpu_median_s": round(cpu, 3), "wall_median_s": round(wall, 3),
                         "cpu_s": [round(x["cpu_s"], 3) for x in rr],
                         "wall_s": [round(x["wall_s"], 3) for x in rr],
                         "n_steps": rr[0]["n_steps"], "n_evals": rr[0]["n_evals"],
                         "bitwise_equal_to_first": same}
        print(f"  {tree:<28} {cpu:>10.2f}s {wall:>11.2f}s {rr[0]['n_steps']:>6} "
              f"{rr[0]['n_evals']:>12} {same!s:>12}")
    for tree in trees[1:]:
        s, r0 = summary[tree], summary[ref]
        print(f"  ratio {tree} / {ref}: CPU {s['cpu_median_s'] / r0['cpu_median_s']:.2f}, "
              f"wall {s['wall_median_s'] / r0['wall_median_s']:.2f}")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
