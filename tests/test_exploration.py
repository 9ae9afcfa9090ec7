"""The audit of what the rounds have not explored (bayescalib.inference.exploration):
basins of the solved log-likelihoods that the posterior does not hold, the mass they
could carry, and the probes sent to them; and the stop rule that waits for them."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bayescalib.inference.exploration import audit, fill_distance, probe_points
from bayescalib.inference.parameters import ParameterSpace

BOX = np.array([[-5.0, 5.0], [-5.0, 5.0]])


def _space(bounds=BOX) -> ParameterSpace:
    return ParameterSpace.from_config([
        {"name": f"x{k}", "prior": {"type": "uniform", "lo": float(lo), "hi": float(hi)},
         "bounds": [float(lo), float(hi)]} for k, (lo, hi) in enumerate(bounds)])


def _gauss(X, m, S):
    D = np.atleast_2d(X) - m
    P = np.linalg.inv(S)
    return -0.5 * np.einsum("ij,jk,ik->i", D, P, D) \
        - 0.5 * math.log(np.linalg.det(2 * math.pi * S))


M1, S1 = np.array([-1.0, -0.5]), np.array([[0.01, 0.0024], [0.0024, 0.0064]])
M2, S2 = np.array([0.6, 0.4]), np.array([[0.0064, -0.00384], [-0.00384, 0.0144]])


def _two_modes(X):
    return np.logaddexp(math.log(0.73) + _gauss(X, M1, S1), math.log(0.27) + _gauss(X, M2, S2))


def _design(n, seed=4):
    """The active design's round 0: its Sobol design of ``n`` points in the box."""
    from bayescalib.inference.design import sobol_design

    return sobol_design(BOX, n, seed)


def _draws(m, S, n, seed=0):
    return np.random.default_rng(seed).multivariate_normal(m, S, n)


def test_the_laplace_mass_of_a_gaussian_basin_is_exact():
    """A Gaussian log-likelihood is exactly quadratic: the basin's estimated peak is the
    mode and its mass, relative to the exact evidence, is 1 (tolerance 1e-6: the least
    squares fit of an exact quadratic; the mode lies 4.6 sd or more inside the box)."""
    m, S = np.array([0.7, -1.2]), np.array([[0.3, 0.1], [0.1, 0.2]])
    X = _design(64)
    L = _gauss(X, m, S)
    log_z = -math.log(100.0)  # the normalized Gaussian against the uniform prior density
    res = audit(X, L, _draws(m, S, 4000), np.ones(4000), log_z, _space())
    top = res["basins"][0]
    np.testing.assert_allclose(top["peak"], m, atol=1e-6)
    assert top["peak_loglik"] == pytest.approx(_gauss(m, m, S)[0], abs=1e-6)
    assert top["log_mass"] == pytest.approx(0.0, abs=1e-6)
    assert top["is_held"] and res["unexplored_mass"] == 0.0


def test_a_mode_no_particle_reaches_is_found_from_the_solves_alone():
    """The two-mode benchmark's seed 4: its Sobol design of 32 points has no point within
    0.9 of the 73 % mode (9 of its sd), and the surrogate of the other mode's bowl
    predicted it low and confidently; the solves in its basin still rise towards it. With 16 more solves and a posterior in the 27 % mode only, the
    audit finds a basin the posterior does not hold whose peak lies within 0.5 of the
    missing mode (five of its sd: a quadratic through points more than 0.9 away from a
    mode 0.1 wide), and its mass exceeds the 2 % tolerance of the stop rule."""
    X = _design(32)
    assert np.min(np.linalg.norm(X - M1, axis=1)) > 0.9
    X = np.vstack([X, _draws(M2, S2, 16, 1)])  # the rounds' solves in the mode found
    L = _two_modes(X)
    log_z = math.log(0.27) - math.log(100.0)  # the evidence of the posterior that was found
    res = audit(X, L, _draws(M2, S2, 4000), np.ones(4000), log_z, _space())
    missing = [b for b in res["basins"] if not b["is_held"]]
    assert missing and res["unexplored_mass"] > 0.02
    assert np.linalg.norm(np.asarray(missing[0]["peak"]) - M1) < 0.5
    probes = probe_points(res, X, BOX, 2, 0.02, np.random.default_rng(0))
    assert np.linalg.norm(probes[0] - M1) < 0.5


