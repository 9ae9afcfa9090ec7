"""The console of a run: a few lines per round with the solves done of the budget, not
one line per step (bayescalib.execution.progress and the Snakemake logger plugin the
default profile names); the libraries' Python warnings in the jobs' logs, not on it."""

from __future__ import annotations

import io
import json
import logging
import subprocess
import sys
from types import SimpleNamespace

import pytest
import yaml
from snakemake_interface_logger_plugins.common import LogEvent

from bayescalib.execution import progress
from bayescalib.execution.progress import RunConsole, format_duration, round_lines, run_plan

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]
UNITS = {"E": "Pa", "nu": "-"}


@pytest.mark.parametrize("seconds, text", [(0, "0 s"), (44.6, "45 s"), (200, "3 min 20 s"),
                                           (3600 + 5 * 60 + 9, "1 h 05 min")])
def test_durations_read_at_a_glance(seconds, text):
    assert format_duration(seconds) == text


def _rec(r, n, *, stop=False, converged=False, settled=False, shift=1.2, q=5, kind="acquired",
         pc=None, failed=0):
    rec = {"round": r, "n_solves": n, "n_failed": failed, "names": ["E", "nu"],
           "posterior": {"mean": [380.26, 0.1787], "sd": [65.4, 0.233]},
           "change": None if r == 0 else {"shift_sd": shift, "sd_change": 0.1},
           "settled": settled, "settled_streak": 1 if settled else 0, "posterior_check": pc,
           "converged": converged, "stop": stop,
           "reason": "continue: " + "a long reason " * 50}
    if not stop:
        rec["next"] = {"points": [[0, 0]] * q, "kind": [kind] * q}
    return rec


def test_a_round_says_its_solves_of_the_budget_its_decision_and_its_posterior():
    assert round_lines(_rec(1, 13), 40, UNITS, 42.0) == [
        "round 1 [42 s]: 13 of 40 solves; the posterior moved 1.2 sd; 5 more solves next",
        "  posterior: E = 380 +- 65 Pa, nu = 0.179 +- 0.23"]
    assert round_lines(_rec(0, 8), 40, UNITS)[0] == \
        "round 0: 8 of 40 solves; the first posterior; 5 more solves next"
    check_next = round_lines(_rec(3, 23, settled=True, q=16, kind="posterior_check"), 40,
                             UNITS)[0]
    assert check_next.endswith("the posterior settled (1 round(s) in a row); 16 draws of it "
                               "are solved next as its check")
    pc = {"round": 3, "n_draws": 16, "n_failed": 0, "confirmed": True}
    done = round_lines(_rec(4, 39, stop=True, converged=True, settled=True, pc=pc), 40, UNITS)
    assert done == [("round 4: 39 of 40 solves; converged: 16 real solves of its draws "
                    "confirm round 3's posterior"),
                    "  posterior: E = 380 +- 65 Pa, nu = 0.179 +- 0.23",
                    "  final posterior, figures and summary next"]
    spent = round_lines(_rec(5, 40, stop=True, failed=2), 40, UNITS)[0]
    assert spent == "round 5: 40 of 40 solves (2 failed); stopped, NOT converged (the " \
                    "verdict at the end says why)"
    # never the record's long reason
    assert all("a long reason" not in ln for ln in round_lines(_rec(1, 13), 40, UNITS))


def test_a_rounds_posterior_cut_by_its_prior_says_so_on_the_console():
    """A round whose posterior piles at an end of a parameter's box (a unit slip, a prior
    too narrow) says so in its posterior line, rounds before the verdict."""
    rec = _rec(1, 13)
    rec["against_bounds"] = [{"name": "E", "index": 0, "side": "upper", "bound": 800.0,
                              "density_ratio": 1.0, "edge_mass": 0.4, "delta": 0.5,
                              "sd_fraction": 0.002}]
    assert round_lines(rec, 40, UNITS)[1] == (
        "  posterior: E = 380 +- 65 Pa (cut by its prior's upper end), nu = 0.179 +- 0.23")


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _plan(**kw):
    return {"study": "smoke", "root": "results/smoke", "active": True, "budget": 40,
            "units": UNITS, "n_solved": 0, "last_round": None, **kw}


