"""Grid reference posterior of a study from real FSI forward solves.

What it computes
----------------
For a study configuration (by default the CI smoke study: ``config/config.yaml``
with ``config/smoke.yaml`` deep-merged over it, exactly as Snakemake layers a
``--configfile``), this script

1. builds :class:`bayescalib.study.Study` from the merged config and takes the
   forward-model, observations, measure and likelihood sections from it, so the
   reference uses the pipeline's own model settings;
2. makes the synthetic observation as the pipeline does: the ``ground_truth`` rule's
   solve (:func:`bayescalib.models.forward.solve_point` at ``study.ground_truth_point()``)
   and the ``observe`` rule's :func:`bayescalib.stages.observe.observe` into an
   ``observations.h5`` in a scratch folder;
3. with ``forward_model.warm_start: prior_centre``, solves the ``base_state`` rule's
   warm-start state (:func:`bayescalib.models.forward.solve_base_state` at the prior centre);
4. solves the forward model on a cell-centred ``n x n`` grid over the parameter box,
   in-process in one model object (mesh and compiled forms built once), each point
   through :func:`bayescalib.models.forward.solve_series` (what the ``solve`` rule's child
   process runs). Each point starts from the prior-centre base state as the pipeline's
   solves do (``--warm centre``, default) or from the previous point solved
   (``--warm previous``); the solver falls back to the continuation from rest when
   Newton fails from the warm start. Failed solves are the slow ones, so the grid is
   solved coarse to fine (lattices of stride ``--max-stride``, then halved down to 1,
   each in serpentine order): a cell whose enclosing coarser-lattice box has failed at
   all its corners is not solved but marked failed and ``inferred``
   (``--max-stride 1`` solves every cell);
5. writes each point's run record and computes its log-likelihood with
   :func:`bayescalib.stages.discrepancy.discrepancy`, the ``discrepancy`` rule's own function
   (a failed solve gives -inf);
6. if the posterior is narrow on that grid (a marginal sd spans fewer than
   ``--min-cells`` grid cells, or a conditional sd, the width across a ridge along a
   grid axis, fewer than ``--min-cond-cells``), solves a second, zoomed grid on the
   bounding box of the cells within ``--zoom-drop`` of the largest log-likelihood
   (plus one cell) and recommends it;
   when that box is most of the parameter box, no zoom helps: it warns that ``--n``
   should be larger instead;
7. optionally (``--check K``) re-solves K grid points exactly as the ``solve`` rule does
   (forked child, fresh model, warm start from the base-state file) and reports how far
   their log-likelihood is from the in-process value (solver-tolerance differences).

The ``.npz`` holds, per grid (``box``; ``zoom_``-prefixed for the zoomed one): the
axes ``E`` (nE,) and ``nu`` (nnu,) (cell centres), ``box`` (outer cell edges),
``loglik`` (nE, nnu) with -inf for failures, ``failed`` (nE, nnu), ``inferred``
(nE, nnu) (failed cells not solved, a subset of ``failed``), ``D`` (nE, nnu)
(the measure's distance), ``recommended`` (``"box"`` or ``"zoom"``: the grid to
compare against), and ``meta``: JSON with the config sections used, their hash, a hash
of the observation, solve counts, failures with reasons, moments and wall times.

With a uniform prior the reference posterior is proportional to ``exp(loglik)`` on
the grid. :func:`hellinger_to_reference` (from ``benchmarks/_reference.py``) evaluates
a surrogate's log posterior on the same grid and returns the Hellinger distance.

How to run
----------
From the repository root, single-threaded::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python benchmarks/fsi_reference.py \\
        [--n N] [--zoom auto|always|never] [--zoom-n N] [--warm centre|previous] \\
        [--max-stride S] [--check K] [--scratch DIR] \\
        [--out benchmarks/data/fsi_reference_smoke.npz]

Another study: ``--config config/config.yaml --overlay config/<study>.yaml`` (a
two-parameter study; ``--overlay ''`` for the default study alone). With
``--scratch DIR`` the run records and a checkpoint are kept there and an interrupted
run resumes where it stopped.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _reference import (
    grid_moments,
    grid_points,
    hellinger_to_reference,
    load_reference,
)

REPO = Path(__file__).resolve().parents[1]

__all__ = ["build_study", "check_against_rule", "grid_moments", "grid_points",
           "hellinger_to_reference", "load_reference", "main", "make_observation", "solve_grid"]


# --------------------------------------------------------------------------- config
def build_study(config: str | Path, overlay: str | Path | None):
    """The :class:`Study` of ``config`` with ``overlay`` deep-merged over it (as
    ``snakemake --configfile overlay`` does over the Snakefile's ``configfile``)."""
    from bayescalib.config import deep_merge, load_yaml
    from bayescalib.study import Study

    cfg = load_yaml(config)
    if overlay:
        cfg = deep_merge(cfg, load_yaml(overlay))
    return Study(cfg, where="config")


def _sections(study) -> dict[str, Any]:
    """The config sections the reference depends on (plain JSON values)."""
    c = study.config
    return {
        "study": study.name,
        "forward_model": study.forward_section(),
        "parameters": c["parameters"],
        "observations": c["observations"],
        "measure_name": study.primary_measure,
        "measure": c["measure"],
        "likelihood": c["likelihood"],
        "ground_truth_point": study.ground_truth_point(),
        "prior_centre": study.prior_centre(),
    }


def _hash(obj: Any) -> str:
    from bayescalib.config import canonical_json

    return hashlib.sha256(canonical_json(obj).encode()).hexdigest()


def _observation_hash(obs_path: Path) -> str:
    """sha256 of the observed interfaces' coordinates (not of the HDF5 file's bytes)."""
    from bayescalib.io.observation_store import read_observations

    obs = read_observations(obs_path)
    h = hashlib.sha256()
    for snap in obs.snapshots:
        h.update(np.ascontiguousarray(np.asarray(snap.points, dtype=np.float64)).tobytes())
    return h.hexdigest()


def _git_commit() -> str | None:
    import subprocess

    try:
        out = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], check=False,
                             capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