def test_a_posterior_that_holds_both_modes_leaves_nothing_unexplored():
    X = np.vstack([_design(32), _draws(M1, S1, 12, 1), _draws(M2, S2, 12, 2)])
    L = _two_modes(X)
    P = np.vstack([_draws(M1, S1, 2920, 3), _draws(M2, S2, 1080, 4)])
    res = audit(X, L, P, np.ones(len(P)), -math.log(100.0), _space())
    assert res["unexplored_mass"] < 0.02, res["basins"]
    assert probe_points(res, X, BOX, 2, 0.02, np.random.default_rng(0)).shape == (0, 2)


def test_failed_solves_are_ignored_and_too_few_solves_audit_nothing():
    X = _design(32)
    L = _two_modes(X)
    L[::3] = -np.inf
    res = audit(X, L, _draws(M2, S2, 100), np.ones(100), -math.log(100.0), _space())
    assert all(np.isfinite(b["loglik"]) for b in res["basins"])
    few = audit(X[:4], L[:4], _draws(M2, S2, 100), np.ones(100), 0.0, _space())
    assert few["basins"] == [] and few["unexplored_mass"] == 0.0


def test_a_probe_on_a_solved_peak_is_moved_aside():
    """A basin whose estimated peak a solve already sits on is probed half a trust radius
    away: the same point solved twice would teach nothing."""
    res = {"basins": [{"is_held": False, "mass": 0.5, "peak": [1.0, 1.0],
                       "trust_radius": 0.2}]}
    X = np.array([[1.0, 1.0], [0.0, 0.0]])
    p = probe_points(res, X, BOX, 2, 0.02, np.random.default_rng(0))
    dist = np.linalg.norm((p[0] - X[0]) / 10.0)  # box units
    assert dist == pytest.approx(0.1, rel=1e-9)


def test_the_fill_distance_of_a_grid_is_half_its_cell_diagonal():
    """A k x k grid of cell centres leaves the box corners and the cells' corners at half
    a cell diagonal, sqrt(2) / (2 k) in box units (tolerance 2 %: a Sobol sample of 4096
    points comes that close to the worst corner)."""
    k = 8
    c = (np.arange(k) + 0.5) / k
    G = np.column_stack([a.ravel() for a in np.meshgrid(c, c)])
    h = fill_distance(-5 + 10 * G, BOX)
    assert h == pytest.approx(math.sqrt(2) / (2 * k), rel=0.02)
    assert h <= math.sqrt(2) / (2 * k) + 1e-12


def test_the_stop_rule_never_says_converged_with_the_missing_mode_of_seed_4():
    """The two-mode benchmark's seed 4 said converged with the 73 % mode missing before
    the audit (benchmarks/bench_modes.py, variant no_audit: 91 evaluations, all the mass on
    the 27 % mode). With the audit the probes find the mode: converged, each mode within
    0.1 of its mass (the surrogate's SMC with 4000 particles)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_modes

    prob = bench_modes.ba.make_bimodal2d()
    row = bench_modes.run(prob, "audit", 4, 128)
    assert row["missed"] == 0, row
    if row["converged"]:
        np.testing.assert_allclose(row["mode_mass"], row["ref_mode_mass"], atol=0.1)


def test_the_round_record_names_the_unheld_basin_of_largest_mass_first():
    """audit lists basins highest peak first; the round's reason must name the one that
    could hold the most mass, and never a basin the posterior holds."""
    from bayescalib.inference.active import unheld_basins

    explored = {"basins": [
        {"peak_loglik": 5.0, "mass": 0.001, "is_held": False},
        {"peak_loglik": 4.0, "mass": 0.9, "is_held": True},
        {"peak_loglik": 3.0, "mass": 0.6, "is_held": False},
    ]}
    assert [b["mass"] for b in unheld_basins(explored)] == [0.6, 0.001]


def _local_max_of_all(X, L, i):
    """The first pass's rule: solve i is at least as high as its 2d nearest solves."""
    from scipy.spatial import cKDTree

    U = (X - BOX[:, 0]) / (BOX[:, 1] - BOX[:, 0])
    _, nb = cKDTree(U).query(U[i], k=2 * X.shape[1] + 1)
    return bool(L[i] >= L[nb[1:]].max())


