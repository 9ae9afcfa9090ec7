"""The one solve path (bayescalib.models.forward.solve_points): a solve process keeps its
model from one point to the next, a crash or a hang fails only its point (the process
is replaced), and a kept fsi model gives bit for bit the records of a new model per point.

Nothing in this module builds an fsi model in the test process itself: solve_points
forks its solve processes, and a process forked after Netgen meshed in its parent hangs.
"""

import numpy as np
import pytest

from bayescalib.models.forward import solve_point, solve_points

PID_MODEL = """\
import os, time
def f(params):
    if params["E"] == -1:
        os._exit(3)
    if params["E"] == -2:
        time.sleep(600)
    return [[0.0, 0.0], [1.0, float(os.getpid())]]
"""


@pytest.fixture
def pid_model(tmp_path, monkeypatch):
    (tmp_path / "pid_model.py").write_text(PID_MODEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    return {"type": "python", "time_limit_s": 1.0, "python": {"function": "pid_model:f"}}


def _pid(res):
    return int(res.interface_current[1, 1])


def test_a_solve_process_solves_point_after_point_and_a_crash_fails_only_its_point(
        tmp_path, pid_model):
    import os

    pts = [{"E": 1.0}, {"E": 2.0}, {"E": -1.0}, {"E": 3.0}, {"E": 4.0}]
    res = solve_points(pid_model, pts, [tmp_path / f"{i}.h5" for i in range(5)], workers=1,
                       grace_s=0.5)
    assert [r.status for r in res] == ["ok", "ok", "failed", "ok", "ok"]
    assert "died" in res[2].reason and "exit code 3" in res[2].reason
    assert _pid(res[0]) == _pid(res[1]) != os.getpid()  # one process, not this one
    assert _pid(res[3]) == _pid(res[4]) != _pid(res[0])  # a new one after the crash


def test_a_hanging_point_is_killed_and_its_process_replaced(tmp_path, pid_model):
    pts = [{"E": 1.0}, {"E": -2.0}, {"E": 2.0}]
    res = solve_points(pid_model, pts, [tmp_path / f"{i}.h5" for i in range(3)], workers=1,
                       grace_s=0.5)
    assert [r.status for r in res] == ["ok", "failed", "ok"]
    assert "time limit" in res[1].reason
    assert _pid(res[2]) != _pid(res[0])


def _same_records(a, b):
    assert (a.status, a.reason, a.newton_iterations, a.load_steps, a.load_fraction) == \
        (b.status, b.reason, b.newton_iterations, b.load_steps, b.load_fraction)
    assert a.parameters == b.parameters
    for name in ("interface_reference", "interface_current", "segments"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.max_displacement == b.max_displacement
    assert [ld.label for ld in a.loadings] == [ld.label for ld in b.loadings]
    for la, lb in zip(a.loadings, b.loadings, strict=True):
        np.testing.assert_array_equal(la.current, lb.current, err_msg=la.label)


def test_a_kept_fsi_model_gives_the_records_of_a_new_model_per_point(tmp_path):
    """Bit for bit (no tolerance): the kept model keeps only its mesh, spaces and
    compiled forms and forgets its solver state before every point, so each Newton
    solve starts from the same state (the warm start) with a fresh factorization and
    does the same floating-point operations as in a new model. The case is the
    pipeline's: every point warm-started from the base state, two loadings by
    continuation."""
    fm = {"type": "fsi", "time_limit_s": 300.0,
          "fsi": {"mesh": {"preset": "coarse"}},
          "loadings": {"parameter": "inflow.rate", "nominal": None, "factors": [0.5, 1.0]}}
    base = tmp_path / "base.state.npz"
    solve_point({**fm, "loadings": {}}, {"material.E": 500.0, "material.nu": 0.3},
                tmp_path / "base.h5", extra_outputs={"state": str(base)})
    pts = [{"material.E": e, "material.nu": nu} for e, nu in ((420.0, 0.3), (560.0, 0.25),
                                                              (480.0, 0.35))]
    kept = solve_points(fm, pts, [tmp_path / "kept" / f"{i}.h5" for i in range(3)],
                        warm_start=base)
    fresh = [solve_point(fm, p, tmp_path / "fresh" / f"{i}.h5", warm_start=base)
             for i, p in enumerate(pts)]
    assert all(r.ok for r in kept)
    for a, b in zip(kept, fresh, strict=True):
        _same_records(a, b)
    # the mesh was built once in the kept process, once per point in the fresh ones
    assert kept[0].stats["build_time"] > 0
    assert kept[1].stats["build_time"] == kept[2].stats["build_time"] == 0
    assert all(r.stats["build_time"] > 0 for r in fresh)


def test_a_process_that_has_meshed_still_solves_isolated(tmp_path):
    """A process forked after Netgen generated a mesh in its parent hangs in its own
    mesh generation; after an in-process solve (a notebook, a test) the solve path starts
    its processes afresh instead, and the record is the in-process one. The time limit
    is short so that a hang fails here in about a minute."""
    import subprocess
    import sys

    script = """
import sys
from pathlib import Path
import numpy as np
from bayescalib.models.forward import solve_point, solve_points
out = Path(sys.argv[1])
fm = {"type": "fsi", "time_limit_s": 60.0, "fsi": {"mesh": {"preset": "coarse"}}}
here = solve_point(fm, {"material.E": 500.0}, out / "here.h5", isolate=False)
(there,) = solve_points(fm, [{"material.E": 500.0}], [out / "there.h5"], grace_s=5.0)
assert there.ok, there.reason
np.testing.assert_array_equal(there.interface_current, here.interface_current)
print("ok")
"""
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True,
                          text=True, timeout=600, check=False)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-2000:]
