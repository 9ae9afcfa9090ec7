"""Pluggable forward models: Python callables and external commands, and the
isolated solve that turns every failure into a recorded failed run."""

import os
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayescalib.io.runrecord import read_run
from bayescalib.models.forward import (
    CommandModel,
    ForwardModelError,
    PythonModel,
    make_forward_model,
    solve_point,
    solve_points,
)

ANALYTIC = "bayescalib.models.analytic:interface"


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
        ("bayescalib.models.analytic:nope", "has no 'nope'"),
        ("bayescalib.models.analytic:__all__", "'__all__' in module .* is a list, not a function"),
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
                         input_name="in.txt", output_name="out.csv", workdir=tmp_path / "w.work")
    res = model.solve({"E": 200.0, "nu": 0.25, "scale": 2.0})
    assert res.status == "ok", res.reason
    assert (tmp_path / "w.work" / "in.txt").read_text() == "E=200.0\nnu=0.25\n"
    np.testing.assert_allclose(res.interface_current[-1], [1.0, 1.0])


def test_command_model_strict_template_names_the_missing_variable(tmp_path):
    tpl = tmp_path / "input.j2"
    tpl.write_text("E={{ E }} G={{ G }}\n")
    model = CommandModel(tpl, ["true"], input_name="in", output_name="out.csv",
                         workdir=tmp_path / "w.work")
    with pytest.raises(ForwardModelError, match="'G' is undefined"):
        model.render_input({"E": 1.0})


@pytest.mark.parametrize("key, name", [
    ("output_name", "../../victim.txt"), ("output_name", "/tmp/victim.txt"),
    ("input_name", "../outside.txt"), ("input_name", ".."), ("output_name", "sub/out.csv"),
    ("output_name", "solver.log")])
