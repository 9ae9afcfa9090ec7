"""The warm job server of a local run (bayescalib.execution.jobserver, scripts/job.py).

Specification: a per-point job handed to the server gives exactly the files the same
job gives in a fresh interpreter; a failing job exits non-zero with its error in its
log; a crashing model is a failed run record; a job whose client goes away is killed;
when the run's Snakemake process dies, the server and its jobs end with it."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
from _workflow_helpers import REPO

from bayescalib.io.runrecord import read_run
from bayescalib.study import Study

CLIENT = [sys.executable, "-I", "-S", str(REPO / "scripts" / "job.py")]
STUDY = "results/analytic"


def _path(first: Path) -> str:
    """``first`` (for python models written there), then the caller's PYTHONPATH (a run
    with PYTHONPATH=<checkout>/src tests that checkout's bayescalib)."""
    return os.pathsep.join(p for p in (str(first), os.environ.get("PYTHONPATH", "")) if p)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is gone for our purpose
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _wait_gone(pid: int, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not _alive(pid):
            return True
        time.sleep(0.05)
    return False


@pytest.fixture
def server(tmp_path):
    """A job server on a socket in tmp_path (python models importable from tmp_path)."""
    sock = str(tmp_path / "s.sock")
    env = {**os.environ, "PYTHONPATH": _path(tmp_path), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "bayescalib.execution.jobserver", "--serve", sock],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while not os.path.exists(sock):
        assert proc.poll() is None, proc.stdout.read()
        assert time.monotonic() < deadline, "job server did not come up"
        time.sleep(0.05)
    yield sock
    proc.terminate()
    proc.wait(timeout=10)


def _doc(stage: str, log: str | None = None, benchmark: str | None = None,
         mem_mb: int | None = None, **args: Any) -> dict[str, Any]:
    """A job document as the workflow writes it (jobserver.job_document)."""
    out = args.get("out", args.get("out_path", ""))
    return {"stage": stage, "args": args, "log": log, "benchmark": benchmark, "mem_mb": mem_mb,
            "threads": 1, "out": str(out)}


def _job(sock: str | None, cwd: Path, stage: str, *, env: Mapping[str, str] | None = None,
         **kw: Any) -> subprocess.CompletedProcess:
    """Run one job through the client: with the server at ``sock``, or (None) without."""
    env = {k: v for k, v in {**os.environ, **(env or {})}.items()
           if sock is None or k != "BAYESCALIB_JOBSERVER"}
    env["PYTHONPATH"] = _path(cwd)
    if sock is not None:
        env["BAYESCALIB_JOBSERVER"] = sock
    return subprocess.run([*CLIENT, json.dumps(_doc(stage, **kw))], check=False, cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=120)


def _solver_pid(tmp_path: Path, client: subprocess.Popen) -> int:
    """The pid the hanging model writes once its solve has started."""
    pidfile = tmp_path / "pid.txt"
    deadline = time.monotonic() + 60
    while not (pidfile.exists() and pidfile.read_text()):
        assert time.monotonic() < deadline and client.poll() is None
        time.sleep(0.05)
    return int(pidfile.read_text())


def _solve_args(study: Study, i: int, out: str) -> dict[str, Any]:
    return {"log": f"logs/{i}.log", "out": out, "forward_model": study.forward_section(),
            "point": study.point(i)}


def _disc_args(study: Study, root: str, i: int, out: str, log: str) -> dict[str, Any]:
    return {"log": log, "out_path": out, "run_path": f"{root}/runs/{i}.h5",
            "obs_path": f"{root}/observations/observations.h5", "measure_name": "rkhs",
            "measure": study.config["measure"]["rkhs"], "likelihood": study.config["likelihood"]}


def test_jobs_through_the_server_equal_jobs_in_a_fresh_interpreter(done_run, base_study,
                                                                   tmp_path, server):
    tmp = tmp_path / "run"
    shutil.copytree(done_run, tmp, symlinks=True)
    study = Study(base_study)
    root = tmp / STUDY
    for i in (0, 3):
        for label, sock in (("server", server), ("fresh", None)):
            out = f"{STUDY}/check/{label}{i}.h5"
            proc = _job(sock, tmp, "solve", **_solve_args(study, i, out))
            assert proc.returncode == 0, proc.stderr
            mine, ref = read_run(tmp / out), read_run(root / "runs" / f"{i}.h5")
            assert mine.status == ref.status
            assert (mine.interface_current == ref.interface_current).all()
            disc = f"{STUDY}/check/{label}{i}.json"
            proc = _job(sock, tmp, "discrepancy",
                        **_disc_args(study, STUDY, i, disc, f"logs/d{label}{i}.log"))
            assert proc.returncode == 0, proc.stderr
            assert json.loads((tmp / disc).read_text()) == \
                json.loads((root / "discrepancy" / "rkhs" / f"{i}.json").read_text())


def test_a_failing_job_exits_nonzero_with_its_error_in_its_log(tmp_path, server, base_study):
    study = Study(base_study)
    args = _disc_args(study, "nowhere", 0, "d.json", "logs/d.log")
    args.update(run_path="missing.h5", obs_path="missing_obs.h5")
    proc = _job(server, tmp_path, "discrepancy", **args)
    assert proc.returncode == 1
    assert "missing.h5" in proc.stderr  # the job's stderr is the client's
    assert "missing.h5" in (tmp_path / "logs" / "d.log").read_text()
    assert not (tmp_path / "d.json").exists()
    unknown = _job(server, tmp_path, "no_such_stage")
    assert unknown.returncode == 1 and "unknown job stage 'no_such_stage'" in unknown.stderr


CRASHING = """
import ctypes, os, time
def segfault(params, **kw):
    ctypes.string_at(0)
def leave(params, **kw):
    os._exit(3)
def hang(params, **kw):
    with open("pid.txt", "w") as fh:
        fh.write(str(os.getpid()))
    time.sleep(120)
"""


BURNING = """
import time
from bayescalib.models.analytic import interface
def burn(params, **kw):
    t = time.process_time()
    while time.process_time() - t < 0.4:
        pass
    return interface(params, **kw)
"""


def test_the_ledger_records_each_job_with_the_cpu_time_of_its_solve(tmp_path, base_study,
                                                                    monkeypatch):
    """Each job the server ran is one ledger line: its stage, its output, its exit status
    and its CPU time, including that of the forked, time-limited process the model ran
    in (0.4 s of CPU spent there; the ledger must not see only the job's own
    bookkeeping)."""
    from bayescalib.execution.jobserver import LEDGER_COLUMNS

    (tmp_path / "burning.py").write_text(BURNING)
    monkeypatch.syspath_prepend(str(tmp_path))  # the study is read where its model imports
    sock, ledger = str(tmp_path / "s.sock"), tmp_path / "jobs.tsv"
    env = {**os.environ, "PYTHONPATH": _path(tmp_path), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "bayescalib.execution.jobserver", "--serve",
                             sock, "--ledger", str(ledger)], cwd=tmp_path, env=env)
    try:
        deadline = time.monotonic() + 60
        while not os.path.exists(sock):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        cfg = json.loads(json.dumps(base_study))
        cfg["forward_model"]["python"] = {"function": "burning:burn"}
        ok = _job(sock, tmp_path, "solve", **_solve_args(Study(cfg), 0, "run.h5"))
        assert ok.returncode == 0, ok.stderr
        assert read_run(tmp_path / "run.h5").status == "ok"
        bad = _job(sock, tmp_path, "no_such_stage", out="x.h5")
        assert bad.returncode == 1
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    rows = [dict(zip(LEDGER_COLUMNS, line.split("\t"))) for line in
            ledger.read_text().splitlines()]
    assert [(r["stage"], r["out"], r["exit"]) for r in rows] == \
        [("solve", "run.h5", "0"), ("no_such_stage", "x.h5", "1")]
    assert float(rows[0]["cpu_s"]) >= 0.4  # the model's 0.4 s in the forked solve
    assert float(rows[0]["wall_s"]) >= 0.4 and float(rows[0]["max_rss_mb"]) > 0


