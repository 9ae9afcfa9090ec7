"""benchmarks/bench_gpu.py at its quick sizes on the CPU: the torch path of the GP
predictor and of the RKHS distance agrees with NumPy, the SMC runs on both, the table is
printed (no timings are asserted)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

pytest.importorskip("torch")

import bench_gpu


def test_quick_run_numpy_vs_torch_cpu(capsys, tmp_path):
    out = tmp_path / "rows.json"
    rows = bench_gpu.main(["--quick", "--devices", "cpu,torch:cpu",
                           "--cases", "predict2d,smc2d,rkhs3d", "--out", str(out)])
    text = capsys.readouterr().out
    by = {(r["case"], r["device"]): r for r in rows}
    assert set(by) == {(c, d) for c in ("predict2d", "smc2d", "rkhs3d")
                       for d in ("cpu", "torch:cpu")}
    # the same float64 algebra in another summation order: round-off only, amplified by
    # the conditioning of K + nugget (the weights alpha); 1e-8 of the largest |mean| is
    # the agreement measured on the GPU (issue 38) and far above the 1e-14 seen here
    p = by["predict2d", "torch:cpu"]
    assert p["rel_dmean"] < 1e-8
    assert p["rel_dvar"] < 1e-6
    # the RKHS terms are sums of positive and negative kernel products in float64
    assert by["rkhs3d", "torch:cpu"]["rel_terms"] < 1e-10
    assert by["rkhs3d", "torch:cpu"]["rel_d2"] < 1e-8
    # equal in distribution: the posterior means within a fraction of a posterior sd
    s = by["smc2d", "torch:cpu"]
    assert s["complete"] and by["smc2d", "cpu"]["complete"]
    assert s["max_dmean_sd"] < 0.5 and abs(s["dlog_evidence"]) < 0.5
    for case in ("predict2d", "smc2d", "rkhs3d"):
        assert f"### {case}" in text
    assert "| device | wall s | speed-up vs NumPy cpu | agreement |" in text
    assert "no GPU" in text or "GPU:" in text
    assert out.exists()


def test_stopped_smc_rows_are_extrapolated_from_a_complete_run():
    rows = [
        {"case": "smc7d", "device": "cpu", "wall_s": 9.0, "complete": False, "steps_done": 3,
         "s_per_step": 3.0},
        {"case": "smc7d", "device": "cuda", "wall_s": 2.0, "complete": True, "steps_done": 10,
         "steps": 10, "post_mean": [0.0], "post_sd": [1.0], "log_evidence": -1.0},
    ]
    cpu, gpu = bench_gpu.smc_agreement(rows)
    assert cpu["extrapolated"] and math.isclose(cpu["wall_s"], 30.0)
    assert gpu["agreement"] == "reference"
    assert "| cuda | 2.000 | ~15.00 |" in bench_gpu.table(rows)


def test_round_cases_run_the_heterogeneous_rounds_sampler_on_both_surrogates():
    """round7d (GP of L) and round7d_outputs (the output emulator; on a torch device both
    batched and one coordinate GP after the other) at quick sizes: the same posterior on
    every device to a fraction of a posterior sd."""
    rows = bench_gpu.main(["--quick", "--devices", "cpu,torch:cpu",
                           "--cases", "round7d,round7d_outputs"])
    by = {(r["case"], r["device"]): r for r in rows}
    assert set(by) == {("round7d", "cpu"), ("round7d", "torch:cpu"),
                       ("round7d_outputs", "cpu"), ("round7d_outputs", "torch:cpu"),
                       ("round7d_outputs", "torch:cpu (per GP)")}
    for key, r in by.items():
        assert r["complete"], key
        if r["agreement"] != "reference":
            assert r["max_dmean_sd"] < 0.5 and abs(r["dlog_evidence"]) < 0.5, key


def test_the_round_cases_use_the_heterogeneous_studys_round_settings():
    import yaml

    root = Path(__file__).resolve().parents[1]
    cfg = yaml.safe_load((root / "config" / "heterogeneous.yaml").read_text())
    rs = cfg["design"]["active"]["smc"]
    assert bench_gpu.ROUND_SMC == (rs["n_particles"], rs["n_rej"], rs["zeta"])
    assert bench_gpu.ROUND_N_TRAIN == cfg["design"]["active"]["max_solves"]