def test_command_file_names_stay_inside_the_work_folder(tmp_path, key, name):
    """The model unlinks its output and writes its input in the work folder: a name
    that is a path could delete or overwrite a file anywhere, so it is refused."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    tpl = tmp_path / "t.j2"
    tpl.write_text("x\n")
    names = {"input_name": "in.txt", "output_name": "out.csv", key: name}
    with pytest.raises(ForwardModelError, match=f"forward_model.command.{key}"):
        CommandModel(tpl, ["true"], workdir=tmp_path / "a" / "b", **names)
    assert victim.read_text() == "keep me"


def test_a_template_cannot_reach_python_internals(tmp_path):
    tpl = tmp_path / "t.j2"
    tpl.write_text("{{ E.__class__.__mro__[1].__subclasses__() }}\n")
    model = CommandModel(tpl, ["true"], input_name="in", output_name="out.csv",
                         workdir=tmp_path / "w.work")
    with pytest.raises(ForwardModelError, match="not allowed in a template"):
        model.render_input({"E": 1.0})


def test_command_arguments_take_numbers_only_never_a_shell(tmp_path):
    tpl = tmp_path / "t.j2"
    tpl.write_text("x\n")
    model = CommandModel(tpl, ["echo", "{E}", "; rm -rf {workdir}"], input_name="in",
                         output_name="out.csv", workdir=tmp_path / "w.work")
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
                         input_name="in", output_name="out.csv", workdir=tmp_path / "w.work")
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
                         output_name="out.csv", workdir=tmp_path / "w.work", time_limit_s=0.5)
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
    import bayescalib.models.forward as fw

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


def test_solve_points_in_parallel_equals_one_at_a_time(tmp_path):
    """Several points at a time give the same records as one at a time, in the order
    of the points, failures included."""
    fm = {"type": "python", "python": {"function": ANALYTIC, "options": {"fail_below_E": 300.0}}}
    pts = [{"E": e, "nu": 0.2} for e in (500.0, 150.0, 420.0, 610.0, 250.0)]
    one = solve_points(fm, pts, [tmp_path / "a" / f"{i}.h5" for i in range(5)], workers=1)
    par = solve_points(fm, pts, [tmp_path / "b" / f"{i}.h5" for i in range(5)], workers=3)
    assert [r.status for r in par] == ["ok", "failed", "ok", "ok", "failed"]
    for a, b in zip(one, par, strict=True):
        assert a.status == b.status and a.parameters == b.parameters
        if a.ok:
            np.testing.assert_array_equal(a.interface_current, b.interface_current)


def test_solve_points_reuses_matching_records_and_redoes_the_rest(tmp_path):
    fm = {"type": "python", "python": {"function": ANALYTIC}}
    paths = [tmp_path / f"{i}.h5" for i in range(3)]
    solve_points(fm, [{"E": 300.0 + 100 * i, "nu": 0.1} for i in range(3)], paths)
    stamps = [p.stat().st_mtime_ns for p in paths]
    paths[2].write_bytes(b"not a run record")  # corrupt: solved again
    res = solve_points(fm, [{"E": 300.0, "nu": 0.1}, {"E": 999.0, "nu": 0.1},
                            {"E": 500.0, "nu": 0.1}], paths, workers=2)
    assert paths[0].stat().st_mtime_ns == stamps[0]  # same values: kept
    assert res[1].parameters["E"] == 999.0  # other values: solved again
    assert res[2].ok and res[2].parameters["E"] == 500.0


def test_solve_points_kills_only_the_hanging_point(tmp_path, monkeypatch):
    mod = tmp_path / "some_hang.py"
    mod.write_text("import time\ndef f(params):\n    if params['E'] < 0:\n"
                   "        time.sleep(600)\n    return [[0.0, 0.0], [1.0, params['E']]]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    fm = {"type": "python", "time_limit_s": 1.0, "python": {"function": "some_hang:f"}}
    res = solve_points(fm, [{"E": 1.0}, {"E": -1.0}, {"E": 2.0}],
                       [tmp_path / f"{i}.h5" for i in range(3)], workers=2, grace_s=0.5)
    assert [r.status for r in res] == ["ok", "failed", "ok"]
    assert "time limit" in res[1].reason


def test_unknown_forward_model_type():
    with pytest.raises(ForwardModelError, match="unknown forward model type 'abaqus'"):
        make_forward_model({"type": "abaqus"})


# ------------------------------------------------------------------ reliability of commands
def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a killed zombie waiting for its reaper counts as dead)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            state = next(line for line in fh if line.startswith("State:"))
    except (FileNotFoundError, StopIteration):
        return False
    return "Z" not in state.split()[1]


def _wait_for(path, timeout=20.0):
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and path.read_text().strip():
            return int(path.read_text())
        time.sleep(0.05)
    raise AssertionError(f"{path} did not appear")


SPAWNER = """
import subprocess, sys, time
p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
open("grandchild.pid", "w").write(str(p.pid))
print("solver started a helper", flush=True)
time.sleep(120)
"""


def test_command_time_limit_kills_everything_the_command_started(tmp_path):
    import time

    script = tmp_path / "wrapper.py"
    script.write_text(SPAWNER)
    tpl = tmp_path / "t.j2"
    tpl.write_text("\n")
    model = CommandModel(tpl, [sys.executable, str(script)], input_name="in",
                         output_name="out.csv", workdir=tmp_path / "w.work", time_limit_s=1.5)
    t0 = time.monotonic()
    res = model.solve({})
    assert time.monotonic() - t0 < 10
    assert res.status == "failed" and "time limit of 1.5 s" in res.reason
    assert "solver started a helper" in res.stats["log_tail"]
    pid = _wait_for(tmp_path / "w.work" / "grandchild.pid")
    time.sleep(0.2)
    assert not _alive(pid), "the command's child outlived the time limit"


def test_command_dies_with_a_killed_solve_process(tmp_path):
    import os
    import signal
    import subprocess
    import time

    script = tmp_path / "solver.py"
    script.write_text("import os, time\nopen('solver.pid', 'w').write(str(os.getpid()))\n"
                      "time.sleep(120)\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("\n")
    driver = tmp_path / "driver.py"
    driver.write_text(textwrap.dedent(f"""
        import sys
        from bayescalib.models.forward import CommandModel
        m = CommandModel({str(tpl)!r}, [sys.executable, {str(script)!r}], input_name="in",
                         output_name="out.csv", workdir={str(tmp_path / "w.work")!r},
                         time_limit_s=300)
        m.solve({{}})
    """))
    proc = subprocess.Popen([sys.executable, str(driver)])
    try:
        pid = _wait_for(tmp_path / "w.work" / "solver.pid")
        assert _alive(pid)
        os.kill(proc.pid, signal.SIGKILL)  # e.g. the snakemake job is killed
        proc.wait()
        end = time.monotonic() + 5
        while _alive(pid) and time.monotonic() < end:
            time.sleep(0.05)
        assert not _alive(pid), "the external solver outlived its killed parent"
    finally:
        proc.kill()
        proc.wait()


def _command_fm(tmp_path, body, output_name="out.csv", time_limit_s=30):
    script = tmp_path / "s.py"
    script.write_text("import sys\nprint('solver says hello', flush=True)\n"
                      + textwrap.dedent(body) + "\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("E={{ E }}\n")
    return {"type": "command", "time_limit_s": time_limit_s,
            "command": {"template": str(tpl), "command": [sys.executable, str(script), "{input}",
                                                          "{output}"],
                        "input_name": "in.txt", "output_name": output_name, "units": "mm"}}


@pytest.mark.parametrize(
    "body, output_name, reason",
    [
        ("import time; time.sleep(60)", "out.csv", "time limit of 1 s"),
        ("sys.exit(3)", "out.csv", "exited with status 3"),
        ("import os; os.kill(os.getpid(), 9)", "out.csv", "exited with status -9"),
        ("pass", "out.csv", "wrote no output file"),
        ("open(sys.argv[2], 'w').close()", "out.csv", "wrote no output file"),
        ("open(sys.argv[2], 'wb').write(bytes(range(256)) * 4)", "out.csv", "unreadable output"),
        ("open(sys.argv[2], 'w').write('x,y\\n0,0\\n1,0.5\\n2,')", "out.csv", "unreadable output"),
        ("open(sys.argv[2], 'w').write('x,y\\n0,0\\nnan,1\\n2,0\\n')", "out.csv", "NaN"),
        ("open(sys.argv[2], 'w').write('<VTKFile type=\"PolyData\"><Piece')", "out.vtp",
         "unreadable output"),
        ("import os; os.mkdir(sys.argv[2])", "out.csv", "wrote no output file"),
    ],
    ids=["hang", "exit3", "sigkill", "nothing", "empty", "binary", "cut-short", "nan",
         "bad-vtk", "directory"],
)
def test_failed_external_command_is_recorded_with_its_log_tail(tmp_path, body, output_name,
                                                              reason):
    """Through solve_point, as the solve rule runs it: a failed-run record, never a crash."""
    fm = _command_fm(tmp_path, body, output_name, time_limit_s=1)
    res = solve_point(fm, {"E": 300.0}, tmp_path / "run.h5", workdir=tmp_path / "w.work",
                      grace_s=5.0)
    assert res.status == "failed" and reason in res.reason, res.reason
    rec = read_run(tmp_path / "run.h5")
    assert rec.status == "failed" and reason in rec.reason
    assert "solver says hello" in rec.stats["log_tail"]
    assert rec.parameters == {"E": 300.0}


def test_log_tail_of_a_huge_log_is_its_end(tmp_path):
    fm = _command_fm(tmp_path, "sys.stdout.write('x' * 5_000_000 + 'THE END')\nsys.exit(1)")
    res = solve_point(fm, {"E": 1.0}, tmp_path / "run.h5", workdir=tmp_path / "w.work")
    assert res.stats["log_tail"].endswith("THE END")
    assert len(res.stats["log_tail"]) <= 2000


# ------------------------------------------------------------------ numbers only, by construction
_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.text(max_size=30),
    st.sampled_from(["1; rm -rf /", "$(touch pwned)", "`id`", "1 2", "-rf", "{input}",
                     "1e3", " 7 ", "nan", "inf", "0x10", "1_000", "\n1", "{{ E }}"]),
)
_NAMES = st.sampled_from(["E", "nu", "material.E", "inflow.rate"])


@settings(max_examples=200, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(values=st.dictionaries(_NAMES, _VALUES, min_size=1, max_size=4))
def test_command_arguments_and_input_are_numbers_only(tmp_path, values):
    """Any value: either it is a finite number and reaches the argv and the input file
    as that number (one argv item per template item, each parsing back to the same
    float), or the solve is refused with ForwardModelError/ValueError/TypeError."""
    tpl = tmp_path / "fuzz.j2"
    tpl.write_text("{% for k, v in params.items() %}{{ k }}={{ v }}\n{% endfor %}")
    command = ["solver", "--in", "{input}", *[f"{{{k}}}" for k in values], "tail"]
    model = CommandModel(tpl, command, input_name="in", output_name="out.csv",
                         workdir=tmp_path / "w.work")
    try:
        numbers = {k: float(v) for k, v in values.items()}
    except (ValueError, TypeError, OverflowError):
        numbers = None
    if numbers is None or not all(np.isfinite(list(numbers.values()))):
        with pytest.raises((ForwardModelError, ValueError, TypeError, OverflowError)):
            model.argv(values, tmp_path / "in", tmp_path / "out")
        with pytest.raises((ForwardModelError, ValueError, TypeError, OverflowError)):
            model.render_input(values)
        return
    argv = model.argv(values, tmp_path / "in", tmp_path / "out")
    assert len(argv) == len(command)
    assert argv[:3] == ["solver", "--in", str(tmp_path / "in")] and argv[-1] == "tail"
    for item, k in zip(argv[3:-1], values, strict=True):
        assert float(item) == numbers[k] and item == repr(numbers[k])
    lines = model.render_input(values).splitlines()
    assert lines == [f"{k}={numbers[k]!r}" for k in values]


def test_a_hostile_value_never_reaches_the_command(tmp_path):
    """End to end: the program receives exactly the argv items, each a number."""
    script = tmp_path / "record.py"
    script.write_text("import json, sys\njson.dump(sys.argv[1:], open('argv.json', 'w'))\n"
                      "sys.exit(1)\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("E={{ E }}\n")
    model = CommandModel(tpl, [sys.executable, str(script), "{E}", "x;{nu}", "$(id)"],
                         input_name="in", output_name="out.csv", workdir=tmp_path / "w.work")
    model.solve({"E": 250.0, "nu": -0.25})
    import json

    assert json.loads((tmp_path / "w.work" / "argv.json").read_text()) == ["250.0", "x;-0.25", "$(id)"]
    with pytest.raises(ValueError):
        model.solve({"E": "250; touch pwned", "nu": 0.1})
    assert not (tmp_path / "w.work" / "pwned").exists()


# ------------------------------------------------------------- the command's work folder
MY_SOLVER = """\
import json, os, sys
args = dict(zip(sys.argv[1::2], sys.argv[2::2]))
E = float(open(args["--in"]).read().split("=")[1])
json.dump(sorted(os.listdir(".")), open("seen.json", "w"))  # what the solve started with
with open(args["--out"], "w") as fh:
    fh.write("x,y\\n")
    for i in range(11):
        fh.write(f"{i / 10},{100.0 / E * i / 10}\\n")