def _model_study(tmp_path: Path, monkeypatch, base_study: dict, source: str,
                 function: str) -> Study:
    """The study with the python model ``function`` (module:name) of ``source``, written
    to tmp_path (where the jobs import it)."""
    (tmp_path / f"{function.split(':')[0]}.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))  # the study is read where its model imports
    cfg = json.loads(json.dumps(base_study))
    cfg["forward_model"]["python"] = {"function": function}
    return Study(cfg)


def _benchmark(path: Path) -> dict[str, str]:
    lines = path.read_text().splitlines()
    assert len(lines) == 2, lines
    return dict(zip(lines[0].split("\t"), lines[1].split("\t")))


def test_the_benchmark_file_measures_the_process_that_worked(tmp_path, server, base_study,
                                                             monkeypatch):
    """The rule's benchmark file (the document's ``benchmark``) holds, in Snakemake's
    columns, what the working process cost: through the server its forked child, without
    one the client's own child; either way with the forked solve it waited for (the
    model's 0.4 s of CPU), not the client's milliseconds. A failed job leaves none."""
    study = _model_study(tmp_path, monkeypatch, base_study, BURNING, "burning:burn")
    for label, sock in (("server", server), ("fresh", None)):
        bench = tmp_path / "benchmarks" / "solve" / f"{label}.tsv"
        ok = _job(sock, tmp_path, "solve", benchmark=str(bench),
                  **_solve_args(study, 0, f"{label}.h5"))
        assert ok.returncode == 0, ok.stderr
        row = _benchmark(bench)
        assert list(row) == ["s", "h:m:s", "max_rss", "max_vms", "max_uss", "max_pss", "io_in",
                             "io_out", "mean_load", "cpu_time"]  # Snakemake's
        assert float(row["cpu_time"]) >= 0.4, (label, row)
        assert float(row["s"]) >= float(row["cpu_time"]) * 0.5, (label, row)
        assert float(row["max_rss"]) > 30, (label, row)  # NumPy at least: not the client's
    bench = tmp_path / "benchmarks" / "solve" / "server.tsv"
    bad = _job(server, tmp_path, "no_such_stage", benchmark=str(bench), out="x.h5")
    assert bad.returncode == 1 and not bench.exists()


HUNGRY = """
import numpy as np
from bayescalib.models.analytic import interface
def eat(params, **kw):
    block = np.ones(int(400e6 // 8))  # 400 MB, written
    return interface(params, **kw)
"""


def test_resources_mem_mb_limits_the_process_that_works(tmp_path, server, base_study,
                                                        monkeypatch):
    """``mem_mb`` limits the job's working process and the solve it forks (an address
    space of mem_mb beyond what it started with): a model that needs 400 MB fails with a
    MemoryError under a 150 MB limit, through the server and in the client's fallback
    (BAYESCALIB_JOBSERVER=off: a local run without a server), and solves under 2000 MB."""
    study = _model_study(tmp_path, monkeypatch, base_study, HUNGRY, "hungry:eat")
    for label, sock in (("server", server), ("fresh", None)):
        env = {"BAYESCALIB_JOBSERVER": "off"}
        tight = _job(sock, tmp_path, "solve", mem_mb=150, env=env,
                     **_solve_args(study, 0, f"{label}_tight.h5"))
        assert tight.returncode == 0, tight.stderr  # a failed solve is a record
        run = read_run(tmp_path / f"{label}_tight.h5")
        assert run.status == "failed" and "MemoryError" in run.reason, (label, run.reason)
        roomy = _job(sock, tmp_path, "solve", mem_mb=2000, env=env,
                     **_solve_args(study, 0, f"{label}_roomy.h5"))
        assert roomy.returncode == 0, roomy.stderr
        assert read_run(tmp_path / f"{label}_roomy.h5").status == "ok", label


BLAS = """
import os
def threads(params, **kw):
    raise RuntimeError("BLAS threads " + os.environ.get("OPENBLAS_NUM_THREADS", "unset"))
"""


def test_every_job_has_one_blas_thread_whatever_snakemake_grants(tmp_path, server, base_study,
                                                                monkeypatch):
    """Snakemake sets OPENBLAS_NUM_THREADS to a job's threads; a job's BLAS has one thread
    through the server and in the client's fallback alike (a GP fit with two differs
    from one with one at 1e-6, and a SLURM run, all fallbacks, then differed from the
    local run): the model, run in the job's solve process, sees 1 where the client had 4."""
    study = _model_study(tmp_path, monkeypatch, base_study, BLAS, "blas:threads")
    for label, sock in (("server", server), ("fresh", None)):
        proc = _job(sock, tmp_path, "solve", env={"OPENBLAS_NUM_THREADS": "4"},
                    **_solve_args(study, 0, f"{label}.h5"))
        assert proc.returncode == 0, proc.stderr  # a failed solve is a record
        run = read_run(tmp_path / f"{label}.h5")
        assert run.status == "failed" and "BLAS threads 1" in run.reason, (label, run.reason)


def test_a_server_refuses_jobs_once_the_source_changed_and_restarts(tmp_path, base_study):
    """The server fingerprints the package's source when it starts; once a module
    changed (here: its modification time, in a copy of the package), it refuses the
    next job with a line that says why, the client runs that job itself (from the
    source on disk), and the server restarts with the new source and serves again."""
    pkg = tmp_path / "pkg"
    shutil.copytree(REPO / "src" / "bayescalib", pkg / "bayescalib",
                    ignore=shutil.ignore_patterns("__pycache__"))
    sock = str(tmp_path / "s.sock")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(pkg), str(tmp_path)]),
           "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "bayescalib.execution.jobserver", "--serve",
                             sock], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)

    def up() -> None:
        deadline = time.monotonic() + 60
        while not os.path.exists(sock):
            assert proc.poll() is None and time.monotonic() < deadline, "server not up"
            time.sleep(0.05)

    def job(name: str) -> subprocess.CompletedProcess:
        out = subprocess.run(
            [*CLIENT, json.dumps(_doc("solve", **_solve_args(study, 0, f"{name}.h5")))],
            cwd=tmp_path, env={**env, "BAYESCALIB_JOBSERVER": sock}, capture_output=True,
            text=True, timeout=120, check=False)
        assert out.returncode == 0, out.stderr
        assert read_run(tmp_path / f"{name}.h5").status == "ok"
        return out

    study = Study(base_study)
    try:
        up()
        assert "refused" not in job("before").stderr
        module = pkg / "bayescalib" / "stages" / "jobs.py"
        st = module.stat()
        os.utime(module, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # edited during the run
        refused = job("changed").stderr
        assert "the job server refused job solve changed.h5" in refused
        assert "source changed after the server started" in refused
        up()  # restarted, importing the source as it is now
        assert "refused" not in job("after").stderr
    finally:
        proc.terminate()
        log = proc.communicate(timeout=30)[0]
    assert "restarting with the changed source" in log, log
    assert log.count("preloaded in") == 2, log


@pytest.mark.parametrize("function", ["segfault", "leave"])
def test_a_crashing_model_is_a_failed_record_and_the_job_succeeds(tmp_path, server, base_study,
                                                                  function, monkeypatch):
    (tmp_path / "crashing.py").write_text(CRASHING)
    monkeypatch.syspath_prepend(str(tmp_path))  # the study is read where its model imports
    cfg = json.loads(json.dumps(base_study))
    cfg["forward_model"]["python"] = {"function": f"crashing:{function}"}
    study = Study(cfg)
    proc = _job(server, tmp_path, "solve", **_solve_args(study, 0, "run.h5"))
    assert proc.returncode == 0, proc.stderr
    run = read_run(tmp_path / "run.h5")
    assert run.status == "failed" and "solver process died" in run.reason


def test_a_job_whose_client_goes_away_is_killed_with_its_solve(tmp_path, server, base_study,
                                                              monkeypatch):
    (tmp_path / "crashing.py").write_text(CRASHING)
    monkeypatch.syspath_prepend(str(tmp_path))  # the study is read where its model imports
    cfg = json.loads(json.dumps(base_study))
    cfg["forward_model"]["python"] = {"function": "crashing:hang"}
    cfg["forward_model"]["time_limit_s"] = 300
    study = Study(cfg)
    env = {**os.environ, "BAYESCALIB_JOBSERVER": server, "PYTHONPATH": _path(tmp_path)}
    args = _solve_args(study, 0, "run.h5")
    client = subprocess.Popen([*CLIENT, json.dumps(_doc("solve", **args))], cwd=tmp_path,
                              env=env)
    solver = _solver_pid(tmp_path, client)
    assert _alive(solver)
    client.kill()  # Snakemake cancels the job
    client.wait()
    assert _wait_gone(solver), "the solve of a cancelled job lives on"
    assert not (tmp_path / "run.h5").exists()


def test_the_server_and_its_jobs_end_when_the_run_is_killed(tmp_path, base_study, monkeypatch):
    """The run's Snakemake process is killed alone (kill -9 PID): its server notices,
    kills the jobs it runs (and their solves) and exits; nothing is left holding the
    study's job lock."""
    (tmp_path / "crashing.py").write_text(CRASHING)
    monkeypatch.syspath_prepend(str(tmp_path))  # the study is read where its model imports
    cfg = json.loads(json.dumps(base_study))
    cfg["forward_model"]["python"] = {"function": "crashing:hang"}
    cfg["forward_model"]["time_limit_s"] = 300
    study = Study(cfg)
    code = ("import sys, time\nfrom bayescalib.execution.jobserver import start_server\n"
            "print(start_server(sys.argv[1]), flush=True)\ntime.sleep(600)\n")
    run = subprocess.Popen(
        [sys.executable, "-c", code, str(tmp_path / "root")],
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": _path(tmp_path)}, stdout=subprocess.PIPE,
        text=True)
    sock = run.stdout.readline().strip()
    assert sock and os.path.exists(sock), sock
    args = _solve_args(study, 0, "run.h5")
    client = subprocess.Popen([*CLIENT, json.dumps(_doc("solve", **args))], cwd=tmp_path,
                              env={**os.environ, "BAYESCALIB_JOBSERVER": sock,
                                   "PYTHONPATH": _path(tmp_path)})
    solver = _solver_pid(tmp_path, client)
    run.send_signal(signal.SIGKILL)
    run.wait()
    assert _wait_gone(solver), "a solve outlives its killed run"
    assert client.wait(timeout=10) != 0  # the client hears that its server went away
    deadline = time.monotonic() + 10
    while os.path.exists(sock) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not os.path.exists(sock)
    # the round server too (it notices once its imports are done, then exits)
    import psutil

    from bayescalib.execution.jobserver import socket_path

    round_sock = socket_path(tmp_path / "root", "round")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        left = [p for p in psutil.process_iter(["cmdline"])
                if round_sock in (p.info["cmdline"] or [])]
        if not left:
            break
        time.sleep(0.2)
    assert not left, "the round server outlives its killed run"
    assert not os.path.exists(round_sock)


def _jobs_run(log: str, kind: str) -> int:
    return int(log.split(f"jobserver ({kind}): ")[-1].split(" jobs run")[0])


@pytest.mark.workflow
def test_a_local_run_hands_its_per_point_jobs_to_the_server(done_run):
    log = (done_run / STUDY / "logs" / "jobserver.log").read_text()
    # point server: 8 solves, 8 discrepancies, gather; round server: train_surrogate,
    # smc, marginalize and the figures (a per-round job that came before the round
    # server was up ran on the point server, so the sum is what is certain)
    assert _jobs_run(log, "point") >= 17, log
    assert _jobs_run(log, "point") + _jobs_run(log, "round") >= 17 + 3 + 4, log
    # one ledger line per job the servers ran, under the run's header
    ledger = (done_run / STUDY / "logs" / "jobserver_jobs.tsv").read_text().splitlines()
    stages = [line.split("\t")[1] for line in ledger[1:]]
    assert ledger[0].split("\t")[:2] == ["server", "stage"]
    assert len(stages) == _jobs_run(log, "point") + _jobs_run(log, "round")
    assert stages.count("solve") >= 8 and stages.count("discrepancy") >= 8


def test_the_client_and_the_server_agree_on_the_round_stages():
    """scripts/job.py imports nothing of the package: its copy of the set of stages for
    the round server must be the server's."""
    import runpy

    from bayescalib.execution.jobserver import ROUND_STAGES, STAGES

    client = runpy.run_path(str(REPO / "scripts" / "job.py"), run_name="not_main")
    assert client["ROUND_STAGES"] == ROUND_STAGES
    assert ROUND_STAGES <= set(STAGES)


PROBE = """
import json, sys
from bayescalib.execution import jobserver as js
js._import_all(js._PRELOAD)
from bayescalib.config import load_schemas
load_schemas()
docs = json.loads(sys.argv[1])
new = {}
for stage in ("solve", "discrepancy"):
    before = set(sys.modules)
    js.run_job(docs[stage])
    new[stage] = sorted(set(sys.modules) - before)
print(json.dumps(new))
"""


def test_a_per_point_job_imports_nothing_the_point_server_has_not(done_run, base_study,
                                                                  tmp_path):
    """The point server's imports (its _PRELOAD) are every module a solve and a
    discrepancy job import, so that no job pays for an import (or, where bytecode is
    not cached, for compiling one); the python model's own module aside."""
    study = Study(base_study)
    root = done_run / STUDY
    solve = _solve_args(study, 2, str(tmp_path / "s.h5"))
    solve["log"] = str(tmp_path / "s.log")
    docs = {"solve": _doc("solve", **solve),
            "discrepancy": _doc("discrepancy", **_disc_args(
                study, str(root), 2, str(tmp_path / "d.json"), str(tmp_path / "d.log")))}
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(docs)], cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": _path(tmp_path)},
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    new = json.loads(proc.stdout.strip().splitlines()[-1])
    model = study.config["forward_model"]["python"]["function"].split(":")[0]
    assert [m for m in new["solve"] if m != model] == []
    assert new["discrepancy"] == []


