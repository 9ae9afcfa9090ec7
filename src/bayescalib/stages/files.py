"""The files of the stages: written atomically, read through one reader, set aside when
they cannot be read, reused when an earlier job had the same input.

Every stage writes its outputs atomically (:func:`write_json`;
:func:`bayescalib.io._atomic_write.atomic_path`), so that an interrupted run never
leaves a half-written file that a later run would trust. Every file a stage reads from
another stage goes through :func:`read_stage_file`, whose table :data:`STAGE_FILES`
holds the one reader of each kind of file; a file it cannot read is moved aside to
``<name>.corrupt`` (:func:`set_aside`), so that the next run of the same ``snakemake``
command rebuilds it and what depends on it instead of failing on it again.
:func:`reuse_output`: a job of ``train_surrogate`` or ``smc`` whose input holds the same
content as an earlier job's (the last active round's) copies that job's output instead
of computing it again (every stage is deterministic). :func:`read_json` reads a JSON
file only to look at it (the report's front page, ``bayescalib summary``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import zipfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayescalib.io._atomic_write import atomic_path
from bayescalib.io.training import read_training
from bayescalib.stages.errors import PipelineError

__all__ = ["STAGE_FILES", "read_json", "read_stage_file", "reuse_output", "set_aside",
           "write_json"]

log = logging.getLogger("bayescalib")


def _clean(obj: Any) -> Any:
    """Make ``obj`` strict-JSON serializable (non-finite floats become None)."""
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented strict JSON, atomically."""
    with atomic_path(path, suffix=".json") as tmp:
        tmp.write_text(json.dumps(_clean(obj), indent=2, sort_keys=False, allow_nan=False) + "\n")


def read_json(path: str | Path) -> Any:
    """A JSON file read only to look at it (the report's front page at parse time,
    ``bayescalib summary``): a file that cannot be read is left where it is. A stage
    reads the outputs of other stages through :func:`read_stage_file`."""
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise PipelineError(f"cannot read JSON file '{p}': {exc}") from None


def set_aside(path: str | Path, problem: str, *,
              rebuilt_by_this_run: bool = False) -> PipelineError:
    """Move a stage output that cannot be used to ``<name>.corrupt`` and say how to
    redo it.

    The file is the output of an upstream job. Every stage output is a target of the
    workflow (``study_outputs``), and the job that failed on it wrote nothing, so the
    next run of the same ``snakemake`` command rebuilds the missing file and what
    depends on it, instead of failing on it again. For run records and discrepancy
    files the gather rule lists the set-aside files as a parameter, so gather reruns
    too. ``rebuilt_by_this_run``: set aside before Snakemake builds its plan, which
    then rebuilds the file in this run (the message says so).
    """
    p = Path(path)
    aside = p.with_name(p.name + ".corrupt")
    k = 1
    while aside.exists():  # every event gets its own name (the gather rule lists them)
        aside = p.with_name(f"{p.name}.{k}.corrupt")
        k += 1
    where = ""
    if p.exists():
        try:
            os.replace(p, aside)
            where = f"; it was moved to '{aside}'"
        except OSError as exc:  # pragma: no cover - read-only results folder
            where = f"; it could not be moved aside ({exc}): delete it"
    then = ("This run recomputes it." if rebuilt_by_this_run else
            "Run the same snakemake command again: it is recomputed, and only what "
            "depends on it.")
    return PipelineError(f"{problem}{where}. {then}")


def _json_object(path: Path) -> dict[str, Any]:
    """A JSON stage output: an object (every stage writes one)."""
    value = json.loads(path.read_bytes())
    if not isinstance(value, dict):
        raise ValueError(f"it holds a JSON {type(value).__name__}, not an object")  # noqa: TRY004 - read_stage_file sets a ValueError aside
    return value


def _run_record(path: Path, **options: Any):
    from bayescalib.io.runrecord import read_run

    return read_run(path, **options)


def _observation_set(path: Path, **options: Any):
    from bayescalib.io.observation_store import read_observations

    return read_observations(path, **options)


def _surrogate(path: Path, **options: Any):
    from bayescalib.inference.emulator import load_surrogate

    return load_surrogate(path, **options)


def _particles(path: Path, **options: Any):
    from bayescalib.inference.posterior import read_particles_h5

    return read_particles_h5(path, **options)


def _warm_start_state(path: Path) -> dict[str, Any]:
    """The arrays of a warm-start state (``FSIModel.save_state``), read in full."""
    with np.load(path, allow_pickle=False) as data:
        return {"state": np.array(data["state"], dtype=float), "key": str(data["key"]),
                "parameters": json.loads(str(data["parameters"]))}


def _vtu_fields(path: Path):
    from bayescalib.stages.figures import read_vtu_fields

    return read_vtu_fields(path)