# ---------------------------------------------------------------------- observation
def make_observation(study, scratch: Path) -> dict[str, Any]:
    """The ``ground_truth``, ``observe`` and (prior-centre warm start) ``base_state``
    rules, with their own library calls, into ``scratch``. Returns the paths."""
    from bayescalib.models.forward import solve_base_state, solve_point
    from bayescalib.stages.observe import observe

    fm = study.forward_section()
    obs_dir = scratch / "observations"
    obs_dir.mkdir(parents=True, exist_ok=True)
    gt_run = obs_dir / "ground_truth_run.h5"
    obs_path = obs_dir / "observations.h5"
    out: dict[str, Any] = {"obs": obs_path, "state": None}
    if study.config["observations"].get("source", "synthetic") == "synthetic":
        if not (gt_run.is_file() and obs_path.is_file()):
            res = solve_point(fm, study.ground_truth_point(), gt_run)
            print(f"ground truth solve: {res.status} in {res.wall_time:.2f} s", flush=True)
            observe(study.config["observations"], obs_path, ground_truth_run=gt_run)
    elif not obs_path.is_file():
        observe(study.config["observations"], obs_path)
    if fm.get("warm_start") == "prior_centre":
        runs = scratch / "runs"
        state = runs / "base_state.state.npz"
        if not state.is_file():
            solve_base_state(fm, study.prior_centre(), runs / "base_state.h5", state)
        out["state"] = state
    return out


# ----------------------------------------------------------------------------- grid
def cell_centres(lo: float, hi: float, n: int) -> np.ndarray:
    h = (hi - lo) / n
    return lo + h * (np.arange(n) + 0.5)


def _point(study, E: float, nu: float) -> dict[str, float]:
    return study.point_values([float(E), float(nu)])


def _checkpoint_load(path: Path, key: str, shape: tuple[int, int]):
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["key"]) != key:
                return None
            ck = {k: f[k] for k in ("loglik", "D", "done", "failed", "wall")}
            ck["inferred"] = f["inferred"] if "inferred" in f.files else np.zeros(shape, bool)
            for t in ("solve_s", "discrepancy_s"):  # cumulative over resumed runs
                ck[t] = float(f[t]) if t in f.files else float("nan")
            ck["reasons"] = json.loads(str(f["reasons"]))
    except (OSError, KeyError, ValueError):
        return None
    if ck["loglik"].shape != shape:
        return None
    return ck


