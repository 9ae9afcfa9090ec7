"""Rigid (mis)registration of observed interfaces.

An imaged interface can be misplaced against the model as a whole: the image origin
off by a few pixels (a shift ``t``), the sample slightly rotated (``theta``), or the
pixel size wrong (an isotropic scale ``s``). About a centre ``c`` the misplacement is

    x -> c + (1 + s) R(theta) (x - c) + t,

applied to every snapshot alike (one scanner set-up). :func:`misplace` applies it
(synthetic data with a hidden misregistration), :func:`register` undoes it (observed
interfaces registered back to the model's frame). Lengths in mm, angles in rad.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["REGISTRATION_MODES", "misplace", "register"]

#: the modes of a rigid misregistration: shifts (mm), a rotation (rad) and an isotropic
#: scale (relative, e.g. a pixel-size error)
REGISTRATION_MODES = ("shift_x", "shift_y", "rotation", "scale")


def _parts(transform: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray, float]:
    unknown = set(transform) - set(REGISTRATION_MODES)
    if unknown:
        raise ValueError(f"registration modes {sorted(unknown)} unknown; choose from "
                         f"{REGISTRATION_MODES}")
    t = np.array([float(transform.get("shift_x", 0.0)), float(transform.get("shift_y", 0.0))])
    th = float(transform.get("rotation", 0.0))
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return t, R, 1.0 + float(transform.get("scale", 0.0))


def misplace(points: np.ndarray, transform: Mapping[str, float], centre: np.ndarray) -> np.ndarray:
    """Apply ``x -> c + (1 + s) R(theta) (x - c) + t``.

    Parameters
    ----------
    points
        (n, 2) nodes, mm.
    transform
        By mode (missing modes are 0): ``shift_x``, ``shift_y`` (mm), ``rotation``
        (rad), ``scale`` (relative).
    centre
        (2,) centre of rotation and scaling, mm.

    Returns
    -------
    ndarray, shape (n, 2)
    """
    t, R, sc = _parts(transform)
    c = np.asarray(centre, dtype=float)
    return c + sc * (np.asarray(points, dtype=float) - c) @ R.T + t


def register(points: np.ndarray, transform: Mapping[str, float], centre: np.ndarray) -> np.ndarray:
    """Undo :func:`misplace` with the same ``transform`` and ``centre`` (exact inverse)."""
    t, R, sc = _parts(transform)
    c = np.asarray(centre, dtype=float)
    return c + ((np.asarray(points, dtype=float) - c - t) @ R) / sc
