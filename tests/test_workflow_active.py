"""The active design as users run it (Snakemake checkpoints), on the analytic model.

Contract: summary.json says whether the posterior converged, with the rounds; a
point is never solved twice (a stop-rule change re-solves nothing, a larger
budget solves only the new rounds' points); a run killed mid-round resumes
without redoing finished solves and ends where an uninterrupted run ends.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from _workflow_helpers import run_and_kill
from _workflow_helpers import setup_study as _setup
from _workflow_helpers import smk as _smk

pytestmark = pytest.mark.workflow

# rounds of 4 acquired points and 1 check point: 8, 13, 18, 23 solves, then (if no
# earlier one confirmed the posterior) a check round of 6 draws: 29 solves at most. The
# check round is chosen once the posterior settled for 2 rounds (the default patience),
# or because only its 6 solves are left of the budget
ACTIVE = {"strategy": "active", "seed": 1,
          "active": {"n_initial": 8, "batch_size": 4, "max_solves": 29}}
CHECK = {"draws": 6}


RESELECT_GROWTH = 0.5


def _study(base: dict, **design) -> dict:
    out = json.loads(json.dumps(base))
    out["design"] = json.loads(json.dumps(ACTIVE))
    # refit the surrogate's previous choice between full searches (off by default)
    out.setdefault("surrogate", {})["reselect_growth"] = RESELECT_GROWTH
    out["posterior_check"] = dict(CHECK)
    for k, v in design.items():
        if isinstance(v, dict):
            out["design"]["active"].setdefault(k, {}).update(v)
        else:
            out["design"]["active"][k] = v
    return out


@pytest.fixture(scope="module")
def active_run(tmp_path_factory, base_study):
    tmp = _setup(tmp_path_factory.mktemp("active"), _study(base_study))
    proc = _smk(tmp)
    return tmp, proc


def _runs(tmp: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (tmp / "results/analytic/runs").glob("*.h5")}


def _summary(tmp: Path) -> dict:
    return json.loads((tmp / "results/analytic/summary.json").read_text())


def test_summary_says_whether_the_active_design_converged(active_run):
    tmp, proc = active_run
    s = _summary(tmp)
    d = s["design"]
    assert d["strategy"] == "active" and isinstance(d["converged"], bool)
    assert s["converged"] == d["converged"]
    assert d["n_rounds"] == len(d["rounds"]) >= 2
    assert next(r["n_solves"] for r in d["rounds"]) == 8
    assert d["n_solves"] == s["n_train"] == len(_runs(tmp)) <= 29
    if not d["converged"]:
        assert d["reason"].startswith("NOT converged")
    assert all((tmp / f).is_file() for f in s["figures"]["rounds"])
    # the end of the run: the posterior in one line, then the verdict (converged or not
    # and why, in at most three short sentences: bayescalib.stages.verdict)
    lines = proc.stdout.splitlines()
    line = [ln for ln in lines if ln.startswith("bayescalib analytic:")]
    assert line, proc.stdout[-2000:]
    said = lines[lines.index(line[0]) + 1]
    assert said.startswith("Converged after" if d["converged"] else "NOT converged"), said
    # the absolute check of the best solve against the noise model (RKHS: n = 1 per
    # snapshot; noise-free data of the model itself, so the fit is within the noise)
    fit = s["fit"]
    assert fit["n_measurements"] == 1 and fit["consistent"] and 0 <= fit["misfit_nats"] < 3
    assert s["measures"]["rkhs"]["fit"] == fit
    assert "worse than the noise" not in said  # the misfit leads only when there is one
    # the posterior checked with real solves of its draws inside the rounds: a check
    # round of 6 draws (the budget keeps room for it), whose verdict is in the record of
    # the round after it and in summary.json
    check = s["posterior_check"]
    assert check["n_draws"] == 6 and isinstance(check["confirmed"], bool)
    assert set(check["shift_sd"]) == {"E", "nu"} and check["log_weight_sd"] >= 0
    path = Path(check["file"]) if Path(check["file"]).is_absolute() else tmp / check["file"]
    verdict = json.loads(path.read_text())
    assert verdict["posterior_check"]["words"] == check["words"]
    checked = json.loads((path.parent.parent / f"{check['round']}/acquire.json").read_text())
    assert checked["next"]["kind"] == ["posterior_check"] * 6
    n0 = checked["n_solves"]
    assert verdict["n_solves"] == n0 + 6  # the draws are design points of the next round
    for k, x in enumerate(checked["next"]["points"]):
        run_values = json.loads((tmp / f"results/analytic/discrepancy/rkhs/{n0 + k}.json")
                                .read_text())["parameters"]
        assert [run_values["E"], run_values["nu"]] == pytest.approx(x, rel=1e-12)
    rounds = d["rounds"]
    assert rounds[-1]["posterior_check_confirmed"] == check["confirmed"]
    if d["converged"]:
        assert check["confirmed"] and "6 real solves of the posterior's draws confirm it" \
            in said
        assert "confirmed by 6 real solves of its draws" in d["reason"]
    elif rounds[-1]["posterior_check_confirmed"] is False:
        assert "did not confirm the posterior" in said, said
    # an active design runs no final check: no predictive solve beyond the figure's
    predictive = sorted((tmp / "results/analytic/predictive").glob("*.h5"))
    assert len(predictive) == 1  # plots.n_interface_samples
    assert not (tmp / "results/analytic/rkhs/posterior_check.json").exists()
    assert "Nothing to be done" in _smk(tmp, "-n").stdout


_DRIVER = """
import json, sys
from pathlib import Path
import yaml
from bayescalib.config import merge_layers
from bayescalib.io.training import read_training
from bayescalib.stages.chain import calibrate_rounds
from bayescalib.study import Study

