"""The one atomic file writer of the project.

Every result file (run records, training tables, surrogates, particles, posterior
summaries, observations, warm-start states, VTU fields) is written through
:func:`atomic_path`: the content goes to a temporary file in the target's folder,
which is flushed to disk (``fsync``), given the permissions of a normally created
file (``0666`` minus the umask, so collaborators can read results on a shared
machine), and then moved onto the target with ``os.replace``; the folder is
``fsync``-ed too, so that the rename survives a power loss. A reader never sees a
half-written file, and a failed write leaves the previous file untouched.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_path(path: Path, *, directory: bool = False) -> None:
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:  # e.g. a folder that cannot be opened on this platform
        return
    try:
        os.fsync(fd)
    except OSError:  # file systems without fsync on folders
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path``.

    The caller writes the whole file to the yielded path (with any library:
    h5py, VTK, numpy, plain text). If the body raises, the temporary file is
    removed and ``path`` is left untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or ".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        _fsync_path(tmp_path)
        os.replace(tmp_path, target)
        _fsync_path(target.parent, directory=True)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
