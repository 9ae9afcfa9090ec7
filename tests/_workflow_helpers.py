"""Helpers for the tests that run the Snakemake workflow in a temporary directory
(on the analytic stand-in model); the fixtures built on them are in conftest.py."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]
DATA = Path(__file__).parent / "data"


def copy_checkout(dest: Path) -> Path:
    """A copy of the checkout's tracked files in ``dest``, links kept as links (the
    ``profiles`` link is how a plain ``snakemake`` in the copy finds the default profile,
    as in a real clone)."""
    import shutil

    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split("\0")
    for f in filter(None, files):
        src, dst = REPO / f, dest / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            dst.symlink_to(os.readlink(src))
        elif src.is_file():
            shutil.copy2(src, dst)
    return dest


def readme_section_commands(heading: str) -> list[str]:
    """The shell commands of the README section under the heading ``heading`` (to the
    next heading): the lines of its ``bash`` blocks, comments dropped."""
    import re

    text = (REPO / "README.md").read_text()
    match = re.search(rf"^#{{2,6}} {re.escape(heading)}\n(.*?)(?=^#{{2,6}} |\Z)", text,
                      flags=re.DOTALL | re.MULTILINE)
    if match is None:
        raise AssertionError(f"README.md has no section '{heading}'")
    out = []
    for block in re.findall(r"```bash\n(.*?)```", match.group(1), flags=re.DOTALL):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line and not line.startswith("#"):
                out.append(line)
    return out


def setup_study(tmp: Path, study: dict) -> Path:
    """Write ``study`` as the config of a workflow run in ``tmp``."""
    (tmp / "config").mkdir(parents=True, exist_ok=True)
    (tmp / "config" / "config.yaml").write_text(yaml.safe_dump(study))
    return tmp


def _env(tmp: Path) -> dict[str, str]:
    """The environment of a workflow run: ``tmp`` first on the module path (for study
    files that name modules there), then the caller's PYTHONPATH, so that a test run
    with PYTHONPATH=<checkout>/src tests that checkout's bayescalib."""
    path = os.pathsep.join(p for p in (str(tmp), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path}


def smk(tmp: Path, *args: str, check: bool = True, timeout: int = 600):
    """Run Snakemake on the repository's Snakefile with ``tmp`` as working directory."""
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "--directory", str(tmp), "--cores", "2",
           *args]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=timeout,
                          env=_env(tmp))
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-6000:]}")
    return proc


SLOW_MODEL = (
    "import time\nfrom bayescalib.models.analytic import interface as _f\n"
    "def interface(params, **kw):\n    time.sleep({sleep})\n    return _f(params, **kw)\n"
)


def run_and_kill(tmp: Path, runs: Path, n: int, *, sleep: float = 1.0,
                 timeout: float = 300) -> None:
    """Run the workflow in ``tmp`` with ``slow_model:interface`` (the analytic model
    taking ``sleep`` s a point; the study must name it) and SIGKILL Snakemake and its
    jobs once ``runs`` holds ``n`` design-point records (or at ``timeout``)."""
    import signal
    import time

    (tmp / "slow_model.py").write_text(SLOW_MODEL.format(sleep=sleep))
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "--directory", str(tmp), "--cores", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=_env(tmp), start_new_session=True)
    deadline = time.time() + timeout
    while time.time() < deadline:
        if runs.is_dir() and len(list(runs.glob("[0-9]*.h5"))) >= n:
            break
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