tmp, out = Path(sys.argv[1]), Path(sys.argv[2])
res = tmp / "results/analytic"
study = Study(merge_layers([yaml.safe_load((tmp / "config/config.yaml").read_text())]))
c = study.config
cal = calibrate_rounds(
    fm=study.forward_section(), parameters=c["parameters"],
    initial=read_training(res / "active/0/training.h5")["X"],
    obs_path=res / "observations/observations.h5", measure_name="rkhs",
    measure=c["measure"], likelihood=c["likelihood"], surrogate=c["surrogate"],
    smc_cfg=c["smc"], posterior_cfg=c["posterior"], active=c["design"]["active"],
    workdir=out, posterior_check=c["posterior_check"])
(out / "rounds.json").write_text(json.dumps(cal["rounds"]))
"""


def test_the_workflows_rounds_are_the_drivers_rounds(active_run, tmp_path):
    """One round driver: the workflow's rounds (rules and the acquire checkpoint) and
    the driver run in files (bayescalib.stages.chain.calibrate_rounds, as the diagnosis
    runs it) from the same round-0 points give the same record in every round, value
    for value, and the same posterior. Both with one BLAS thread, as pipeline jobs run:
    the optimizer's result depends on the order of summation at round-off, and a round
    that refits the surrogate from the previous one's optimum passes that on."""
    import os
    import subprocess
    import sys

    tmp, _ = active_run
    res = tmp / "results/analytic"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", _DRIVER, str(tmp), str(tmp_path / "driver")],
                          env=env, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]

    def records(root):
        return [json.loads(p.read_text()) for p in sorted(
            root.glob("active/*/acquire.json"), key=lambda p: int(p.parent.name))]

    mine, theirs = records(tmp_path / "driver"), records(res)
    assert len(mine) == len(theirs) >= 2
    assert len(json.loads((tmp_path / "driver/rounds.json").read_text())) == len(mine)
    for a, b in zip(mine, theirs, strict=True):
        assert a == b, a["round"]
    assert json.loads((tmp_path / "driver/posterior.json").read_text())["mean"] == \
        json.loads((res / "rkhs/posterior.json").read_text())["mean"]


def test_a_fixed_design_checks_its_final_posterior_with_the_posterior_check_rule(done_run):
    """A fixed design has no rounds: its final posterior's draws are solved after the
    design (predictive solves, default 32) and checked there."""
    s = _summary(done_run)
    check = s["posterior_check"]
    assert check["n_draws"] == 32 and "round" not in check
    assert check["file"].endswith("rkhs/posterior_check.json")
    assert len(list((done_run / "results/analytic/predictive").glob("*.h5"))) == 32
    # the draws are judged against the weighted particles they were resampled from
    assert set(check["draws_shift_sd"]) == set(check["draws_sd_ratio"]) == set(check["sd_q"])
    assert isinstance(check["representative"], bool)
    if not check["representative"]:
        assert not check["confirmed"] and "do not represent" in check["words"]


def _planned_jobs(dry_run: str) -> dict[str, int]:
    """Job counts per rule of a dry run's job table ("rule  count" lines)."""
    counts = {}
    for line in dry_run.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[1].isdigit() and parts[0] not in ("total", "job"):
            counts[parts[0]] = int(parts[1])
    return counts


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def test_a_stop_rule_change_resolves_nothing(active_run, base_study, tmp_path):
    tmp = _copy(active_run[0], tmp_path / "run")
    before = _runs(tmp)
    n_before = _summary(tmp)["design"]["n_solves"]
    records = tmp / "results/analytic/active/0/acquire.json"
    stamp = records.stat().st_mtime_ns
    # the trust check's tolerance (words only) and a looser posterior check, which can
    # only confirm earlier: the rounds are decided again, no new point, none redone
    study = _study(base_study, stop={"gp_tol": 1e6})
    study["posterior_check"].update(sd_tol=0.5, max_log_weight_sd=2.0)
    _setup(tmp, study)
    assert "posterior_check" not in _planned_jobs(_smk(tmp, "-n").stdout)  # fixed only
    _smk(tmp)
    s = _summary(tmp)
    assert records.stat().st_mtime_ns != stamp  # the rounds were decided again
    assert s["design"]["n_solves"] <= n_before
    after = _runs(tmp)
    assert all(after[n] == t for n, t in before.items() if n in after), "a solve was redone"


