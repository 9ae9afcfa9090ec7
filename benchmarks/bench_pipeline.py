"""Where a study's time goes: whole-run wall time against the physics, per stage.

Runs each study end to end with ``snakemake --cores 2`` in a scratch copy of the
repository, once per execution mode, side by side in one run of this script:

* ``server``: the default, per-point jobs (solve, discrepancy) handed to the run's
  warm job server (``bayescalib.execution.jobserver``);
* ``fresh``: every job in a fresh interpreter (``BAYESCALIB_JOBSERVER=off``): the
  same code, paying the imports per job;
* ``before``: with ``--before REV``, the repository at git revision REV (e.g. the
  commit before the job server), run the same way.

Studies: ``default`` (config/config.yaml: FSI, active design), ``python64`` (the
analytic stand-in model as a ``python`` forward model, a fixed design of 64 points,
no fields figure: its physics costs about a millisecond a point, so its run time is
nearly all overhead) and ``smoke`` (config/smoke.yaml: the default study on the
coarse mesh, active design of at most 40 solves).

Figures per study and mode: wall time of the whole run; the physics summed over the
run (solves: each run record's own ``wall_time``; discrepancies: every point's
discrepancy recomputed in this process after a warm-up, i.e. the in-process cost);
per stage (each figure family its own row, ``fig_posterior`` etc.): the median job
wall time from the rules' benchmark files (since the job document: the wall time of
the process that worked, written by ``scripts/job.py``; before it, Snakemake's, of the
client; the ``script:`` rules', Snakemake's), the median wall time of the job inside
its job server (fork to exit) and its median CPU time (the servers' job ledger,
``logs/jobserver_jobs.tsv``), the median in-process work, the ratio of job wall to work
and the overhead per job (median job wall minus median in-process work). The whole
run's CPU time (Snakemake, the servers and every job) is given beside its wall time:
on a shared machine wall times grow with the load, CPU times much less, so the CPU
figures say what the run costs where the wall times cannot.
In-process work of the per-round stages (gather, train_surrogate, smc, acquire; and
marginalize): the stage function of the mode's own code rerun, warm, in a subprocess,
on the run's own files for up to three rounds (first, middle, last) and the final
measure (which, after an active design, reuses the last round's surrogate and
particles as the workflow does, where the mode's code can). With two or more modes, a
last table sets each mode's figures beside the first mode's (ratios).

Usage::

    python benchmarks/bench_pipeline.py [--studies default,python64,smoke]
        [--modes server,fresh] [--before REV] [--keep DIR]

Prints a table per study and a final one-line JSON summary. No assertions. Run it on
a quiet machine: the figures are wall times.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]

PYTHON64 = {
    "study": "python64",
    "forward_model": {"type": "python",
                      "python": {"function": "bayescalib.models.analytic:interface"}},
    "parameters": [
        {"name": "E", "unit": "Pa", "target": "E", "bounds": [100.0, 800.0],
         "prior": {"type": "uniform", "lo": 100.0, "hi": 800.0}, "ground_truth": 400.0},
        {"name": "nu", "unit": "-", "target": "nu", "bounds": [-0.8, 0.45],
         "prior": {"type": "uniform", "lo": -0.8, "hi": 0.45}, "ground_truth": 0.3}],
    "likelihood": {"sigma_n": 0.002},
    "design": {"strategy": "fixed", "n_train": 64, "seed": 1},
    "plots": {"fields": False, "formats": ["png"]},
}


def _copy_repo(rev: str | None, dest: Path) -> Path:
    """The working tree (rev None) or a git revision, without results."""
    if rev is None:
        ignore = shutil.ignore_patterns(".git", ".venv", "results", ".snakemake", "__pycache__",
                                        "*.egg-info")
        shutil.copytree(REPO, dest, ignore=ignore, symlinks=True)
    else:
        dest.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(REPO), "archive", rev], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def _run_study(tree: Path, study: str, env_extra: dict[str, str]) -> dict:
    args = []
    if study == "python64":
        (tree / "config" / "python64.yaml").write_text(yaml.safe_dump(PYTHON64))
        args = ["--configfile", "config/python64.yaml"]
    elif study == "smoke":
        args = ["--configfile", "config/smoke.yaml"]
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), **env_extra}
    t0, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", *args],
                          check=False, cwd=tree, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f"{study} failed in {tree}:\n{proc.stderr[-3000:]}")
    name = _study_config(tree, study)["study"]
    return {"wall_s": wall, "cpu_s": cpu, "root": tree / "results" / name}


def _children_cpu() -> float:
    """User + system time of this process's waited-for descendants: for a Snakemake run,
    Snakemake itself, its job servers (which wait for their jobs) and the jobs it ran."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


