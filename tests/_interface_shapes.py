"""Test geometry shared by the interface/measure tests (circles, arcs, spheres, planes)."""

from __future__ import annotations

import math

import numpy as np

from bayescalib.geometry.interface import Interface


def arc(R: float, n: int, a0: float = 0.0, a1: float = math.pi, centre=(0.0, 0.0)) -> Interface:
    """Arc of radius R from angle a1 to a0 (clockwise), n nodes; normals point outward."""
    t = np.linspace(a1, a0, n)
    return Interface.polyline(np.column_stack([centre[0] + R * np.cos(t), centre[1] + R * np.sin(t)]))


def circle(R: float, n: int, phase: float = 0.0) -> Interface:
    """Closed clockwise circle (outward normals) with n nodes."""
    t = phase - np.arange(n) * 2 * math.pi / n
    return Interface.polyline(np.column_stack([R * np.cos(t), R * np.sin(t)]), closed=True)


def icosphere(R: float, level: int) -> Interface:
    """Icosahedron refined ``level`` times, projected to radius R; outward normals."""
    p = (1 + 5**0.5) / 2
    v = np.array(
        [[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p],
         [0, -1, -p], [0, 1, -p], [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]], float)
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    verts = [x / np.linalg.norm(x) for x in v]
    for _ in range(level):
        cache: dict[tuple[int, int], int] = {}

        def mid(a, b, cache=cache):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        nf = []
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = np.array(nf)
    pts = R * np.array(verts)
    s = Interface.surface(pts, f)
    if np.mean(np.einsum("md,md->m", s.normals, s.centres)) < 0:
        s = s.reversed()
    return s


def square(L: float, n: int, z: float = 0.0) -> Interface:
    """Square [0, L]^2 at height z, n x n quads split in triangles; normal +z."""
    g = np.linspace(0, L, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Interface.surface(pts, tris)


def rotation2d(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def dome(R: float, level: int) -> Interface:
    """The upper half of :func:`icosphere` (y >= 0): an open colony surface whose rim lies
    on the floor y = 0, outward normals (the form of an observed 3D interface)."""
    from bayescalib.geometry.surface import colony_surface

    s = icosphere(R, level)
    return colony_surface(s.points, s.cells, floor=0.0, name="dome")[0]
