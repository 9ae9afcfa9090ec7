"""Is the closest-point (cpp) likelihood biased on noisy 3D surfaces? Real solves, no surrogate.

(``--measure rkhs``: the same for the RKHS measure, sigma_W = 0.1 mm, sigma_N^2 from
:func:`bayescalib.measures.noise_floor` on the colony at rest, as the 3D study's.)

The noiseless surfaces of ``benchmarks/two_vs_three.py``'s recording (``truth_load_*.vtp``)
get fresh 2 um noise per seed; the cpp log-likelihood (sigma_N^2 = (2 um)^2, the 3D
study's) of the 3D model's solve at the truth is compared with that at other points. A
likelihood with the right noise model prefers the truth about as often as not; the doc
(`docs/two_vs_three.md`, "The measure") reports how often another point wins.

Usage::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/cpp_noise_bias.py \
        [--recording results/two_vs_three_inputs_very_coarse] [--seeds 12] [--measure cpp]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

POINTS = [(400.0, 0.3), (336.5, 0.0), (370.0, 0.15), (460.0, 0.45)]  # the truth first


def main(argv: list[str] | None = None) -> int:
    from bayescalib.geometry.interface import Interface
    from bayescalib.io.observations import add_noise, read_interface
    from bayescalib.measures import compute, noise_floor
    from bayescalib.models.forward import FSIForward, solve_series

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recording", type=Path,
                    default=Path("results/two_vs_three_inputs_very_coarse"))
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--measure", default="cpp", choices=["cpp", "rkhs"])
    a = ap.parse_args(argv)
    rec = json.loads((a.recording / "recording" / "recording.json").read_text())
    mesh = a.recording.name.removeprefix("two_vs_three_inputs_")
    cfg = yaml.safe_load(next((a.recording / "configs").glob(f"two_vs_three_3d_{mesh}*.yaml"))
                         .read_text())
    fm = cfg["forward_model"]
    sigma = rec["noise_sigma_mm"]
    clean = [read_interface(a.recording / "recording" / s["truth"]) for s in rec["snapshots"]]
    opts = {"sigma_w": 0.1} if a.measure == "rkhs" else {}
    rest = read_interface(a.recording / "recording" / rec["rest"]["truth"])
    s2 = sigma**2 if a.measure == "cpp" else noise_floor("rkhs", rest, sigma, draws=32,
                                                           seed=11, **opts)
    model = FSIForward(fm["fsi"], time_limit_s=1800.0)
    runs = [solve_series(model, {"material.E": e, "material.nu": nu}, fm["loadings"])
            for e, nu in POINTS]
    wins = np.zeros(len(POINTS), dtype=int)
    print("seed | " + " | ".join(f"loglik at E={e:g}, nu={nu:g}" for e, nu in POINTS))
    for seed in range(a.seeds):
        rng = np.random.default_rng(seed)
        obs = [add_noise(c, sigma, rng) for c in clean]
        ll = [sum(-compute(a.measure, Interface(ld.current, r.segments), o, **opts).D ** 2
                  / (2 * s2)
                  for ld, o in zip(r.loadings, obs, strict=True)) for r in runs]
        wins[1:] += np.asarray(ll[1:]) > ll[0]
        print(f"{seed} | " + " | ".join(f"{v:.1f}" for v in ll), flush=True)
    for (e, nu), w in zip(POINTS[1:], wins[1:], strict=True):
        print(f"E={e:g}, nu={nu:g} beats the truth in {w} of {a.seeds} seeds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
