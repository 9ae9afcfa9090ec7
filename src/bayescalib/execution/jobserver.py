"""A warm process that runs the jobs of a local run (per point: solve, discrepancy;
per round and per measure: train_surrogate, smc, acquire, marginalize; the figures and
summary.json).

Why
---
Each design point is its own Snakemake job, cached on its own (the user's design). A
``script:`` job starts a fresh interpreter, unpickles Snakemake's job object and
imports numpy, scipy, h5py and NGSolve before any physics: about a second a job,
several times the cost of a solve on the default mesh, and nearly all of a
discrepancy job; GPy, torch and ArviZ add about two seconds to every surrogate, SMC
and acquisition job of every active-design round. Here the imports are paid once per
run: the workflow's ``onstart`` starts the servers (below), which import the stage
code, open a Unix socket each and then serve. A job is
a tiny client (``scripts/job.py``, standard library only, started with
``python -I -S``) that hands the server its arguments, its working directory, its
environment and its stdout/stderr (file descriptors passed over the socket); the
server forks a child that runs the stage in that setting and reports the child's
exit status, which the client exits with.

What a job keeps
----------------
* Isolation: every job runs in its own forked process, in its own process group; a
  solve is moreover evaluated in a forked, time-limited grandchild
  (:func:`bayescalib.models.forward.solve_point`), so a crash, a hang or ``os._exit`` in the
  model is a failed run record, as before.
* Killing: if the client goes away (Snakemake cancels the job, or is killed), the
  server kills the job's process group. If Snakemake itself dies, the server notices
  within a second (its parent changed), kills every job it runs and exits.
* Cache keys: the rules' params are unchanged; the job receives exactly them.
* No server (a cluster executor, a run without ``onstart``, a server that failed to
  start): the client runs the same stage in-process (``python -m
  bayescalib.execution.jobserver --run``), with the full imports: slower, same result.

Two servers
-----------
A run starts two servers side by side (:func:`start_server`): the *point* server
(``BAYESCALIB_JOBSERVER``) imports only what the per-point jobs need (NumPy, h5py,
NGSolve, the measures: about 2 s) and serves at once; the *round* server
(``BAYESCALIB_JOBSERVER_ROUND``) imports GPy, ArviZ, Matplotlib (and torch where a GPU
can exist) for the per-round, per-measure, figure and summary stages
(:data:`ROUND_STAGES`); it also draws one throw-away figure
(:func:`bayescalib.plotting.style.warm_up`) so that the figure jobs inherit the fonts
and the mathtext grammar.
Measured on the smoke study: with one server, the solves that arrived during its
12 s of GPy/torch/ArviZ imports waited for them, and every per-point job forked from
a 460 MB process instead of a 160 MB one (fork, copy-on-write and exit about 0.1 s
more per job). A per-round job that arrives before the round server is up goes to
the point server (its child imports what it needs): slower, same result. Both
servers freeze their imported objects (:func:`gc.freeze`) before they fork jobs, so a
child's garbage collections do not touch (and copy) the server's pages.

Protocol (``AF_UNIX``, ``SOCK_SEQPACKET``, one request per connection): the client
sends one JSON message ``{"stage", "argv", "cwd", "env"}`` with two file
descriptors (its stdout and stderr); the server answers ``{"exit": code}`` when the
job has ended. ``argv`` is the job's ``KEY VALUE ...`` words (:func:`parse_args`: a
value ``[`` opens a list of paths closed by ``]``, for the stages that read many files).
"""

from __future__ import annotations

import array
import ast
import gc
import hashlib
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from bayescalib._process import die_with_parent

__all__ = ["ROUND_STAGES", "STAGES", "export_job_command", "parse_args", "run_stage", "serve",
           "socket_path", "start_server", "stop_server"]

#: environment variable through which the jobs of a run find its point server
SOCKET_ENV = "BAYESCALIB_JOBSERVER"
#: ... and its round server (the stages of :data:`ROUND_STAGES`)
ROUND_SOCKET_ENV = "BAYESCALIB_JOBSERVER_ROUND"
_MAX_MESSAGE = 1 << 20
#: the servers this process started (start_server), stopped by stop_server
_SERVERS: list[subprocess.Popen] = []


