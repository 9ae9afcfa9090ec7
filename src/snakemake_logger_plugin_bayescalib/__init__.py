"""Snakemake logger plugin of bayescalib (``snakemake --logger bayescalib``; the default
profile sets it): a console of a few lines per round instead of one per step.

* Snakemake's per-step output is not printed: the per-job blocks (rule, input, output,
  wildcards, resources: eight lines per job), the "N of M steps done" line after every
  step (192 for the default study, its percentage going backwards as active rounds add
  steps), the banner and the scheduler's chatter. Each job's log file under
  ``results/<study>/logs/`` holds what the job did, and Snakemake's own log file
  (named at the end) everything Snakemake said.
* In their place :class:`bayescalib.execution.progress.RunConsole` prints the study's
  header, per active round the solves done of the budget (design.active.max_solves),
  what the stop rule decided and the round's posterior, and at most one line a minute
  while a stage runs long. The plan of the run comes from the Snakefile
  (:func:`bayescalib.execution.progress.set_plan`, same process).
* Kept as before: the job stats table (what this run will do, e.g. after a resume),
  errors, failed jobs with their log (``show-failed-logs``), warnings, and Snakemake's
  closing lines. ``--verbose``, and a dry run (``-n``, read for its jobs), bring all of
  Snakemake's output back. ``--quiet`` settings apply as in Snakemake; ``--quiet
  progress`` (or ``all``) silences the run's own lines too.
"""

from __future__ import annotations

import logging
import sys

from snakemake_interface_logger_plugins.base import LogHandlerBase
from snakemake_interface_logger_plugins.common import LogEvent

from bayescalib.execution.progress import RunConsole, get_plan

__all__ = ["LogHandler"]

#: events left out of the console unless --verbose: the per-job blocks and progress
_PER_JOB = {LogEvent.JOB_INFO, LogEvent.JOB_STARTED, LogEvent.JOB_FINISHED,
            LogEvent.SHELLCMD, LogEvent.GROUP_INFO, LogEvent.PROGRESS,
            LogEvent.WORKFLOW_STARTED}

#: Snakemake's lines without information for the user of a run
_CHATTER = ("Select jobs to execute...", "Execute 1 jobs...", "Building DAG of jobs...",
            "DAG of jobs will be updated after completion.", "Updating checkpoint dependencies.",
            "Using shell:", "Rules claiming more threads will be scaled down.",
            "Conda environments: ignored", "Assuming unrestricted shared filesystem usage.")


class LogHandler(LogHandlerBase):
    """Snakemake's console handler with the per-step output replaced by the run's console."""

    def __post_init__(self) -> None:
        from snakemake.logging import ColorizingTextHandler, DefaultFilter, DefaultFormatter

        cs = self.common_settings
        self._inner = ColorizingTextHandler(
            nocolor=cs.nocolor, stream=sys.stdout if cs.stdout else sys.stderr,
            formatter=DefaultFormatter(cs.quiet, cs.show_failed_logs))
        self._verbose = bool(cs.verbose) or bool(cs.dryrun)  # a dry run is read for its jobs
        self._default = DefaultFilter(cs.quiet, cs.debug_dag, cs.verbose, cs.dryrun,
                                      cs.printshellcmds)
        self._console: RunConsole | None = None
        # --quiet progress (or all) silences the run's lines too: they are its progress
        quiet = {getattr(q, "name", str(q)).lower() for q in (cs.quiet or ())}
        self._silent = bool(quiet & {"progress", "all"})

    def _run_console(self) -> RunConsole | None:
        if self._console is None and not self._verbose and not self._silent:
            plan = get_plan()
            if plan is not None:
                self._console = RunConsole(plan)
        return self._console

    def _say(self, lines: list[str]) -> None:
        if lines:
            stream = self._inner.stream
            stream.write("".join(line + "\n" for line in lines))
            stream.flush()

    def _feed(self, record: logging.LogRecord) -> None:
        console = self._run_console()
        if console is None:
            return
        event = getattr(record, "event", None)
        if event == LogEvent.WORKFLOW_STARTED:
            self._say(console.start())
        elif event == LogEvent.JOB_INFO:
            self._say(console.job_info(getattr(record, "jobid", -1),
                                       getattr(record, "rule_name", ""),
                                       getattr(record, "wildcards", None),
                                       getattr(record, "output", None)))
        elif event == LogEvent.JOB_FINISHED:
            self._say(console.job_finished(getattr(record, "job_id", -1)))

    def _shown(self, record: logging.LogRecord) -> bool:
        if self._verbose:
            return True
        event = getattr(record, "event", None)
        if event in _PER_JOB:
            return False
        if event in (None, LogEvent.RESOURCES_INFO) and record.levelno <= logging.INFO:
            msg = record.getMessage().strip()
            if msg.startswith(_CHATTER):
                return False
        return True

    def emit(self, record: logging.LogRecord) -> None:
        # called by handle() under this handler's lock: the console's state is safe
        self._feed(record)
        if self._shown(record) and self._default.filter(record):
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