def test_an_active_run_prints_a_few_lines_per_round_not_one_per_step():
    """The smoke study's shape: 8 Sobol solves, then rounds of 5, a check round of 16;
    every step (solve, discrepancy, gather, fit, SMC, acquire) finishes: the console
    prints a header and three lines or fewer per round, whatever the number of steps."""
    records = {f"results/smoke/active/{r}/acquire.json": rec for r, rec in enumerate([
        _rec(0, 8), _rec(1, 13), _rec(2, 18, settled=True, shift=0.1),
        _rec(3, 23, settled=True, shift=0.1, q=16, kind="posterior_check"),
        _rec(4, 39, stop=True, converged=True, settled=True,
             pc={"round": 3, "n_draws": 16, "n_failed": 0, "confirmed": True})])}
    clock = _Clock()
    con = RunConsole(_plan(), read_record=records.__getitem__, clock=clock)
    out, steps, jobid = [], 0, 0

    def step(rule, output=(), **wc):
        nonlocal steps, jobid
        jobid += 1
        steps += 1
        clock.t += 1.0
        out.extend(con.job_info(jobid, rule, wc, list(output)))
        out.extend(con.job_finished(jobid))

    for rule in ("base_state", "ground_truth", "observe"):
        step(rule)
    batches = [8, 5, 5, 16]
    for r, q in enumerate(batches + [0]):
        for i in range(q):
            step("solve", i=str(i))
            step("discrepancy", i=str(i))
        for rule in ("gather_round", "train_round", "smc_round"):
            step(rule, r=str(r))
        step("acquire", [f"results/smoke/active/{r}/acquire.json"], r=str(r))
        assert con.solves == records[f"results/smoke/active/{r}/acquire.json"]["n_solves"]
    for rule in ("gather", "train_surrogate", "smc", "marginalize", "fig_posterior",
                 "fig_response", "fig_rounds", "predictive_solve", "fig_interfaces", "summary"):
        step(rule)
    assert steps > 100
    assert out[0].startswith("bayescalib smoke: active design, at most 40 solves "
                             "(design.active.max_solves)")
    assert len(out) == 1 + 2 * 5 + 1, out  # header, two lines a round, the final stage
    assert [ln.split(":")[0].split(" [")[0] for ln in out if ln.startswith("round")] == \
        [f"round {r}" for r in range(5)]
    assert all("steps" not in ln and "%" not in ln for ln in out)


def test_a_long_stage_says_what_runs_at_most_once_a_minute():
    clock = _Clock()
    con = RunConsole(_plan(n_solved=3), read_record=lambda p: {}, clock=clock, interval_s=60)
    assert con.start()[0].endswith("Each step's log: results/smoke/logs/")
    lines = []
    for k in range(30):  # 30 solves of 10 s each, two at a time
        clock.t += 10.0
        lines += con.job_info(k, "solve", {"i": str(k)}, [])
        lines += con.job_finished(k - 1) if k else []
    assert 4 <= len(lines) <= 5, lines
    assert lines[0] == "  [1 min 00 s] running: solves; 7 of 40 solves done"


def test_a_fixed_design_says_when_its_solves_are_done():
    con = RunConsole(_plan(active=False, budget=3), clock=_Clock())
    out = con.start()
    assert out == [("bayescalib smoke: fixed design of 3 solves. Each step's log: "
                   "results/smoke/logs/")]
    for k in range(3):
        out += con.job_info(k, "solve", {}, []) + con.job_finished(k)
    assert out[-1].startswith("all 3 solves done [0 s]; surrogate, posterior")


def test_the_plan_of_a_resumed_run_says_where_it_starts(tmp_path):
    root = tmp_path / "results" / "smoke"
    (root / "runs").mkdir(parents=True)
    for i in range(18):
        (root / "runs" / f"{i}.h5").write_bytes(b"")
    (root / "runs" / "base_state.state.npz").write_bytes(b"")
    (root / "runs" / "3.h5.corrupt").write_bytes(b"")
    for r, n in enumerate((8, 13, 18)):
        (root / "active" / str(r)).mkdir(parents=True)
        (root / "active" / str(r) / "acquire.json").write_text(
            json.dumps({"round": r, "n_solves": n, "stop": False}))
    plan = run_plan("smoke", root, active=True, budget=40, units=UNITS)
    assert plan["n_solved"] == 18 and plan["last_round"] == {"round": 2, "n_solves": 18,
                                                             "stop": False}
    head = RunConsole(plan).start()[0]
    assert "at most 40 solves (design.active.max_solves); resuming after round 2 (18 " \
           "solves done)" in head
    fresh = run_plan("smoke", tmp_path / "none", active=True, budget=40, units=UNITS)
    assert fresh["n_solved"] == 0 and fresh["last_round"] is None