def test_a_larger_budget_solves_only_new_points(active_run, base_study, tmp_path):
    """A run that did not converge, given a larger budget, goes on from its rounds: no
    finished solve is redone but those of a check round that was chosen only because
    the budget was ending (with more budget left that round is an ordinary batch)."""
    tmp = _copy(active_run[0], tmp_path / "run")
    s0 = _summary(tmp)
    if s0["design"]["converged"]:
        pytest.skip("the base run converged within its budget")
    before = _runs(tmp)
    rounds = s0["design"]["rounds"]
    last_batch = set()
    if rounds[-1]["posterior_check_confirmed"] is not None:  # the last batch was a check
        last_batch = {f"{i}.h5" for i in range(rounds[-2]["n_solves"], rounds[-1]["n_solves"])}
    _setup(tmp, _study(base_study, max_solves=40))
    _smk(tmp)
    after = _runs(tmp)
    assert all(after[n] == t for n, t in before.items() if n not in last_batch), \
        "a finished solve was redone"
    assert len(after) == _summary(tmp)["design"]["n_solves"] > len(before)


def test_lighter_round_smc_resamples_the_result_with_the_full_settings(active_run, base_study,
                                                                         tmp_path):
    """design.active.smc: the rounds are sampled again with it (their SMC settings
    changed), and the study's posterior is not the last round's particles but a new
    SMC with the study's settings; no solve is redone where the rounds choose the
    same points (dry run: what would run)."""
    tmp = _copy(active_run[0], tmp_path / "run")
    _setup(tmp, _study(base_study, smc={"n_particles": 100, "n_rej": 2}))
    plan = _planned_jobs(_smk(tmp, "-n").stdout)
    assert plan.get("smc_round", 0) >= 1 and plan.get("smc") == 1, plan
    assert "solve" not in plan, plan
    _smk(tmp)
    log = (tmp / "results/analytic/logs/rkhs/smc.log").read_text()
    assert "is reused" not in log
    import h5py
    with h5py.File(tmp / "results/analytic/rkhs/particles.h5") as f:
        assert f["particles"].shape[0] == base_study["smc"]["n_particles"] == 200
    with h5py.File(tmp / "results/analytic/active/0/particles.h5") as f:
        assert f["particles"].shape[0] == 100


ROUND_RULES = {"solve", "gather_round", "train_round", "smc_round", "acquire", "train_surrogate",
               "smc"}


def _stamps(tmp: Path, name: str) -> dict[str, int]:
    """mtime of each round's ``name`` file, by round."""
    return {p.parent.name: p.stat().st_mtime_ns
            for p in (tmp / "results/analytic/active").glob(f"*/{name}")}


def test_the_rounds_search_the_surrogates_choices_when_the_design_grew_by_half(active_run):
    """surrogate.reselect_growth (0.5 here) through the workflow: round r reads round
    r-1's surrogate file; it searches the choices in full in round 0 and when its n is
    at least 1.5 times that of the last search, or when the previous round's surrogate
    mispredicted the new values (surrogate.reselect_error), else it refits (n of the
    search kept); each file says why."""
    import h5py

    f = RESELECT_GROWTH
    rounds = sorted((active_run[0] / "results/analytic/active").glob("*/surrogate.h5"),
                    key=lambda p: int(p.parent.name))
    n_search = None
    for path in rounds:
        with h5py.File(path) as h:
            n, sel, sel_n = h["X_train"].shape[0], h.attrs["selection"], h.attrs["selection_n"]
            why = h.attrs["selection_reason"]
            why = why.decode() if isinstance(why, bytes) else str(why)
        if n_search is None or n >= (1 + f) * n_search:
            assert (sel, sel_n, why) == ("search", n, "round 0" if n_search is None
                                         else "growth"), path
            n_search = n
        elif sel == "search":
            assert sel_n == n and why in ("mispredicted", "refit rejected"), path
            n_search = n
        else:
            assert sel_n == n_search and why in ("predicted well",
                                                 "no new value in the region"), path


