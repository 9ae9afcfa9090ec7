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


def setup_study(tmp: Path, study: dict) -> Path:
    """Write ``study`` as the config of a workflow run in ``tmp``."""
    (tmp / "config").mkdir(parents=True, exist_ok=True)
    (tmp / "config" / "config.yaml").write_text(yaml.safe_dump(study))
    return tmp


def smk(tmp: Path, *args: str, check: bool = True, timeout: int = 600):
    """Run Snakemake on the repository's Snakefile with ``tmp`` as working directory."""
    cmd = [*SNAKEMAKE, "-s", str(REPO / "Snakefile"), "--directory", str(tmp), "--cores", "2",
           *args]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONPATH": str(tmp)})
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-6000:]}")
    return proc
