"""A real single-node SLURM cluster on this machine, for trying the SLURM profile.

Starts munged, slurmctld and slurmd from the Debian packages (``apt-get install
slurm-wlm munge``) with a configuration written under a state folder: one node
(this host, its CPUs and memory), one partition ``compute``, no accounting
database (job states come from ``squeue``, kept 10 min after a job ends), no
cgroups (process tracking by ``/proc``). Must run as root (the daemons' users).

Usage::

    python benchmarks/slurm_cluster.py start [--state /tmp/bayescalib-slurm]
    python benchmarks/slurm_cluster.py status
    python benchmarks/slurm_cluster.py stop  [--state ...]

The configuration is also written to ``/etc/slurm/slurm.conf`` unless a configuration
this script did not write is there (``srun`` inside a batch job reads that path).
``start`` prints the environment to use (``SLURM_CONF=...``); the SLURM commands
(sbatch, squeue, scancel) and Snakemake's SLURM executor then talk to this cluster.
The test ``tests/test_slurm.py`` runs the smoke study through
``workflow/profiles/slurm`` against it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

DEFAULT_STATE = Path("/tmp/bayescalib-slurm")
DAEMONS = ("slurmctld", "slurmd", "munged")
MARKER = "# written by benchmarks/slurm_cluster.py"


def missing() -> str | None:
    """Why a cluster cannot be started here, or None."""
    if os.geteuid() != 0:
        return "the SLURM daemons need root"
    for exe in ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "scontrol"):
        if shutil.which(exe) is None and not Path("/usr/sbin", exe).exists():
            return f"'{exe}' is not installed (apt-get install slurm-wlm munge)"
    return None


def _conf(state: Path) -> str:
    host = socket.gethostname().split(".")[0]
    cpus = os.cpu_count() or 1
    mem_mb = int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20 * 0.9)
    return f"""{MARKER}
ClusterName=bayescalib
SlurmctldHost={host}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation={state}/ctld
SlurmdSpoolDir={state}/d
SlurmctldPidFile={state}/slurmctld.pid
SlurmdPidFile={state}/slurmd.pid
SlurmctldLogFile={state}/slurmctld.log
SlurmdLogFile={state}/slurmd.log
SlurmctldPort=6817
SlurmdPort=6818
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MinJobAge=600
ReturnToService=2
SlurmdTimeout=300
InactiveLimit=0
KillWait=5
NodeName={host} CPUs={cpus} RealMemory={mem_mb} State=UNKNOWN
PartitionName=compute Nodes={host} Default=YES MaxTime=INFINITE State=UP
"""


def _run(*cmd: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(list(cmd), check=check, capture_output=True, text=True)


def start(state: Path = DEFAULT_STATE, timeout: float = 60.0) -> dict[str, str]:
    """Start the cluster; return the environment variables that point to it."""
    why = missing()
    if why:
        raise RuntimeError(f"cannot start a SLURM cluster: {why}")
    stop(state)
    for d in ("ctld", "d"):
        (state / d).mkdir(parents=True, exist_ok=True)
    conf = state / "slurm.conf"
    conf.write_text(_conf(state))
    # the default path too: srun inside a batch job reads it (SLURM_CONF is not passed
    # to job steps everywhere); never over a configuration this script did not write
    system = Path("/etc/slurm/slurm.conf")
    if not system.exists() or system.read_text().startswith(MARKER):
        system.parent.mkdir(parents=True, exist_ok=True)
        system.write_text(conf.read_text())
    env = {"SLURM_CONF": str(conf)}
    # munge: a key and the daemon (as the munge user the package created)
    key = Path("/etc/munge/munge.key")
    if not key.exists():
        _run("/usr/sbin/mungekey", "--create", f"--keyfile={key}")
        shutil.chown(key, "munge", "munge")
        key.chmod(0o400)
    Path("/run/munge").mkdir(parents=True, exist_ok=True)
    shutil.chown("/run/munge", "munge", "munge")
    if _run("pgrep", "-x", "munged", check=False).returncode != 0:
        _run("runuser", "-u", "munge", "--", "/usr/sbin/munged")
    full = {**os.environ, **env}
    subprocess.run(["/usr/sbin/slurmctld"], check=True, env=full)
    subprocess.run(["/usr/sbin/slurmd"], check=True, env=full)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True,
                             env=full, check=False).stdout.strip()
        if out in ("idle", "mix", "alloc"):
            return env
        if out in ("down", "drain", "unk", "down*", "unk*"):
            subprocess.run(["scontrol", "update", f"NodeName={socket.gethostname().split('.')[0]}",
                            "State=RESUME"], env=full, check=False, capture_output=True)
        time.sleep(0.5)
    raise RuntimeError(f"the SLURM node did not become idle within {timeout:g} s; "
                       f"see {state}/slurmctld.log and {state}/slurmd.log")


def stop(state: Path = DEFAULT_STATE) -> None:
    """Stop slurmctld and slurmd of this state folder (munged is left running) and remove
    the ``/etc/slurm/slurm.conf`` that :func:`start` wrote.

    A configuration left behind without its controller costs every later ``snakemake``
    call about 9 s: the SLURM executor plugin runs ``scontrol show config`` when it is
    loaded, and ``scontrol`` waits for the controller named there before it gives up.
    """
    system = Path("/etc/slurm/slurm.conf")
    if system.is_file() and system.read_text().startswith(MARKER):
        system.unlink()
    for name in ("slurmctld", "slurmd"):
        pid = state / f"{name}.pid"
        if pid.exists():
            try:
                os.kill(int(pid.read_text().strip()), 15)
            except (ProcessLookupError, ValueError):
                pass
            pid.unlink(missing_ok=True)
    _run("pkill", "-x", "slurmctld", check=False)
    _run("pkill", "-x", "slurmd", check=False)
    time.sleep(0.5)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("action", choices=["start", "stop", "status"])
    ap.add_argument("--state", type=Path, default=DEFAULT_STATE)
    a = ap.parse_args()
    if a.action == "start":
        env = start(a.state)
        print(" ".join(f"{k}={v}" for k, v in env.items()))
    elif a.action == "stop":
        stop(a.state)
    else:
        why = missing()
        print(why or "SLURM can be started here")
        subprocess.run(["sinfo"], env={**os.environ, "SLURM_CONF": str(a.state / "slurm.conf")},
                       check=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