#: job-server stage names as the benchmark files name them (figures: fig_<family>)
_LEDGER_STAGE = {"predictive_solve": "predictive"}


def _ledger(root: Path) -> dict[str, dict[str, list[float]]]:
    """Per stage, the wall (fork to exit) and CPU times of the jobs the run's job
    servers ran (``logs/jobserver_jobs.tsv``; empty for a run without servers)."""
    path = root / "logs" / "jobserver_jobs.tsv"
    out: dict[str, dict[str, list[float]]] = {}
    if not path.exists():
        return out
    lines = path.read_text().splitlines()
    cols = lines[0].split("\t") if lines else []
    for line in lines[1:]:
        row = dict(zip(cols, line.split("\t")))
        stage = _LEDGER_STAGE.get(row["stage"], row["stage"])
        entry = out.setdefault(stage, {"wall": [], "cpu": []})
        entry["wall"].append(float(row["wall_s"]))
        entry["cpu"].append(float(row["cpu_s"]))
    return out


def _job_walls(root: Path) -> dict[str, list[float]]:
    """Median-able job wall times per stage from Snakemake's benchmark files."""
    out: dict[str, list[float]] = {}
    for tsv in (root / "benchmarks").rglob("*.tsv"):
        parts = tsv.relative_to(root / "benchmarks").parts
        stage = parts[0].removesuffix(".tsv")
        if stage == "figures":  # one row per figure family: fig_posterior, fig_rounds, ...
            stage = "fig_" + parts[-1].removesuffix(".tsv")
        lines = tsv.read_text().splitlines()
        if len(lines) >= 2:
            out.setdefault(stage, []).append(float(lines[1].split("\t")[0]))
    return out


def _physics(root: Path, study_cfg: dict) -> dict[str, list[float]]:
    """In-process cost per point: solve (its record's wall time), discrepancy (recomputed
    here, warm)."""
    from bayescalib.io.runrecord import read_run
    from bayescalib.stages.discrepancy import discrepancy

    runs = sorted(p for p in (root / "runs").glob("[0-9]*.h5"))
    solve = [read_run(p).wall_time for p in runs]
    disc = []
    obs = root / "observations" / "observations.h5"
    with tempfile.TemporaryDirectory() as tmp:
        for k, p in enumerate([runs[0], *runs]):  # the first call warms up
            t0 = time.perf_counter()
            name = study_cfg["measures"][0]
            discrepancy(p, obs, name, study_cfg["measure"][name], study_cfg["likelihood"],
                        Path(tmp) / f"{k}.json")
            if k:
                disc.append(time.perf_counter() - t0)
    return {"solve": solve, "discrepancy": disc}


def _study_config(tree: Path, study: str) -> dict:
    from bayescalib.config import load_yaml, merge_layers
    from bayescalib.study import Study

    layers = [load_yaml(tree / "config" / "config.yaml")]
    if study == "python64":
        layers.append(PYTHON64)
    elif study == "smoke":
        layers.append(load_yaml(tree / "config" / "smoke.yaml"))
    return Study(merge_layers(layers)).config


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _stages():
    """The stage functions of the tree this process imports, by name: each from the module
    of its rule (``bayescalib.stages.<module>``), or, in a tree from before the stages were
    split into those modules (a ``before`` mode's), from ``bayescalib.stages`` itself."""
    import importlib
    from types import SimpleNamespace

    where = {"read_json": "files", "gather": "gather", "train_surrogate": "surrogate",
             "smc": "smc", "acquire": "acquire", "marginalize": "marginalize"}
    try:
        return SimpleNamespace(**{name: getattr(importlib.import_module(
            f"bayescalib.stages.{module}"), name) for name, module in where.items()})
    except ModuleNotFoundError:
        package = importlib.import_module("bayescalib.stages")
        return SimpleNamespace(**{name: getattr(package, name) for name in where})


def _takes_reuse(stages) -> bool:
    import inspect

    return "reuse" in inspect.signature(stages.train_surrogate).parameters


