"""The one atomic file writer of the project.

Every result file (run records, training tables, surrogates, particles, posterior
summaries, observations, warm-start states, VTU fields) is written through
:func:`atomic_path`: the content goes to a temporary file in the target's folder,
which is flushed to disk (``fsync``), given the permissions of a normally created
file (``0666`` minus the umask, so collaborators can read results on a shared
machine), and then moved onto the target with ``os.replace``; the folder is
``fsync``-ed too, so that the rename survives a power loss. A reader never sees a
half-written file, and a failed write leaves the previous file untouched.

Nothing is left behind: whatever ends a write early (an exception of the body such as
a full disk, a failed ``fsync`` or rename, ``KeyboardInterrupt``), the temporary file
is removed. A writer killed outright (``SIGKILL``, a power loss) cannot clean up: its
temporary file (``.<name>.<8 random characters><suffix>``, e.g.
``active/0/.particles.h5.k3_x9a2q.h5``) is removed by the next successful write of the
same target (:func:`_remove_stale`).
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path"]

#: the random part of :func:`tempfile.mkstemp`'s names: 8 of these characters
_RANDOM = "[a-z0-9_]{8}"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_path(path: Path, *, directory: bool = False) -> None:
    """``fsync`` the folder ``path`` (``directory``: best effort, some file systems
    cannot) or the file ``path`` (an error is raised: its content may not be on disk)."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        if directory:  # e.g. a folder that cannot be opened on this platform
            return
        raise
    try:
        os.fsync(fd)
    except OSError as exc:
        # folders: file systems without fsync on folders; files: only "not supported"
        if not directory and exc.errno not in (errno.EINVAL, errno.ENOTSUP):
            raise
    finally:
        os.close(fd)


def _temp_pattern(target: Path, suffix: str) -> re.Pattern[str]:
    """The names :func:`atomic_path` gives the temporary files of ``target``."""
    return re.compile(rf"\.{re.escape(target.name)}\.{_RANDOM}{re.escape(suffix)}")


def _remove_stale(target: Path, suffix: str, own: Path, started_ns: int) -> None:
    """Remove the temporary files of earlier writes of ``target`` that were killed
    before they could clean up: regular files named as :func:`atomic_path` names them,
    last modified no later than this write began (``started_ns``, the creation time of
    ``own``, this write's temporary file; file times have the kernel's clock tick, a few
    ms). Links are not followed, a file that cannot be removed is left. One job writes a
    target at a time (Snakemake, and the study's run lock); a writer whose temporary
    file was removed all the same fails at its rename, it never writes a partial file."""
    pattern = _temp_pattern(target, suffix)
    try:
        entries = list(os.scandir(target.parent))
    except OSError:
        return
    for entry in entries:
        if entry.name == own.name or not pattern.fullmatch(entry.name):
            continue
        try:
            st = entry.stat(follow_symlinks=False)
            if stat.S_ISREG(st.st_mode) and st.st_mtime_ns <= started_ns:
                os.unlink(entry.path)
        except OSError:
            continue


def _discard(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError:  # e.g. a read-only folder: nothing more can be done
        pass


@contextmanager
def atomic_path(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path``.

    The caller writes the whole file to the yielded path (with any library:
    h5py, VTK, numpy, plain text). If anything fails before the file is in place
    (the body raises, ``fsync`` or the rename fails, ``KeyboardInterrupt``), the
    temporary file is removed and ``path`` is left untouched. After a successful
    write, the temporary files of earlier writes of ``path`` that were killed outright
    are removed (:func:`_remove_stale`).

    Parameters
    ----------
    path
        The file to write; its folder is created when missing.
    suffix
        Suffix of the temporary file (a library may pick its format by it); ``.tmp``
        when empty.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    suffix = suffix or ".tmp"
    tmp_path: Path | None = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix, dir=target.parent)
        tmp_path = Path(tmp)
        try:
            started_ns = os.fstat(fd).st_mtime_ns
        finally:
            os.close(fd)
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        _fsync_path(tmp_path)
        os.replace(tmp_path, target)
        done, tmp_path = tmp_path, None
        _fsync_path(target.parent, directory=True)
    finally:
        if tmp_path is not None:  # the write did not complete: nothing of it stays
            _discard(tmp_path)
    _remove_stale(target, suffix, done, started_ns)