@pytest.mark.parametrize("spread", [1.0, 3.0])
def test_a_basin_whose_solves_all_have_a_higher_neighbour_in_the_found_mode_is_seen(spread):
    """The two-mode benchmark's seed 19 (docs/bench_modes.md): its Sobol design has two
    points in the 73 % mode's basin, (-0.21, -0.68) and (-0.47, 0.15), 8-10 of its sd
    away, and the rounds' 68 solves lie in the 27 % mode (here: draws of it, ``spread``
    times its sd). Each of the two has a higher neighbour among those solves, so the
    first pass (local maxima of all the solves) finds no basin the posterior does not
    hold; the second pass (local maxima among the solves outside the particles' region
    and explained neither by the held basin's quadratic nor by the posterior's
    Gaussian) finds it, its peak within 0.1 of the missing mode, and the probe goes
    there."""
    X0 = _design(32, seed=19)
    two = [int(np.argmin(np.linalg.norm(X0 - p, axis=1))) for p in ([-0.21, -0.68],
                                                                    [-0.47, 0.15])]
    np.testing.assert_allclose(X0[two], [[-0.21, -0.68], [-0.47, 0.15]], atol=0.01)
    X = np.vstack([X0, _draws(M2, spread ** 2 * S2, 68, 0)])
    L = _two_modes(X)
    assert not any(_local_max_of_all(X, L, i) for i in two)  # the old rule's blind spot
    log_z = math.log(0.27) - math.log(100.0)
    res = audit(X, L, _draws(M2, S2, 4000), np.ones(4000), log_z, _space())
    assert all(b["is_held"] for b in res["basins"] if b["found_by"] == 1)
    missing = [b for b in res["basins"] if not b["is_held"]]
    assert [b["found_by"] for b in missing] == [2], missing
    assert np.linalg.norm(np.asarray(missing[0]["peak"]) - M1) < 0.1
    assert res["unexplored_mass"] > 0.02
    probes = probe_points(res, X, BOX, 2, 0.02, np.random.default_rng(0))
    assert len(probes) == 1 and np.linalg.norm(probes[0] - M1) < 0.1


