"""Client of a per-point job (rules `solve` and `discrepancy`): hands the job to the
run's warm job server and exits with the job's status (bayescalib.execution.jobserver).

Started as ``python -I -S scripts/job.py STAGE KEY VALUE ...`` by the rule's shell
command: the standard library only, no site-packages, so it starts in milliseconds.
Without a server (none started, or on another machine) it runs the job in-process:
``python -m bayescalib.execution.jobserver --run STAGE KEY VALUE ...``.
"""

import array
import json
import os
import socket
import sys


def main() -> int:
    stage, rest = sys.argv[1], sys.argv[2:]
    path = os.environ.get("BAYESCALIB_JOBSERVER")
    conn = None
    if path:
        try:
            conn = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            conn.connect(path)
        except OSError:
            conn = None
    if conn is None:
        python = sys.executable
        os.execv(python, [python, "-m", "bayescalib.execution.jobserver", "--run", stage, *rest])
    request = {"stage": stage, "args": dict(zip(rest[::2], rest[1::2])), "cwd": os.getcwd(),
               "env": dict(os.environ)}
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
