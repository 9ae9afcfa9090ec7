"""Forward solves of the diagnosis stage: many points, in parallel, reused when present.

The diagnosis needs solves that are not known before the base calibration ends
(posterior draws, finite-difference steps, extended designs), so they run inside the
stage rather than as Snakemake jobs. Each point is written as a run record
(:mod:`bayescalib.runrecord`) at its own path; a valid record with the same inputs is
reused, so an interrupted stage resumes without redoing finished solves. Worker
processes (forked) keep one forward model each (an FSI model builds its mesh and forms
once per worker); every solve starts from rest or from the given warm-start state, so
the result does not depend on which worker solved which point.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bayescalib.runrecord import RunFileError, SolveResult, read_run, write_run

__all__ = ["solve_many"]

log = logging.getLogger(__name__)

_MODELS: dict[str, Any] = {}


def _same_inputs(run: SolveResult, params: Mapping[str, Any]) -> bool:
    for k, v in params.items():
        if isinstance(v, bool):
            continue  # switches are not recorded as parameters
        if k not in run.parameters or abs(run.parameters[k] - float(v)) > 1e-12 * max(1.0, abs(float(v))):
            return False
    return True


def _solve_one(task: tuple[dict, dict, str, str | None]) -> str:
    from bayescalib.forward import failed_result, make_forward_model, solve_series

    fm, params, out, warm = task
    key = json.dumps([fm, warm], sort_keys=True, default=str)
    try:
        model = _MODELS.get(key)
        if model is None or fm.get("type") == "command":
            model = make_forward_model(fm, workdir=Path(out).with_suffix(".work"),
                                       warm_start=warm)
            _MODELS.clear()
            _MODELS[key] = model
        res = solve_series(model, params, fm.get("loadings"))
    except Exception as exc:  # noqa: BLE001 - a failed solve is data
        res = failed_result(params, f"{type(exc).__name__}: {exc}",
                            log_tail=traceback.format_exc()[-2000:])
    write_run(out, res)
    return out


def solve_many(fm: Mapping[str, Any], points: Sequence[Mapping[str, Any]],
               out_paths: Sequence[str | Path], *, workers: int = 1,
               warm_start: str | Path | None = None) -> list[SolveResult]:
    """Solve ``fm`` at every point (run records at ``out_paths``), reusing valid records.

    Parameters
    ----------
    fm
        Validated ``forward_model`` section (``loadings`` included).
    points
        Parameter values (and switches such as ``physics.growth.enabled``) per point.
    out_paths
        One run-record path per point.
    workers
        Parallel processes (1: in this process).
    warm_start
        State file every solve starts from (fsi only).

    Returns
    -------
    list of SolveResult
        In the order of ``points``.
    """
    if len(points) != len(out_paths):
        raise ValueError("solve_many: one output path per point is needed")
    fm = json.loads(json.dumps(fm))
    if fm.get("type") == "fsi":
        # no factorization carried from one point to the next: results independent of
        # the order and of the number of workers
        fm.setdefault("fsi", {}).setdefault("solver", {})["keep_factorization"] = False
    todo = []
    for p, out in zip(points, out_paths, strict=True):
        out = Path(out)
        if out.is_file():
            try:
                if _same_inputs(read_run(out), p):
                    continue
            except RunFileError:
                pass  # corrupt or incomplete: solve again
        out.parent.mkdir(parents=True, exist_ok=True)
        todo.append((dict(fm), dict(p), str(out), None if warm_start is None else str(warm_start)))
    log.info("diagnosis solves: %d of %d to do (%d reused), %d worker(s)", len(todo),
             len(points), len(points) - len(todo), workers)
    if todo:
        if workers > 1 and len(todo) > 1:
            ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
            with ctx.Pool(min(workers, len(todo)), maxtasksperchild=64) as pool:
                for _ in pool.imap_unordered(_solve_one, todo):
                    pass
        else:
            for t in todo:
                _solve_one(t)
    return [read_run(p) for p in out_paths]
