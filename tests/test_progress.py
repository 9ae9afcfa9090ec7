"""The console of a run: progress with the time left, per-job blocks left out
(bayescalib.execution.progress and the Snakemake logger plugin the default profile names)."""

from __future__ import annotations

import io
import logging
from types import SimpleNamespace

import pytest
import yaml
from snakemake_interface_logger_plugins.common import LogEvent

from bayescalib.execution.progress import format_duration, progress_line

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("seconds, text", [(0, "0 s"), (44.6, "45 s"), (200, "3 min 20 s"),
                                           (3600 + 5 * 60 + 9, "1 h 05 min")])
def test_durations_read_at_a_glance(seconds, text):
    assert format_duration(seconds) == text


def test_time_left_is_the_pace_so_far_times_the_steps_left():
    # 10 of 40 steps in 50 s: 5 s a step, 30 steps left -> 150 s
    assert progress_line(10, 40, 50.0) == \
        "10 of 40 steps (25 %) done, about 2 min 30 s left at the pace so far"
    assert progress_line(0, 40, 3.0) == "0 of 40 steps (0 %) done"
    assert progress_line(40, 40, 75.0) == "40 of 40 steps (100 %) done in 1 min 15 s"


def _handler(verbose=False, dryrun=False):
    from snakemake_logger_plugin_bayescalib import LogHandler

    settings = SimpleNamespace(printshellcmds=False, nocolor=True, quiet=set(), debug_dag=False,
                               verbose=verbose, show_failed_logs=True, stdout=False,
                               dryrun=dryrun)
    h = LogHandler(settings, None)
    h._inner.stream = io.StringIO()
    return h


def _record(msg, event=None, level=logging.INFO, **extra):
    r = logging.LogRecord("snakemake", level, __file__, 0, msg, None, None)
    if event is not None:
        r.event = event
    for k, v in extra.items():
        setattr(r, k, v)
    return r


def test_console_leaves_out_per_job_blocks_and_shows_progress_with_time_left():
    h = _handler()
    job = _record("rule solve", LogEvent.JOB_INFO, rule_name="solve", jobid=3, input=[],
                  output=["runs/3.h5"], log=[], wildcards={"i": "3"}, reason="", priority=0,
                  threads=1, resources={}, benchmark=None, rule_msg=None, indent=False,
                  is_checkpoint=False, is_handover=False, shellcmd=None, local=False)
    for r in (job, _record("Select jobs to execute..."),
              _record("Finished jobid: 3", LogEvent.JOB_FINISHED, job_id=3),
              _record("", LogEvent.PROGRESS, done=1, total=4),
              _record("job 3 failed", LogEvent.ERROR, level=logging.ERROR)):
        h.handle(r)
    out = h._inner.stream.getvalue()
    assert "rule solve" not in out and "Select jobs" not in out and "Finished jobid" not in out
    assert "1 of 4 steps (25 %) done" in out
    assert "job 3 failed" in out  # errors stay
    # --verbose: everything back
    hv = _handler(verbose=True)
    hv.handle(_record("Select jobs to execute..."))
    assert "Select jobs to execute..." in hv._inner.stream.getvalue()
    # a dry run is read for its jobs: the blocks stay
    hd = _handler(dryrun=True)
    hd.handle(job)
    assert "runs/3.h5" in hd._inner.stream.getvalue()


def test_the_default_profile_uses_the_plugin_and_two_cores():
    prof = yaml.safe_load((REPO / "workflow" / "profiles" / "default" / "config.yaml").read_text())
    assert prof["logger"] == "bayescalib" and prof["cores"] == 2
    from snakemake_interface_logger_plugins.registry import LoggerPluginRegistry

    assert LoggerPluginRegistry().get_plugin("bayescalib").log_handler.__name__ == "LogHandler"
