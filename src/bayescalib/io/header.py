"""The header of every HDF5 file the pipeline writes: what the file is and which
version of its layout it holds.

Six stage outputs are HDF5 files: run records (``runs/<i>.h5``), the observation
set, training tables, GP surrogates (or output emulators, ``surrogate.target:
outputs``) and SMC particles. Each carries two root
attributes, ``format`` (the kind, e.g. ``bayescalib.TrainingTable``) and
``format_version`` (an integer raised whenever the layout changes). A reader
checks both before it reads anything, so a file of another kind, or one written
by another version of the layout, is refused with a message that names the file
and says how to rebuild it, instead of failing later on a missing dataset.

A layout that only adds fields keeps the older versions readable
(:data:`READABLE_OLDER`); a file of a newer version is refused.

Files written before a kind had a header (observation sets, training tables and
particles of earlier runs) carry no ``format`` attribute; they are read as
version 1 of their kind, so finished results stay usable.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["FORMATS", "validate_header", "write_header"]

#: kind -> (format name, current layout version, what the file is, in words)
FORMATS: dict[str, tuple[str, int, str]] = {
    "run": ("bayescalib-run", 1, "run record"),
    "observations": ("bayescalib.Observations", 1, "observation set"),
    "training": ("bayescalib.TrainingTable", 1, "training table"),
    "surrogate": ("bayescalib.GPSurrogate", 3, "GP surrogate file"),
    "particles": ("bayescalib.SMCParticles", 1, "particle file"),
    "emulator": ("bayescalib.EmulatedLikelihood", 1, "output emulator file"),
}

#: kinds whose files had no header before it was introduced (read as version 1)
_UNMARKED = {"observations", "training", "particles"}

#: older layout versions a reader still reads, per kind: version 3 of the GP surrogate
#: only added the quadratic prior mean (a version-2 file is a constant-mean surrogate)
READABLE_OLDER: dict[str, frozenset[int]] = {"surrogate": frozenset({2})}


def _plain(value: Any) -> Any:
    return value.decode() if isinstance(value, bytes) else value


def write_header(f, kind: str) -> None:
    """Write the header of ``kind`` to the open h5py file ``f``."""
    name, version, _ = FORMATS[kind]
    f.attrs["format"] = name
    f.attrs["format_version"] = version


def validate_header(f, kind: str, path: str | Path, error: type[Exception] = ValueError) -> int:
    """Check that the open h5py file ``f`` (read from ``path``) is a ``kind`` file of the
    current layout (or an older one it still reads, :data:`READABLE_OLDER`); raise
    ``error`` naming the file otherwise. Returns the version."""
    name, current, what = FORMATS[kind]
    found = _plain(f.attrs.get("format"))
    if found is None and kind in _UNMARKED:
        found, version = name, 1
    else:
        version = int(_plain(f.attrs.get("format_version", 1)))
    if found != name:
        described = f"a file of format {found!r}" if found else "a file without a bayescalib header"
        raise error(f"'{path}' is not a bayescalib {what}: it is {described}")
    if version != current and version not in READABLE_OLDER.get(kind, frozenset()):
        raise error(
            f"'{path}' is a {what} of format version {version}; this bayescalib reads "
            f"version {current}. Delete it and rerun to rebuild it from its inputs")
    return version