#: every kind of file a stage reads from another stage: its reader (the one place that
#: knows each format). JSON: the discrepancy, posterior, convergence, posterior-check,
#: active-round and study records; HDF5: run records, the observation set, training
#: tables, surrogates, particles; NumPy: the warm-start state; VTK: the fields.
STAGE_FILES: dict[str, Callable[..., Any]] = {
    "run record": _run_record,
    "observation set": _observation_set,
    "training table": read_training,
    "surrogate": _surrogate,
    "SMC particle file": _particles,
    "warm-start state": _warm_start_state,
    "VTU field file": _vtu_fields,
    "discrepancy record": _json_object,
    "posterior summary": _json_object,
    "GP convergence record": _json_object,
    "posterior check": _json_object,
    "active round record": _json_object,
    "study summary": _json_object,
}

#: what a reader raises on a file it cannot read (a missing, truncated, corrupt file, one
#: of another kind or layout version, a JSON file cut short or not an object)
_UNREADABLE = (OSError, KeyError, ValueError, TypeError, EOFError, IndexError,
               zipfile.BadZipFile)


def read_stage_file(path: str | Path, kind: str, *, rebuilt_by_this_run: bool = False,
                    **options: Any) -> Any:
    """Read the stage output ``path``, a file of ``kind`` (a key of :data:`STAGE_FILES`).

    The one reader of every file a stage reads from another stage, whatever its format.
    A file that cannot be read (missing, truncated, corrupt, of another kind or layout
    version) is moved aside to ``<name>.corrupt`` (:func:`set_aside`), so that the next
    run of the same ``snakemake`` command rebuilds it, and what depends on it, instead
    of failing on it again (``rebuilt_by_this_run``: read before Snakemake builds its
    plan, which then rebuilds it in this run; the message says so). ``options`` go to
    the kind's reader (e.g. ``device`` of a surrogate).

    Raises
    ------
    PipelineError
        Naming the file, what it is and why it cannot be read, where it was moved and
        what to run.
    """
    try:
        reader = STAGE_FILES[kind]
    except KeyError:
        raise ValueError(f"read_stage_file: unknown kind of stage file {kind!r} "
                         f"(known: {', '.join(STAGE_FILES)})") from None
    p = Path(path)
    try:
        return reader(p, **options)
    except _UNREADABLE as exc:
        from bayescalib.io.runrecord import RunFileError

        why = str(exc) if isinstance(exc, RunFileError) else f"{type(exc).__name__}: {exc}"
        raise set_aside(p, f"the {kind} '{p}' cannot be read ({why})",
                         rebuilt_by_this_run=rebuilt_by_this_run) from None


def _same_bits(u: Any, v: Any) -> bool:
    """Two stored values (datasets or attributes) are the same: equal shapes, dtypes
    and bytes (numeric), or equal elements (strings)."""
    a, b = np.asarray(u), np.asarray(v)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind in "biufc":
        return a.tobytes() == b.tobytes()
    return bool(np.array_equal(a, b))


def _same_h5_content(a: str | Path, b: str | Path) -> bool:
    """True when two HDF5 files hold the same groups, datasets and attributes, each
    value bitwise (the files' own bytes may differ: HDF5 lays them out freely)."""
    import h5py

    def same(x, y) -> bool:
        if set(x.attrs) != set(y.attrs) or not all(_same_bits(x.attrs[k], y.attrs[k])
                                                   for k in x.attrs):
            return False
        if isinstance(x, h5py.Dataset):
            return isinstance(y, h5py.Dataset) and _same_bits(x[()], y[()])
        return (isinstance(y, h5py.Group) and set(x) == set(y)
                and all(same(x[k], y[k]) for k in x))

    try:
        with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
            return same(fa, fb)
    except OSError:
        return False


def _h5_readable(path: str | Path) -> bool:
    """True when ``path`` is an HDF5 file whose every dataset can be read."""
    import h5py

    def read_all(g) -> None:
        for v in g.values():
            if isinstance(v, h5py.Dataset):
                v[()]
            else:
                read_all(v)

    try:
        with h5py.File(path, "r") as f:
            read_all(f)
        return True
    except OSError:
        return False


def reuse_output(input_path: str | Path, reuse: Sequence[str | Path], out_path: str | Path,
                 what: str) -> bool:
    """``reuse`` = (an earlier job's input, that job's output), of the same stage with
    the same settings (the rule passes them: the last active round's files for the
    primary measure). When this job's input holds the same content as the earlier
    input, its output would be the earlier output bit for bit (every stage is
    deterministic): that file is copied to ``out_path`` and True returned."""
    import shutil

    if not reuse:
        return False
    if len(reuse) != 2:
        raise ValueError(f"reuse: expected (earlier input, earlier output), got {list(reuse)}")
    earlier_in, earlier_out = (Path(p) for p in reuse)
    if not _h5_readable(earlier_out):  # missing or damaged: compute
        return False
    if not _same_h5_content(input_path, earlier_in):
        return False
    with atomic_path(out_path, suffix=Path(out_path).suffix) as tmp:
        shutil.copyfile(earlier_out, tmp)
    log.info("%s: input '%s' is the same as '%s': its output '%s' is reused", what,
             input_path, earlier_in, earlier_out)
    return True
