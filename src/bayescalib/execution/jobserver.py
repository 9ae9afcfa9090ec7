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
``python -I -S``) that hands the server its job document, its working directory, its
environment and its stdout/stderr (file descriptors passed over the socket); the
server forks a child that runs the stage in that setting and reports the child's
exit status and cost, which the client exits with and writes to the rule's benchmark
file.

One launch path
---------------
A stage is declared once, in :data:`STAGES` (stage name -> function). A rule's command
is ``job(locals())`` (:func:`job_command`): in the job, the client with the job's
document (:func:`job_document`), one JSON argument holding the rule's named inputs,
outputs and params, which are the stage function's keyword arguments (the only
encoding of the job's values), its log, its benchmark file, its ``mem_mb`` and its
threads. The server's child, or the client's own child without a server, calls
:func:`run_job` with it. A stage parameter is added to the function and the rule.

What a job keeps
----------------
* Isolation: every job runs in its own forked process, in its own process group; a
  solve is moreover evaluated in a forked, time-limited grandchild
  (:func:`bayescalib.models.forward.solve_point`), so a crash, a hang or ``os._exit`` in the
  model is a failed run record, as before.
* Killing: if the client goes away (Snakemake cancels the job, or is killed), the
  server kills the job's process group. If Snakemake itself dies, the server notices
  within a second (its parent changed), kills every job it runs and exits.
* Cache keys: the rules' params hold the config values they depend on; the job
  receives exactly them.
* No server (a cluster executor, a run without ``onstart``, a server that failed to
  start, a server that refused the job): the client runs the same stage in a child of
  its own (``python -m bayescalib.execution.jobserver --run-job``), with the full
  imports: slower, same result (one BLAS thread there too, :data:`JOB_BLAS_ENV`).
* Changed code: a server refuses jobs once the package's source differs from what it
  imported (:func:`source_fingerprint`) and restarts (:func:`serve`); the refused job
  runs in its client, from the source on disk.