"""


def _readme_command_example() -> dict:
    """The README's command-model example (its yaml block of type command)."""
    import re
    from pathlib import Path

    import yaml

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = [yaml.safe_load(textwrap.dedent(b))
              for b in re.findall(r"```yaml\n(.*?)```", readme, flags=re.DOTALL)]
    (example,) = [b for b in blocks if (b.get("forward_model") or {}).get("type") == "command"]
    return example


@pytest.fixture
def checkout(tmp_path, monkeypatch):
    """A stand-in checkout as the README's example names it, the current folder: the
    template under solver/, the solver ``my_solver`` on PATH; returns the validated
    forward_model section of a study with the example on top of the defaults."""
    from pathlib import Path

    from bayescalib.config import load_yaml, merge_layers
    from bayescalib.study import Study

    repo = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "solver").mkdir()
    (tmp_path / "solver" / "input.j2").write_text('E = {{ params["material.E"] }}\n')
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    solver = bin_dir / "my_solver"
    solver.write_text(f"#!{sys.executable}\n" + MY_SOLVER)
    solver.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    study = Study(merge_layers([load_yaml(repo / "config" / "config.yaml"),
                                _readme_command_example()]), where="README")
    return study.forward_section()


def test_the_readme_command_example_solves_from_the_checkout(checkout):
    """The README's placeholders as written ({input}, {output}), the run record under the
    relative results folder as the workflow names it: the solver finds its input and
    its output lands where it is read (relative paths failed every solve)."""
    from pathlib import Path

    res = solve_point(checkout, {"material.E": 250.0, "material.nu": 0.3},
                      Path("results/demo/runs/0.h5"))
    assert res.status == "ok", res.reason
    np.testing.assert_allclose(res.interface_current[-1], [1.0, 0.4])
    assert Path("results/demo/runs/0.work/input.txt").read_text() == "E = 250.0\n"