class _Named(list):
    """Snakemake's named lists as a rule function sees them (snakemake.io.Namedlist):
    positional entries, and named ones (a file or a list of files)."""

    def __init__(self, *positional: Any, **named: Any) -> None:
        super().__init__(positional)
        self._named = named
        for value in named.values():
            self.extend(value if isinstance(value, list) else [value])

    def items(self):
        return self._named.items()


def _namespace(**parts: Any) -> dict[str, Any]:
    ns = {"rule": "gather", "bench_record": None, "threads": 2, "input": _Named(),
          "output": _Named(), "params": _Named(), "log": _Named(), "resources": _Named()}
    ns.update(parts)
    return ns


def test_a_job_document_holds_the_named_entries_of_its_rule_once():
    """The rule's named inputs, outputs and params are the stage's keyword arguments
    (lists of paths as lists, an empty input as an empty list, params as their values);
    its unnamed entries (rerun triggers) are left out; the unnamed log entry is the
    log, ``benchmark=`` the benchmark file; mem_mb from the resources. The command is
    the client with the document as one shell-quoted JSON argument; at parse time it is
    the template Snakemake records as the rule's code."""
    import shlex

    from bayescalib.execution.jobserver import JOB_TEMPLATE, job_command, job_document

    ns = _namespace(
        input=_Named("trigger.json", run_paths=["r/0.h5", "r 1.h5"], disc_paths=[]),
        output=_Named(out_path="t.h5"),
        params=_Named(["set", "aside"], names=["E", "nu"], n_train=None, cfg={"a": [1, 2.5]}),
        log=_Named("logs/g.log", benchmark="benchmarks/g.tsv"),
        resources=_Named(mem_mb=1500, _cores=2))
    doc = job_document(ns)
    assert doc == {"stage": "gather", "args": {
        "run_paths": ["r/0.h5", "r 1.h5"], "disc_paths": [], "out_path": "t.h5",
        "names": ["E", "nu"], "n_train": None, "cfg": {"a": [1, 2.5]}},
        "log": "logs/g.log", "benchmark": "benchmarks/g.tsv", "mem_mb": 1500, "threads": 2,
        "out": "t.h5"}
    assert job_document(ns, "smc")["stage"] == "smc"
    assert job_document(_namespace())["mem_mb"] is None
    command = job_command(ns).format()  # Snakemake formats it once more
    words = shlex.split(command)
    assert words[:4] == ["$BAYESCALIB_PYTHON", "-I", "-S", "$BAYESCALIB_JOB_CLIENT"]
    assert json.loads(words[4]) == doc and len(words) == 5
    assert job_command({"workflow": None, "params": None}) == JOB_TEMPLATE
    with pytest.raises(ValueError, match="'n_train' is named twice"):
        job_document(_namespace(input=_Named(n_train="x"), params=_Named(n_train=3)))