@pytest.mark.parametrize("case", ["gauss", "ridge"])
def test_a_posterior_with_one_mode_leaves_no_basin_unheld(case):
    """One mode, held by the posterior: the second pass finds no basin it does not hold.
    ``gauss``: a correlated Gaussian, no unheld basin at all; ``ridge``: bench_active's
    ridge2d (a curved ridge x2 = 0.6 x1^2, not quadratic: the held basin's quadratic does
    not explain the ridge's arms), where the first pass already finds two false basins on
    the arms (quadratics through solves 1-2 sd off the ridge; measured, not fixed here)
    and the second adds none. Solves: 32 Sobol points and 68 draws of the posterior at
    twice its sd."""
    rng = np.random.default_rng(7)
    if case == "gauss":
        m, S = np.array([0.7, -1.2]), np.array([[0.3, 0.1], [0.1, 0.2]])

        def f(X):
            return _gauss(X, m, S)

        P = _draws(m, S, 4000)
        R = _draws(m, 4 * S, 68, 1)
    else:
        def f(X):
            X = np.atleast_2d(X)
            return -0.5 * X[:, 0] ** 2 - 0.5 * ((X[:, 1] - 0.6 * X[:, 0] ** 2) / 0.25) ** 2

        def ridge(n, scale):
            x1 = scale * rng.standard_normal(n)
            return np.column_stack([x1, 0.6 * x1 ** 2 + 0.25 * scale * rng.standard_normal(n)])

        P, R = ridge(4000, 1.0), ridge(68, 2.0)
    X = np.vstack([_design(32), R])
    inbox = np.all((X > -5) & (X < 5), axis=1)
    X = X[inbox]
    P = P[np.all((P > -5) & (P < 5), axis=1)]
    G = np.linspace(-5, 5, 401)
    GX = np.column_stack([a.ravel() for a in np.meshgrid(G, G)])
    log_z = float(np.log(np.mean(np.exp(f(GX)))))  # uniform prior: Z = mean of exp(L)
    res = audit(X, f(X), P, np.ones(len(P)), log_z, _space())
    unheld = [(b["found_by"], b["point"], b["peak"], b["mass"]) for b in res["basins"]
              if not b["is_held"]]
    assert not [b for b in unheld if b[0] == 2], unheld  # the second pass adds none
    if case == "gauss":
        assert res["unexplored_mass"] < 0.02, unheld
    else:  # the first pass's own false basins on the ridge's arms (the module docstring)
        assert all(b[0] == 1 for b in unheld)


def test_a_solve_below_the_basins_quadratic_inside_its_ellipsoid_refutes_it():
    """A basin's quadratic L* - q/2 (q = (u - u*)'P(u - u*)) is refuted by a solve inside
    its chi2_0.99 ellipsoid that lies more than chi2_0.99 / 2 nats below it, not by one on
    it or a little below it, nor by a low solve outside the ellipsoid."""
    from scipy.stats import chi2

    from bayescalib.inference.exploration import contradicted

    level = float(chi2.ppf(0.99, 2))
    P = np.diag([400.0, 100.0])  # sd 0.05 and 0.1 box units
    u_star, L_star = np.array([0.5, 0.5]), -1.0
    on = np.array([[0.55, 0.5], [0.5, 0.6], [0.5, 0.5]])
    L_on = L_star - 0.5 * np.einsum("ij,jk,ik->i", on - u_star, P, on - u_star)
    assert not contradicted(on, L_on, u_star, L_star, P, level)
    assert not contradicted(on, L_on - 0.4 * level, u_star, L_star, P, level)
    assert contradicted(on[:1], L_on[:1] - 0.6 * level, u_star, L_star, P, level)
    far = np.array([[0.9, 0.9]])  # q = 80 > level: outside the basin
    assert not contradicted(far, np.array([-1e3]), u_star, L_star, P, level)


def test_the_missing_modes_basin_is_not_refuted_by_its_own_slopes():
    """Seed 4's missing mode (above): its basin's quadratic, fitted through solves on its
    own slopes, is not refuted by them, so it keeps the run from converging."""
    X = np.vstack([_design(32), _draws(M2, S2, 16, 1)])
    L = _two_modes(X)
    res = audit(X, L, _draws(M2, S2, 4000), np.ones(4000), math.log(0.27) - math.log(100.0),
                _space())
    missing = [b for b in res["basins"] if not b["is_held"]]
    assert missing and not missing[0]["refuted"]
    assert np.linalg.norm(np.asarray(missing[0]["peak"]) - M1) < 0.5