def test_every_solve_starts_in_a_fresh_empty_work_folder(checkout):
    import json
    from pathlib import Path

    work = Path("results/demo/runs/0.work")
    solve_point(checkout, {"material.E": 250.0}, Path("results/demo/runs/0.h5"))
    (work / "left_by_the_last_solve.txt").write_text("old")
    (work / "sub").mkdir()
    (work / "sub" / "old.csv").write_text("old")
    res = solve_point(checkout, {"material.E": 500.0}, Path("results/demo/runs/0.h5"))
    assert res.status == "ok", res.reason
    # the second solve saw its own input and log only
    assert json.loads((work / "seen.json").read_text()) == ["input.txt", "solver.log"]
    np.testing.assert_allclose(res.interface_current[-1], [1.0, 0.2])


@pytest.mark.parametrize("where", ["input.txt", "solver.log", "interface.csv"])
def test_a_link_left_in_the_work_folder_is_never_written_through(checkout, tmp_path, where):
    """A link left where the model writes its files: the next solve removes it and
    writes its own file; the file outside is untouched."""
    from pathlib import Path

    outside = tmp_path / "outside.txt"
    outside.write_text("keep me")
    work = Path("results/demo/runs/0.work")
    solve_point(checkout, {"material.E": 250.0}, Path("results/demo/runs/0.h5"))
    (work / where).unlink()
    (work / where).symlink_to(outside)
    res = solve_point(checkout, {"material.E": 250.0}, Path("results/demo/runs/0.h5"))
    assert res.status == "ok", res.reason
    assert outside.read_text() == "keep me"
    assert not (work / where).is_symlink()