def test_a_plot_setting_reruns_no_round(active_run, base_study, tmp_path):
    """A round's surrogate reads the previous round's (surrogate.reselect_growth): a
    setting of the figures still recomputes no solve, surrogate, SMC or round record."""
    tmp = _copy(active_run[0], tmp_path / "run")
    study = _study(base_study)
    study["plots"]["dpi"] = int(study["plots"]["dpi"]) + 1
    _setup(tmp, study)
    plan = _planned_jobs(_smk(tmp, "-n").stdout)
    assert not ROUND_RULES & set(plan), plan


def test_an_acquisition_setting_decides_the_rounds_again_from_the_first_changed_one(
        active_run, base_study, tmp_path):
    """Another explore_fraction: every round's record is decided again (dry run: acquire
    jobs, no surrogate and no solve planned); then a round's surrogate is refitted only
    where its training table changed (round 0's, the Sobol design's, never does), though
    each reads the previous round's surrogate."""
    tmp = _copy(active_run[0], tmp_path / "run")
    surrogates, tables = _stamps(tmp, "surrogate.h5"), _stamps(tmp, "training.h5")
    _setup(tmp, _study(base_study, explore_fraction=0.25))
    plan = _planned_jobs(_smk(tmp, "-n").stdout)
    assert plan.get("acquire", 0) >= 1, plan
    assert not {"solve", "gather_round", "train_round", "smc_round"} & set(plan), plan
    _smk(tmp)
    after_s, after_t = _stamps(tmp, "surrogate.h5"), _stamps(tmp, "training.h5")
    assert after_s["0"] == surrogates["0"] and after_t["0"] == tables["0"]
    for r, t in after_t.items():
        if tables.get(r) == t:  # the same training table: the same surrogate file
            assert after_s[r] == surrogates[r], f"round {r}'s surrogate was refitted"


# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_killed_mid_round_resumes_without_redoing_solves(active_run, base_study, tmp_path):
    study = _study(base_study)
    study["forward_model"]["python"]["function"] = "slow_model:interface"
    tmp = _setup(tmp_path / "run", study)
    # killed inside round 1: its first solves are written
    run_and_kill(tmp, tmp / "results" / "analytic" / "runs", 10)
    finished = _runs(tmp)
    assert 10 <= len(finished) < 23
    _smk(tmp)  # the README's resume: the command that started the run
    after = _runs(tmp)
    redone = [n for n, t in finished.items() if after.get(n) != t]
    assert len(redone) <= 2, f"finished solves were redone: {redone}"
    a, b = _summary(tmp), _summary(active_run[0])
    for s in (a, b):
        s.pop("timings_s")
    assert a == b


def test_cli_summary_prints_the_run_line_the_table_and_the_rounds(active_run, capsys):
    from bayescalib.cli import main

    tmp, proc = active_run
    assert main(["summary", str(tmp / "results" / "analytic")]) == 0
    out = capsys.readouterr().out
    last = next(ln for ln in proc.stdout.splitlines() if ln.startswith("bayescalib analytic:"))
    assert out.splitlines()[0] == last
    # the analytic model fails below E = 130 Pa: a failure of the model, which marks where
    # it cannot be solved (bayescalib.inference.feasibility), and the run line says so
    s = _summary(tmp)
    assert s["n_failed_infeasible"] == s["n_failed"] >= 1
    assert all(f["marks_infeasible"] and f["parameters"]["E"] < 130.0 for f in s["failed_runs"])
    assert (f"{s['n_failed']} failed ({s['n_failed']} mark where the model cannot be solved: "
            "the posterior excludes their neighbourhood)") in last
    assert "90% equal-tailed" in out and "active design:" in out
    assert out.count("\n0 ") + out.count("\n0  ") >= 1  # round 0 row
    assert main(["summary", str(tmp / "nowhere")]) == 2


def test_cli_summary_lists_failed_solves_with_their_reasons(active_run, tmp_path, capsys):
    from bayescalib.cli import main

    s = _summary(active_run[0])
    s["failed_runs"] = [{"point": 5, "parameters": {"E": 120.5, "nu": 0.1},
                         "reason": "Newton did not converge at load step 3",
                         "marks_infeasible": True}]
    del s["map"]["nu"]  # an uncertain condition has no MAP (marginalized out)
    (tmp_path / "summary.json").write_text(json.dumps(s))
    assert main(["summary", str(tmp_path / "summary.json")]) == 0
    out = capsys.readouterr().out
    assert "failed solves (1; 1 mark where the model cannot be solved" in out
    assert next(ln for ln in out.splitlines() if ln.startswith("nu ")).split()[2] == "-"
    row = next(ln for ln in out.splitlines() if ln.startswith("5 "))
    assert "120.5" in row and "Newton did not converge at load step 3" in row
    assert row.split()[3] == "yes"  # point, E, nu, region