def _round_stages_of(tree: Path, root: Path, study: str) -> dict[str, list[float]]:
    """:func:`_round_stages` run by the tree's own code: a subprocess that imports the
    package from ``tree/src`` (so a ``before`` mode's in-process work is its own), with
    one BLAS thread, as the job servers run their jobs (a multithreaded BLAS on a loaded
    2-core machine made the same GP fit 10-30x slower)."""
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--round-stages",
                           str(tree), str(root), study], check=True, env=env,
                          capture_output=True, text=True)
    return json.loads(proc.stdout.splitlines()[-1])


def _round_stages(root: Path, cfg: dict) -> dict[str, list[float]]:
    """In-process cost of the per-round and per-measure stages, rerun here on the run's
    files (into a scratch folder; warm: the imports are paid by a first call)."""
    stages = _stages()
    out: dict[str, list[float]] = {}
    m = cfg["measures"][0]
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        active = sorted((root / "active").glob("[0-9]*"), key=lambda p: int(p.name))
        rounds = sorted({0, len(active) // 2, len(active) - 1}) if active else []
        jobs = [(root / "active" / str(r), r) for r in rounds] + [(root / m, None)]
        first = True
        last = root / "active" / str(len(active) - 1) if active else None
        for folder, r in jobs:
            n = (len(list((root / "runs").glob("[0-9]*.h5"))) if r is None else
                 int(stages.read_json(folder / "acquire.json")["n_solves"]))
            runs = [root / "runs" / f"{i}.h5" for i in range(n)]
            disc = [root / "discrepancy" / m / f"{i}.json" for i in range(n)]
            names = [p["name"] for p in cfg["parameters"]]
            targets = [p["target"] for p in cfg["parameters"]]
            # the workflow passes the last round's files (where the tree's code can reuse)
            final = r is None and last is not None and _takes_reuse(stages)
            reuse_train = {"reuse": [last / "training.h5", last / "surrogate.h5"]} if final else {}
            reuse_smc = {"reuse": [last / "surrogate.h5", last / "particles.h5"]} if final else {}
            calls = {
                "gather": partial(stages.gather, runs, disc, names, targets, None,
                                  t / "training.h5"),
                "train_surrogate": partial(stages.train_surrogate, folder / "training.h5",
                                           cfg["surrogate"], cfg["parameters"],
                                           t / "surrogate.h5", **reuse_train),
                "smc": partial(stages.smc, folder / "surrogate.h5", cfg["smc"],
                               cfg["parameters"], t / "particles.h5", **reuse_smc),
            }
            if r is not None:
                prev = root / "active" / str(r - 1) / "acquire.json" if r > 0 else None
                import inspect

                # the tree's acquire takes the posterior_check section since the check
                # rounds (older trees: not)
                check = ([cfg["posterior_check"]] if "check" in
                         inspect.signature(stages.acquire).parameters else [])
                calls["acquire"] = partial(
                    stages.acquire, r, folder / "training.h5", folder / "surrogate.h5",
                    folder / "particles.h5", prev, cfg["design"]["active"], *check,
                    cfg["parameters"], t / "acquire.json")
            else:
                calls["marginalize"] = partial(
                    stages.marginalize, folder / "particles.h5", folder / "surrogate.h5",
                    cfg["posterior"], cfg["parameters"], cfg["smc"]["seed"],
                    t / "posterior.json", t / "posterior.nc")
            if first:  # imports (GPy, ArviZ, ...) paid once, outside the figures
                for fn in calls.values():
                    fn()
                first = False
            for stage, fn in calls.items():
                out.setdefault(stage, []).append(_timed(fn))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--studies", default="default,python64,smoke")
    ap.add_argument("--modes", default="server,fresh")
    ap.add_argument("--before", default=None, help="git revision to run as mode 'before'")
    ap.add_argument("--keep", default=None, help="keep the scratch trees in this folder")
    ap.add_argument("--round-stages", nargs=3, metavar=("TREE", "ROOT", "STUDY"),
                    help=argparse.SUPPRESS)  # internal: see _round_stages_of
    a = ap.parse_args()
    if a.round_stages:
        tree, root, study = a.round_stages
        print(json.dumps(_round_stages(Path(root), _study_config(Path(tree), study))))
        return
    modes = [m for m in a.modes.split(",") if m] + (["before"] if a.before else [])
    base = Path(a.keep or tempfile.mkdtemp(prefix="bench_pipeline_"))
    base.mkdir(parents=True, exist_ok=True)
    summary: dict = {}
    for study in a.studies.split(","):
        summary[study] = {}
        for mode in modes:
            tree = _copy_repo(a.before if mode == "before" else None, base / f"{study}_{mode}")
            env = {"BAYESCALIB_JOBSERVER": "off"} if mode == "fresh" else {}
            res = _run_study(tree, study, env)
            cfg = _study_config(tree, study)
            walls = _job_walls(res["root"])
            ledger = _ledger(res["root"])
            phys = _physics(res["root"], cfg)
            phys.update(_round_stages_of(tree, res["root"], study))
            row = {"wall_s": round(res["wall_s"], 1), "cpu_s": round(res["cpu_s"], 1),
                   "physics_s": round(sum(phys["solve"]) + sum(phys["discrepancy"]), 1),
                   "stages": {}}
            for stage, w in sorted(walls.items()):
                entry = {"jobs": len(w), "job_median_s": round(statistics.median(w), 3)}
                if ledger.get(stage):
                    entry.update(
                        server_wall_median_s=round(statistics.median(ledger[stage]["wall"]), 3),
                        cpu_median_s=round(statistics.median(ledger[stage]["cpu"]), 3))
                if phys.get(stage):
                    work = statistics.median(phys[stage])
                    entry.update(work_median_s=round(work, 3),
                                 ratio=round(statistics.median(w) / work, 2),
                                 overhead_s=round(statistics.median(w) - work, 3))
                row["stages"][stage] = entry
            summary[study][mode] = row
            print(f"\n{study} / {mode}: whole run {row['wall_s']:.1f} s wall, "
                  f"{row['cpu_s']:.1f} s CPU (Snakemake, servers and jobs), physics "
                  f"{row['physics_s']:.1f} s (solves + discrepancies, in-process)")
            print(f"  {'stage':<16} {'jobs':>5} {'job median':>11} {'in server':>10} "
                  f"{'job CPU':>8} {'in-process':>11} {'ratio':>6} {'overhead':>9}")
            for stage, e in row["stages"].items():
                srv = (f"{e['server_wall_median_s']:>9.3f}s {e['cpu_median_s']:>7.3f}s"
                       if "cpu_median_s" in e else f"{'-':>10} {'-':>8}")
                extra = (f"{e['work_median_s']:>10.3f}s {e['ratio']:>6.2f} "
                         f"{e['overhead_s']:>8.3f}s") if "ratio" in e else ""
                print(f"  {stage:<16} {e['jobs']:>5} {e['job_median_s']:>10.3f}s {srv} {extra}")
            if not a.keep:
                shutil.rmtree(tree, ignore_errors=True)
        _compare(study, summary[study], modes)
    print("\n" + json.dumps(summary))


def _compare(study: str, rows: dict, modes: list[str]) -> None:
    """Each mode's figures beside the first mode's: value and ratio (mode / first)."""
    if len(modes) < 2:
        return
    ref = rows[modes[0]]
    print(f"\n{study}: side by side (ratio = mode / {modes[0]})")
    for mode in modes[1:]:
        row = rows[mode]
        print(f"  whole run: {ref['wall_s']:.1f} s ({modes[0]}) vs {row['wall_s']:.1f} s "
              f"({mode}), ratio {row['wall_s'] / ref['wall_s']:.2f}; CPU {ref['cpu_s']:.1f} s "
              f"vs {row['cpu_s']:.1f} s, ratio {row['cpu_s'] / max(ref['cpu_s'], 1e-9):.2f}")
        print(f"  {'stage':<16} {modes[0] + ' job':>12} {mode + ' job':>12} {'ratio':>6} "
              f"{modes[0] + ' overhead':>17} {mode + ' overhead':>17}")
        for stage in sorted(set(ref["stages"]) & set(row["stages"])):
            a, b = ref["stages"][stage], row["stages"][stage]
            oa = f"{a['overhead_s']:.3f}s" if "overhead_s" in a else "-"
            ob = f"{b['overhead_s']:.3f}s" if "overhead_s" in b else "-"
            print(f"  {stage:<16} {a['job_median_s']:>11.3f}s {b['job_median_s']:>11.3f}s "
                  f"{b['job_median_s'] / max(a['job_median_s'], 1e-9):>6.2f} {oa:>17} {ob:>17}")


if __name__ == "__main__":
    main()
