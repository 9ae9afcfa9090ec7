"""Pluggable forward models: Python callables and external commands, and the
isolated solve that turns every failure into a recorded failed run."""

import sys
import textwrap

import numpy as np
import pytest

from bayescalib.forward import (
    CommandModel,
    ForwardModelError,
    PythonModel,
    make_forward_model,
    solve_point,
)
from bayescalib.runrecord import read_run

ANALYTIC = "bayescalib.analytic_model:interface"


def test_python_model_returns_the_callables_interface():
    res = PythonModel(ANALYTIC).solve({"E": 400.0, "nu": 0.3})
    assert res.status == "ok"
    assert res.interface_current.shape == (66, 2)
    # the analytic model's maximum displacement is u0 = 0.028 mm scaled by its shape modes
    assert 0.01 < res.max_displacement < 0.05
    assert res.segments.shape == (65, 2)


def test_python_model_exception_is_a_failed_run_with_reason():
    res = PythonModel(ANALYTIC, {"fail_below_E": 300.0}).solve({"E": 200.0, "nu": 0.3})
    assert res.status == "failed"
    assert "failure threshold" in res.reason
    assert "Traceback" in res.stats["log_tail"]


@pytest.mark.parametrize(
    "spec, match",
    [
        ("no_colon", "module:function"),
        ("no_such_module_xyz:f", "cannot import module 'no_such_module_xyz'"),
        ("bayescalib.analytic_model:nope", "no callable 'nope'"),
    ],
)
def test_python_model_bad_spec_names_the_problem(spec, match):
    with pytest.raises(ForwardModelError, match=match):
        PythonModel(spec)


def test_python_model_bad_return_shape_is_failed(tmp_path, monkeypatch):
    mod = tmp_path / "badmodel_fwd.py"
    mod.write_text("def f(params):\n    return [1.0, 2.0, 3.0]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    res = PythonModel("badmodel_fwd:f").solve({"E": 1.0})
    assert res.status == "failed" and "(n, 2)" in res.reason


def _writer_script(tmp_path, body):
    script = tmp_path / "solver.py"
    script.write_text(textwrap.dedent(body))
    return script


def test_command_model_renders_template_runs_and_reads_output(tmp_path):
    script = _writer_script(tmp_path, """
        import sys
        vals = dict(line.split("=") for line in open(sys.argv[1]).read().split())
        E = float(vals["E"]); scale = float(sys.argv[3])
        with open(sys.argv[2], "w") as fh:
            fh.write("x,y\\n")
            for i in range(11):
                fh.write(f"{i / 10},{scale * 100.0 / E * i / 10}\\n")
    """)
    tpl = tmp_path / "input.j2"
    tpl.write_text("E={{ E }}\nnu={{ params['nu'] }}\n")
    model = CommandModel(tpl, [sys.executable, str(script), "{input}", "{output}", "{scale}"],
                         input_name="in.txt", output_name="out.csv", workdir=tmp_path / "w")
    res = model.solve({"E": 200.0, "nu": 0.25, "scale": 2.0})
    assert res.status == "ok", res.reason
    assert (tmp_path / "w" / "in.txt").read_text() == "E=200.0\nnu=0.25\n"
    np.testing.assert_allclose(res.interface_current[-1], [1.0, 1.0])


def test_command_model_strict_template_names_the_missing_variable(tmp_path):
    tpl = tmp_path / "input.j2"
    tpl.write_text("E={{ E }} G={{ G }}\n")
    model = CommandModel(tpl, ["true"], input_name="in", output_name="out.csv",
                         workdir=tmp_path)
    with pytest.raises(ForwardModelError, match="'G' is undefined"):
        model.render_input({"E": 1.0})


def test_command_arguments_take_numbers_only_never_a_shell(tmp_path):
    tpl = tmp_path / "t.j2"
    tpl.write_text("x\n")
    model = CommandModel(tpl, ["echo", "{E}", "; rm -rf {workdir}"], input_name="in",
                         output_name="out.csv", workdir=tmp_path / "w")
    argv = model.argv({"E": 3.5}, tmp_path / "in", tmp_path / "out")
    # the value becomes one numeric argument; the ';' stays inside one argv item
    assert argv[:2] == ["echo", "3.5"]
    assert len(argv) == 3
    with pytest.raises(ForwardModelError, match="non-finite"):
        model.argv({"E": float("nan")}, tmp_path / "in", tmp_path / "out")
    with pytest.raises((ValueError, TypeError)):
        model.argv({"E": "1; rm -rf /"}, tmp_path / "in", tmp_path / "out")


@pytest.mark.parametrize(
    "body, reason",
    [
        ("import sys; sys.exit(3)", "exited with status 3"),
        ("pass", "wrote no output file"),
        ("import sys; open(sys.argv[2], 'w').write('garbage without header')", "unreadable output"),
    ],
)
def test_command_failures_are_recorded_with_log_tail(tmp_path, body, reason):
    script = tmp_path / "s.py"
    script.write_text("print('solver says hello')\n" + body + "\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("E={{ E }}\n")
    model = CommandModel(tpl, [sys.executable, str(script), "{input}", "{output}"],
                         input_name="in", output_name="out.csv", workdir=tmp_path / "w")
    res = model.solve({"E": 1.0})
    assert res.status == "failed"
    assert reason in res.reason
    assert "solver says hello" in res.stats["log_tail"]


def test_command_time_limit(tmp_path):
    script = tmp_path / "s.py"
    script.write_text("import time; time.sleep(30)\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("\n")
    model = CommandModel(tpl, [sys.executable, str(script)], input_name="in",
                         output_name="out.csv", workdir=tmp_path / "w", time_limit_s=0.5)
    res = model.solve({})
    assert res.status == "failed" and "time limit" in res.reason


def test_solve_point_writes_a_record_for_success_and_failure(tmp_path):
    fm = {"type": "python", "python": {"function": ANALYTIC, "options": {"fail_below_E": 300.0}}}
    ok = solve_point(fm, {"E": 500.0, "nu": 0.2}, tmp_path / "ok.h5")
    bad = solve_point(fm, {"E": 150.0, "nu": 0.2}, tmp_path / "bad.h5")
    assert ok.status == "ok" and bad.status == "failed"
    assert read_run(tmp_path / "ok.h5").status == "ok"
    assert "threshold" in read_run(tmp_path / "bad.h5").reason


def test_solve_point_kills_a_hanging_model(tmp_path, monkeypatch):
    mod = tmp_path / "hang_fwd.py"
    mod.write_text("import time\ndef f(params):\n    time.sleep(600)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    fm = {"type": "python", "python": {"function": "hang_fwd:f"}}
    import bayescalib.forward as fw

    res = fw.solve_point(fm, {"E": 1.0}, tmp_path / "hang.h5", time_limit_s=0.5, grace_s=0.5)
    assert res.status == "failed" and "time limit" in res.reason
    assert read_run(tmp_path / "hang.h5").status == "failed"


def test_solve_point_records_a_crashing_process(tmp_path, monkeypatch):
    mod = tmp_path / "crash_fwd.py"
    mod.write_text("import os\ndef f(params):\n    os._exit(9)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    fm = {"type": "python", "python": {"function": "crash_fwd:f"}}
    res = solve_point(fm, {"E": 1.0}, tmp_path / "crash.h5")
    assert res.status == "failed" and "died" in res.reason


def test_unknown_forward_model_type():
    with pytest.raises(ForwardModelError, match="unknown forward model type 'abaqus'"):
        make_forward_model({"type": "abaqus"})
