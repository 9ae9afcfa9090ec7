"""Pluggable forward models and the isolated solve of one design point.

A forward model maps parameter values (keyed by their *target*, a dotted
config key such as ``material.E``) to the deformed interface. Three kinds are
built in, chosen by ``forward_model.type`` in the study config:

``fsi``
    The NGSolve monolithic ALE fluid–structure model (:mod:`bayescalib.models.fsi`).
``python``
    A Python callable given as ``module:function`` (the module must be
    importable, e.g. from the working directory or an installed package). It is
    called as ``function(params, **options)`` with ``params`` a ``dict`` of
    floats and must return the deformed interface: an ``(n, 2)`` or ``(n, 3)``
    array of ordered points, an :class:`~bayescalib.geometry.interface.Interface`, or a
    mapping with ``current`` (and optionally ``reference``) entries of either
    kind. Raising an exception marks the run as failed.
``command``
    An external solver (e.g. 4C): a Jinja2 input template is rendered with the
    parameter values (strict undefined variables: a misspelt name is an error),
    the command is run *without a shell* in a private work folder, made fresh and
    empty for every solve, and the interface file it writes (CSV or VTK) is read
    back. Its ``{input}``, ``{output}`` and ``{workdir}`` placeholders are absolute
    paths.

:func:`solve_points` is the one way design points are solved (the workflow's
``solve`` jobs through :func:`solve_point`, the base state, the diagnosis, the
``bayescalib solve`` command): every point in a forked process with a wall-clock
limit, so that a crash, a hang or a segmentation fault inside a solver ends as a
recorded failed run (:class:`~bayescalib.io.runrecord.SolveResult` with
``status == "failed"``) instead of taking the study down. The run record is always
written atomically. A solve process solves point after point with one kept fsi
model (mesh, spaces and compiled forms; never its solver state, so results are bit
for bit those of a new model); a point that kills its process or runs past its limit
fails alone, and the next point gets a new process.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import math
import multiprocessing as mp
import multiprocessing.connection
import os
import re
import shutil
import stat
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bayescalib._process import die_with_parent
from bayescalib.io.runrecord import LoadingResult, SolveResult, write_run

log = logging.getLogger(__name__)

__all__ = [
    "CommandModel",
    "FSIForward",
    "ForwardModel",
    "ForwardModelError",
    "PythonModel",
    "failed_result",
    "load_callable",
    "loading_factors",
    "loading_labels",
    "make_forward_model",
    "solve_point",
    "solve_points",
    "solve_series",
    "validate_call",
    "validate_executable",
]


class ForwardModelError(ValueError):
    """A forward model is misconfigured (bad module path, template, command...)."""


class ForwardModel(Protocol):
    """Anything that maps parameter values to a :class:`SolveResult`."""

    def solve(self, params: Mapping[str, float]) -> SolveResult:  # pragma: no cover
        ...


def failed_result(params: Mapping[str, float], reason: str, wall_time: float = 0.0,
                  **stats: Any) -> SolveResult:
    """A failed-run record with no interface."""
    empty = np.zeros((0, 2))
    return SolveResult(
        status="failed",
        reason=reason,
        parameters={k: float(v) for k, v in params.items()},
        load_fraction=0.0,
        newton_iterations=0,
        load_steps=0,
        wall_time=float(wall_time),
        interface_reference=empty,
        interface_current=empty,
        segments=np.zeros((0, 2), dtype=np.int64),
        max_displacement=float("nan"),
        stats=dict(stats),
    )


def _points_of(obj: Any, what: str) -> np.ndarray:
    pts = getattr(obj, "points", obj)
    arr = np.asarray(pts, dtype=float)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or arr.shape[0] < 2:
        raise ForwardModelError(
            f"{what} must be an (n, 2) or (n, 3) array of at least 2 ordered points, "
            f"got shape {arr.shape}"
        )
    return arr


def _result_from_points(params: Mapping[str, float], current: np.ndarray,
                        reference: np.ndarray | None, wall_time: float,
                        **stats: Any) -> SolveResult:
    ref = current if reference is None else reference
    if ref.shape != current.shape:
        raise ForwardModelError(
            f"reference interface has shape {ref.shape} but current has {current.shape}"
        )
    n = current.shape[0]
    segs = np.column_stack([np.arange(n - 1), np.arange(1, n)]).astype(np.int64)
    finite = bool(np.all(np.isfinite(current)))
    disp = np.linalg.norm(current - ref, axis=1)
    return SolveResult(
        status="ok" if finite else "failed",
        reason="" if finite else "interface contains NaN or inf",
        parameters={k: float(v) for k, v in params.items()},
        load_fraction=1.0 if finite else 0.0,
        newton_iterations=0,
        load_steps=1,
        wall_time=float(wall_time),
        interface_reference=ref,
        interface_current=current,
        segments=segs,
        max_displacement=float(disp.max()) if finite else float("nan"),
        stats=dict(stats),
    )


def load_callable(function: str) -> Callable[..., Any]:
    """The callable a ``forward_model.python.function`` setting names (``"module:function"``),
    imported as a solve imports it (the working directory first on ``sys.path``).

    Raises
    ------
    ForwardModelError
        Naming the key and what is wrong: not ``module:function``, a module that cannot be
        found or fails to import (the error it raised), a name the module does not have
        (with the closest names it has), or a name that is not callable (its type).
    """
    key = "forward_model.python.function"
    if not isinstance(function, str) or ":" not in function:
        raise ForwardModelError(f"{key} must look like 'module:function', got {function!r}")
    mod_name, _, fn_name = function.partition(":")
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ForwardModelError(
            f"{key}: cannot import module '{mod_name}': {exc} (a module is found in the "
            f"working directory {os.getcwd()} or on the Python path: an installed package "
            "or PYTHONPATH)") from None
    except Exception as exc:  # noqa: BLE001 - a module may raise anything while importing
        raise ForwardModelError(f"{key}: importing module '{mod_name}' failed: "
                                f"{type(exc).__name__}: {exc}") from None
    where = f"module '{mod_name}'" + (f" ({mod.__file__})" if getattr(mod, "__file__", None)
                                      else "")
    if not hasattr(mod, fn_name):
        import difflib

        names = [n for n in dir(mod) if not n.startswith("_") and callable(getattr(mod, n))]
        close = difflib.get_close_matches(fn_name, names, n=3)
        raise ForwardModelError(
            f"{key}: {where} has no '{fn_name}'"
            + (f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""))
    fn = getattr(mod, fn_name)
    if not callable(fn):
        raise ForwardModelError(f"{key}: '{fn_name}' in {where} is a {type(fn).__name__}, "
                                "not a function")
    return fn


def validate_call(fn: Callable[..., Any], options: Mapping[str, Any]) -> None:
    """Check that ``fn(params, **options)`` binds to the callable's signature (a
    misspelt or unknown option is then known before any solve). A callable whose
    signature cannot be read is not checked.

    Raises
    ------
    ForwardModelError
        Naming ``forward_model.python.options`` and the argument that does not fit.
    """
    import inspect

    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return
    try:
        sig.bind({}, **dict(options))
    except TypeError as exc:
        names = ", ".join(("**" if q.kind is q.VAR_KEYWORD else "*" if q.kind is q.VAR_POSITIONAL
                           else "") + q.name for q in sig.parameters.values())
        raise ForwardModelError(
            f"forward_model.python.options: {sorted(options)} do not fit the model's "
            f"{getattr(fn, '__name__', 'callable')}({names}), called as "
            f"function(params, **options): {exc}") from None


def validate_executable(argv0: str) -> None:
    """Check that the program a command model runs (its argument list's first word) will
    be found: a plain name on ``PATH`` (:func:`shutil.which`), an absolute path an
    executable file. A relative path with a folder in it is refused: the command runs
    in each solve's own work folder (``runs/<i>.work``), where the path does not lead to
    it. A first word with a placeholder (``{workdir}/...``) is not checked.

    Raises
    ------
    ForwardModelError
        Naming ``forward_model.command.command[0]``, the value and how to fix it.
    """
    import shutil

    key = "forward_model.command.command[0]"
    if _ARG_FIELD.search(argv0):
        return
    if "/" not in argv0:
        if shutil.which(argv0) is None:
            raise ForwardModelError(
                f"{key}: '{argv0}' is not found on PATH ({os.environ.get('PATH', '')}): "
                "install it, add its folder to PATH, or give its absolute path")
        return
    path = Path(argv0)
    if not path.is_absolute():
        here = Path.cwd() / path
        raise ForwardModelError(
            f"{key}: '{argv0}' is a relative path, but the command runs in each solve's "
            "work folder (results/<study>/runs/<i>.work), where it does not lead to the "
            "program: give its absolute path"
            + (f" ({here.resolve()})" if here.is_file() else ""))
    if not path.is_file():
        raise ForwardModelError(f"{key}: '{argv0}' does not exist"
                                + (" as a file (it is a folder)" if path.exists() else ""))
    if not os.access(path, os.X_OK):
        raise ForwardModelError(f"{key}: '{argv0}' is not executable: chmod +x it, or run "
                                "it through its interpreter (e.g. [python3, script.py, ...])")


class PythonModel:
    """Forward model given as a Python callable ``module:function``.

    Parameters
    ----------
    function
        ``"package.module:function"``.
    options
        Extra keyword arguments passed to the callable on every call.
    """

    def __init__(self, function: str, options: Mapping[str, Any] | None = None):
        self.function = load_callable(function)
        self.options = dict(options or {})

    def solve(self, params: Mapping[str, float]) -> SolveResult:
        t0 = time.perf_counter()
        try:
            out = self.function(dict(params), **self.options)
            if isinstance(out, Mapping):
                if "current" not in out:
                    raise ForwardModelError("the callable returned a mapping without 'current'")
                current = _points_of(out["current"], "returned 'current'")
                reference = (
                    _points_of(out["reference"], "returned 'reference'")
                    if out.get("reference") is not None else None
                )
            else:
                current, reference = _points_of(out, "the returned interface"), None
            return _result_from_points(params, current, reference, time.perf_counter() - t0)
        except Exception as exc:  # noqa: BLE001 - the model's failure is data, not a crash
            return failed_result(
                params, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0,
                log_tail=traceback.format_exc()[-2000:],
            )


_ARG_FIELD = re.compile(r"\{([A-Za-z_][A-Za-z0-9_.]*)\}")
_PLAIN_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*")


def _run_command(argv: list[str], cwd: Path, log: int, time_limit_s: float) -> tuple[int, str]:
    """Run ``argv`` (no shell) in its own session with stdout/stderr to the open file
    descriptor ``log`` (closed here).

    Returns the exit status and a failure reason ("" on success). Whatever the
    command leaves running when it ends or when its time limit is reached (an
    MPI launcher's ranks, a wrapper script's solver) is killed with the whole
    session, and the command dies with the solve process if that is killed.
    """
    import signal

    deadline = time.monotonic() + time_limit_s
    with open(log, "wb", closefd=True) as fh:
        try:
            proc = subprocess.Popen(argv, cwd=cwd, stdout=fh, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True,
                                    preexec_fn=partial(die_with_parent, os.getpid()))  # noqa: PLW1509 - no threads start in the child
        except (OSError, ValueError, subprocess.SubprocessError) as exc:
            return -1, f"command could not be started: {exc}"
        timed_out = False
        try:
            # wait without reaping, so that the session id cannot be reused meanwhile
            while not os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT):
                if time.monotonic() >= deadline:
                    timed_out = True
                    break
                time.sleep(0.02)
        finally:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            proc.wait()
    if timed_out:
        return -1, f"command exceeded its time limit of {time_limit_s:g} s (killed)"
    rc = proc.returncode
    return rc, "" if rc == 0 else f"command exited with status {rc}"


#: flags of every file the command model opens in its work folder: a link there is
#: never followed (O_NOFOLLOW, where the platform has it)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)


def _fresh_folder(path: Path) -> int:
    """Make ``path`` a new, empty folder and return a file descriptor of it.

    Whatever is at ``path`` goes first, without following a link: a folder with its
    content (:func:`shutil.rmtree`, which removes links inside a folder and never
    what they point to), a file or a link itself. The folder is then created anew
    (``os.mkdir``: it fails if something took the name meanwhile) and opened without
    following a link.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        pass
    else:
        if stat.S_ISDIR(st.st_mode):
            shutil.rmtree(path)
        else:
            os.unlink(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkdir(path)
    return os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | _NOFOLLOW)


def _create(folder: int, name: str) -> int:
    """A new file ``name`` in the folder open as ``folder``, for writing: never an
    existing file, never through a link."""
    return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666, dir_fd=folder)


