"""Run-record HDF5 I/O: round trip, atomic writes, detection of broken files."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayescalib.io.header import FORMATS
from bayescalib.io.runrecord import RunFileError, SolveResult, read_run, write_run


def _result(n: int = 7, status: str = "ok", seed: int = 0) -> SolveResult:
    rng = np.random.default_rng(seed)
    ref = np.column_stack([np.linspace(0.7, 1.3, n), rng.random(n)])
    cur = ref + 0.01 * rng.standard_normal((n, 2))
    return SolveResult(
        status=status,
        reason="" if status == "ok" else "Newton did not converge",
        parameters={"material.E": 400.0, "material.nu": 0.3, "inflow.rate": 100.0},
        load_fraction=1.0 if status == "ok" else 0.8125,
        newton_iterations=11,
        load_steps=2,
        wall_time=1.25,
        interface_reference=ref,
        interface_current=cur,
        segments=np.column_stack([np.arange(n - 1), np.arange(1, n)]),
        max_displacement=float(np.max(np.linalg.norm(cur - ref, axis=1))),
        stats={"ndof": 14103, "law": "svk", "t_factor": 0.5},
    )


def test_round_trip(tmp_path):
    res = _result(status="failed")
    path = tmp_path / "sub" / "run.h5"
    write_run(path, res)
    back = read_run(path)
    assert back.status == "failed" and back.reason == res.reason
    assert back.parameters == res.parameters
    assert back.load_fraction == res.load_fraction
    assert back.newton_iterations == 11 and back.load_steps == 2
    np.testing.assert_array_equal(back.interface_reference, res.interface_reference)
    np.testing.assert_array_equal(back.interface_current, res.interface_current)
    np.testing.assert_array_equal(back.segments, res.segments)
    assert back.stats == res.stats
    assert not back.ok
    # no temporary files left next to the result
    assert os.listdir(path.parent) == ["run.h5"]


@settings(max_examples=20, deadline=None)
@given(n=st.integers(min_value=1, max_value=50), seed=st.integers(0, 10_000),
       E=st.floats(1e-3, 1e6, allow_nan=False))
def test_round_trip_property(tmp_path_factory, n, seed, E):
    res = _result(n=max(n, 2), seed=seed)
    res.parameters["material.E"] = E
    path = tmp_path_factory.mktemp("rr") / "r.h5"
    write_run(path, res)
    back = read_run(path)
    assert back.parameters["material.E"] == E
    np.testing.assert_array_equal(back.interface_current, res.interface_current)


def test_overwrite_is_atomic(tmp_path):
    path = tmp_path / "run.h5"
    write_run(path, _result(seed=1))
    write_run(path, _result(seed=2))
    np.testing.assert_array_equal(read_run(path).interface_current, _result(seed=2).interface_current)


def test_missing_file_named(tmp_path):
    with pytest.raises(RunFileError, match="nope.h5"):
        read_run(tmp_path / "nope.h5")


def test_truncated_file_detected(tmp_path):
    path = tmp_path / "run.h5"
    write_run(path, _result())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(RunFileError, match="run.h5"):
        read_run(path)


def test_garbage_file_detected(tmp_path):
    path = tmp_path / "run.h5"
    path.write_bytes(b"not an hdf5 file at all" * 10)
    with pytest.raises(RunFileError, match="corrupt"):
        read_run(path)


def test_incomplete_flag_detected(tmp_path):
    path = tmp_path / "run.h5"
    write_run(path, _result())
    with h5py.File(path, "a") as f:
        f.attrs["complete"] = 0
    with pytest.raises(RunFileError, match="incomplete"):
        read_run(path)


def test_missing_dataset_detected(tmp_path):
    path = tmp_path / "run.h5"
    write_run(path, _result())
    with h5py.File(path, "a") as f:
        del f["interface/current"]
    with pytest.raises(RunFileError, match="run.h5"):
        read_run(path)


def test_wrong_version_detected(tmp_path):
    path = tmp_path / "run.h5"
    write_run(path, _result())
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = FORMATS["run"][1] + 1
    with pytest.raises(RunFileError, match="version"):
        read_run(path)


def test_runfileerror_is_valueerror():
    assert issubclass(RunFileError, ValueError)


def test_bad_status_rejected(tmp_path):
    res = _result()
    res.status = "maybe"
    with pytest.raises(ValueError):
        write_run(tmp_path / "x.h5", res)
    assert not (tmp_path / "x.h5").exists()