* Benchmarks and memory: the rule's benchmark file measures the process that worked
  (the forked child with the solve it waited for: wall time, CPU time, peak RSS,
  ``scripts/job.py``), not the client; ``resources: mem_mb`` limits that process
  (:func:`limit_memory`).

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
sends one JSON message ``{"job", "cwd", "env"}`` (``job``: the job document) with two
file descriptors (its stdout and stderr); the server answers ``{"exit": code, "wall_s",
"cpu_s", "max_rss_mb", "io_in_mb", "io_out_mb"}`` when the job has ended, or
``{"refused": reason}`` at once (changed source).
"""

from __future__ import annotations

import array
import gc
import hashlib
import inspect
import json
import os
import resource
import selectors
import shlex
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

__all__ = ["JOB_TEMPLATE", "ROUND_STAGES", "STAGES", "export_job_command", "job_command",
           "job_document", "limit_memory", "run_job", "serve", "socket_path",
           "source_fingerprint", "start_server", "stop_server"]

#: every job's BLAS threads, through a server or in its client's fallback: one, whatever
#: threads Snakemake grants the job (it sets OPENBLAS_NUM_THREADS to them). A job's
#: threads are processes (a solve batch, a surrogate search's candidates), and a GP fit
#: with two BLAS threads differs from one with one at 1e-6, which moved an active
#: design's rounds: the fallback must give what the server gives (test_jobserver.py)
JOB_BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

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

#: stage name -> its function (``module:function``, imported when a job of it runs, so that
#: the point server imports no figure code). A job calls the function with the keyword
#: arguments of its job document (:func:`job_document`: the rule's named inputs, outputs
#: and params), and with ``threads=`` (Snakemake's) where the function takes it. Adding a
#: parameter to a stage: the function's signature and the rule's params, nothing else.
#: Per point: solve, discrepancy, predictive_solve, posterior_mean_solve; per round (active
#: design) and per measure: gather, train_surrogate, smc, acquire, marginalize; the
#: posterior check, summary.json and the figures.
STAGES: dict[str, str] = {
    "solve": "bayescalib.stages.jobs:solve",
    "discrepancy": "bayescalib.stages.discrepancy:discrepancy",
    "predictive_solve": "bayescalib.stages.jobs:predictive_solve",
    "posterior_mean_solve": "bayescalib.stages.figures:solve_at_posterior_mean",
    "posterior_check": "bayescalib.stages.posterior_check:posterior_check",
    "gather": "bayescalib.stages.gather:gather",
    "train_surrogate": "bayescalib.stages.surrogate:train_surrogate",
    "smc": "bayescalib.stages.smc:smc",
    "acquire": "bayescalib.stages.acquire:acquire",
    "marginalize": "bayescalib.stages.marginalize:marginalize",
    "summary": "bayescalib.stages.jobs:summary",
    "fig_response": "bayescalib.stages.figures:response_figures",
    "fig_convergence": "bayescalib.stages.figures:convergence_figure",
    "fig_posterior": "bayescalib.stages.figures:posterior_figures",
    "fig_interfaces": "bayescalib.stages.figures:interface_figure",
    "fig_fields": "bayescalib.stages.figures:field_figure",
    "fig_rounds": "bayescalib.stages.figures:rounds_figure",
    "fig_segmentation": "bayescalib.stages.figures:segmentation_figure",
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
            "bayescalib.models.forward", "bayescalib.stages.logs", "bayescalib.stages.files",
            "bayescalib.stages.jobs", "bayescalib.stages.discrepancy", "bayescalib.stages.gather",
            "bayescalib.study", "bayescalib.measures", "bayescalib.measures.currents",
            "bayescalib.geometry.interface", "bayescalib.geometry.projection",
            "bayescalib.geometry.surface", "bayescalib.io.observations",
            "bayescalib.inference.likelihood", "bayescalib.io.observation_store",
            "bayescalib.io.runrecord", "bayescalib.io.training", "bayescalib.models.fsi.model",
            "bayescalib.models.fsi.solver", "ngsolve", "netgen.occ", "multiprocessing.popen_fork")

#: what the round server imports before it accepts jobs (torch only where a GPU may
#: be used: :func:`bayescalib.inference.gp.predictor.gpu_possible`)
_PRELOAD_ROUND = ("numpy", "scipy.linalg", "scipy.optimize", "scipy.stats", "h5py", "GPy",
                  "arviz", "matplotlib", "matplotlib.pyplot", "bayescalib.stages.logs",
                  "bayescalib.stages.surrogate", "bayescalib.stages.smc",
                  "bayescalib.stages.acquire", "bayescalib.stages.marginalize",
                  "bayescalib.stages.posterior_check", "bayescalib.stages.summary",
                  "bayescalib.stages.jobs", "bayescalib.stages.figures", "bayescalib.study",
                  "bayescalib.inference.gp", "bayescalib.inference.smc",
                  "bayescalib.inference.active", "bayescalib.inference.posterior",
                  "bayescalib.inference.weights", "bayescalib.plotting")

#: the command of every job-server rule as Snakemake records it (its ``code`` rerun
#: trigger, its ``--printshellcmds`` line): no path of this machine, no job's values
_CLIENT = '"$BAYESCALIB_PYTHON" -I -S "$BAYESCALIB_JOB_CLIENT"'
JOB_TEMPLATE = f"{_CLIENT} JOB_DOCUMENT"


def _plain(value: Any) -> Any:
    """A rule's value as JSON takes it: Snakemake's file names and lists as ``str`` and
    ``list``, NumPy scalars as numbers."""
    if isinstance(value, str):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if hasattr(value, "item") and not isinstance(value, (int, float, bool)):
        return value.item()
    return value


def job_document(namespace: Mapping[str, Any], stage: str | None = None) -> dict[str, Any]:
    """The job of a rule as one JSON-able document, from the rule function's namespace
    (``input``, ``output``, ``params``, ``log``, ``threads``, ``resources``, ``rule``):

    * ``stage``: ``stage`` or the rule's name (a key of :data:`STAGES`);
    * ``args``: the rule's *named* inputs, outputs and params, by name: the stage
      function's keyword arguments. Unnamed entries are Snakemake's only (rerun
      triggers such as ``_set_aside``, report files); a name given twice is an error;
    * ``log``: the job's log file (the unnamed ``log:`` entry, or ``log=``), set up
      before the stage runs; ``benchmark``: the ``benchmark=`` log entry, the TSV the
      client writes the working process's measurements to (Snakemake's columns: see
      ``scripts/job.py``); ``mem_mb``: ``resources.mem_mb`` (None where the rule and the
      profile set none), the limit of the working process (:func:`limit_memory`);
      ``threads``; ``out``: the first output (the ledger's column).
    """
    rule = str(namespace["rule"])
    args: dict[str, Any] = {}
    for kind in ("input", "output", "params"):
        for name, value in namespace[kind].items():
            if name in args:
                raise ValueError(f"rule {rule}: '{name}' is named twice among its inputs, "
                                 "outputs and params (each is one keyword of its stage)")
            args[name] = _plain(value)
    log = namespace["log"]
    named = dict(log.items())
    bench = named.pop("benchmark", None)
    logfile = named.pop("log", None)
    if logfile is None:
        logfile = next((f for f in log if f != bench and f not in named.values()), None)
    resources = dict(namespace["resources"].items())
    mem_mb = resources.get("mem_mb")
    output = list(namespace["output"])
    return {"stage": stage or rule, "args": args,
            "log": None if logfile is None else str(logfile),
            "benchmark": None if bench is None else str(bench),
            "mem_mb": int(mem_mb) if isinstance(mem_mb, (int, float)) else None,
            "threads": int(namespace["threads"]), "out": str(output[0]) if output else ""}


def job_command(namespace: Mapping[str, Any], stage: str | None = None, *,
                recorded: str | None = None) -> str:
    """The shell command of a job-server rule: ``shell: job(locals())`` (``job(locals(),
    "smc")`` where the stage is not the rule's name).

    Snakemake evaluates a ``shell:`` expression twice: once when it parses the rule (at
    module level, where this returns :data:`JOB_TEMPLATE`, the text Snakemake records
    as the rule's code) and once in the job (in the rule function, whose locals are the
    job's input, output, params, ...): there it returns the client's command with the
    job's document (:func:`job_document`) as its one, shell-quoted JSON argument: the
    only encoding of the job's values between the rule and the stage function.
    ``recorded``: the text to record instead of :data:`JOB_TEMPLATE` (a rule whose
    earlier command text is kept so that its results stay current).
    """
    if "bench_record" not in namespace:  # parse time: the module's namespace
        return JOB_TEMPLATE if recorded is None else recorded
    text = json.dumps(job_document(namespace, stage), separators=(",", ":"))
    # Snakemake formats the command once more: its braces are doubled
    return f"{_CLIENT} {shlex.quote(text)}".replace("{", "{{").replace("}", "}}")


def _stage_function(stage: str) -> Callable[..., Any]:
    import importlib

    try:
        module, name = STAGES[stage].split(":")
    except KeyError:
        raise ValueError(f"unknown job stage {stage!r} (known: {', '.join(STAGES)})") from None
    return getattr(importlib.import_module(module), name)


def limit_memory(mem_mb: float) -> int | None:
    """Limit this process (and the processes it forks, e.g. a solve's) to ``mem_mb`` MB of
    address space more than it holds now: a job given ``resources: mem_mb`` that maps
    more fails with a MemoryError (an allocation refused), instead of pushing the
    machine into swap. Measured from the job's start because a job forked from a job
    server starts with the server's imports mapped (shared with the server, not the
    job's: about 800 MB of address space for the point server, 500 MB for the round
    server, 160-230 MB resident). An address-space limit (``RLIMIT_AS``) counts
    reserved, unused mappings too; CUDA reserves very large ones, so a rule that runs on
    a GPU should not set mem_mb. Returns the limit in bytes (None where
    ``/proc/self/statm`` is not there: not Linux)."""
    try:
        with open("/proc/self/statm") as fh:
            size = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return None
    limit = size + int(float(mem_mb) * 2**20)
    _soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    return limit


def run_job(doc: Mapping[str, Any]) -> None:
    """Run one job (its document, :func:`job_document`) in this process: its log set
    up, its memory limited (``mem_mb``, in a run on this machine: where a job server
    was started or ``BAYESCALIB_JOBSERVER=off`` asked for none; a cluster job is
    limited by its scheduler), then the stage function called with its arguments."""
    from bayescalib.stages.logs import setup_logging

    fn = _stage_function(str(doc.get("stage")))
    setup_logging(doc.get("log"))
    limited = None
    if doc.get("mem_mb") and os.environ.get(SOCKET_ENV):
        limited = limit_memory(doc["mem_mb"])
    kwargs = dict(doc.get("args") or {})
    if "threads" in inspect.signature(fn).parameters:
        kwargs.setdefault("threads", int(doc.get("threads") or 1))
    try:
        fn(**kwargs)
    except (MemoryError, RuntimeError) as exc:
        # an allocation refused under the job's limit (NumPy: MemoryError; torch: a
        # RuntimeError "can't allocate memory"): name the limit and how to raise it
        if limited is None or not (isinstance(exc, MemoryError)
                                   or "allocate memory" in str(exc)):
            raise
        mem = int(doc["mem_mb"])
        raise MemoryError(
            f"job {doc.get('stage')}: an allocation was refused under the job's memory limit "
            f"(resources.mem_mb = {mem} MB of address space beyond what the job held at its "
            f"start; {type(exc).__name__}: {str(exc).splitlines()[0]}): rerun with a larger "
            f"limit for its rule, e.g. snakemake ... --set-resources <rule>:mem_mb={2 * mem} "
            "(finished jobs are kept)") from exc


def source_fingerprint(root: str | Path | None = None) -> str:
    """A fingerprint of the package's source as it is on disk now: the path, the
    modification time and the size of every ``.py``, ``.yaml`` and ``.json`` file under
    ``root`` (this package: its modules and its config schemas). About a millisecond;
    a server takes it when it starts and compares it before each job
    (:func:`serve`)."""
    base = Path(__file__).resolve().parents[1] if root is None else Path(root)
    digest = hashlib.sha1()
    for folder, dirs, files in os.walk(base):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith((".py", ".yaml", ".json")):
                path = os.path.join(folder, name)
                try:
                    st = os.stat(path)
                except FileNotFoundError:
                    continue
                digest.update(f"{os.path.relpath(path, base)}\0{st.st_mtime_ns}\0"
                              f"{st.st_size}\n".encode())
    return digest.hexdigest()


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
    env = {**os.environ, **JOB_BLAS_ENV}
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


def _cost(wall: float, usage: Any) -> dict[str, float]:
    """What a job cost, from its fork to its exit: ``cpu_s`` is the job's own user +
    system time and that of the processes it waited for (the time-limited solve): unlike
    a wall time, it does not grow with the load of a shared machine; ``max_rss_mb`` its
    peak resident memory (or that of a process it waited for, if larger); ``io_in_mb``,
    ``io_out_mb`` what it read from and wrote to disk (blocks of 512 bytes)."""
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "max_rss_mb": usage.ru_maxrss / 1024.0,  # kilobytes on Linux
            "io_in_mb": usage.ru_inblock * 512 / 1e6, "io_out_mb": usage.ru_oublock * 512 / 1e6}


def _ledger_row(kind: str, job: _Job, cost: Mapping[str, float], code: int) -> str:
    """One line of the job ledger (:func:`_cost`)."""
    out = job.out.replace("\t", " ").replace("\n", " ")
    return (f"{kind}\t{job.stage}\t{out}\t{cost['wall_s']:.4f}\t{cost['cpu_s']:.4f}\t"
            f"{cost['max_rss_mb']:.1f}\t{code}\n")


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
        os.environ.update({**request["env"], **JOB_BLAS_ENV})  # a spawned solve's too
        run_job(request["job"])
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
          kind: str = "point", ledger: str | None = None,
          restart: list[str] | None = None) -> None:
    """Run the server: import ``preload``, listen on ``path``, fork a child per job.

    Ends when ``parent`` (the Snakemake process) is gone or on SIGTERM, killing the
    jobs it still runs and removing the socket. With ``ledger``, each finished job
    appends one tab-separated line (:data:`LEDGER_COLUMNS`) to that file: the server,
    the stage, the job's output path, its wall time from fork to exit, its CPU time,
    its peak memory and its exit status (read by ``benchmarks/bench_pipeline.py``).
    The client hears the same figures with the job's exit status (``scripts/job.py``
    writes them to the rule's benchmark file).

    Changed code: the server takes :func:`source_fingerprint` before its imports and
    again before each job. When the package's source has changed since (a module or a
    schema edited during the run), its children would run the old modules it imported:
    it refuses the job (``{"refused": reason}``; the client then runs the job itself,
    from the source on disk), stops accepting jobs (its socket is removed: the jobs that
    follow run in their clients), lets the jobs it runs end, and then, with ``restart``
    (the command line that started it, :func:`main`), starts again in its place
    (``os.execv``: the same process, so the run still stops it), importing the new
    source; without ``restart`` it exits.
    """
    t0 = time.monotonic()
    name = f"jobserver ({kind})"
    fingerprint = source_fingerprint()  # before the imports: an edit during them counts
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
    stale: str | None = None  # why the server stopped accepting jobs (changed source)

    def kill(job: _Job) -> None:
        try:
            os.killpg(job.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    try:
        while True:
            if parent is not None and os.getppid() != parent and not _alive(parent):
                break
            if stale is not None and not jobs:
                break
            for key, _ in sel.select(timeout=1.0):
                what = key.data
                if what == "listen":
                    if stale is not None:  # closed in this round of events
                        continue
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
                    reason = None
                    if not isinstance(request.get("job"), dict):
                        reason = "the request holds no job document (a client of another version)"
                    elif stale is not None or source_fingerprint() != fingerprint:
                        reason = (f"{name}: the bayescalib source changed after the server "
                                  "started (it runs the modules it imported then)")
                        if stale is None:
                            stale = reason
                            print(f"{reason}: refusing jobs, restarting once its "
                                  f"{len(jobs)} running jobs end", flush=True)
                            sel.unregister(listener)
                            listener.close()
                            try:
                                if os.stat(path).st_ino == inode:
                                    os.unlink(path)
                            except FileNotFoundError:
                                pass
                    if reason is not None:
                        for f in fds:
                            os.close(f)
                        try:
                            conn.send(json.dumps({"refused": reason}).encode())
                        except OSError:
                            pass
                        sel.unregister(conn)
                        conn.close()
                        continue
                    keep = [conn.fileno(), sel.fileno()] + \
                        ([listener.fileno()] if stale is None else []) + \
                        [j.conn.fileno() for j in jobs.values()] + list(jobs)
                    pid = os.fork()
                    if pid == 0:
                        _run_child(request, fds, keep)
                    for f in fds:
                        os.close(f)
                    pidfd = os.pidfd_open(pid)
                    doc = request["job"]
                    job = _Job(conn, pid, pidfd, str(doc.get("stage")), str(doc.get("out", "")))
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
                    cost = _cost(time.monotonic() - job.t0, usage)
                    if ledger is not None:
                        row = _ledger_row(kind, job, cost, code)
                        try:
                            with open(ledger, "a") as fh:  # one short append per job
                                fh.write(row)
                        except OSError:
                            pass
                    if job.conn.fileno() in by_conn:
                        by_conn.pop(job.conn.fileno())
                        try:
                            job.conn.send(json.dumps({"exit": code, **cost}).encode())
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
    if stale is not None and restart is not None:
        print(f"{name}: restarting with the changed source", flush=True)
        sys.stdout.flush()
        sys.stderr.flush()
        os.execv(sys.executable, [sys.executable, *restart])


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
    ``--run-job`` runs the job whose document (:func:`job_document`, JSON) is on standard
    input in this process (the client's fallback)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"] and len(argv) >= 2:
        opts = dict(zip(argv[2::2], argv[3::2]))
        kind = opts.get("--kind", "point")
        if kind not in ("point", "round"):
            sys.stderr.write(f"jobserver: unknown server kind {kind!r}\n")
            return 2
        parent = int(opts["--parent"]) if "--parent" in opts else None
        serve(argv[1], parent, _PRELOAD_ROUND if kind == "round" else _PRELOAD, kind,
              opts.get("--ledger"), restart=["-m", "bayescalib.execution.jobserver", *argv])
        return 0
    if argv == ["--run-job"]:
        die_with_parent(os.getppid())  # the client is killed: so is its job
        os.environ.update(JOB_BLAS_ENV)  # before NumPy is imported: as in a server's job
        doc = json.loads(sys.stdin.read())
        sys.stdin.close()
        run_job(doc)
        return 0
    sys.stderr.write("usage: python -m bayescalib.execution.jobserver --serve PATH [--parent PID] "
                     "[--kind point|round] [--ledger TSV] | --run-job < JOB_DOCUMENT\n")
    return 2


if __name__ == "__main__":
    sys.exit(main())
