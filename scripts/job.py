"""Client of a job of the workflow (rules `solve`, `discrepancy`, `gather`, the per-round
and per-measure stages, the figures): hands the job to the run's warm job server and
exits with the job's status (bayescalib.execution.jobserver).

Started as ``python -I -S scripts/job.py STAGE KEY VALUE ...`` by the rule's shell
command: the standard library only, no site-packages, so it starts in milliseconds.
The stages of ROUND_STAGES go to the round server (``BAYESCALIB_JOBSERVER_ROUND``)
when it is up, the others (and those, until it is) to the point server
(``BAYESCALIB_JOBSERVER``). Without a server (none started, or on another machine) it
runs the job in-process: ``python -m bayescalib.execution.jobserver --run STAGE KEY
VALUE ...``.
"""

import array
import json
import os
import socket
import sys

#: the same set as bayescalib.execution.jobserver.ROUND_STAGES (tested)
ROUND_STAGES = frozenset({"train_surrogate", "smc", "acquire", "marginalize", "fig_response",
                          "fig_convergence", "fig_posterior", "fig_interfaces", "fig_fields",
                          "fig_rounds", "fig_segmentation", "summary", "posterior_check"})


def _connect(path):
    if not path:
        return None
    try:
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        conn.connect(path)
    except OSError:
        return None
    return conn


def main() -> int:
    stage, rest = sys.argv[1], sys.argv[2:]
    path = os.environ.get("BAYESCALIB_JOBSERVER")
    conn = None
    if stage in ROUND_STAGES:
        conn = _connect(os.environ.get("BAYESCALIB_JOBSERVER_ROUND"))
    if conn is None:
        conn = _connect(path)
    if conn is None:
        python = sys.executable
        os.execv(python, [python, "-m", "bayescalib.execution.jobserver", "--run", stage, *rest])
    request = {"stage": stage, "argv": rest, "cwd": os.getcwd(), "env": dict(os.environ)}
    sys.stdout.flush()
    sys.stderr.flush()
    conn.sendmsg([json.dumps(request).encode()],
                 [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", [1, 2]))])
    reply = conn.recv(4096)
    if not reply:
        sys.stderr.write(f"bayescalib: the job server ({path}) went away during job "
                         f"{stage} {' '.join(rest[:4])}\n")
        return 1
    return int(json.loads(reply.decode())["exit"])


if __name__ == "__main__":
    sys.exit(main())
