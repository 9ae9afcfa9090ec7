"""Benchmark of the NGSolve FSI forward model (one thread).

Measures, per mesh preset (``paper``: ~65 interface nodes, ``coarse``: ~32):

* build time (mesh + compiled forms, once per model);
* cold solve (from rest, full inflow at once): median wall time and Newton iterations
  over ``--repeats`` solves at distinct parameters near the ground truth
  (E = 400 Pa, nu = 0.3, +-5 %);
* warm solve from a state *file* of the prior centre (E = 450 Pa, nu = -0.15), as a
  fresh worker process would do it (no factorization kept), at the same parameters;
* warm solve in a sequence (previous solution and its LU factorization kept in the
  model: chord steps only), at the same parameters;
* over a 64-point scrambled Sobol sample (seed fixed) of E in [100, 800] Pa,
  nu in [-0.8, 0.499]: the fraction of converged solves, with the solves warm-started
  from the prior-centre state file (failures fall back to the continuation from rest);
* peak resident memory (``resource.getrusage``).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fsi.py [--repeats 5] [--sobol 64]
        [--presets paper,coarse] [--sobol-preset paper]

Prints a human-readable table and a final one-line JSON summary. No assertions.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

PRIOR_CENTRE = {"material.E": 450.0, "material.nu": -0.15}


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _near_truth(n: int, seed: int = 1) -> list[dict[str, float]]:
    rng = np.random.default_rng(seed)
    return [
        {"material.E": 400.0 * (1 + 0.05 * rng.uniform(-1, 1)),
         "material.nu": 0.3 * (1 + 0.05 * rng.uniform(-1, 1))}
        for _ in range(n)
    ]


def bench_preset(preset: str, repeats: int, workdir: Path) -> dict:
    from bayescalib.models.fsi import FSIModel

    model = FSIModel({"mesh": {"preset": preset}})
    t0 = time.perf_counter()
    first = model.solve()
    t_first = time.perf_counter() - t0
    out: dict = {
        "preset": preset,
        "n_interface_nodes": first.stats["n_interface_nodes"],
        "ndof": first.stats["ndof"],
        "build_s": model.build_time,
        "first_solve_incl_build_s": t_first,
        "max_displacement_mm": first.max_displacement,
    }
    params = _near_truth(repeats)

    cold = [model.solve(p) for p in params]
    out["cold_median_s"] = statistics.median(r.wall_time for r in cold)
    out["cold_newton_median"] = statistics.median(r.newton_iterations for r in cold)
    out["cold_factorizations_median"] = statistics.median(r.stats["factorizations"] for r in cold)
    out["cold_phase_medians_s"] = {
        k: statistics.median(float(r.stats[k]) for r in cold)
        for k in ("t_assemble", "t_factor", "t_solve", "t_residual")
    }

    centre = model.solve(PRIOR_CENTRE)
    assert centre.ok, centre.reason
    state = workdir / f"centre_{preset}.npz"
    model.save_state(state)
    fresh = FSIModel({"mesh": {"preset": preset}, "solver": {"keep_factorization": False}})
    fresh.solve({"inflow.rate": 0.0})  # build outside the timing
    warm_file = [fresh.solve(p, warm_start=state) for p in params]
    out["warm_file_median_s"] = statistics.median(r.wall_time for r in warm_file)
    out["warm_file_newton_median"] = statistics.median(r.newton_iterations for r in warm_file)

    model.solve(params[0])
    seq = [model.solve(p, warm_start="last") for p in params[1:] + params[:1]]
    out["warm_seq_median_s"] = statistics.median(r.wall_time for r in seq)
    out["warm_seq_newton_median"] = statistics.median(r.newton_iterations for r in seq)
    out["warm_seq_factorizations_median"] = statistics.median(r.stats["factorizations"] for r in seq)
    ok = all(r.ok for r in cold + warm_file + seq)
    out["all_ok"] = ok
    out["speedup_cold_over_warm_file"] = out["cold_median_s"] / out["warm_file_median_s"]
    out["speedup_cold_over_warm_seq"] = out["cold_median_s"] / out["warm_seq_median_s"]
    out["peak_rss_mb"] = _peak_mb()
    return out


def bench_sobol(preset: str, n: int, workdir: Path, time_limit: float) -> dict:
    from scipy.stats import qmc

    from bayescalib.models.fsi import FSIModel

    sampler = qmc.Sobol(d=2, scramble=True, seed=20240611)
    u = sampler.random(n)
    pts = qmc.scale(u, [100.0, -0.8], [800.0, 0.499])
    model = FSIModel({"mesh": {"preset": preset}, "solver": {"keep_factorization": False}})
    centre = model.solve(PRIOR_CENTRE)
    state = workdir / f"centre_sobol_{preset}.npz"
    model.save_state(state)
    rows = []
    for E, nu in pts:
        r = model.solve({"material.E": float(E), "material.nu": float(nu)}, warm_start=state,
                        time_limit=time_limit)
        rows.append((float(E), float(nu), r.status, r.load_fraction, r.newton_iterations,
                     r.wall_time, r.reason))
    ok = [row for row in rows if row[2] == "ok"]
    failed = [row for row in rows if row[2] != "ok"]
    return {
        "preset": preset,
        "n": n,
        "converged_fraction": len(ok) / n,
        "median_s_ok": statistics.median(row[5] for row in ok) if ok else float("nan"),
        "median_newton_ok": statistics.median(row[4] for row in ok) if ok else float("nan"),
        "total_s": sum(row[5] for row in rows),
        "failed": [
            {"E": round(row[0], 1), "nu": round(row[1], 3), "load_fraction": row[3],
             "reason": row[6][:90]}
            for row in failed
        ],
        "centre_ok": centre.ok,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--presets", default="paper,coarse")
    ap.add_argument("--sobol", type=int, default=64, help="Sobol sample size (0: skip)")
    ap.add_argument("--sobol-preset", default="paper")
    ap.add_argument("--time-limit", type=float, default=60.0, help="per Sobol solve, s")
    args = ap.parse_args(argv)
    import ngsolve as ng

    ng.SetNumThreads(1)
    results = {"threads": 1, "load_average": os.getloadavg(), "presets": [], "sobol": None}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for preset in args.presets.split(","):
            r = bench_preset(preset.strip(), args.repeats, work)
            results["presets"].append(r)
            print(f"[{r['preset']}] {r['n_interface_nodes']} interface nodes, {r['ndof']} DOFs, "
                  f"build {r['build_s']:.2f} s, max displacement {r['max_displacement_mm']:.5f} mm")
            print(f"  cold (from rest)        median {r['cold_median_s']:.3f} s, "
                  f"{r['cold_newton_median']:.0f} Newton its, {r['cold_factorizations_median']:.0f} LU; "
                  f"phases {json.dumps({k: round(v, 3) for k, v in r['cold_phase_medians_s'].items()})}")
            print(f"  warm (state file)       median {r['warm_file_median_s']:.3f} s, "
                  f"{r['warm_file_newton_median']:.0f} Newton its  "
                  f"(cold/warm = {r['speedup_cold_over_warm_file']:.2f})")
            print(f"  warm (sequence, LU kept) median {r['warm_seq_median_s']:.3f} s, "
                  f"{r['warm_seq_newton_median']:.0f} Newton its, {r['warm_seq_factorizations_median']:.0f} LU  "
                  f"(cold/warm = {r['speedup_cold_over_warm_seq']:.2f})")
            print(f"  peak RSS {r['peak_rss_mb']:.0f} MB; all ok: {r['all_ok']}")
            sys.stdout.flush()
        if args.sobol > 0:
            s = bench_sobol(args.sobol_preset, args.sobol, work, args.time_limit)
            results["sobol"] = s
            print(f"[sobol {s['n']} points, {s['preset']}] converged {s['converged_fraction']:.3f}, "
                  f"median {s['median_s_ok']:.3f} s ({s['median_newton_ok']:.0f} its) per converged "
                  f"solve, total {s['total_s']:.1f} s")
            for f in s["failed"]:
                print(f"  failed: E={f['E']} nu={f['nu']} reached {f['load_fraction']:.3f}: {f['reason']}")
    results["peak_rss_mb"] = _peak_mb()
    print(json.dumps(results, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