def test_a_check_round_forced_by_the_budget_carries_the_probes_of_an_open_basin():
    """Seed 4's situation (the 73 % mode missing, its basin open) when only two looks of
    the check are left: the check round's batch is its first look of 8 draws plus the
    probes (2) at the open basin's peak, within the budget; the run could not converge
    while the basin is open, and before, such a check left it unprobed to the end."""
    from bayescalib.config import validate
    from bayescalib.inference.active import acquire_round
    from bayescalib.inference.gp import fit_gp

    X = np.vstack([_design(32), _draws(M2, S2, 16, 1)])
    L = _two_modes(X)
    space = _space()
    gp = fit_gp(X, L, bounds=space.bounds, restarts=1, kernel="matern52", nugget="fixed",
                mean="constant", ard=False)
    cfg = validate({"design": {"strategy": "active", "active": {
        "n_initial": 32, "batch_size": 8, "max_solves": len(X) + 16}}}, "inference")
    P = _draws(M2, S2, 4000)
    rec = acquire_round(0, X, L, gp, P, np.ones(4000), math.log(0.27) - math.log(100.0),
                        space, cfg["design"]["active"], None, cfg["posterior_check"])
    kinds = rec["next"]["kind"]
    assert not rec["explored"] and not rec["stop"]
    assert kinds.count("posterior_check") == 8 and kinds.count("probe") == 2, kinds
    probes = np.asarray(rec["next"]["points"])[np.asarray(kinds) == "probe"]
    assert np.min(np.linalg.norm(probes - M1, axis=1)) < 0.5


def test_a_basin_refuted_by_a_solve_inside_it_is_neither_counted_nor_probed():
    """A quadratic basin (peak -1 at (0.7, 0.7), sd 0.1) seen through a tight cluster of
    solves at (0.6, 0.6) that the posterior (a mode at (0.2, 0.2)) does not hold: open,
    5 % of the mass, probed. A solve inside its estimated ellipsoid (outside the fit's
    neighbours) 28 nats below its quadratic refutes it: nothing unexplored, no probe. The
    same solve at the quadratic's own value leaves it open."""
    space = _space(np.array([[0.0, 1.0], [0.0, 1.0]]))
    c, a = np.array([0.7, 0.7]), np.array([0.2, 0.2])

    def bump(X):
        return -1.0 - 0.5 * np.sum((np.atleast_2d(X) - c) ** 2, 1) / 0.1 ** 2

    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    circle = np.c_[np.cos(ang), np.sin(ang)]
    XB = np.vstack([[0.6, 0.6], [0.6, 0.6] + 0.015 * circle])
    XA = np.vstack([a, a + 0.03 * circle])
    X = np.vstack([XA, XB])
    L = np.concatenate([-0.5 * np.sum((XA - a) ** 2, 1) / 0.05 ** 2, bump(XB)])
    P = a + 0.05 * np.random.default_rng(0).standard_normal((4000, 2))
    log_z = math.log(2 * math.pi * 0.05 ** 2)
    u = np.array([[0.582, 0.652]])
    for extra, refuted in ((None, False), (-30.0, True), (float(bump(u)[0]), False)):
        Xe, Le = (X, L) if extra is None else (np.vstack([X, u]), np.append(L, extra))
        res = audit(Xe, Le, P, np.ones(4000), log_z, space)
        b = [b for b in res["basins"] if np.linalg.norm(np.asarray(b["point"]) - c) < 0.2]
        assert len(b) == 1 and not b[0]["is_held"] and b[0]["refuted"] is refuted
        assert (res["unexplored_mass"] > 0.02) is not refuted
        probes = probe_points(res, Xe, space.bounds, 2, 0.02, np.random.default_rng(0))
        assert len(probes) == (0 if refuted else 1)


def _hetero7d_round3():
    """The audit's inputs at round 3 of the output emulator's rounds on
    ``benchmarks/bench_active.py``'s ``hetero7d`` (seed 0, 104 solves; the posterior's
    particles resampled to 1000 equally weighted): a 7-D posterior along a tilted ridge
    (E_i ~ q), uniform prior on the box."""
    z = np.load(Path(__file__).parent / "data" / "hetero7d_round3_audit.npz")
    return (z["X"], z["L"], z["particles"], float(z["log_evidence"]), float(z["bound"]),
            _space(z["bounds"]))


