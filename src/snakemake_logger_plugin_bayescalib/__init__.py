"""Snakemake logger plugin of bayescalib (``snakemake --logger bayescalib``; the default
profile sets it): Snakemake's own console output, quieter and with the time left.

* The per-job blocks (rule, input, output, wildcards, resources: eight lines per job,
  thousands in a large study) are not printed; each job's log file under
  ``results/<study>/logs/`` holds what the job did. Errors, failed jobs with their log
  (``show-failed-logs``), warnings and the run summary are printed as before.
  The scheduler's "Select jobs to execute..." is left out too. ``--verbose``, and a
  dry run (``-n``, read for its jobs), bring all of it back. The jobs themselves print
  warnings and errors only (their information goes to their log file,
  :func:`bayescalib.stages.setup_logging`).
* The progress line carries an estimate of the time left
  (:func:`bayescalib.execution.progress.progress_line`).
"""

from __future__ import annotations

import logging
import sys
import time

from snakemake_interface_logger_plugins.base import LogHandlerBase
from snakemake_interface_logger_plugins.common import LogEvent

from bayescalib.execution.progress import progress_line

__all__ = ["LogHandler"]

#: events left out of the console unless --verbose: the per-job start and finish blocks
_PER_JOB = {LogEvent.JOB_INFO, LogEvent.JOB_STARTED, LogEvent.JOB_FINISHED,
            LogEvent.SHELLCMD, LogEvent.GROUP_INFO}

#: scheduler lines without information for the user
_SCHEDULER_CHATTER = {"Select jobs to execute...", "Execute 1 jobs...",
                      "DAG of jobs will be updated after completion.",
                      "Updating checkpoint dependencies."}


class LogHandler(LogHandlerBase):
    """Snakemake's console handler with per-job blocks filtered and a time-left estimate."""

    def __post_init__(self) -> None:
        from snakemake.logging import ColorizingTextHandler, DefaultFilter, DefaultFormatter

        cs = self.common_settings
        t0: list[float | None] = [None]
        init = time.monotonic()

        class _Formatter(DefaultFormatter):
            def format_progress(self, msg):  # Snakemake's hook
                now = time.monotonic()
                start = t0[0] if t0[0] is not None else init
                return progress_line(int(msg["done"]), int(msg["total"]), now - start)

        self._inner = ColorizingTextHandler(
            nocolor=cs.nocolor, stream=sys.stdout if cs.stdout else sys.stderr,
            formatter=_Formatter(cs.quiet, cs.show_failed_logs))
        verbose = bool(cs.verbose) or bool(cs.dryrun)  # a dry run is read for its jobs

        def _quiet_jobs(record: logging.LogRecord) -> bool:
            event = getattr(record, "event", None)
            if event in (LogEvent.JOB_INFO, LogEvent.JOB_STARTED) and t0[0] is None:
                t0[0] = time.monotonic()  # the run's first step starts the clock
            if verbose:
                return True
            if event is None and record.getMessage() in _SCHEDULER_CHATTER:
                return False
            return event not in _PER_JOB

        self.addFilter(_quiet_jobs)  # first: it sees the first job start
        self.addFilter(DefaultFilter(cs.quiet, cs.debug_dag, cs.verbose, cs.dryrun,
                                     cs.printshellcmds))

    def emit(self, record: logging.LogRecord) -> None:
        self._inner.emit(record)

    @property
    def writes_to_stream(self) -> bool:
        return True

    @property
    def writes_to_file(self) -> bool:
        return False

    @property
    def has_filter(self) -> bool:
        return True

    @property
    def has_formatter(self) -> bool:
        return True

    @property
    def needs_rulegraph(self) -> bool:
        return False