def _handler(verbose=False, dryrun=False, quiet=()):
    from snakemake_logger_plugin_bayescalib import LogHandler

    settings = SimpleNamespace(printshellcmds=False, nocolor=True, quiet=set(quiet),
                               debug_dag=False,
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


def _job(jobid, rule, output, **wc):
    return _record(f"rule {rule}", LogEvent.JOB_INFO, rule_name=rule, jobid=jobid, input=[],
                   output=output, log=[], wildcards=wc, reason="", priority=0, threads=1,
                   resources={}, benchmark=None, rule_msg=None, indent=False,
                   is_checkpoint=False, is_handover=False, shellcmd=None, local=False)


@pytest.fixture
def plan_set(tmp_path):
    rec = tmp_path / "acquire.json"
    rec.write_text(json.dumps(_rec(0, 8)))
    progress.set_plan(_plan())
    yield rec
    progress.set_plan(None)


def test_the_plugin_prints_the_runs_lines_in_place_of_snakemakes_per_step_output(plan_set):
    h = _handler()
    for r in (_record("", LogEvent.WORKFLOW_STARTED),
              _record("Building DAG of jobs..."),
              _record("Provided cores: 2", LogEvent.RESOURCES_INFO, cores=2),
              _record("Rules claiming more threads will be scaled down.",
                      LogEvent.RESOURCES_INFO),
              _job(3, "solve", ["runs/3.h5"], i="3"), _record("Select jobs to execute..."),
              _record("Finished jobid: 3", LogEvent.JOB_FINISHED, job_id=3),
              _record("", LogEvent.PROGRESS, done=1, total=4),
              _job(4, "acquire", [str(plan_set)], r="0"),
              _record("Finished jobid: 4", LogEvent.JOB_FINISHED, job_id=4),
              _record("", LogEvent.PROGRESS, done=2, total=9),
              _record("job 3 failed", LogEvent.ERROR, level=logging.ERROR),
              _record("Nothing to be done (all requested files are present and up to date).")):
        h.handle(r)
    out = h._inner.stream.getvalue().splitlines()
    assert out == [
        ("bayescalib smoke: active design, at most 40 solves (design.active.max_solves). "
        "Each step's log: results/smoke/logs/"),
        "Provided cores: 2",
        "round 0 [0 s]: 8 of 40 solves; the first posterior; 5 more solves next",
        "  posterior: E = 380 +- 65 Pa, nu = 0.179 +- 0.23",
        "job 3 failed",  # errors stay
        "Nothing to be done (all requested files are present and up to date).",
    ], out
    # --verbose: all of Snakemake's output back, none of the run's own lines
    hv = _handler(verbose=True)
    for r in (_record("Select jobs to execute..."), _record("", LogEvent.PROGRESS, done=1,
                                                               total=4)):
        hv.handle(r)
    said = hv._inner.stream.getvalue()
    assert "Select jobs to execute..." in said and "1 of 4 steps" in said
    # --quiet progress: none of the run's lines either
    from snakemake.settings.enums import Quietness

    hq = _handler(quiet={Quietness.PROGRESS})
    hq.handle(_record("", LogEvent.WORKFLOW_STARTED))
    hq.handle(_job(4, "acquire", [str(plan_set)], r="0"))
    hq.handle(_record("Finished jobid: 4", LogEvent.JOB_FINISHED, job_id=4))
    assert hq._inner.stream.getvalue() == ""
    # a dry run is read for its jobs: the blocks stay
    hd = _handler(dryrun=True)
    hd.handle(_job(3, "solve", ["runs/3.h5"], i="3"))
    assert "runs/3.h5" in hd._inner.stream.getvalue()


def test_without_a_plan_the_plugin_still_hides_the_per_step_lines():
    progress.set_plan(None)
    h = _handler()
    h.handle(_job(3, "solve", ["runs/3.h5"], i="3"))
    h.handle(_record("", LogEvent.PROGRESS, done=1, total=4))
    h.handle(_record("Complete log(s): .snakemake/log/x.log"))
    assert h._inner.stream.getvalue() == "Complete log(s): .snakemake/log/x.log\n"


def test_the_default_profile_uses_the_plugin_and_two_cores():
    prof = yaml.safe_load((REPO / "workflow" / "profiles" / "default" / "config.yaml").read_text())
    assert prof["logger"] == "bayescalib" and prof["cores"] == 2
    from snakemake_interface_logger_plugins.registry import LoggerPluginRegistry

    assert LoggerPluginRegistry().get_plugin("bayescalib").log_handler.__name__ == "LogHandler"


def test_a_jobs_python_warnings_go_to_its_log_not_to_the_console(tmp_path):
    """GPy's RuntimeWarnings (with their site-packages paths) leaked onto the console."""
    log = tmp_path / "logs" / "job.log"
    code = ("import logging, warnings\n"
            "from bayescalib.stages.logs import setup_logging\n"
            f"setup_logging({str(log)!r})\n"
            "warnings.warn('invalid value encountered in add', RuntimeWarning)\n"
            "logging.getLogger('bayescalib').warning('a warning of bayescalib itself')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    assert "invalid value encountered" not in proc.stderr + proc.stdout
    assert "a warning of bayescalib itself" in proc.stderr  # its own warnings stay
    text = log.read_text()
    assert "RuntimeWarning" in text and "invalid value encountered in add" in text