def test_the_posteriors_own_top_in_7d_is_held_though_its_diagonal_quadratic_overshoots():
    """Above 3 dimensions the first pass fits diagonal quadratics: through the top solves
    of hetero7d's tilted ridge (-23.2 nats; the mode is -21.85) they rise to the
    likelihood's bound along the ridge, where the particles are few, and were counted as
    basins the posterior does not hold, "up to 100 % of the mass", round after round
    (the emulator's rounds, which had converged in 98-114 solves, never converged in
    200). A local maximum of the data inside the posterior's region, no higher than the
    posterior's Gaussian says, is the posterior's own top: held, nothing unexplored."""
    X, L, P, log_z, bound, space = _hetero7d_round3()
    res = audit(X, L, P, np.ones(len(P)), log_z, space, bound=bound)
    top = [b for b in res["basins"] if b["region_ratio"] <= 1.0]
    assert len(top) == 3 and all(b["is_held"] for b in top), res["basins"]
    assert res["unexplored_mass"] < 0.02, res["basins"]


def test_a_top_solve_higher_than_the_posteriors_gaussian_is_not_held_by_that_rule():
    """The rule above asks the data to agree with the posterior: the same top solve
    raised 30 nats above what the posterior's Gaussian says (a sharp peak the posterior
    missed) is not held by it."""
    X, L, P, log_z, bound, space = _hetero7d_round3()
    top = int(np.argmax(L))
    for raise_by, held in ((0.0, True), (30.0, False)):
        Lr = L.copy()
        Lr[top] += raise_by
        res = audit(X, Lr, P, np.ones(len(P)), log_z, space, bound=bound + raise_by)
        b = next(b for b in res["basins"] if np.allclose(b["point"], X[top]))
        assert b["region_ratio"] <= 1.0 and b["is_held"] is held, (raise_by, b)


def test_a_missing_modes_region_with_few_solves_is_fitted_by_a_full_quadratic_in_4d():
    """bench_active's bimodal4d (two narrow modes about 20 sd apart, 73 % / 27 %), seed 0
    at round 2: the posterior holds one mode; 16 solves lie where it does not hold them,
    fewer than a full 4-D quadratic with 4 spare solves (19), and the second pass fitted
    nothing: the run said converged with 27 % of the mass missing. A full quadratic
    through them (one spare) is that mode's own (the log-likelihood there is its
    Gaussian): the basin's peak is the missing mode's centre, and it is counted (the
    mode's mass estimate 0.68 against 0.27 / 0.73 = 0.37 relative to the posterior held:
    'up to')."""
    z = np.load(Path(__file__).parent / "data" / "bimodal4d_round2_audit.npz")
    res = audit(z["X"], z["L"], z["particles"], np.ones(len(z["particles"])),
                float(z["log_evidence"]), _space(z["bounds"]), bound=float(z["bound"]))
    found = [b for b in res["basins"] if b["found_by"] == 2 and not b["is_held"]]
    assert len(found) == 1, res["basins"]
    np.testing.assert_allclose(found[0]["peak"], [0.6, 0.4, -0.5, -0.3], atol=0.01)
    assert res["unexplored_mass"] > 0.3


def test_a_first_pass_maximum_fitted_diagonally_is_fitted_again_by_the_second_pass():
    """bimodal4d seed 11 at its verdict (113 solves): the posterior holds the 27 % mode;
    a solve in the other mode's region is a local maximum of all the solves, and the
    first pass's diagonal quadratic through it finds the missing mode's centre but its
    height 10 nats low (mass 2e-4): the run said converged with 73 % of the mass
    missing. The second pass fits it again with a full quadratic through the solves the
    posterior does not hold: the missing mode itself, counted."""
    z = np.load(Path(__file__).parent / "data" / "bimodal4d_seed11_audit.npz")
    res = audit(z["X"], z["L"], z["particles"], np.ones(len(z["particles"])),
                float(z["log_evidence"]), _space(z["bounds"]), bound=float(z["bound"]))
    found = [b for b in res["basins"] if b["found_by"] == 2 and not b["is_held"]]
    assert len(found) == 1, res["basins"]
    np.testing.assert_allclose(found[0]["peak"], [-1.0, -0.5, 0.4, 0.8], atol=0.01)
    assert res["unexplored_mass"] > 0.5