def _log_tail(path: Path, n: int = 2000) -> str:
    """Last ``n`` bytes of a log file as text (without reading a huge log whole; a
    link is not followed)."""
    try:
        with open(os.open(path, os.O_RDONLY | _NOFOLLOW), "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - n))
            return fh.read().decode(errors="replace")
    except OSError:
        return ""


class CommandModel:
    """Forward model run as an external command (no shell).

    Parameters
    ----------
    template
        Path of a Jinja2 input template. Parameter values are available by
        target name (``{{ E }}``) and as ``{{ params["material.E"] }}``; all
        are Python floats, so only numbers reach the file.
    command
        Argument list. ``{input}``, ``{output}``, ``{workdir}`` are replaced
        by absolute paths; ``{NAME}`` by the number of parameter ``NAME``. No shell
        is involved, so no value can change the command. It runs with the work
        folder as its current folder (so the bare file names work as well).
    input_name, output_name
        File names inside the work folder.
    workdir
        The run's work folder, named ``<something>.work``: every solve removes it
        and creates it empty (the name guards against emptying any other folder).
    time_limit_s
        Wall-clock limit of the command.
    """

    def __init__(self, template: str | Path, command: list[str], *, input_name: str,
                 output_name: str, workdir: str | Path, time_limit_s: float = 600.0,
                 units: str = "mm"):
        import jinja2

        tpath = Path(template)
        if not tpath.is_file():
            raise ForwardModelError(f"forward_model.command.template: file '{tpath}' does not exist")
        if not command or not all(isinstance(a, str) for a in command):
            raise ForwardModelError("forward_model.command.command must be a non-empty list of strings")
        from jinja2.sandbox import SandboxedEnvironment

        for key, name in (("input_name", input_name), ("output_name", output_name)):
            if not _PLAIN_NAME.fullmatch(str(name)) or name == "solver.log":
                raise ForwardModelError(
                    f"forward_model.command.{key}: '{name}' must be a plain file name inside "
                    "the run's work folder (letters, digits, _ . -; no folder, not solver.log)")
        if input_name == output_name:
            raise ForwardModelError("forward_model.command: input_name and output_name must differ")
        if Path(workdir).suffix != ".work":
            raise ForwardModelError(
                f"command model: the work folder '{workdir}' must be named <name>.work: it "
                "is deleted and created empty before every solve, and a folder of any other "
                "name is never deleted")
        # a template renders numbers into a file; it never needs Python's internals
        env = SandboxedEnvironment(undefined=jinja2.StrictUndefined, keep_trailing_newline=True)
        try:
            self.template = env.from_string(tpath.read_text())
        except jinja2.TemplateSyntaxError as exc:
            raise ForwardModelError(
                f"forward_model.command.template '{tpath}': syntax error line {exc.lineno}: {exc.message}"
            ) from None
        self.template_path = tpath
        self.command = list(command)
        self.input_name = input_name
        self.output_name = output_name
        self.workdir = Path(os.path.abspath(workdir))
        self.time_limit_s = float(time_limit_s)
        self.units = units

    def _values(self, params: Mapping[str, float]) -> dict[str, Any]:
        values: dict[str, Any] = {}
        for k, v in params.items():
            fv = float(v)  # numbers only, by construction
            if not math.isfinite(fv):
                raise ForwardModelError(f"parameter '{k}' has non-finite value {v!r}")
            values[k] = fv
        return values

    def render_input(self, params: Mapping[str, float]) -> str:
        import jinja2

        values = self._values(params)
        ctx: dict[str, Any] = {k: v for k, v in values.items() if k.isidentifier()}
        ctx["params"] = values
        try:
            return self.template.render(**ctx)
        except jinja2.UndefinedError as exc:
            raise ForwardModelError(
                f"forward_model.command.template '{self.template_path}': {exc.message}; "
                f"available: {', '.join(sorted(values))}"
            ) from None
        except jinja2.exceptions.SecurityError as exc:
            raise ForwardModelError(
                f"forward_model.command.template '{self.template_path}': not allowed in a "
                f"template: {exc}") from None

    def argv(self, params: Mapping[str, float], input_path: Path, output_path: Path) -> list[str]:
        values = self._values(params)
        paths = {"input": str(input_path), "output": str(output_path), "workdir": str(self.workdir)}

        def sub(m: re.Match) -> str:
            name = m.group(1)
            if name in paths:
                return paths[name]
            if name in values:
                return repr(values[name])
            raise ForwardModelError(
                f"forward_model.command.command: unknown placeholder '{{{name}}}'; "
                f"available: {', '.join(sorted([*paths, *values]))}"
            )

        return [_ARG_FIELD.sub(sub, a) for a in self.command]

    def solve(self, params: Mapping[str, float]) -> SolveResult:
        from bayescalib.io.observations import read_interface

        t0 = time.perf_counter()
        text = self.render_input(params)
        inp = self.workdir / self.input_name
        out = self.workdir / self.output_name
        argv = self.argv(params, inp, out)
        try:
            folder = _fresh_folder(self.workdir)
        except OSError as exc:
            raise ForwardModelError(
                f"command model: the work folder '{self.workdir}' could not be made empty "
                f"({exc}); remove it by hand") from None
        try:
            with open(_create(folder, self.input_name), "w") as fh:
                fh.write(text)
            log = _create(folder, "solver.log")
            rc, reason = _run_command(argv, self.workdir, log, self.time_limit_s)
            try:
                found = os.stat(self.output_name, dir_fd=folder, follow_symlinks=False)
            except FileNotFoundError:
                found = None
        finally:
            os.close(folder)
        tail = _log_tail(self.workdir / "solver.log")
        wall = time.perf_counter() - t0
        if rc != 0:
            return failed_result(params, reason, wall, log_tail=tail)
        if found is not None and stat.S_ISLNK(found.st_mode):
            return failed_result(params, f"the command's output '{out.name}' is a link: it "
                                         "is not followed (write the file itself)", wall,
                                 log_tail=tail)
        if found is None or not stat.S_ISREG(found.st_mode) or found.st_size == 0:
            return failed_result(params, f"command wrote no output file '{out.name}'", wall,
                                 log_tail=tail)
        try:
            iface = read_interface(out, units=self.units)
            return _result_from_points(params, np.asarray(iface.points), None, wall)
        except Exception as exc:  # noqa: BLE001 - any unreadable output is a failed run
            return failed_result(params, f"unreadable output '{out.name}': {exc}", wall,
                                 log_tail=tail)


class FSIForward:
    """The built-in NGSolve FSI model (:class:`bayescalib.models.fsi.model.FSIModel`).

    Parameters
    ----------
    fsi_config
        The ``forward_model.fsi`` section.
    warm_start
        State file (``.npz`` from :meth:`FSIModel.save_state`) to start from.
    time_limit_s
        Wall-clock limit of one solve (the solver's own limit).
    vtu_path
        When given, the fields of every solve are written there (ParaView).
    state_path
        When given, the converged state of every successful solve is saved there.
    """

    def __init__(self, fsi_config: Mapping[str, Any], warm_start: str | Path | None = None,
                 time_limit_s: float | None = None, vtu_path: str | Path | None = None,
                 state_path: str | Path | None = None):
        from bayescalib.models.fsi.model import FSIModel

        self.model = FSIModel(dict(fsi_config))
        self.warm_start = warm_start
        self.time_limit_s = time_limit_s
        self.vtu_path = vtu_path
        self.state_path = state_path

    def next_point(self, vtu_path: str | Path | None = None,
                   state_path: str | Path | None = None) -> None:
        """Prepare this model for another design point: its extra outputs, and
        :meth:`~bayescalib.models.fsi.model.FSIModel.forget_solves` (only the mesh, the
        spaces and the compiled forms are kept, so the point's result is bit for bit that
        of a new model)."""
        self.vtu_path, self.state_path = vtu_path, state_path
        self.model.forget_solves()

    def solve(self, params: Mapping[str, float]) -> SolveResult:
        res = self.model.solve(dict(params), warm_start=self.warm_start,
                               time_limit=self.time_limit_s)
        self._extra_outputs(res)
        return res

    def _extra_outputs(self, res: SolveResult) -> None:
        if self.vtu_path is not None and res.status == "ok":
            self.model.write_vtu(self.vtu_path)
            res.stats["vtu"] = str(self.vtu_path)
        if self.state_path is not None and res.status == "ok":
            self.model.save_state(self.state_path)
            res.stats["state_file"] = str(self.state_path)

    def solve_loadings(self, params: Mapping[str, float], parameter: str,
                       factors: list[float], nominal: float | None) -> list[SolveResult]:
        """Series of loadings by continuation in the inflow rate (see
        :meth:`bayescalib.models.fsi.model.FSIModel.solve_loadings`); VTU/state of the last one."""
        if parameter != "inflow.rate":
            raise ForwardModelError(
                f"forward_model.loadings.parameter: the fsi model loads 'inflow.rate', "
                f"not '{parameter}'"
            )
        overrides = dict(params)
        if nominal is not None and parameter not in overrides:
            overrides[parameter] = float(nominal)
        results = self.model.solve_loadings(overrides, factors, warm_start=self.warm_start,
                                            time_limit=self.time_limit_s)
        self._extra_outputs(results[-1])
        return results


def loading_factors(fm: Mapping[str, Any]) -> list[float]:
    """The loading factors of a forward-model section; [] where it has no loadings (the
    section as a solve gets it with a single loading, which
    :meth:`bayescalib.study.Study.forward_section` leaves out, or ``loadings: {}``, the
    base solve's)."""
    loadings = fm.get("loadings")
    return [float(f) for f in loadings["factors"]] if loadings else []


def loading_labels(factors: list[float]) -> list[str]:
    """Snapshot labels of a series of loadings, e.g. ``["load_0", "load_0.5", "load_1"]``."""
    return [f"load_{float(f):g}" for f in factors]


def solve_series(model: ForwardModel, params: Mapping[str, float],
                 loadings: Mapping[str, Any] | None) -> SolveResult:
    """Solve ``model`` at ``params`` for every loading of ``loadings`` and combine.

    Parameters
    ----------
    model
        A forward model; one with a ``solve_loadings`` method (fsi) solves the series
        by continuation, any other is called once per loading with the loaded
        parameter set to ``factor * nominal``.
    params
        Parameter values by target.
    loadings
        The ``forward_model.loadings`` section (``parameter``, ``nominal``,
        ``factors``); ``None`` or ``factors == [1.0]`` is a single solve.

    Returns
    -------
    SolveResult
        ``ok`` when every loading converged. ``loadings`` holds one interface per
        factor (in order); ``interface_current`` is the one at factor 1 if present,
        else at the largest factor. On failure the reason names the loading.
    """
    if not loadings:
        return model.solve(params)
    factors = [float(f) for f in loadings["factors"]]
    if factors == [1.0]:
        return model.solve(params)
    key = str(loadings["parameter"])
    nominal = loadings.get("nominal")
    t0 = time.perf_counter()
    solve_loadings = getattr(model, "solve_loadings", None)
    if solve_loadings is not None:
        results = solve_loadings(params, key, factors, nominal)
    else:
        base = params.get(key, nominal)
        if base is None:
            raise ForwardModelError(
                f"forward_model.loadings.nominal is required: '{key}' is not a calibrated "
                "parameter of this study"
            )
        results = [model.solve({**params, key: f * float(base)}) for f in factors]
    labels = loading_labels(factors)
    failed = [(lab, r) for lab, r in zip(labels, results) if not r.ok]
    primary = factors.index(1.0) if 1.0 in factors else int(np.argmax(factors))
    first = results[primary]
    combined_params = {k: float(v) for k, v in params.items()}
    if key not in combined_params:  # the nominal value of a loaded parameter not calibrated
        if nominal is not None:
            combined_params[key] = float(nominal)
        elif key in first.parameters and factors[primary] > 0:
            combined_params[key] = float(first.parameters[key]) / factors[primary]
    stats = dict(first.stats)
    stats.update(n_loadings=len(factors), loadings_wall_time=time.perf_counter() - t0)
    for extra in ("newton_per_step", "failed_steps"):  # per loading, in the order given
        parts = [f"[{lab}] {r.stats[extra]}" for lab, r in zip(labels, results)
                 if r.stats.get(extra)]
        if parts:
            stats[extra] = " ".join(parts)
    if failed:
        reason = "; ".join(f"loading {lab}: {r.reason}" for lab, r in failed)
        res = failed_result(combined_params, reason, time.perf_counter() - t0, **stats)
        res.load_fraction = float(min(r.load_fraction for _, r in failed))
        return res
    return SolveResult(
        status="ok",
        reason="",
        parameters={**combined_params,
                    **{k: v for k, v in first.parameters.items() if k not in combined_params}},
        load_fraction=1.0,
        newton_iterations=int(sum(r.newton_iterations for r in results)),
        load_steps=int(sum(r.load_steps for r in results)),
        wall_time=time.perf_counter() - t0,
        interface_reference=first.interface_reference,
        interface_current=first.interface_current,
        segments=first.segments,
        max_displacement=float(max(r.max_displacement for r in results)),
        stats=stats,
        loadings=[LoadingResult(lab, f, float(r.parameters.get(key, float("nan"))),
                                r.interface_current)
                  for lab, f, r in zip(labels, factors, results)],
    )


def make_forward_model(fm: Mapping[str, Any], *, workdir: str | Path = ".",
                       warm_start: str | Path | None = None,
                       extra_outputs: Mapping[str, str] | None = None) -> ForwardModel:
    """Build the forward model described by a validated ``forward_model`` section.

    ``extra_outputs`` may name a ``vtu`` and a ``state`` path (fsi only).
    """
    kind = fm["type"]
    extra = dict(extra_outputs or {})
    if kind == "fsi":
        return FSIForward(fm["fsi"], warm_start=warm_start, time_limit_s=fm["time_limit_s"],
                          vtu_path=extra.get("vtu"), state_path=extra.get("state"))
    if kind == "python":
        py = fm["python"]
        return PythonModel(py["function"], py.get("options"))
    if kind == "command":
        c = fm["command"]
        return CommandModel(
            c["template"], c["command"], input_name=c["input_name"],
            output_name=c["output_name"], workdir=workdir,
            time_limit_s=fm["time_limit_s"], units=c["units"],
        )
    raise ForwardModelError(
        f"forward_model.type: unknown forward model type {kind!r} (expected fsi, python or command)"
    )


def log_solve(res: SolveResult, out_path: str | Path) -> None:
    """One log record per solve: status, values, time, load steps and Newton iterations
    (per step when the model records them), the reason of a failure."""
    values = ", ".join(f"{k} = {v:.6g}" for k, v in res.parameters.items())
    text = (f"solve {Path(out_path).name}: {res.status} at {values} in {res.wall_time:.2f} s; "
            f"{res.load_steps} load step(s), {res.newton_iterations} Newton iteration(s), "
            f"load fraction reached {res.load_fraction:.3g}")
    if res.stats.get("newton_per_step"):
        text += f"; Newton per load step (load:iterations) {res.stats['newton_per_step']}"
    if res.stats.get("failed_steps"):
        text += f"; failed steps: {res.stats['failed_steps']}"
    if not res.ok:
        text += f"; reason: {res.reason}"
    (log.info if res.ok else log.warning)(text)


def _same_inputs(run: SolveResult, params: Mapping[str, Any]) -> bool:
    """Whether a run record was solved at ``params`` (switches are not recorded)."""
    for k, v in params.items():
        if isinstance(v, bool):
            continue
        if k not in run.parameters or abs(run.parameters[k] - float(v)) > 1e-12 * max(1.0, abs(float(v))):
            return False
    return True


class _Evaluator:
    """Builds the forward model of a design point and solves it (:func:`solve_series`).

    The fsi model is kept from one point to the next, with only what is bit-neutral:
    its mesh, spaces and compiled forms (rebuilt when a point's switches change them);
    before every point it forgets its solver state (:meth:`FSIForward.next_point`: no
    kept factorization, no last state), so each result is bit for bit that of a new
    model. A Python or command model is made anew for every point (cheap: the module
    stays imported; the command's work folder is the point's own). After a solve that
    raised, the kept model is dropped (it may be half built).
    """

    def __init__(self, fm: Mapping[str, Any], warm_start: str | Path | None) -> None:
        self.fm, self.warm_start = fm, warm_start
        self.fsi: FSIForward | None = None

    def solve(self, params: Mapping[str, Any], workdir: str | Path,
              extra: Mapping[str, str]) -> SolveResult:
        try:
            if self.fm["type"] == "fsi":
                if self.fsi is None:
                    model = make_forward_model(self.fm, warm_start=self.warm_start)
                    assert isinstance(model, FSIForward)
                    self.fsi = model
                self.fsi.next_point(extra.get("vtu"), extra.get("state"))
                model = self.fsi
            else:
                model = make_forward_model(self.fm, workdir=workdir, warm_start=self.warm_start,
                                           extra_outputs=extra)
            return solve_series(model, params, self.fm.get("loadings"))
        except BaseException:
            self.fsi = None
            raise


def _worker(fm: Mapping[str, Any], warm_start: str | None, conn, parent: int) -> None:
    """A solve process: solves the points it is sent, one at a time, with one
    :class:`_Evaluator`, and sends each result back; ends at ``None`` or when its
    parent closes the pipe."""
    die_with_parent(parent)  # a killed job takes its solves with it
    evaluator = _Evaluator(fm, warm_start)
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            break
        if job is None:
            break
        params, workdir, extra = job
        try:
            res = evaluator.solve(params, workdir, extra)
        except BaseException as exc:  # noqa: BLE001 - any failure is recorded
            res = failed_result(params, f"{type(exc).__name__}: {exc}",
                                log_tail=traceback.format_exc()[-2000:])
        conn.send(res)
    conn.close()


class _Job:
    """One design point to solve: its values, run record, work folder and extra outputs."""

    def __init__(self, index: int, params: Mapping[str, Any], out: Path, workdir: Path,
                 extra: Mapping[str, str]) -> None:
        self.index, self.params, self.out, self.workdir = index, dict(params), out, workdir
        self.extra = dict(extra)


class _Worker:
    """A forked solve process (:func:`_worker`) and the point it is solving."""

    def __init__(self, ctx, fm: Mapping[str, Any], warm_start: str | Path | None) -> None:
        self.conn, child = ctx.Pipe(duplex=True)
        self.proc = ctx.Process(target=_worker, args=(
            dict(fm), None if warm_start is None else str(warm_start), child, os.getpid()))
        self.proc.start()
        child.close()
        self.job: _Job | None = None
        self.t0 = 0.0
        self.eof = False

    def start(self, job: _Job) -> None:
        self.job, self.t0, self.eof = job, time.perf_counter(), False
        with contextlib.suppress(OSError):  # a process gone meanwhile: seen as EOF
            self.conn.send((job.params, str(job.workdir), job.extra))

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def result(self) -> SolveResult | None:
        """The result of the current point if it came (``None``: not yet, or never:
        :attr:`eof` says that the process has gone)."""
        try:
            if self.conn.poll(0):
                return self.conn.recv()
        except (EOFError, OSError):
            self.eof = True
        return None

    def failure(self, hard: float | None) -> SolveResult:
        """End the process; the failed-run record of its point."""
        assert self.job is not None
        wall = self.elapsed()
        self.proc.join(timeout=5.0 if self.eof else 0.1)
        self.stop()
        if hard is not None and wall >= hard:
            return failed_result(self.job.params,
                                 f"killed after exceeding the time limit ({hard:g} s)", wall)
        return failed_result(self.job.params,
                             f"solver process died (exit code {self.proc.exitcode})", wall)

    def stop(self, wait: float = 0.0) -> None:
        """End the process: after ``wait`` seconds for it to exit, killed."""
        if wait > 0:
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
            self.proc.join(timeout=wait)
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join()
        self.conn.close()


def _hard_limit(fm: Mapping[str, Any], time_limit_s: float | None, grace_s: float) -> float | None:
    limit = time_limit_s if time_limit_s is not None else fm.get("time_limit_s")
    return None if limit is None else float(limit) + float(grace_s)


def _finish(job: _Job, res: SolveResult, results: dict[int, SolveResult]) -> None:
    write_run(job.out, res)
    log_solve(res, job.out)
    results[job.index] = res


def _start_method() -> str:
    """How solve processes start: forked (cheap: the caller's imports are shared), unless
    Netgen has generated a mesh in this process or one it was forked from
    (:data:`bayescalib.models.fsi.geometry.MESHED`): a process forked after that hangs in
    its own mesh generation, so they start from a fresh interpreter (``spawn``: a
    script calling this must then guard its top level with ``if __name__ ==
    "__main__":``, as multiprocessing requires; not ``forkserver``, whose processes are
    not children of this one)."""
    geometry = sys.modules.get("bayescalib.models.fsi.geometry")
    if "fork" in mp.get_all_start_methods() and not getattr(geometry, "MESHED", False):
        return "fork"
    return "spawn"


def _solve_isolated(fm: Mapping[str, Any], jobs: list[_Job], workers: int,
                    warm_start: str | Path | None, hard: float | None) -> dict[int, SolveResult]:
    """Solve ``jobs`` in at most ``workers`` forked solve processes that keep their model
    from one point to the next; a point that crashes its process or runs past ``hard``
    seconds is a failed run, and its process is replaced for the next point."""
    ctx = mp.get_context(_start_method())
    todo = list(jobs)
    idle: list[_Worker] = []
    busy: list[_Worker] = []
    results: dict[int, SolveResult] = {}
    try:
        while todo or busy:
            while todo and len(busy) < max(int(workers), 1):
                w = idle.pop() if idle else _Worker(ctx, fm, warm_start)
                w.start(todo.pop(0))
                busy.append(w)
            left = [hard - w.elapsed() for w in busy] if hard is not None else []
            mp.connection.wait([w.conn for w in busy],
                               timeout=max(min(left), 0.0) if left else None)
            for w in list(busy):
                res = w.result()
                if res is None:
                    if not w.eof and (hard is None or w.elapsed() < hard):
                        continue  # still solving
                    res = w.failure(hard)
                else:
                    idle.append(w)
                busy.remove(w)
                assert w.job is not None
                _finish(w.job, res, results)
                w.job = None
    finally:
        for w in busy:
            w.stop()
        for w in idle:
            w.stop(wait=5.0)
    return results


def solve_points(fm: Mapping[str, Any], points: Sequence[Mapping[str, Any]],
                 out_paths: Sequence[str | Path], *, workers: int = 1,
                 warm_start: str | Path | None = None, grace_s: float = 30.0,
                 time_limit_s: float | None = None,
                 workdirs: Sequence[str | Path | None] | None = None,
                 extra_outputs: Sequence[Mapping[str, str] | None] | None = None,
                 isolate: bool = True, reuse: bool = True) -> list[SolveResult]:
    """Solve the forward model at ``points`` and write one run record per point: the one
    solve path of the package (the workflow's ``solve`` jobs through :func:`solve_point`,
    the base state, the posterior-mean and predictive solves, the diagnosis, the
    ``bayescalib solve`` command).

    Every point is solved in a forked, time-limited process, so that a crash, a hang
    or a segmentation fault inside a solver ends as a failed-run record
    (``status == "failed"`` with the reason) instead of taking the caller down; every
    record is written atomically, whatever happens. Up to ``workers`` such processes
    run side by side. A process solves point after point and keeps its model in
    between where that is bit-neutral (:class:`_Evaluator`: the fsi model's mesh,
    spaces and compiled forms; its solver state is forgotten before every point), so
    each record is bit for bit what a new model gives, whichever process solved which
    points before. A point that kills its process or runs past its limit fails alone:
    its process is ended and the next point gets a new one.

    The solve processes are forked, unless this process (or one it was forked from) has
    generated a Netgen mesh: a process forked after that hangs in its own mesh
    generation (NGSolve 6.2.2608), so they then start from a fresh interpreter
    (:func:`_start_method`; the workflow's jobs, the diagnosis and the command line never
    mesh before they solve, and fork).

    Parameters
    ----------
    fm
        Validated ``forward_model`` section (``loadings`` included).
    points
        Parameter values keyed by target, plus switches such as
        ``physics.growth.enabled: True``, one mapping per point.
    out_paths
        One run-record path per point.
    workers
        Solve processes at a time.
    warm_start
        State file every solve starts from (fsi only).
    grace_s
        Extra seconds past the time limit before a process is killed, so that the
        model's own time limit (which records how far it got) acts first.
    time_limit_s
        Wall-clock limit of one point (``fm["time_limit_s"]`` when None; no limit
        when neither is given); the process is killed ``grace_s`` after it.
    workdirs
        Work folder per point (a command model's; None: ``<run record>.work``).
    extra_outputs
        Per point, ``{"vtu": path, "state": path}`` written by the fsi model on success
        (or None).
    isolate
        ``False`` solves in this process, one point after the other (tests of cheap
        models): no time limit, and a :class:`ForwardModelError` (a misconfigured
        model) is raised instead of recorded.
    reuse
        Keep a run record that exists, reads and was solved at the same values (an
        interrupted stage resumes without redoing finished solves). ``False`` solves
        every point.

    Returns
    -------
    list of SolveResult
        In the order of ``points``: the records written (or kept).
    """
    from bayescalib.io.runrecord import RunFileError, read_run

    if len(points) != len(out_paths):
        raise ValueError("solve_points: one output path per point is needed")
    n = len(points)
    dirs = list(workdirs) if workdirs is not None else [None] * n
    extras = list(extra_outputs) if extra_outputs is not None else [None] * n
    if len(dirs) != n or len(extras) != n:
        raise ValueError("solve_points: one work folder and one extra_outputs per point")
    results: dict[int, SolveResult] = {}
    jobs: list[_Job] = []
    for i, (p, out) in enumerate(zip(points, out_paths, strict=True)):
        out = Path(out)
        if reuse and out.is_file():
            try:
                run = read_run(out)
                if _same_inputs(run, p):
                    results[i] = run
                    continue
            except RunFileError:
                pass  # corrupt or incomplete: solve again
        out.parent.mkdir(parents=True, exist_ok=True)
        jobs.append(_Job(i, p, out, Path(dirs[i]) if dirs[i] is not None
                         else out.with_suffix(".work"), extras[i] or {}))
    if n > 1:
        log.info("solves: %d of %d to do (%d reused), %d at a time", len(jobs), n,
                 n - len(jobs), workers)
    if isolate:
        results.update(_solve_isolated(fm, jobs, workers, warm_start,
                                       _hard_limit(fm, time_limit_s, grace_s)))
    else:
        evaluator = _Evaluator(fm, warm_start)
        for job in jobs:
            try:
                res = evaluator.solve(job.params, job.workdir, job.extra)
            except ForwardModelError:
                raise
            except Exception as exc:  # noqa: BLE001 - a failed solve is data
                res = failed_result(job.params, f"{type(exc).__name__}: {exc}",
                                    log_tail=traceback.format_exc()[-2000:])
            _finish(job, res, results)
    return [results[i] for i in range(n)]


def solve_point(fm: Mapping[str, Any], params: Mapping[str, float], out_path: str | Path, *,
                time_limit_s: float | None = None, warm_start: str | Path | None = None,
                workdir: str | Path | None = None, isolate: bool = True,
                extra_outputs: Mapping[str, str] | None = None,
                grace_s: float = 30.0) -> SolveResult:
    """:func:`solve_points` at one point, always solved (an existing record is
    replaced): the workflow's ``solve`` job, the ground truth, the posterior-mean solve.

    Parameters
    ----------
    fm
        Validated ``forward_model`` config section.
    params
        Parameter values keyed by target (user units).
    out_path
        HDF5 run record to write (atomically), whatever happens.
    time_limit_s, warm_start, isolate, grace_s
        As in :func:`solve_points`.
    workdir
        The point's work folder (None: ``<out_path>.work``).
    extra_outputs
        Optional ``{"vtu": path, "state": path}`` written by the fsi model on success.

    Returns
    -------
    SolveResult
        The record that was written.
    """
    return solve_points(fm, [params], [out_path], time_limit_s=time_limit_s,
                        warm_start=warm_start, workdirs=[workdir], isolate=isolate,
                        extra_outputs=[extra_outputs], grace_s=grace_s, reuse=False)[0]


def solve_base_state(fm: Mapping[str, Any], params: Mapping[str, float], run_path: str | Path,
                     state_path: str | Path) -> SolveResult:
    """Solve at ``params`` (the design-box centre) and save the warm-start state: one
    point of :func:`solve_points` at the nominal loading only (``loadings: {}``: the
    design-point solves start from a state at factor 1), with the state as an extra
    output.

    Raises
    ------
    ForwardModelError
        If the base solve fails: the design-point solves cannot start from it.
    """
    single = {**fm, "loadings": {}}
    res = solve_point(single, params, run_path, extra_outputs={"state": str(state_path)})
    if res.status != "ok" or not Path(state_path).is_file():
        raise ForwardModelError(
            f"the warm-start base solve at the design-box centre {dict(params)} failed "
            f"({res.reason}); set forward_model.warm_start: none or change the bounds"
        )
    return res
