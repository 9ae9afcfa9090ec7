"""Where the forward model cannot be solved: failed solves as a feasibility region.

A solve fails where the model has no steady state the solver can reach (an element
inverted under flow, Newton stalled at a very soft material, the time limit): its
design point carries no log-likelihood. The GP of the log-likelihood is fitted on the
solved points only (:mod:`bayescalib.inference.gp`), so by itself it
extrapolates over the failed region as if the model could be solved there, and the
posterior may settle where every solve fails: its check solves then fail too, and
nothing real ever tests it (:func:`bayescalib.inference.importance.importance_check`
refuses such a posterior; it cannot repair it).

The failed region is taken as infeasible: the likelihood is zero there, the target the
sampler sees is

    pi(x)  proportional to  1_F(x) exp(L(x)) p(x),

with F the feasible set estimated from the solves. The estimate is a nearest-neighbour
rule in the surrogate's own unit-box input coordinates (``GPSurrogate.scale_inputs``:
the design box scaled to [0, 1], log inputs where the surrogate uses them): a point is
infeasible when the solve nearest to it failed, and it lies no farther from that failed
solve than the failed solve's nearest successful one (the radius ``rho_f``). Between
solves this is the Voronoi cell of the failure; where no successful solve lies beyond a
failure (a failure at the edge of the box) the radius keeps the cell from reaching
without evidence across the box. GPry (Gammal et al. 2023) classifies the same
information with a support vector machine; the neighbour rule has no hyperparameters,
is exact at every solve (a failed point is infeasible, a solved one feasible) and
sharpens as solves are added where the posterior meets the failures, which is where
the active design puts them.

Only failures that say something about the model count: a solve that failed for the
machine's sake (its wall-clock time limit on a loaded machine, its process killed or
dead, a command that could not be started) would fail or not at the same point on
another day, and is left out of the region (:func:`says_nothing_of_the_model`; the
surrogate is given NaN for it instead of -inf: no value, no region). Every other failure
is deterministic in the parameters (an inverted element, Newton diverging, NaN in the
interface, a user command's error) and marks its point.

The GP surrogate keeps the failed points (``GPSurrogate.X_failed``) and applies the
region in :meth:`~bayescalib.inference.gp.predictor.GPSurrogate.loglik`; the output
emulator keeps them in its first coordinate's GP and applies it in
:meth:`~bayescalib.inference.emulator.EmulatedLikelihood.loglik`. Every sampler of the
pipeline targets ``loglik``.

Without failed solves nothing changes: the sampler sees the surrogate's mean, bitwise.
The SMC (:mod:`bayescalib.inference.smc`) takes ``-inf`` as outside the likelihood's
support: such particles get weight zero, and a Metropolis move into the region is
never accepted. The evidence is then that of the restricted likelihood,
Z = int_F exp(L) p dx.

Pure functions over arrays.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FailedRegion", "failure_radii", "fit_targets", "marks_infeasible",
           "says_nothing_of_the_model"]

#: failure reasons (run records, bayescalib.models.forward and the FSI solver) that
#: depend on the machine, not on the parameters
_MACHINE_FAILURES = ("time limit", "killed", "solver process died", "could not be started")


def says_nothing_of_the_model(reason: str) -> bool:
    """True when a failed solve's ``reason`` is the machine's (a time limit, a killed or
    dead process, a command not started), so that its point is not marked infeasible."""
    text = str(reason).lower()
    return any(key in text for key in _MACHINE_FAILURES)


def marks_infeasible(solved: np.ndarray, reasons: list[str]) -> np.ndarray:
    """Which design points mark where the model cannot be solved, (n,) bool: those whose
    solve failed (``solved`` False) for a reason that is not the machine's
    (:func:`says_nothing_of_the_model`)."""
    solved = np.asarray(solved, bool).reshape(-1)
    if len(reasons) != solved.size:
        raise ValueError(f"marks_infeasible: {solved.size} points and {len(reasons)} reasons")
    return np.array([not ok and not says_nothing_of_the_model(r)
                     for ok, r in zip(solved.tolist(), reasons, strict=True)], bool)


def fit_targets(loglik: np.ndarray, reasons: list[str]) -> np.ndarray:
    """The log-likelihood values a surrogate is fitted to, (n,): a failure for the
    machine's sake (no value and no infeasible region, :func:`says_nothing_of_the_model`)
    as NaN, left out; any other failure kept as -inf, marking where the model cannot be
    solved."""
    L = np.asarray(loglik, float).reshape(-1)
    finite = np.isfinite(L)
    return np.where(~finite & ~marks_infeasible(finite, reasons), np.nan, L)


def failure_radii(U_ok: np.ndarray, U_failed: np.ndarray) -> np.ndarray:
    """Radius of each failure's infeasible cell: its distance to the nearest solved
    point, (F,) in unit-box coordinates (``inf`` when no point solved).

    Parameters
    ----------
    U_ok : (n, d) solved points; U_failed : (F, d) failed ones (unit-box coordinates).
    """
    from scipy.spatial import cKDTree

    U_failed = np.atleast_2d(np.asarray(U_failed, float))
    U_ok = np.asarray(U_ok, float).reshape(-1, U_failed.shape[1])
    if U_ok.shape[0] == 0:
        return np.full(U_failed.shape[0], np.inf)
    return cKDTree(U_ok).query(U_failed, k=1)[0]


class FailedRegion:
    """The region the failed solves mark as infeasible (module docstring).

    Parameters
    ----------
    U_ok : (n, d) solved points; U_failed : (F, d) failed points, F >= 1, both in the
        same unit-box coordinates (the nearest-neighbour trees are built once here).
    """

    def __init__(self, U_ok: np.ndarray, U_failed: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        self.U_failed = np.atleast_2d(np.asarray(U_failed, float))
        d = self.U_failed.shape[1]
        if self.U_failed.shape[0] == 0:
            raise ValueError("FailedRegion needs at least one failed point")
        self.U_ok = np.asarray(U_ok, float).reshape(-1, d)
        self.radii = failure_radii(self.U_ok, self.U_failed)
        self._tree_failed = cKDTree(self.U_failed)
        self._tree_ok = cKDTree(self.U_ok) if self.U_ok.shape[0] else None

    def contains(self, U: np.ndarray) -> np.ndarray:
        """Which points are infeasible, (M,) bool, for U (M, d) in the same coordinates:
        those whose nearest solve (Euclidean) failed and that lie within that failure's
        radius. A tie between a failed and a solved point counts as feasible."""
        U = np.atleast_2d(np.asarray(U, float))
        d_fail, i_fail = self._tree_failed.query(U, k=1)
        inside = d_fail <= self.radii[i_fail]
        if self._tree_ok is None:
            return inside
        return inside & (d_fail < self._tree_ok.query(U, k=1)[0])
