"""The atomic writer (bayescalib.io._atomic_write.atomic_path) leaves nothing behind: a
write that fails (a full disk inside the writer, a failed fsync or rename, Ctrl-C)
removes its temporary file and leaves the previous file as it was; the temporary file
of a writer killed outright is removed by the next successful write of its target."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from bayescalib.inference.parameters import ParameterSpace
from bayescalib.inference.posterior import read_particles_h5, write_particles_h5
from bayescalib.inference.smc import SMCResult
from bayescalib.io import _atomic_write
from bayescalib.io._atomic_write import atomic_path

SRC = Path(__file__).resolve().parents[1] / "src"


def _space() -> ParameterSpace:
    return ParameterSpace.from_config([
        {"name": "E", "unit": "Pa", "prior": {"type": "uniform", "lo": 0.0, "hi": 1.0},
         "bounds": [0.0, 1.0]}])


def _particles(value: float) -> SMCResult:
    x = np.full((5, 1), value)
    return SMCResult(particles=x, weights=np.full(5, 0.2), loglik=np.zeros(5),
                     logprior=np.zeros(5), log_evidence=-1.0,
                     history={"beta": np.array([0.0, 1.0])}, n_steps=1)


@pytest.fixture
def particles(tmp_path) -> Path:
    """``active/0/particles.h5`` of a finished round (particles at 0.25)."""
    path = tmp_path / "active" / "0" / "particles.h5"
    write_particles_h5(path, _particles(0.25), _space())
    return path


def _only_the_target(path: Path) -> None:
    assert sorted(os.listdir(path.parent)) == [path.name]
    assert read_particles_h5(path).particles[0, 0] == 0.25  # the previous file, untouched


def test_a_full_disk_inside_the_writer_leaves_nothing(particles, monkeypatch):
    def full(self, name, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(h5py.Group, "create_dataset", full)
    with pytest.raises(OSError, match="No space left"):
        write_particles_h5(particles, _particles(0.75), _space())
    _only_the_target(particles)


def test_ctrl_c_inside_the_writer_leaves_nothing(particles):
    with pytest.raises(KeyboardInterrupt), atomic_path(particles, suffix=".h5") as tmp:
        tmp.write_bytes(b"half a file")
        raise KeyboardInterrupt
    _only_the_target(particles)


def test_a_failed_fsync_fails_the_write_and_leaves_nothing(particles, monkeypatch):
    def fsync(fd):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(_atomic_write.os, "fsync", fsync)
    with pytest.raises(OSError, match="Input/output error"):
        write_particles_h5(particles, _particles(0.75), _space())
    _only_the_target(particles)


@pytest.mark.parametrize("fault", [OSError(errno.ENOSPC, "No space left on device"),
                                   KeyboardInterrupt()], ids=["ENOSPC", "KeyboardInterrupt"])
def test_a_failed_rename_leaves_nothing(particles, monkeypatch, fault):
    def replace(src, dst):
        raise fault

    monkeypatch.setattr(_atomic_write.os, "replace", replace)
    with pytest.raises(type(fault)):
        write_particles_h5(particles, _particles(0.75), _space())
    _only_the_target(particles)


def _killed_writer(target: Path) -> Path:
    """Start a writer of ``target`` in a child process and SIGKILL it mid-write; return
    the temporary file it left."""
    code = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(SRC)!r})
        from bayescalib.io._atomic_write import atomic_path
        with atomic_path({str(target)!r}, suffix=".h5") as tmp:
            tmp.write_bytes(b"half a file")
            os.kill(os.getpid(), signal.SIGKILL)
        """)
    proc = subprocess.run([sys.executable, "-c", code], check=False)
    assert proc.returncode == -signal.SIGKILL
    left = [p for p in target.parent.iterdir() if p != target]
    assert len(left) == 1 and left[0].name.startswith(f".{target.name}.")
    return left[0]


def test_the_next_write_removes_the_temp_file_of_a_killed_writer(particles):
    stale = _killed_writer(particles)
    write_particles_h5(particles, _particles(0.75), _space())
    assert not stale.exists()
    assert sorted(os.listdir(particles.parent)) == ["particles.h5"]
    assert read_particles_h5(particles).particles[0, 0] == 0.75


def test_the_cleanup_removes_only_the_temp_files_of_its_target(particles):
    folder = particles.parent
    old = (1, 1)  # 1970: older than any write
    others = {
        ".surrogate.h5.abcd1234.h5": "another target's temp file",
        ".particles.h5.abcd1234.tmp": "another suffix",
        ".particles.h5.notatemp.file.h5": "not the writer's pattern",
        "particles.h5.corrupt": "a file set aside",
        ".particles.h5.user": "the user's file",
    }
    for name in others:
        (folder / name).write_text("keep")
        os.utime(folder / name, old)
    outside = folder.parent / "outside.txt"
    outside.write_text("keep")
    link = folder / ".particles.h5.zzzz9999.h5"  # a link named like a temp file: not followed
    link.symlink_to(outside)
    stale = folder / ".particles.h5.k3_x9a2q.h5"
    stale.write_bytes(b"half a file")
    os.utime(stale, old)

    write_particles_h5(particles, _particles(0.75), _space())

    assert not stale.exists()
    assert sorted(os.listdir(folder)) == sorted([*others, "particles.h5", link.name])
    assert outside.read_text() == "keep"
