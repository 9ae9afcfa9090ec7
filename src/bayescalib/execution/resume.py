"""One command starts a study and resumes it, however its last run ended.

The README's command for a study (``snakemake --cores 2 --configfile
config/<study>.yaml``) is also its resume command, after Ctrl-C, a kill of Snakemake
and its jobs, or a power loss. Two things would stop Snakemake on its own:

* the outputs of the jobs that were running when the run ended are marked incomplete
  (a run record written in the instant of a Ctrl-C is one); Snakemake refuses to plan
  over them without ``--rerun-incomplete``. The profiles (``workflow/profiles/``) set
  ``rerun-incomplete: true``: those jobs run again, nothing else does.
* a run killed hard (SIGKILL, power loss) leaves its lock files in
  ``.snakemake/locks``; Snakemake refuses to run until ``snakemake --unlock``, which
  removes every lock of the directory, those of other studies' live runs included.

:func:`claim_run`, called when the Snakefile is read by a command that may run jobs,
makes the resume safe instead: it takes the study's run lock (a kernel lock, held
only by a live run, :func:`bayescalib.study.hold_run_lock`), so a live run of the
study is never resumed over; waits a few seconds for the jobs of a killed run that
are still ending (and refuses, naming them, if they do not end); and only then removes
the Snakemake lock files that name this study's files, which no live run holds any
more. Another study's locks are left alone.

:func:`report_refusal` says, instead of Snakemake's "summary.json ... does not exist",
why a report cannot be made yet: the study is being run, or its run has not finished.

Imported when the Snakefile is parsed: standard library only.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

from bayescalib.study import (
    StudyBusyError,
    hold_run_lock,
    job_lock_holders,
    run_lock_holder,
)

__all__ = ["asks_report", "claim_run", "configfile_words", "report_note", "report_path",
           "report_refusal", "stale_snakemake_locks"]

#: Snakemake's lock folder, relative to the working directory (FilePersistence)
SNAKEMAKE_LOCKS = Path(".snakemake") / "locks"
#: seconds a new run waits for the jobs of a killed run to end (they end within about
#: a second of their Snakemake: the job server sees its parent gone and kills them)
ORPHAN_WAIT_S = 15.0


def _under(path: str, root: str) -> bool:
    p, r = os.path.abspath(path), os.path.abspath(root)
    return p == r or p.startswith(r.rstrip(os.sep) + os.sep)


def stale_snakemake_locks(root: str | Path, locks: str | Path = SNAKEMAKE_LOCKS) -> list[Path]:
    """Snakemake's lock files (``<n>.input.lock``, ``<n>.output.lock`` in ``locks``)
    that name a file under ``root``: the locks of a run of the study whose outputs are
    there. Stale only when no run of that study is alive (see :func:`claim_run`)."""
    folder = Path(locks)
    if not folder.is_dir():
        return []
    found = []
    for lock in sorted(folder.glob("*.lock")):
        try:
            lines = lock.read_text().splitlines()
        except (OSError, UnicodeDecodeError):
            continue
        if any(line.strip() and _under(line.strip(), str(root)) for line in lines):
            found.append(lock)
    return found


def _orphans_message(name: str, pids: list[int]) -> str:
    return (f"jobs of an earlier run of study '{name}' are still running (pid "
            f"{', '.join(map(str, pids)) or 'unknown'}): that run was killed and left them "
            "behind. Wait for them to end (or kill them), then run the same command again "
            "to resume; a run beside them would redo their work.")


def claim_run(root: str | Path, name: str, *, locks: str | Path = SNAKEMAKE_LOCKS,
              orphan_wait_s: float = ORPHAN_WAIT_S) -> list[str]:
    """Make this process the one run of the study whose outputs are under ``root``,
    ready to resume wherever the last run stopped.

    1. Takes the study's run lock for the life of this process
       (:func:`bayescalib.study.hold_run_lock`): a run of the study that is alive
       holds it, so the study is never resumed (or unlocked) over a live run.
    2. Waits up to ``orphan_wait_s`` for the jobs of a killed run that are still
       ending (:func:`bayescalib.study.job_lock_holders`).
    3. Removes Snakemake's lock files that name files under ``root``
       (:func:`stale_snakemake_locks`): after 1 and 2 no live process holds them.

    Returns notes for the console (the stale locks removed). Raises
    :class:`bayescalib.study.StudyBusyError` (naming the pids) if the study is being
    run, or if jobs of a killed run are still running after ``orphan_wait_s``.
    """
    hold_run_lock(root, name)
    deadline = time.monotonic() + orphan_wait_s
    while (pids := job_lock_holders(root)) is not None:
        if time.monotonic() >= deadline:
            raise StudyBusyError(_orphans_message(name, pids))
        time.sleep(0.2)
    notes = []
    stale = stale_snakemake_locks(root, locks)
    for lock in stale:
        try:
            lock.unlink()
        except FileNotFoundError:
            pass
    if stale:
        notes.append(
            f"removed Snakemake's lock left by an interrupted run of study '{name}' "
            f"({', '.join(str(p) for p in stale)}); no run of the study is alive "
            f"(its run lock {Path(root) / '.run.lock'} was free), so the run resumes")
    return notes


def asks_report(argv: Sequence[str]) -> bool:
    """Whether a Snakemake command line (``sys.argv``) asks for the HTML report."""
    return any(a.split("=", 1)[0] == "--report" for a in argv[1:])


def report_path(argv: Sequence[str]) -> str | None:
    """The path a Snakemake command line (``sys.argv``) gives ``--report`` (Snakemake's
    ``report.html`` for a bare ``--report``), or None without ``--report``."""
    args = list(argv[1:])
    for i, a in enumerate(args):
        key, eq, value = a.partition("=")
        if key == "--report":
            if eq:
                return value
            nxt = args[i + 1] if i + 1 < len(args) else None
            return nxt if nxt is not None and not nxt.startswith("-") else "report.html"
    return None


def report_note(root: str | Path, argv: Sequence[str]) -> str | None:
    """A note when the report goes outside the study's folder (where the report of
    another study made with the same command would replace it), or None."""
    path = report_path(argv)
    if path is None or _under(path, str(root)):
        return None
    return (f"the report goes to {path}, outside {root}/: a report of another study made "
            f"at the same path replaces it; {root}/report.html keeps one per study")


def configfile_words(argv: Sequence[str]) -> str:
    """The ``--configfile ...`` words of a Snakemake command line, as typed (empty for
    the default study), for the commands a message suggests."""
    words: list[str] = []
    taking = False
    for a in argv[1:]:
        key, eq, value = a.partition("=")
        if key in ("--configfile", "--configfiles"):
            words.append(key)
            if eq:
                words.append(value)
                taking = False
            else:
                taking = True
        elif taking and not a.startswith("-"):
            words.append(a)
        else:
            taking = False
    return " ".join(words)


def report_refusal(root: str | Path, name: str, argv: Sequence[str]) -> str | None:
    """Why the report of the study under ``root`` cannot be made now, with what to do,
    or None when it can: the study is being run (its run lock is held: the report
    would mix this run's files with the last one's), or its run has not finished (no
    ``summary.json``, which the run writes last)."""
    study = configfile_words(argv)
    study = f" {study}" if study else ""
    report = f"snakemake --report {root}/report.html{study}"
    holder = run_lock_holder(root)
    if holder is not None:
        return (f"study '{name}' is being run right now ({holder}; lock {root}/.run.lock): "
                "its report can be made once the run has ended. Wait for the run to end, "
                f"then run: {report}")
    summary = Path(root) / "summary.json"
    if summary.is_file():
        return None
    state = ("its run has not finished (interrupted or failed)" if Path(root).is_dir()
             else "it has not been run")
    return (f"study '{name}' has no results yet: {summary} does not exist, {state}. Run "
            f"it (the same command resumes an interrupted run): snakemake --cores 2{study}; "
            f"then make the report: {report}")