def _checkpoint_save(path: Path, key: str, g: Mapping[str, Any], wall: float) -> None:
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, key=np.array(key), loglik=g["loglik"], D=g["D"], done=g["done"],
             failed=g["failed"], inferred=g["inferred"],
             reasons=np.array(json.dumps(g["reasons"])), wall=np.array(wall),
             solve_s=np.array(g["solve_s"]), discrepancy_s=np.array(g["discrepancy_s"]))
    os.replace(tmp, path)


def _strides(n1: int, n2: int, max_stride: int) -> list[int]:
    """Strides of the coarse-to-fine passes: powers of two down to 1."""
    s = 1
    while 2 * s <= max_stride and 4 * (2 * s) <= min(n1, n2) - 1:
        s *= 2
    out = []
    while s >= 1:
        out.append(s)
        s //= 2
    return out


def _level_cells(shape: tuple[int, int], s: int) -> list[tuple[int, int]]:
    """Cells on the stride-``s`` lattice, serpentine."""
    rows = range(0, shape[0], s)
    cols = list(range(0, shape[1], s))
    return [(i, j) for r, i in enumerate(rows) for j in (cols if r % 2 == 0 else cols[::-1])]


def _enclosing(i: int, j: int, s: int, shape: tuple[int, int]) -> list[tuple[int, int]] | None:
    """Corners of the stride-``2s`` lattice box that contains cell (i, j) (one or two per
    axis), or None when a corner lies outside the grid."""
    def ends(k: int, n: int) -> list[int] | None:
        lo = (k // (2 * s)) * 2 * s
        if lo == k:
            return [k]
        return [lo, lo + 2 * s] if lo + 2 * s <= n - 1 else None

    a, b = ends(i, shape[0]), ends(j, shape[1])
    if a is None or b is None:
        return None
    return [(x, y) for x in a for y in b]


def solve_grid(study, paths: Mapping[str, Any], E: np.ndarray, nu: np.ndarray, scratch: Path,
               *, name: str, warm: str = "centre", key: str = "", max_stride: int = 8,
               progress_every: float = 30.0) -> dict[str, Any]:
    """Log-likelihood of every grid point (E[i], nu[j]) from an in-process solve.

    Each point: :func:`solve_series` with the study's forward model (one model object
    for the whole grid), the run record written to ``scratch/<name>/run.h5`` and
    :func:`bayescalib.stages.discrepancy.discrepancy` on it.

    Failed solves are the slow ones (the load continuation stalls after many Newton
    steps), so the grid is solved coarse to fine: first the cells on a lattice of stride
    ``max_stride``, then strides halved down to 1. A cell whose enclosing coarser-lattice
    box has all its corners failed is not solved: it is marked failed and ``inferred``
    (``max_stride=1``: every cell is solved). Resumes from a checkpoint in ``scratch``
    when one matches ``key`` and the grid.
    """
    from bayescalib.io.runrecord import write_run
    from bayescalib.models.forward import make_forward_model, solve_series
    from bayescalib.stages.discrepancy import discrepancy

    if warm not in ("centre", "previous"):
        raise ValueError(f"warm must be 'centre' or 'previous', got {warm!r}")
    fm = study.forward_section()
    measure_name = study.primary_measure
    measure, likelihood = study.config["measure"], study.config["likelihood"]
    work = scratch / name
    work.mkdir(parents=True, exist_ok=True)
    ck_path = work / "checkpoint.npz"
    shape = (len(E), len(nu))
    # the values do not depend on the order of the solves: a checkpoint of another
    # max_stride is resumed as well
    ck_key = _hash({"key": key, "E": E.tolist(), "nu": nu.tolist(), "warm": warm})
    g: dict[str, Any] = _checkpoint_load(ck_path, ck_key, shape) or {
        "loglik": np.full(shape, -np.inf), "D": np.full(shape, np.nan),
        "done": np.zeros(shape, bool), "failed": np.zeros(shape, bool),
        "inferred": np.zeros(shape, bool), "reasons": {}, "wall": 0.0, "solve_s": 0.0,
        "discrepancy_s": 0.0}
    wall_before = float(g.pop("wall"))
    L, D, done, failed, inferred = g["loglik"], g["D"], g["done"], g["failed"], g["inferred"]
    if done.any():
        print(f"[{name}] resuming: {int(done.sum())} of {done.size} points done", flush=True)

    state = paths.get("state")  # the prior-centre base state (None: cold solves)
    if state is not None:
        with np.load(state, allow_pickle=False) as f:
            start = np.array(f["state"], dtype=float)
    else:
        start = None
    model = make_forward_model(fm, workdir=work / "model.work", warm_start=None)
    run_path, disc_path = work / "run.h5", work / "discrepancy.json"

    t0 = time.perf_counter()
    last_print = t0
    have_last = False
    n_solved = 0
    strides = _strides(*shape, max_stride)
    for s in strides:
        for i, j in _level_cells(shape, s):
            if done[i, j]:
                continue
            corners = None if s == strides[0] else _enclosing(i, j, s, shape)
            if corners and all(done[c] and failed[c] for c in corners):
                done[i, j] = failed[i, j] = inferred[i, j] = True
                continue
            model.warm_start = "last" if warm == "previous" and have_last else start
            ts = time.perf_counter()
            res = solve_series(model, _point(study, E[i], nu[j]), fm.get("loadings"))
            g["solve_s"] += time.perf_counter() - ts
            have_last = have_last or res.status == "ok"
            td = time.perf_counter()
            write_run(run_path, res)
            rec = discrepancy(run_path, paths["obs"], measure_name, measure[measure_name], likelihood,
                              disc_path)
            g["discrepancy_s"] += time.perf_counter() - td
            if rec["loglik"] is None:
                failed[i, j] = True
                L[i, j] = -np.inf
                g["reasons"][f"{i},{j}"] = str(rec.get("reason") or res.reason)[:300]
            else:
                L[i, j] = float(rec["loglik"])
                D[i, j] = float(rec["D"])
            done[i, j] = True
            n_solved += 1
            now = time.perf_counter()
            if now - last_print >= progress_every:
                last_print = now
                el = now - t0
                left = int((~done).sum())
                print(f"[{name}] stride {s}: {int(done.sum())}/{done.size} cells, "
                      f"{int(failed.sum())} failed ({int(inferred.sum())} inferred), {el:.0f} s "
                      f"(solve {g['solve_s']:.0f} s, discrepancy {g['discrepancy_s']:.0f} s), "
                      "at most "
                      f"{el / n_solved * left:.0f} s left", flush=True)
                _checkpoint_save(ck_path, ck_key, g, wall_before + now - t0)
    wall = wall_before + time.perf_counter() - t0
    _checkpoint_save(ck_path, ck_key, g, wall)
    print(f"[{name}] done: {done.size} cells, {int((done & ~inferred).sum())} solved, "
          f"{int(failed.sum())} failed ({int(inferred.sum())} inferred), {wall:.0f} s", flush=True)
    return {"E": E, "nu": nu, "loglik": L, "D": D, "failed": failed, "inferred": inferred,
            "reasons": g["reasons"], "wall_s": wall,
            "n_solves": int((done & ~inferred).sum()), "n_failed": int(failed.sum()),
            "n_inferred": int(inferred.sum()), "solve_s": g["solve_s"],
            "discrepancy_s": g["discrepancy_s"]}


_RULE_SOLVES = """
import json, sys
from bayescalib.models.forward import solve_point
for job in json.load(open(sys.argv[1])):
    solve_point(job["fm"], job["point"], job["run"], warm_start=job["state"])
"""


def check_against_rule(study, paths: Mapping[str, Any], grid: Mapping[str, Any], k: int,
                       scratch: Path, seed: int = 0) -> dict[str, Any]:
    """Re-solve ``k`` grid points (the mode, then random ones) as the ``solve`` rule does
    (:func:`solve_point`: a forked child with a fresh model, warm start from the base-state
    file) and compare the log-likelihoods with the grid's.

    The solves run in a fresh Python process: this one has NGSolve loaded, and a child
    forked from it would not be the rule's clean child.
    """
    import subprocess

    from bayescalib.stages.discrepancy import discrepancy

    fm = study.forward_section()
    work = scratch / "check"
    work.mkdir(parents=True, exist_ok=True)
    L = grid["loglik"]
    rng = np.random.default_rng(seed)
    picks = [tuple(int(x) for x in np.unravel_index(int(np.argmax(L)), L.shape))]
    picks += [tuple(int(x) for x in rng.integers(0, L.shape, 2)) for _ in range(max(k - 1, 0))]
    picks = picks[:k]
    jobs = [{"fm": fm, "point": _point(study, grid["E"][i], grid["nu"][j]),
             "run": str(work / f"{i}_{j}.h5"),
             "state": None if paths.get("state") is None else str(paths["state"])}
            for i, j in picks]
    (work / "jobs.json").write_text(json.dumps(jobs))
    subprocess.run([sys.executable, "-c", _RULE_SOLVES, str(work / "jobs.json")], check=True)
    rows = []
    for (i, j), job in zip(picks, jobs, strict=True):
        rec = discrepancy(job["run"], paths["obs"], study.primary_measure,
                          study.config["measure"][study.primary_measure],
                          study.config["likelihood"], work / f"{i}_{j}.json")
        lr = -np.inf if rec["loglik"] is None else float(rec["loglik"])
        lg = float(L[i, j])
        if np.isfinite(lr) and np.isfinite(lg):
            diff = abs(lr - lg)
        else:
            diff = 0.0 if lr == lg else np.inf
        rows.append({"E": float(grid["E"][i]), "nu": float(grid["nu"][j]), "loglik_rule": lr,
                     "loglik_grid": lg, "abs_diff": float(diff)})
    return {"points": rows, "max_abs_diff": max((r["abs_diff"] for r in rows), default=0.0)}


# ----------------------------------------------------------------------------- main
def _cells(g: dict[str, Any], h: np.ndarray) -> None:
    g["sd_in_cells"] = (np.asarray(g["moments"]["sd"]) / h).tolist()
    g["sd_cond_in_cells"] = (np.asarray(g["moments"]["sd_conditional"]) / h).tolist()


def _fmt(values) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def high_density_box(g: Mapping[str, Any], box: np.ndarray, drop: float) -> np.ndarray:
    """Bounding box of the cells whose log-likelihood is within ``drop`` of the largest
    (relative density above exp(-drop)), widened by one cell each way, within ``box``."""
    L = g["loglik"]
    keep = np.isfinite(L) & (L >= np.max(L[np.isfinite(L)]) - drop)
    out = []
    for d, ax in enumerate((np.asarray(g["E"]), np.asarray(g["nu"]))):
        idx = np.flatnonzero(keep.any(axis=1 - d))
        half = 0.5 * (ax[1] - ax[0]) if len(ax) > 1 else 0.0
        lo, hi = ax[idx.min()] - 3 * half, ax[idx.max()] + 3 * half
        out.append([max(box[d, 0], lo), min(box[d, 1], hi)])
    return np.array(out)


def _summary_line(names, mom) -> str:
    return ", ".join(f"{n} = {m:.6g} +- {s:.4g}" for n, m, s in
                     zip(names, mom["mean"], mom["sd"], strict=True))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(REPO / "config" / "config.yaml"))
    ap.add_argument("--overlay", default=str(REPO / "config" / "smoke.yaml"),
                    help="config layered over --config ('' for none)")
    ap.add_argument("--n", type=int, default=41, help="grid points per parameter (box grid)")
    ap.add_argument("--zoom", choices=("auto", "always", "never"), default="auto")
    ap.add_argument("--zoom-n", type=int, default=None, help="zoom grid size (default --n)")
    ap.add_argument("--zoom-drop", type=float, default=15.0,
                    help="zoom box: cells with loglik within this of the largest, plus one cell")
    ap.add_argument("--zoom-max-fraction", type=float, default=0.5,
                    help="auto: no zoom when the zoom box is more than this fraction of the box")
    ap.add_argument("--min-cells", type=float, default=3.0,
                    help="zoom (auto) when a marginal posterior sd spans fewer grid cells")
    ap.add_argument("--min-cond-cells", type=float, default=1.5,
                    help="zoom (auto) when a conditional posterior sd (the width across a "
                         "ridge along a grid axis) spans fewer grid cells (the midpoint rule's "
                         "relative error for a Gaussian of sd s cells is about "
                         "2 exp(-2 pi^2 s^2): 1e-19 at 1.5 cells)")
    ap.add_argument("--warm", choices=("centre", "previous"), default="centre")
    ap.add_argument("--max-stride", type=int, default=8,
                    help="coarsest lattice stride of the coarse-to-fine passes (1: solve all)")
    ap.add_argument("--check", type=int, default=0, help="grid points re-solved as the rule does")
    ap.add_argument("--scratch", default=None, help="keep run records and checkpoints here")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "data" / "fsi_reference_smoke.npz"))
    args = ap.parse_args(argv)

    import logging

    logging.getLogger("bayescalib").setLevel(logging.WARNING)
    t_all = time.perf_counter()
    study = build_study(args.config, args.overlay or None)
    names = [p["name"] for p in study.config["parameters"]]
    if len(names) != 2:
        raise SystemExit(f"a 2-parameter study is needed, this one has {names}")
    for p in study.config["parameters"]:
        if p.get("prior", {}).get("type", "uniform") != "uniform":
            print(f"note: the prior of {p['name']} is not uniform; the stored values are "
                  "log-likelihoods, add the log prior before comparing", flush=True)
    sections = _sections(study)
    key = _hash(sections)

    tmp = None
    if args.scratch:
        scratch = Path(args.scratch)
        scratch.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.TemporaryDirectory(prefix="fsi_reference_")
        scratch = Path(tmp.name)
    try:
        t = time.perf_counter()
        paths = make_observation(study, scratch)
        t_setup = time.perf_counter() - t
        obs_hash = _observation_hash(paths["obs"])
        key_all = _hash({"sections": key, "obs": obs_hash})

        (Elo, Ehi), (nlo, nhi) = (tuple(map(float, b)) for b in study.space.bounds)
        box = np.array([[Elo, Ehi], [nlo, nhi]])
        grids: dict[str, dict[str, Any]] = {}
        g = solve_grid(study, paths, cell_centres(Elo, Ehi, args.n), cell_centres(nlo, nhi, args.n),
                       scratch, name="box", warm=args.warm, key=key_all,
                       max_stride=args.max_stride)
        g["box"] = box
        g["moments"] = grid_moments(g["E"], g["nu"], g["loglik"])
        grids["box"] = g
        h = np.array([(Ehi - Elo) / args.n, (nhi - nlo) / args.n])
        _cells(g, h)
        print(f"[box] {args.n} x {args.n}: {_summary_line(names, g['moments'])}; "
              f"sd / cell = {_fmt(g['sd_in_cells'])}, conditional sd / cell = "
              f"{_fmt(g['sd_cond_in_cells'])}", flush=True)

        recommended = "box"
        zoom_note = None
        narrow = (min(g["sd_in_cells"]) < args.min_cells
                  or min(g["sd_cond_in_cells"]) < args.min_cond_cells)
        if args.zoom == "always" or (args.zoom == "auto" and narrow):
            zb = high_density_box(g, box, args.zoom_drop)
            frac = float(np.prod((zb[:, 1] - zb[:, 0]) / (box[:, 1] - box[:, 0])))
            if args.zoom == "auto" and frac > args.zoom_max_fraction:
                zoom_note = (f"the posterior is narrow on the {args.n} x {args.n} grid but its "
                             f"high-density region fills {frac:.0%} of the box: no zoom; rerun "
                             "with a larger --n")
                print("WARNING: " + zoom_note, flush=True)
            else:
                nz = args.zoom_n or args.n
                z = solve_grid(study, paths, cell_centres(*zb[0], nz), cell_centres(*zb[1], nz),
                               scratch, name="zoom", warm=args.warm, key=key_all,
                               max_stride=args.max_stride)
                z["box"] = zb
                z["moments"] = grid_moments(z["E"], z["nu"], z["loglik"])
                _cells(z, (zb[:, 1] - zb[:, 0]) / nz)
                grids["zoom"] = z
                recommended = "zoom"
                print(f"[zoom] {nz} x {nz} on E in [{zb[0, 0]:.6g}, {zb[0, 1]:.6g}], nu in "
                      f"[{zb[1, 0]:.6g}, {zb[1, 1]:.6g}] ({frac:.0%} of the box): "
                      f"{_summary_line(names, z['moments'])}; sd / cell = "
                      f"{_fmt(z['sd_in_cells'])}, conditional sd / cell = "
                      f"{_fmt(z['sd_cond_in_cells'])}", flush=True)

        check = None
        t_check = 0.0
        if args.check > 0 and paths.get("state") is not None:
            t = time.perf_counter()
            check = check_against_rule(study, paths, grids[recommended], args.check, scratch)
            t_check = time.perf_counter() - t
            print(f"check against the solve rule ({args.check} points): max |dL| = "
                  f"{check['max_abs_diff']:.3g}", flush=True)
    finally:
        if tmp is not None:
            tmp.cleanup()

    wall_run = time.perf_counter() - t_all
    # compute time of the reference (the grids' times are summed over resumed runs)
    wall = t_setup + sum(gr["wall_s"] for gr in grids.values()) + t_check
    meta = {
        "what": "log-likelihood of real forward solves on cell-centred grids; "
                "posterior = exp(loglik) x uniform prior",
        "names": names,
        "targets": study.targets(),
        "config_files": [str(args.config), str(args.overlay or "")],
        "sections": sections,
        "config_hash": key,
        "observation_sha256": obs_hash,
        "bayescalib_commit": _git_commit(),
        "warm": args.warm,
        "max_stride": args.max_stride,
        "recommended": recommended,
        "grids": {
            n: {"shape": list(gr["loglik"].shape), "box": gr["box"].tolist(),
                "n_cells": int(gr["loglik"].size), "n_solves": gr["n_solves"],
                "n_failed": gr["n_failed"], "n_inferred": gr["n_inferred"],
                "solve_s": gr["solve_s"], "discrepancy_s": gr["discrepancy_s"],
                "failures": [{"E": float(gr["E"][int(ij.split(',')[0])]),
                              "nu": float(gr["nu"][int(ij.split(',')[1])]), "reason": r}
                             for ij, r in gr["reasons"].items()],
                "moments": gr["moments"], "sd_in_cells": gr["sd_in_cells"],
                "sd_conditional_in_cells": gr["sd_cond_in_cells"],
                "wall_s": gr["wall_s"]}
            for n, gr in grids.items()
        },
        "setup_s": t_setup,
        "check": check,
        "check_s": t_check,
        "zoom_note": zoom_note,
        "n_solves": int(sum(gr["n_solves"] for gr in grids.values())),
        "wall_s": wall,
        "wall_s_this_run": wall_run,
        "threads": 1,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, Any] = {"recommended": np.array(recommended),
                              "meta": np.array(json.dumps(meta, allow_nan=True))}
    for n, gr in grids.items():
        p = "" if n == "box" else "zoom_"
        arrays.update({p + "E": gr["E"], p + "nu": gr["nu"], p + "box": gr["box"],
                       p + "loglik": gr["loglik"], p + "failed": gr["failed"],
                       p + "inferred": gr["inferred"], p + "D": gr["D"]})
    tmp_out = out.with_name(out.name + ".tmp.npz")
    np.savez_compressed(tmp_out, **arrays)
    os.replace(tmp_out, out)

    rec = grids[recommended]
    print(f"reference ({recommended} grid {rec['loglik'].shape[0]} x {rec['loglik'].shape[1]}): "
          f"{_summary_line(names, rec['moments'])}; correlation {rec['moments']['corr']:.3f}; "
          f"mode {rec['moments']['mode']}", flush=True)
    print(f"solves {meta['n_solves']}, failed "
          + ", ".join(f"{n} {gr['n_failed']} of {gr['loglik'].size} ({gr['n_inferred']} "
                      "inferred)" for n, gr in grids.items())
          + f"; wall {wall:.1f} s ({wall_run:.1f} s in this run) -> {out} "
          f"({out.stat().st_size / 1024:.1f} KiB)", flush=True)
    # the reference against itself: 0 (a smoke test of the comparison)
    assert hellinger_to_reference(rec["loglik"], out) < 1e-6  # rounding: ~1e-8
    return 0


if __name__ == "__main__":
    sys.exit(main())
