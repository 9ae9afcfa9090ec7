"""The README's resume command resumes a study after any interruption.

The command is read from the README's "Resuming after an interruption" section and
run verbatim, in a copy of the checkout (its profiles link included, as in a clone),
both to start the study and to resume it: ``snakemake --cores 2 --configfile
config/smoke.yaml``. The study behind ``config/smoke.yaml`` is a stand-in (the smoke
study's FSI solves would take minutes per probe): the analytic study of
tests/data/analytic_study.yaml under the name ``smoke``, with the smallest settings
that make each stage last long enough to be interrupted in: solves of 1 s each
(``slow_model``), a GP fit of 20 restarts (about 5 s) and an SMC of 200000 particles
(about 4 s).

Each probe starts the command in its own process group, waits for its stage by
polling for files under ``results/smoke/`` (the first run record: solves running; the
GP training's log: GP running; the SMC's log: SMC running), then sends the signal to
the whole group, as Ctrl-C (SIGINT) or ``kill -9 -<pgid>`` (SIGKILL) would, and
runs the command again. It must end with rc 0 and ``summary.json``, redo at most the
two solves that were running, and give the summary of an uninterrupted run.

Before the change (Snakemake 9.27, default profile without ``rerun-incomplete``): the
SIGINT during the solves and the SIGKILL stopped the resume with
``IncompleteFilesException`` (4 of 4 tries and 1 of 1); the SIGKILL's stale lock
needed ``snakemake --unlock``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from _workflow_helpers import DATA, SLOW_MODEL, copy_checkout, readme_section_commands

pytestmark = [pytest.mark.workflow, pytest.mark.extended]

STUDY = Path("results") / "smoke"


def resume_command() -> str:
    """The README's one resume command (it also starts the study)."""
    cmds = readme_section_commands("Resuming after an interruption")
    assert len(cmds) == 1, cmds
    return cmds[0]


def _scratch(dest: Path) -> Path:
    """A copy of the checkout whose config/smoke.yaml is the stand-in study."""
    copy_checkout(dest)
    study = yaml.safe_load((DATA / "analytic_study.yaml").read_text())
    study["forward_model"]["python"]["function"] = "slow_model:interface"
    study["surrogate"]["restarts"] = 20
    study["smc"].update(n_particles=200000, n_rej=30)
    study["posterior_check"] = {"draws": 8}
    (dest / "config" / "config.yaml").write_text(yaml.safe_dump(study))
    (dest / "config" / "smoke.yaml").write_text(yaml.safe_dump({"study": "smoke"}))
    (dest / "slow_model.py").write_text(SLOW_MODEL.format(sleep=1.0))
    return dest


def _env(scratch: Path) -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(scratch), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path,
            "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}


def _run(scratch: Path, log: str) -> subprocess.CompletedProcess:
    """The README's command, run to its end in ``scratch`` (its output in ``log``)."""
    with open(scratch / log, "w") as out:
        return subprocess.run(["bash", "-c", resume_command()], cwd=scratch,
                              env=_env(scratch), stdout=out, stderr=subprocess.STDOUT,
                              check=False, timeout=900)


def _summary(scratch: Path) -> dict:
    summary = json.loads((scratch / STUDY / "summary.json").read_text())
    summary.pop("timings_s")
    return summary


def _runs(scratch: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (scratch / STUDY / "runs").glob("[0-9]*.h5")}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """The stand-in study run once without interruption."""
    scratch = _scratch(tmp_path_factory.mktemp("uninterrupted"))
    proc = _run(scratch, "run.out")
    assert proc.returncode == 0, (scratch / "run.out").read_text()[-4000:]
    return _summary(scratch)


def _solving(root: Path) -> bool:
    return (root / "runs").is_dir() and any((root / "runs").glob("[0-9]*.h5"))


#: probe -> (signal, the stage's sign under results/smoke/, output not yet written)
PROBES: dict[str, tuple[signal.Signals, Callable[[Path], bool], str]] = {
    "SIGINT during the solves": (signal.SIGINT, _solving, "rkhs/training.h5"),
    "SIGINT during the GP fit": (signal.SIGINT,
                                 lambda r: (r / "logs/rkhs/train_surrogate.log").exists(),
                                 "rkhs/surrogate.h5"),
    "SIGINT during the SMC": (signal.SIGINT, lambda r: (r / "logs/rkhs/smc.log").exists(),
                              "rkhs/particles.h5"),
    "SIGKILL of the group during the solves": (signal.SIGKILL, _solving, "rkhs/training.h5"),
}


@pytest.mark.parametrize("probe", list(PROBES))
def test_the_readme_resume_command_finishes_an_interrupted_study(probe, reference, tmp_path):
    sig, at_stage, not_yet = PROBES[probe]
    scratch = _scratch(tmp_path / "run")
    root = scratch / STUDY
    out = open(scratch / "interrupted.out", "w")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(["bash", "-c", resume_command()], cwd=scratch, env=_env(scratch),
                            stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 300
        while not at_stage(root):
            assert proc.poll() is None, (
                f"the run ended (rc {proc.returncode}) before the stage of '{probe}':\n"
                + (scratch / "interrupted.out").read_text()[-3000:])
            assert time.monotonic() < deadline, f"no sign of the stage of '{probe}' in 300 s"
            time.sleep(0.02)
        os.killpg(proc.pid, sig)  # the whole group, as Ctrl-C or kill -9 -<pgid>
        proc.wait(timeout=120)  # a Ctrl-C must end the run, not hang it
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        out.close()
    assert not (root / not_yet).exists(), f"the {sig.name} came too late for '{probe}'"
    assert not (root / "summary.json").exists()
    if sig == signal.SIGKILL:
        assert any((scratch / ".snakemake" / "locks").iterdir()), "a kill leaves the lock"
    finished = _runs(scratch)

    resumed = _run(scratch, "resumed.out")
    said = (scratch / "resumed.out").read_text()
    assert resumed.returncode == 0, f"the resume after '{probe}' failed:\n{said[-4000:]}"
    assert (root / "summary.json").is_file()
    # a record written in the instant of the signal may belong to a job Snakemake had
    # not marked finished: at most the two jobs running (--cores 2) run again
    redone = [n for n, t in finished.items() if _runs(scratch).get(n) != t]
    assert len(redone) <= 2, f"finished solves were redone: {redone}"
    assert _summary(scratch) == reference
