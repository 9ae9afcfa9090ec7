"""Every shell command of the README works as written.

The commands are taken from the README's ``bash`` blocks (and its inline
``bayescalib ...`` commands) and run verbatim, in order, in a scratch copy of the
repository. Only the data behind them is a stand-in: the studies they name are the
analytic model of ``tests/data/analytic_study.yaml`` under the names the README uses
(an FSI study would take hours here; that every shipped study validates is tested in
``test_study.py``, and the smoke study runs end to end in ``.ci/run``). The install
steps (``python3 -m venv``, ``pip install``) are the environment this test runs in
and are left out; the SLURM command needs its executor plugin and runs as a dry run
where it is installed (against the single-node test cluster the README starts, where
its daemons can run).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from _workflow_helpers import DATA, REPO, copy_checkout

pytestmark = pytest.mark.workflow

SETUP = ("python3 -m venv", ". .venv/bin/activate", "pip install")


def readme_commands(text: str) -> list[str]:
    """The shell commands of the README: lines of ``bash`` blocks (comments dropped,
    ``&&`` chains kept whole) and inline ``bayescalib ...`` commands, in order."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                out.append(line)
    out += [c for c in re.findall(r"`(bayescalib [^`]+)`", text) if c not in out]
    return out


def _slurm_missing() -> str | None:
    """Why the README's test cluster cannot start here (benchmarks/slurm_cluster.py)."""
    spec = importlib.util.spec_from_file_location("slurm_cluster",
                                                  REPO / "benchmarks" / "slurm_cluster.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.missing()


def _steps(command: str) -> list[str]:
    return [s.strip() for s in command.split("&&") if not s.strip().startswith(SETUP)]


def test_readme_commands_are_found():
    cmds = readme_commands((REPO / "README.md").read_text())
    # one resume command, naming the study (the one that starts it): no --unlock recipe
    assert "snakemake --cores 2 --configfile config/smoke.yaml" in cmds
    assert not any("--unlock" in c or "--rerun-incomplete" in c for c in cmds), cmds
    # each study's report at its own path
    reports = [c for c in cmds if c.startswith("snakemake --report")]
    assert reports and all(re.match(r"snakemake --report results/(\w+)/report\.html "
                                    r"--configfile \S+/(study|\1)\.yaml$", c) for c in reports), \
        reports
    assert any(c.endswith("&& pytest") for c in cmds)
    assert any(c.startswith("bayescalib summary") for c in cmds)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """A copy of the repository's tracked files with stand-in studies."""
    root = copy_checkout(tmp_path_factory.mktemp("readme"))
    study = yaml.safe_load((DATA / "analytic_study.yaml").read_text())
    (root / "config" / "config.yaml").write_text(yaml.safe_dump(study))
    for cfg in (root / "config").glob("*.yaml"):
        if cfg.name != "config.yaml":  # a study of its own name on the stand-in model
            cfg.write_text(yaml.safe_dump({"study": cfg.stem}))
    from bayescalib.models.analytic import interface

    for name, e in (("model.csv", 300.0), ("observed.csv", 400.0)):
        pts = interface({"E": e, "nu": 0.3})["current"]
        np.savetxt(root / name, np.asarray(pts), delimiter=",", header="x,y", comments="")
    return root


@pytest.mark.extended
def test_every_readme_command_works_verbatim(scratch):
    cmds = readme_commands((REPO / "README.md").read_text())
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    ran, skipped = [], []
    for command in cmds:
        steps = _steps(command)
        if steps == ["pytest"]:
            continue  # the test suite itself: this test is part of it
        line = " && ".join(steps).replace("results/<study>", "results/analytic")
        if "examples/oct_colony" in line:  # run verbatim by tests/test_oct_example.py
            continue
        if "slurm_cluster.py" in line and _slurm_missing():
            skipped.append(f"{line} ({_slurm_missing()})")
            continue
        if "workflow/profiles/slurm" in line:
            if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
                skipped.append(f"{line} (snakemake-executor-plugin-slurm not installed)")
                continue
            line += " -n"
        if not line:
            continue
        proc = subprocess.run(["bash", "-c", line], check=False, cwd=scratch, env=env, capture_output=True,
                              text=True, timeout=900)
        assert proc.returncode == 0, (
            f"README command failed: {line}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
        ran.append(line)
    assert (scratch / "results" / "analytic" / "summary.json").is_file()
    report = (scratch / "results" / "uncertain_inflow" / "report.html").read_text()
    # the front page: the result line and the table of key numbers
    assert "<strong>Result.</strong> bayescalib uncertain_inflow: E = " in report
    assert "90 % equal-tailed interval" in report
    assert (scratch / "out").is_dir() and any((scratch / "out").iterdir())
    assert len(ran) >= 7, (ran, skipped)


def test_the_readme_study_example_validates(tmp_path, monkeypatch):
    """The "Calibrate your own data" example is a valid study on top of the defaults
    (with a stand-in scan at the path it names)."""
    from bayescalib.config import load_yaml, merge_layers
    from bayescalib.study import Study

    blocks = [b for b in re.findall(r"```yaml\n(.*?)```", (REPO / "README.md").read_text(),
                                    flags=re.DOTALL)
              if "observations" in (yaml.safe_load(b) or {})]  # not the forward-model examples
    assert blocks
    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    x = np.linspace(0.7, 1.3, 41)
    y = 0.4 * np.sqrt(np.clip(1 - ((x - 1.0) / 0.3) ** 2, 0, None))
    np.savetxt(tmp_path / "data" / "scan_100.csv", np.column_stack([x, y]), delimiter=",",
               header="x,y", comments="")
    for block in blocks:
        study = Study(merge_layers([load_yaml(REPO / "config" / "config.yaml"),
                                    yaml.safe_load(block)]), where="README")
        assert study.config["observations"]["source"] == "files"
        assert study.config["likelihood"].get("sigma_n2") is None
