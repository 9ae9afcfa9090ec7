"""Client of a job of the workflow (rules `solve`, `discrepancy`, `gather`, the per-round
and per-measure stages, the figures): hands the job to the run's warm job server and
exits with the job's status (bayescalib.execution.jobserver).

Started as ``python -I -S scripts/job.py JOB_DOCUMENT`` by the rule's shell command
(``shell: job(locals())``, bayescalib.execution.jobserver.job_command): the job's stage,
its arguments, its log, its benchmark file and its memory limit as one JSON document.
The standard library only, no site-packages, so it starts in milliseconds.
The stages of ROUND_STAGES go to the round server (``BAYESCALIB_JOBSERVER_ROUND``)
when it is up, the others (and those, until it is) to the point server
(``BAYESCALIB_JOBSERVER``). Without a server (none started, or on another machine), or
when the server refuses the job (the package's source changed since it started), it
runs the job in a child process of its own: ``python -m bayescalib.execution.jobserver
--run-job`` with the document on standard input.

Either way it writes the rule's benchmark file (the document's ``benchmark``, a named
``log:`` entry of the rule) after a successful job, in Snakemake's columns, with what the
process that worked cost (the server's forked child, or the fallback's child, with the
processes each waited for, e.g. a solve's): ``s`` its wall time, ``cpu_time`` its user +
system time, ``max_rss`` its peak resident memory (MB), ``io_in``/``io_out`` what it read
from and wrote to disk (MB), ``mean_load`` cpu_time / s; ``max_vms``, ``max_uss`` and
``max_pss`` are not measured ("-"). A failed job leaves no benchmark file.
"""

import array
import json
import os
import socket
import sys
import time

#: the same set as bayescalib.execution.jobserver.ROUND_STAGES (tested)
ROUND_STAGES = frozenset({"train_surrogate", "smc", "acquire", "marginalize", "fig_response",
                          "fig_convergence", "fig_posterior", "fig_interfaces", "fig_fields",
                          "fig_rounds", "fig_segmentation", "summary", "posterior_check"})

#: Snakemake's benchmark columns (snakemake.benchmark.BenchmarkRecord.get_header)
BENCHMARK_COLUMNS = ("s", "h:m:s", "max_rss", "max_vms", "max_uss", "max_pss", "io_in", "io_out",
                     "mean_load", "cpu_time")


def _connect(path):
    if not path:
        return None
    try:
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        conn.connect(path)
    except OSError:
        return None
    return conn


def _through_server(conn, doc, path):
    """The server's answer: ``{"exit", "wall_s", ...}``, or None where it refused the job."""
    request = {"job": doc, "cwd": os.getcwd(), "env": dict(os.environ)}
    sys.stdout.flush()
    sys.stderr.flush()
    conn.sendmsg([json.dumps(request).encode()],
                 [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", [1, 2]))])
    reply = conn.recv(4096)
    conn.close()
    if not reply:
        sys.stderr.write(f"bayescalib: the job server ({path}) went away during job "
                         f"{doc.get('stage')} {doc.get('out', '')}\n")
        return {"exit": 1}
    answer = json.loads(reply.decode())
    if "refused" in answer:
        sys.stderr.write(f"bayescalib: the job server refused job {doc.get('stage')} "
                         f"{doc.get('out', '')}: {answer['refused']}; running it here\n")
        return None
    return answer


def _here(text):
    """Run the job in a child process (its imports paid here): its exit status and cost."""
    import subprocess

    python = sys.executable
    t0 = time.monotonic()
    proc = subprocess.Popen([python, "-m", "bayescalib.execution.jobserver", "--run-job"],
                            stdin=subprocess.PIPE)
    try:
        proc.stdin.write(text.encode())
    except BrokenPipeError:
        pass
    proc.stdin.close()
    _, status, usage = os.wait4(proc.pid, 0)
    code = os.waitstatus_to_exitcode(status)
    proc.returncode = code  # waited for here (wait4 gives its cost)
    return {"exit": code if code >= 0 else 128 - code, "wall_s": time.monotonic() - t0,
            "cpu_s": usage.ru_utime + usage.ru_stime, "max_rss_mb": usage.ru_maxrss / 1024.0,
            "io_in_mb": usage.ru_inblock * 512 / 1e6, "io_out_mb": usage.ru_oublock * 512 / 1e6}


def benchmark_text(cost):
    """Snakemake's benchmark TSV (header and one line) of a job's cost."""
    wall, cpu = float(cost["wall_s"]), float(cost["cpu_s"])
    h, rest = divmod(int(wall), 3600)
    m, s = divmod(rest, 60)
    row = (f"{wall:.4f}", f"{h}:{m:02d}:{s:02d}", f"{float(cost['max_rss_mb']):.2f}", "-", "-", "-",
           f"{float(cost.get('io_in_mb', 0.0)):.2f}", f"{float(cost.get('io_out_mb', 0.0)):.2f}",
           f"{cpu / wall if wall > 0 else 0.0:.2f}", f"{cpu:.4f}")
    return "\t".join(BENCHMARK_COLUMNS) + "\n" + "\t".join(row) + "\n"


def _write_benchmark(path, result):
    if not path:
        return
    if result.get("exit") != 0 or "wall_s" not in result:
        try:  # a failed job has no benchmark (as with Snakemake's benchmark:)
            os.unlink(path)
        except OSError:
            pass
        return
    try:
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        with open(path, "w") as fh:
            fh.write(benchmark_text(result))
    except OSError as exc:
        sys.stderr.write(f"bayescalib: benchmark file {path} not written: {exc}\n")


def main() -> int:
    if len(sys.argv) != 2:
        sys.stderr.write("usage: python -I -S scripts/job.py JOB_DOCUMENT (JSON)\n")
        return 2
    text = sys.argv[1]
    doc = json.loads(text)
    path = os.environ.get("BAYESCALIB_JOBSERVER")
    conn = None
    if doc.get("stage") in ROUND_STAGES:
        conn = _connect(os.environ.get("BAYESCALIB_JOBSERVER_ROUND"))
    if conn is None:
        conn = _connect(path)
    result = None if conn is None else _through_server(conn, doc, path)
    if result is None:
        result = _here(text)
    _write_benchmark(doc.get("benchmark"), result)
    return int(result["exit"])


if __name__ == "__main__":
    sys.exit(main())
