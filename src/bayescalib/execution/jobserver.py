"""A warm process that runs the jobs of a local run (per point: solve, discrepancy;
per round and per measure: train_surrogate, smc, acquire, marginalize).

Why
---
Each design point is its own Snakemake job, cached on its own (the user's design). A
``script:`` job starts a fresh interpreter, unpickles Snakemake's job object and
imports numpy, scipy, h5py and NGSolve before any physics: about a second a job,
several times the cost of a solve on the default mesh, and nearly all of a
discrepancy job; GPy, torch and ArviZ add about two seconds to every surrogate, SMC
and acquisition job of every active-design round. Here the imports are paid once per
run: the workflow's ``onstart`` starts this server, which imports the per-point stage
code, opens a Unix socket, imports the per-round stage code and then serves. A job is
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

Protocol (``AF_UNIX``, ``SOCK_SEQPACKET``, one request per connection): the client
sends one JSON message ``{"stage", "args", "cwd", "env"}`` with two file
descriptors (its stdout and stderr); the server answers ``{"exit": code}`` when the
job has ended.
"""

from __future__ import annotations

import array
import ast
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

__all__ = ["STAGES", "export_job_command", "run_stage", "serve", "socket_path", "start_server",
           "stop_server"]

#: environment variable through which the jobs of a run find its server
SOCKET_ENV = "BAYESCALIB_JOBSERVER"
_MAX_MESSAGE = 1 << 20
#: the server this process started (start_server), stopped by stop_server
_SERVER: subprocess.Popen | None = None


class _Stop(Exception):
    """Raised by the server's SIGTERM handler: ends its loop at once."""


# ----------------------------------------------------------------------------- stages