def test_a_work_folder_that_is_a_link_is_removed_not_followed(checkout, tmp_path):
    from pathlib import Path

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious.txt").write_text("keep me")
    (elsewhere / "input.txt").write_text("keep me")
    work = Path("results/demo/runs/0.work")
    work.parent.mkdir(parents=True)
    work.symlink_to(elsewhere)
    res = solve_point(checkout, {"material.E": 250.0}, Path("results/demo/runs/0.h5"))
    assert res.status == "ok", res.reason
    assert not work.is_symlink() and (work / "input.txt").read_text() == "E = 250.0\n"
    assert sorted(p.name for p in elsewhere.iterdir()) == ["input.txt", "precious.txt"]
    assert (elsewhere / "input.txt").read_text() == "keep me"


def test_an_output_that_is_a_link_is_not_read(tmp_path):
    outside = tmp_path / "outside.csv"
    outside.write_text("x,y\n0,0\n1,1\n")
    script = tmp_path / "s.py"
    script.write_text(f"import os, sys\nos.symlink({str(outside)!r}, sys.argv[1])\n")
    tpl = tmp_path / "t.j2"
    tpl.write_text("\n")
    model = CommandModel(tpl, [sys.executable, str(script), "{output}"], input_name="in",
                         output_name="out.csv", workdir=tmp_path / "w.work")
    res = model.solve({})
    assert res.status == "failed" and "'out.csv' is a link" in res.reason


def test_a_folder_not_named_work_is_never_emptied(tmp_path):
    data = tmp_path / "my_data"
    data.mkdir()
    (data / "scan.csv").write_text("keep me")
    tpl = tmp_path / "t.j2"
    tpl.write_text("\n")
    with pytest.raises(ForwardModelError, match="my_data.*must be named <name>.work"):
        CommandModel(tpl, ["true"], input_name="in", output_name="out.csv", workdir=data)
    assert (data / "scan.csv").read_text() == "keep me"