def test_a_per_round_job_goes_to_the_point_server_while_the_round_server_is_not_up(
        done_run, tmp_path, server):
    """BAYESCALIB_JOBSERVER_ROUND naming no live socket: the client hands a per-round
    job (train_surrogate) to the point server, whose child imports GPy itself; the
    surrogate is the one of the run (bitwise: same training table, same seeds)."""
    import h5py
    import yaml

    study = Study(yaml.safe_load((done_run / "config" / "config.yaml").read_text()))
    env = {**os.environ, "PYTHONPATH": _path(tmp_path), "BAYESCALIB_JOBSERVER": server,
           "BAYESCALIB_JOBSERVER_ROUND": str(tmp_path / "absent.sock")}
    root = done_run / STUDY
    out = tmp_path / "surrogate.h5"
    doc = _doc("train_surrogate", log=str(tmp_path / "t.log"), out_path=str(out),
               training_path=str(root / "rkhs" / "training.h5"),
               surrogate=study.config["surrogate"], parameters=study.config["parameters"])
    proc = subprocess.run(
        [*CLIENT, json.dumps(doc)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    with h5py.File(out) as mine, h5py.File(root / "rkhs" / "surrogate.h5") as ref:
        for key in ("alpha", "chol", "X_train", "y_train"):
            assert (mine[key][()] == ref[key][()]).all(), key


@pytest.mark.workflow
def test_a_moved_checkout_reruns_nothing(done_run, tmp_path):
    """The per-point rules' shell commands name no path of this machine (interpreter,
    client script): the same results with the workflow in another folder, run by
    another interpreter path, are up to date (Snakemake reruns a shell rule whose
    command text changed)."""
    import subprocess as sp

    moved = tmp_path / "elsewhere" / "checkout"
    moved.mkdir(parents=True)
    shutil.copy(REPO / "Snakefile", moved / "Snakefile")
    for d in ("workflow", "scripts"):
        shutil.copytree(REPO / d, moved / d, symlinks=True)
    tmp = tmp_path / "run"
    shutil.copytree(done_run, tmp, symlinks=True)
    python = sys.executable
    if sys.prefix != sys.base_prefix:  # a venv: reach the same one by another path
        link = tmp_path / "venv-elsewhere"
        link.symlink_to(sys.prefix, target_is_directory=True)
        python = str(link / Path(sys.executable).relative_to(sys.prefix))
    proc = sp.run([python, "-m", "snakemake", "-s", str(moved / "Snakefile"), "--directory",
                   str(tmp), "--cores", "2", "-n"], check=False, capture_output=True, text=True,
                  env={**os.environ, "PYTHONPATH": _path(tmp)}, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr, (proc.stdout + proc.stderr)[-3000:]


def test_an_allocation_refused_under_the_limit_names_mem_mb(monkeypatch, tmp_path):
    """Found on the 3D example (an RKHS distance of a volume's 22 000-vertex surface):
    torch's refused allocation under a job's limit read "DefaultCPUAllocator: can't
    allocate memory". The job now fails with a MemoryError that names the limit and how
    to raise it; other errors pass unchanged (the limit itself is not applied here)."""
    from bayescalib.execution import jobserver

    def torch_like(**kw):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't "
                           "allocate memory: you tried to allocate 8388608 bytes.")

    def other(**kw):
        raise RuntimeError("a bug")

    monkeypatch.setenv(jobserver.SOCKET_ENV, str(tmp_path / "sock"))
    monkeypatch.setattr(jobserver, "limit_memory", lambda mem_mb: 1 << 30)
    doc = {"stage": "discrepancy", "args": {}, "log": None, "mem_mb": 1000, "threads": 1}
    monkeypatch.setattr(jobserver, "_stage_function", lambda stage: torch_like)
    with pytest.raises(MemoryError, match=r"job discrepancy: an allocation was refused under "
                       r"the job's memory limit \(resources.mem_mb = 1000 MB .*"
                       r"--set-resources <rule>:mem_mb=2000"):
        jobserver.run_job(doc)
    monkeypatch.setattr(jobserver, "_stage_function", lambda stage: other)
    with pytest.raises(RuntimeError, match="^a bug$"):
        jobserver.run_job(doc)
