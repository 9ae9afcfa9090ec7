"""CPU time of the heavy per-measure stages, this tree against a git revision, interleaved.

On a shared machine wall times swing with the other jobs' load; this benchmark runs
the SMC and the posterior figures of one finished study (its own files) alternately
with this tree's code and with the code of git revision REV (each in a fresh
subprocess importing that tree's package), ``--repeat`` times, and prints each run's
process CPU time and wall time, and the medians. The stage outputs go to a scratch
folder; nothing of the study is changed.

Usage::

    python benchmarks/bench_stages_ab.py --before REV --results results/python64
        --study python64 [--repeat 2]

``--study`` names the layers as in ``bench_pipeline.py`` (default, python64, smoke).
Prints a table and a final one-line JSON summary. No assertions.
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
sys.path.insert(0, str(REPO / "benchmarks"))

CHILD = """
import json, sys, time
from pathlib import Path
sys.path.insert(0, {bench!r})
import bench_pipeline as bp
from bayescalib.stages import figures
stage, tree, results, study, out = sys.argv[1:6]
cfg = bp._study_config(Path(tree), study)
folder = Path(results) / cfg["measures"][0]
out = Path(out)
if stage == "smc":
    run = lambda: bp._stages().smc(folder / "surrogate.h5", cfg["smc"], cfg["parameters"],
                                   out / "particles.h5")
else:
    stems = {{k: out / k for k in ("joint", "particles", "marginals", "pairs", "parallel")}}
    run = lambda: figures.posterior_figures(folder / "particles.h5", folder / "posterior.json",
                                            cfg["parameters"], cfg["plots"], stems)
c0, w0 = time.process_time(), time.perf_counter()
run()
print(json.dumps({{"cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0}}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="git revision to compare with")
    ap.add_argument("--results", required=True, help="a finished study's results folder")
    ap.add_argument("--study", required=True, help="default, python64 or smoke")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--stages", default="smc,fig_posterior")
    a = ap.parse_args()
    from bench_pipeline import _copy_repo

    scratch = Path(tempfile.mkdtemp(prefix="bench_stages_ab_"))
    trees = {"this": REPO, "before": _copy_repo(a.before, scratch / "before")}
    rows: dict = {}
    for stage in a.stages.split(","):
        for rep in range(a.repeat):
            for mode, tree in trees.items():
                out = scratch / f"{stage}_{mode}_{rep}"
                out.mkdir()
                env = {**os.environ, "PYTHONPATH": str(tree / "src")}
                proc = subprocess.run(
                    [sys.executable, "-c", CHILD.format(bench=str(REPO / "benchmarks")),
                     stage, str(tree), str(Path(a.results).resolve()), a.study, str(out)],
                    check=True, env=env, capture_output=True, text=True)
                r = json.loads(proc.stdout.splitlines()[-1])
                rows.setdefault(stage, {}).setdefault(mode, []).append(r)
                print(f"{stage:<14} {mode:<7} run {rep}: cpu {r['cpu_s']:7.2f} s, "
                      f"wall {r['wall_s']:7.2f} s", flush=True)
    summary = {s: {m: {k: round(statistics.median(x[k] for x in v), 2)
                       for k in ("cpu_s", "wall_s")} for m, v in d.items()}
               for s, d in rows.items()}
    for s, d in summary.items():
        print(f"{s}: median cpu {d['this']['cpu_s']:.2f} s (this) vs "
              f"{d['before']['cpu_s']:.2f} s (before), ratio "
              f"{d['before']['cpu_s'] / d['this']['cpu_s']:.2f}")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