def _literal(text: str) -> Any:
    """A params value as Snakemake formats it into the shell command (Python literal)."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError) as exc:
        raise ValueError(f"job argument is not a Python literal: {text[:200]!r} ({exc})") from None


def _solve(args: Mapping[str, str]) -> None:
    from bayescalib.models.forward import solve_point
    from bayescalib.stages import setup_logging

    setup_logging(args["log"])
    solve_point(_literal(args["forward_model"]), _literal(args["point"]), args["out"],
                warm_start=args.get("base") or None)


def _discrepancy(args: Mapping[str, str]) -> None:
    from bayescalib.stages import discrepancy, setup_logging

    setup_logging(args["log"])
    discrepancy(args["run"], args["obs"], args["measure_name"], _literal(args["measure"]),
                _literal(args["likelihood"]), args["out"])


def _train_surrogate(args: Mapping[str, str]) -> None:
    from bayescalib.stages import setup_logging, train_surrogate

    setup_logging(args["log"])
    train_surrogate(args["training"], _literal(args["surrogate"]), _literal(args["parameters"]),
          args["out"])


def _smc(args: Mapping[str, str]) -> None:
    from bayescalib.stages import setup_logging, smc

    setup_logging(args["log"])
    smc(args["surrogate"], _literal(args["smc"]), _literal(args["parameters"]), args["out"])


def _acquire(args: Mapping[str, str]) -> None:
    from bayescalib.stages import acquire, setup_logging

    setup_logging(args["log"])
    acquire(int(args["round"]), args["training"], args["surrogate"], args["particles"],
            args.get("previous") or None, _literal(args["active"]),
            _literal(args["parameters"]), args["out"])


def _marginalize(args: Mapping[str, str]) -> None:
    from bayescalib.stages import marginalize, setup_logging

    setup_logging(args["log"])
    marginalize(args["particles"], args["surrogate"], _literal(args["posterior"]),
                _literal(args["parameters"]), int(args["seed"]), args["out"], args["netcdf"])


#: stage name -> function of the job's arguments (strings, as formatted by the rule's
#: shell command). Per point: solve, discrepancy; per round (active design) and per
#: measure: train_surrogate, smc, acquire, marginalize.
STAGES: dict[str, Callable[[Mapping[str, str]], None]] = {
    "solve": _solve,
    "discrepancy": _discrepancy,
    "train_surrogate": _train_surrogate,
    "smc": _smc,
    "acquire": _acquire,
    "marginalize": _marginalize,
}

#: what the server imports before it accepts jobs (the heavy part of every per-point job)
_PRELOAD = ("numpy", "scipy.sparse", "scipy.spatial", "h5py", "bayescalib.models.forward",
            "bayescalib.stages", "bayescalib.study", "bayescalib.measures",
            "bayescalib.inference.likelihood", "bayescalib.io.observation_store", "bayescalib.models.fsi.model",
            "bayescalib.models.fsi.solver", "ngsolve", "netgen.occ")


#: imported once it accepts jobs (the per-round stages: GPy, torch, ArviZ); a job that
#: arrives meanwhile waits in the socket's queue
_PRELOAD_LATER = ("GPy", "torch", "arviz", "bayescalib.inference.surrogate", "bayescalib.inference.smc",
                  "bayescalib.inference.active", "bayescalib.inference.posterior")


def run_stage(stage: str, args: Mapping[str, str]) -> None:
    """Run one job of ``stage`` with its arguments in this process."""
    try:
        fn = STAGES[stage]
    except KeyError:
        raise ValueError(f"unknown job stage {stage!r} (known: {', '.join(STAGES)})") from None
    fn(args)


# ----------------------------------------------------------------------------- server


def socket_path(root: str | Path) -> str:
    """The socket of the server of a run of the study under ``root`` (short: Unix
    socket paths are limited to about 100 characters)."""
    key = hashlib.sha1(str(Path(root).resolve()).encode()).hexdigest()[:16]
    return os.path.join(tempfile.gettempdir(), f"bayescalib-{key}.sock")


def export_job_command(basedir: str | Path, *, conda: bool = False) -> None:
    """Set the environment variables the per-point rules' shell commands use: the
    interpreter (``BAYESCALIB_PYTHON``: this one, or ``python`` of the rule's conda
    environment) and the client script (``BAYESCALIB_JOB_CLIENT``) under the
    workflow's ``basedir``. Called when the Snakefile is parsed, so also in the
    Snakemake process a cluster job starts."""
    os.environ["BAYESCALIB_PYTHON"] = "python" if conda else sys.executable
    os.environ["BAYESCALIB_JOB_CLIENT"] = str(Path(basedir) / "scripts" / "job.py")


def start_server(root: str | Path, *, wait_s: float = 20.0) -> str | None:
    """Start the server of this run (called by the workflow's ``onstart``) and point
    the jobs to it (``BAYESCALIB_JOBSERVER``, inherited by the jobs).

    Returns the socket path once the server accepts jobs, or None if it did not come
    up within ``wait_s`` (jobs then run in-process; nothing is lost), or if
    ``BAYESCALIB_JOBSERVER=off`` asks for every job in a fresh interpreter. The server
    exits when this process does.
    """
    if os.environ.get(SOCKET_ENV) == "off":
        return None
    path = socket_path(root)
    # a socket left by a killed run of this study (this run holds the study's run
    # lock, so no live server owns it): gone, so that only the new one counts as ready
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    log = Path(root) / "logs" / "jobserver.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    with open(log, "w") as fh:
        proc = subprocess.Popen(
            [sys.executable, "-m", "bayescalib.execution.jobserver", "--serve", path,
             "--parent", str(os.getpid())],
            stdin=subprocess.DEVNULL, stdout=fh, stderr=subprocess.STDOUT, env=env)
    global _SERVER
    _SERVER = proc
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return None
        if os.path.exists(path):
            os.environ[SOCKET_ENV] = path
            return path
        time.sleep(0.02)
    return None


def stop_server(timeout: float = 10.0) -> None:
    """Stop the server :func:`start_server` started in this process (the workflow's
    ``onsuccess``/``onerror``), so that its log is complete when the run returns. It
    would stop by itself within a second of this process's end anyway."""
    global _SERVER
    proc, _SERVER = _SERVER, None
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class _Job:
    __slots__ = ("conn", "pid", "pidfd", "t0")

    def __init__(self, conn: socket.socket, pid: int, pidfd: int) -> None:
        self.conn, self.pid, self.pidfd, self.t0 = conn, pid, pidfd, time.monotonic()


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
        run_stage(request["stage"], request["args"])
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
          preload_later: tuple[str, ...] = _PRELOAD_LATER) -> None:
    """Run the server: import ``preload``, listen on ``path``, import ``preload_later``,
    fork a child per job.

    Ends when ``parent`` (the Snakemake process) is gone or on SIGTERM, killing the
    jobs it still runs and removing the socket.
    """
    t0 = time.monotonic()
    _import_all(preload)
    try:  # the config schemas, validated by every solve (fsi model) and job
        from bayescalib.config import load_schemas

        load_schemas()
    except ImportError:
        pass
    print(f"jobserver: preloaded in {time.monotonic() - t0:.2f} s", flush=True)
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
    t0 = time.monotonic()
    _import_all(preload_later)
    print(f"jobserver: per-round stages preloaded in {time.monotonic() - t0:.2f} s", flush=True)
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
                    job = _Job(conn, pid, pidfd)
                    jobs[pidfd] = job
                    by_conn[conn.fileno()] = job
                    sel.register(pidfd, selectors.EVENT_READ, "child")
                elif what == "child":
                    pidfd = key.fd
                    job = jobs.pop(pidfd)
                    sel.unregister(pidfd)
                    _, status = os.waitpid(job.pid, 0)
                    os.close(pidfd)
                    code = os.waitstatus_to_exitcode(status)
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
        print(f"jobserver: {n_done} jobs run; stopped", flush=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def main(argv: list[str] | None = None) -> int:
    """``--serve PATH [--parent PID]`` runs the server; ``--run STAGE KEY VALUE ...``
    runs one job in this process (the client's fallback)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"]:
        parent = int(argv[3]) if len(argv) >= 4 and argv[2] == "--parent" else None
        serve(argv[1], parent)
        return 0
    if argv[:1] == ["--run"] and len(argv) >= 2:
        # a last key without value (an empty list formatted by Snakemake) is left out
        stage, rest = argv[1], argv[2:]
        run_stage(stage, dict(zip(rest[::2], rest[1::2])))
        return 0
    sys.stderr.write("usage: python -m bayescalib.execution.jobserver --serve PATH [--parent PID] | "
                     "--run STAGE [KEY VALUE ...]\n")
    return 2


if __name__ == "__main__":
    sys.exit(main())