class _Stop(Exception):
    """Raised by the server's SIGTERM handler: ends its loop at once."""


# ----------------------------------------------------------------------------- stages


def parse_args(words: list[str]) -> dict[str, Any]:
    """A job's ``KEY VALUE ...`` words as a mapping: each value is a string, or a list of
    strings where the value is the word ``[`` (the list ends at the word ``]``: the
    rule's command writes ``runs [ {input.runs:q} ]``). A last key without a value (an
    empty input formatted by Snakemake) is left out.

    >>> parse_args(["out", "a.h5", "runs", "[", "r/0.h5", "r/1.h5", "]", "n", "3"])
    {'out': 'a.h5', 'runs': ['r/0.h5', 'r/1.h5'], 'n': '3'}
    """
    out: dict[str, Any] = {}
    k = 0
    while k + 1 < len(words):
        key, value = words[k], words[k + 1]
        k += 2
        if value == "[":
            end = words.index("]", k) if "]" in words[k:] else len(words)
            out[key] = list(words[k:end])
            k = end + 1
        else:
            out[key] = value
    return out


def _literal(text: str) -> Any:
    """A params value as Snakemake formats it into the shell command (Python literal)."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError) as exc:
        raise ValueError(f"job argument is not a Python literal: {text[:200]!r} ({exc})") from None


def _solve(args: Mapping[str, str]) -> None:
    from bayescalib.models.forward import solve_point
    from bayescalib.stages import read_stage_file, setup_logging

    setup_logging(args["log"])
    base = args.get("base") or None
    if base is not None:  # a damaged state is set aside and rebuilt, never solved from
        read_stage_file(base, "warm-start state")
    solve_point(_literal(args["forward_model"]), _literal(args["point"]), args["out"],
                warm_start=base)


def _discrepancy(args: Mapping[str, str]) -> None:
    from bayescalib.stages import discrepancy, setup_logging

    setup_logging(args["log"])
    discrepancy(args["run"], args["obs"], args["measure_name"], _literal(args["measure"]),
                _literal(args["likelihood"]), args["out"])


def _train_surrogate(args: Mapping[str, str]) -> None:
    from bayescalib.stages import setup_logging, train_surrogate

    setup_logging(args["log"])
    previous = args.get("previous") or []  # a list: empty in round 0 and for a measure
    train_surrogate(args["training"], _literal(args["surrogate"]), _literal(args["parameters"]),
          args["out"], reuse=args.get("reuse") or (),
          previous=previous[0] if isinstance(previous, list) and previous else None,
          threads=_granted_threads())


def _granted_threads() -> int:
    """The threads Snakemake granted the job (its ``threads:``), which its shell command
    receives as ``OMP_NUM_THREADS``; 1 where unset."""
    try:
        return max(1, int(os.environ.get("OMP_NUM_THREADS", "1")))
    except ValueError:
        return 1


def _smc(args: Mapping[str, str]) -> None:
    from bayescalib.stages import setup_logging, smc

    setup_logging(args["log"])
    smc(args["surrogate"], _literal(args["smc"]), _literal(args["parameters"]), args["out"],
        threads=_granted_threads(), reuse=args.get("reuse") or ())


def _acquire(args: Mapping[str, str]) -> None:
    from bayescalib.stages import acquire, setup_logging

    setup_logging(args["log"])
    acquire(int(args["round"]), args["training"], args["surrogate"], args["particles"],
            args.get("previous") or None, _literal(args["active"]), _literal(args["check"]),
            _literal(args["parameters"]), args["out"])


def _marginalize(args: Mapping[str, str]) -> None:
    from bayescalib.stages import marginalize, setup_logging

    setup_logging(args["log"])
    marginalize(args["particles"], args["surrogate"], _literal(args["posterior"]),
                _literal(args["parameters"]), int(args["seed"]), args["out"], args["netcdf"])


def _gather(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import gather, setup_logging

    setup_logging(args["log"])
    gather(args["runs"], args["disc"], _literal(args["names"]), _literal(args["targets"]),
           _literal(args["n_train"]), args["out"])


def _summary(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import (
        collect_timings,
        design_summary,
        posterior_check_summary,
        round_check_summary,
        setup_logging,
        summary,
    )

    setup_logging(args["log"])
    budget = _literal(args["budget"]) if "budget" in args else {}
    extra = {"design": design_summary(args["strategy"], args.get("active", []),
                                      int(args["n_solves"]), **budget),
             "timings_s": collect_timings(args["root"])}
    if args.get("convergence"):
        extra["gp_convergence"] = list(args["convergence"])
    if args.get("check"):  # fixed design: a list, empty when posterior_check.draws is 0
        extra["posterior_check"] = posterior_check_summary(args["check"][0])
    elif args["strategy"] == "active":  # the last check of the rounds (None: none ran)
        extra["posterior_check"] = round_check_summary(args.get("active", []))
    summary(args["study"], _literal(args["parameters"]), _literal(args["measures"]),
            args["posterior"], args["training"], args["particles"],
            _literal(args["figure_map"]), args["out"], extra=extra)


def _posterior_check(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import posterior_check, setup_logging

    setup_logging(args["log"])
    posterior_check(args["samples"], args["obs"], args["measure_name"],
                    _literal(args["measure"]), _literal(args["likelihood"]), args["surrogate"],
                    _literal(args["parameters"]), _literal(args["check"]), args["out"],
                    args["particles"])


def _predictive_solve(args: Mapping[str, Any]) -> None:
    from bayescalib.models.forward import solve_point
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import posterior_draws

    setup_logging(args["log"])
    point = posterior_draws(args["particles"], _literal(args["parameters"]), int(args["k"]),
                            int(args["n"]), int(args["seed"]))
    solve_point(_literal(args["forward_model"]), point, args["out"])


def _posterior_mean_solve(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import solve_at_posterior_mean

    setup_logging(args["log"])
    solve_at_posterior_mean(args["posterior"], _literal(args["parameters"]),
                            _literal(args["forward_model"]), args["out"], args["vtu"])


def _fig_response(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import response_figures

    setup_logging(args["log"])
    response_figures(args["training"], args["surrogate"], _literal(args["parameters"]),
                     _literal(args["plots"]), args["stem"])


def _fig_convergence(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import convergence_figure

    setup_logging(args["log"])
    convergence_figure(args["convergence"], _literal(args["plots"]), args["stem"])


def _fig_posterior(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import posterior_figures

    setup_logging(args["log"])
    posterior_figures(args["particles"], args["posterior"], _literal(args["parameters"]),
                      _literal(args["plots"]), _literal(args["stems"]))


def _fig_interfaces(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import interface_figure

    setup_logging(args["log"])
    interface_figure(args["obs"], args["samples"], _literal(args["plots"]), args["stem"],
                     ground_truth_run=args.get("truth") or None)


def _fig_fields(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import field_figure

    setup_logging(args["log"])
    field_figure(args["vtu"], args["run"], _literal(args["plots"]), args["stem"],
                 at=args.get("at") or None,
                 parameters=_literal(args["parameters"]) if "parameters" in args else None)


def _fig_segmentation(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import segmentation_figure

    setup_logging(args["log"])
    segmentation_figure(args["obs"], _literal(args["observations"]), _literal(args["plots"]),
                        args["stem"])


def _fig_rounds(args: Mapping[str, Any]) -> None:
    from bayescalib.stages import setup_logging
    from bayescalib.stages.figures import rounds_figure

    setup_logging(args["log"])
    rounds_figure(args["records"], args["particles"], args["training"],
                  _literal(args["parameters"]), _literal(args["active"]),
                  _literal(args["plots"]), args["stem"])


#: stage name -> function of the job's arguments (strings, or lists of paths, as
#: formatted by the rule's shell command and read by :func:`parse_args`). Per point:
#: solve, discrepancy, predictive_solve, posterior_mean_solve; per round (active design)
#: and per measure: gather, train_surrogate, smc, acquire, marginalize; the figures.
STAGES: dict[str, Callable[[Mapping[str, Any]], None]] = {
    "solve": _solve,
    "discrepancy": _discrepancy,
    "predictive_solve": _predictive_solve,
    "posterior_mean_solve": _posterior_mean_solve,
    "posterior_check": _posterior_check,
    "gather": _gather,
    "train_surrogate": _train_surrogate,
    "smc": _smc,
    "acquire": _acquire,
    "marginalize": _marginalize,
    "summary": _summary,
    "fig_response": _fig_response,
    "fig_convergence": _fig_convergence,
    "fig_posterior": _fig_posterior,
    "fig_interfaces": _fig_interfaces,
    "fig_fields": _fig_fields,
    "fig_rounds": _fig_rounds,
    "fig_segmentation": _fig_segmentation,
}

#: the stages the round server runs (GPy, ArviZ, Matplotlib); the others go to the point
#: server. ``scripts/job.py`` holds the same set (it imports nothing of this package).
ROUND_STAGES = frozenset({"train_surrogate", "smc", "acquire", "marginalize", "fig_response",
                          "fig_convergence", "fig_posterior", "fig_interfaces", "fig_fields",
                          "fig_rounds", "fig_segmentation", "summary", "posterior_check"})

#: what the point server imports before it accepts jobs (the heavy part of every
#: per-point job; also the modules a solve or discrepancy imports on its way, so that
#: no job compiles or loads one of its own)
_PRELOAD = ("numpy", "scipy.sparse", "scipy.spatial", "scipy.linalg", "h5py",
            "bayescalib.models.forward", "bayescalib.stages", "bayescalib.study",
            "bayescalib.measures", "bayescalib.measures.currents",
            "bayescalib.geometry.interface", "bayescalib.geometry.projection",
            "bayescalib.inference.likelihood", "bayescalib.io.observation_store",
            "bayescalib.io.runrecord", "bayescalib.io.training", "bayescalib.models.fsi.model",
            "bayescalib.models.fsi.solver", "ngsolve", "netgen.occ", "multiprocessing.popen_fork")

#: what the round server imports before it accepts jobs (torch only where a GPU may
#: be used: :func:`bayescalib.inference.gp.predictor.gpu_possible`)
_PRELOAD_ROUND = ("numpy", "scipy.linalg", "scipy.optimize", "scipy.stats", "h5py", "GPy",
                  "arviz", "matplotlib", "matplotlib.pyplot", "bayescalib.stages",
                  "bayescalib.stages.figures", "bayescalib.study", "bayescalib.inference.gp",
                  "bayescalib.inference.smc", "bayescalib.inference.active",
                  "bayescalib.inference.posterior", "bayescalib.inference.weights",
                  "bayescalib.plotting")


def run_stage(stage: str, args: Mapping[str, str]) -> None:
    """Run one job of ``stage`` with its arguments in this process."""
    try:
        fn = STAGES[stage]
    except KeyError:
        raise ValueError(f"unknown job stage {stage!r} (known: {', '.join(STAGES)})") from None
    fn(args)


# ----------------------------------------------------------------------------- server


def socket_path(root: str | Path, kind: str = "point") -> str:
    """The socket of the ``kind`` ("point" or "round") server of a run of the study
    under ``root`` (short: Unix socket paths are limited to about 100 characters)."""
    key = hashlib.sha1(str(Path(root).resolve()).encode()).hexdigest()[:16]
    tail = "" if kind == "point" else f"-{kind}"
    return os.path.join(tempfile.gettempdir(), f"bayescalib-{key}{tail}.sock")


def export_job_command(basedir: str | Path, *, conda: bool = False) -> None:
    """Set the environment variables the per-point rules' shell commands use: the
    interpreter (``BAYESCALIB_PYTHON``: this one, or ``python`` of the rule's conda
    environment) and the client script (``BAYESCALIB_JOB_CLIENT``) under the
    workflow's ``basedir``. Called when the Snakefile is parsed, so also in the
    Snakemake process a cluster job starts."""
    os.environ["BAYESCALIB_PYTHON"] = "python" if conda else sys.executable
    os.environ["BAYESCALIB_JOB_CLIENT"] = str(Path(basedir) / "scripts" / "job.py")


def start_server(root: str | Path, *, wait_s: float = 20.0) -> str | None:
    """Start the servers of this run (called by the workflow's ``onstart``) and point
    the jobs to them (``BAYESCALIB_JOBSERVER``, ``BAYESCALIB_JOBSERVER_ROUND``,
    inherited by the jobs).

    Returns the point server's socket path once it accepts jobs, or None if it did not
    come up within ``wait_s`` (jobs then run in-process; nothing is lost), or if
    ``BAYESCALIB_JOBSERVER=off`` asks for every job in a fresh interpreter. The round
    server is not waited for (its imports take longer; until it is up, its jobs go to
    the point server). Both exit when this process does. Their output goes to
    ``<root>/logs/jobserver.log``, one line per job they ran to
    ``<root>/logs/jobserver_jobs.tsv`` (the job ledger, :func:`serve`).
    """
    if os.environ.get(SOCKET_ENV) == "off":
        return None
    paths = {kind: socket_path(root, kind) for kind in ("point", "round")}
    # sockets left by a killed run of this study (this run holds the study's run
    # lock, so no live server owns them): gone, so that only new ones count as ready
    for path in paths.values():
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
    log = Path(root) / "logs" / "jobserver.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    ledger = log.with_name("jobserver_jobs.tsv")
    ledger.write_text("\t".join(LEDGER_COLUMNS) + "\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    log.write_text("")
    procs = {}
    for kind, path in paths.items():
        with open(log, "a") as fh:
            procs[kind] = subprocess.Popen(
                [sys.executable, "-m", "bayescalib.execution.jobserver", "--serve", path,
                 "--parent", str(os.getpid()), "--kind", kind, "--ledger", str(ledger)],
                stdin=subprocess.DEVNULL, stdout=fh, stderr=subprocess.STDOUT, env=env)
        _SERVERS.append(procs[kind])
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if procs["point"].poll() is not None:
            return None
        if os.path.exists(paths["point"]):
            os.environ[SOCKET_ENV] = paths["point"]
            os.environ[ROUND_SOCKET_ENV] = paths["round"]
            return paths["point"]
        time.sleep(0.02)
    return None


def stop_server(timeout: float = 10.0) -> None:
    """Stop the servers :func:`start_server` started in this process (the workflow's
    ``onsuccess``/``onerror``), so that their log is complete when the run returns.
    They would stop by themselves within a second of this process's end anyway."""
    procs = list(_SERVERS)
    _SERVERS.clear()
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class _Job:
    __slots__ = ("conn", "out", "pid", "pidfd", "stage", "t0")

    def __init__(self, conn: socket.socket, pid: int, pidfd: int, stage: str, out: str) -> None:
        self.conn, self.pid, self.pidfd, self.t0 = conn, pid, pidfd, time.monotonic()
        self.stage, self.out = stage, out


#: columns of the job ledger (:func:`serve`, ``<root>/logs/jobserver_jobs.tsv``)
LEDGER_COLUMNS = ("server", "stage", "out", "wall_s", "cpu_s", "max_rss_mb", "exit")


def _ledger_row(kind: str, job: _Job, wall: float, usage: Any, code: int) -> str:
    """One line of the job ledger: what a job cost in the server, from its fork to its
    exit. ``cpu_s`` is the job's own user + system time and that of the processes it
    waited for (the time-limited solve): unlike a wall time, it does not grow with the
    load of a shared machine."""
    cpu = usage.ru_utime + usage.ru_stime
    rss_mb = usage.ru_maxrss / 1024.0  # kilobytes on Linux
    out = job.out.replace("\t", " ").replace("\n", " ")
    return f"{kind}\t{job.stage}\t{out}\t{wall:.4f}\t{cpu:.4f}\t{rss_mb:.1f}\t{code}\n"


def _receive(conn: socket.socket) -> tuple[dict[str, Any], list[int]]:
    fds = array.array("i")
    msg, anc, _flags, _addr = conn.recvmsg(_MAX_MESSAGE, socket.CMSG_LEN(2 * fds.itemsize))
    for level, kind, data in anc:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.frombytes(data[: len(data) - (len(data) % fds.itemsize)])
    return json.loads(msg.decode()), list(fds)


def _run_child(request: Mapping[str, Any], fds: list[int], close: list[int]) -> None:
    """In the forked child: take over the client's setting, run the stage, exit."""
    code = 1
    try:
        die_with_parent(os.getppid())
        os.setpgid(0, 0)
        for s in (signal.SIGTERM, signal.SIGINT, signal.SIGCHLD, signal.SIGHUP):
            signal.signal(s, signal.SIG_DFL)
        for fd in close:
            try:
                os.close(fd)
            except OSError:
                pass
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(fds[0], 1)
        os.dup2(fds[1], 2)
        for fd in (null, *fds):
            os.close(fd)
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        args = parse_args(request["argv"]) if "argv" in request else request["args"]
        run_stage(request["stage"], args)
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - reported like an uncaught exception
        sys.excepthook(*sys.exc_info())
        code = 1
    finally:
        try:
            import logging

            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def _import_all(modules: tuple[str, ...]) -> None:
    import importlib

    for mod in modules:
        try:
            importlib.import_module(mod)
        except ImportError as exc:  # e.g. NGSolve absent for a python-model study
            print(f"jobserver: not preloaded: {mod} ({exc})", flush=True)


def serve(path: str, parent: int | None = None, preload: tuple[str, ...] = _PRELOAD,
          kind: str = "point", ledger: str | None = None) -> None:
    """Run the server: import ``preload``, listen on ``path``, fork a child per job.

    Ends when ``parent`` (the Snakemake process) is gone or on SIGTERM, killing the
    jobs it still runs and removing the socket. With ``ledger``, each finished job
    appends one tab-separated line (:data:`LEDGER_COLUMNS`) to that file: the server,
    the stage, the job's output path, its wall time from fork to exit, its CPU time,
    its peak memory and its exit status (read by ``benchmarks/bench_pipeline.py``).
    """
    t0 = time.monotonic()
    name = f"jobserver ({kind})"
    _import_all(preload)
    try:  # the config schemas, validated by every solve (fsi model) and job
        from bayescalib.config import load_schemas

        load_schemas()
    except ImportError:
        pass
    if kind == "round":
        try:
            import matplotlib

            matplotlib.use("Agg")  # the figure stages' backend, chosen once here
            from bayescalib.plotting.style import warm_up
        except ImportError:
            pass
        else:
            try:  # fonts, mathtext grammar: paid here once, not in every figure job
                warm_up()
            except Exception as exc:  # noqa: BLE001 - a job pays them itself; serve on
                print(f"{name}: figure warm-up failed ({exc})", flush=True)
        from bayescalib.inference.gp import gpu_possible

        if gpu_possible():  # a surrogate on device "auto" may use it
            _import_all(("torch",))
    # the imported objects are never collected: a child's collections skip them and
    # leave their pages shared with this process
    gc.collect()
    gc.freeze()
    print(f"{name}: preloaded in {time.monotonic() - t0:.2f} s", flush=True)
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    tmp = path + ".tmp"
    try:
        os.unlink(tmp)
    except FileNotFoundError:
        pass
    listener.bind(tmp)
    os.chmod(tmp, 0o600)
    listener.listen(64)
    os.rename(tmp, path)  # the socket appears only when it accepts jobs
    inode = os.stat(path).st_ino
    sel = selectors.DefaultSelector()
    sel.register(listener, selectors.EVENT_READ, "listen")
    jobs: dict[int, _Job] = {}  # by pidfd
    by_conn: dict[int, _Job] = {}

    def _on_term(*_):
        raise _Stop

    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: Snakemake cancels the jobs
    n_done = 0

    def kill(job: _Job) -> None:
        try:
            os.killpg(job.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    try:
        while True:
            if parent is not None and os.getppid() != parent and not _alive(parent):
                break
            for key, _ in sel.select(timeout=1.0):
                what = key.data
                if what == "listen":
                    conn, _ = listener.accept()
                    sel.register(conn, selectors.EVENT_READ, "request")
                elif what == "request":
                    conn = key.fileobj
                    fd = conn.fileno()
                    if fd in by_conn:  # EOF or stray data while the job runs: client gone
                        job = by_conn.pop(fd)
                        kill(job)
                        sel.unregister(conn)
                        conn.close()
                        continue
                    try:
                        request, fds = _receive(conn)
                    except (OSError, ValueError):
                        sel.unregister(conn)
                        conn.close()
                        continue
                    if len(fds) != 2:
                        for f in fds:
                            os.close(f)
                        sel.unregister(conn)
                        conn.close()
                        continue
                    keep = [listener.fileno(), conn.fileno(), sel.fileno()] + \
                        [j.conn.fileno() for j in jobs.values()] + list(jobs)
                    pid = os.fork()
                    if pid == 0:
                        _run_child(request, fds, keep)
                    for f in fds:
                        os.close(f)
                    pidfd = os.pidfd_open(pid)
                    argv = request.get("argv") or []
                    out = argv[argv.index("out") + 1] if "out" in argv[:-1] else ""
                    job = _Job(conn, pid, pidfd, str(request.get("stage")), str(out))
                    jobs[pidfd] = job
                    by_conn[conn.fileno()] = job
                    sel.register(pidfd, selectors.EVENT_READ, "child")
                elif what == "child":
                    pidfd = key.fd
                    job = jobs.pop(pidfd)
                    sel.unregister(pidfd)
                    _, status, usage = os.wait4(job.pid, 0)
                    os.close(pidfd)
                    code = os.waitstatus_to_exitcode(status)
                    if ledger is not None:
                        row = _ledger_row(kind, job, time.monotonic() - job.t0, usage, code)
                        try:
                            with open(ledger, "a") as fh:  # one short append per job
                                fh.write(row)
                        except OSError:
                            pass
                    if job.conn.fileno() in by_conn:
                        by_conn.pop(job.conn.fileno())
                        try:
                            job.conn.send(json.dumps({"exit": code}).encode())
                        except OSError:
                            pass
                        sel.unregister(job.conn)
                        job.conn.close()
                    n_done += 1
    except _Stop:
        pass
    finally:
        for job in jobs.values():
            kill(job)
        try:  # unless a later run's server has taken the path over
            if os.stat(path).st_ino == inode:
                os.unlink(path)
        except FileNotFoundError:
            pass
        print(f"{name}: {n_done} jobs run; stopped", flush=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def main(argv: list[str] | None = None) -> int:
    """``--serve PATH [--parent PID] [--kind point|round] [--ledger TSV]`` runs a server;
    ``--run STAGE
    KEY VALUE ...`` runs one job in this process (the client's fallback)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"] and len(argv) >= 2:
        opts = dict(zip(argv[2::2], argv[3::2]))
        kind = opts.get("--kind", "point")
        if kind not in ("point", "round"):
            sys.stderr.write(f"jobserver: unknown server kind {kind!r}\n")
            return 2
        parent = int(opts["--parent"]) if "--parent" in opts else None
        serve(argv[1], parent, _PRELOAD_ROUND if kind == "round" else _PRELOAD, kind,
              opts.get("--ledger"))
        return 0
    if argv[:1] == ["--run"] and len(argv) >= 2:
        run_stage(argv[1], parse_args(argv[2:]))
        return 0
    sys.stderr.write("usage: python -m bayescalib.execution.jobserver --serve PATH [--parent PID] "
                     "[--kind point|round] [--ledger TSV] | --run STAGE [KEY VALUE ...]\n")
    return 2


if __name__ == "__main__":
    sys.exit(main())
