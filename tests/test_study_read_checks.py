"""What can be known about a study when it is read is known then, before any solve
(issue 36): bad observation files, a python or command model that cannot run, and
settings whose cost is out of all proportion are refused by :class:`Study` (which the
Snakefile builds when it is parsed), each naming the key and the file or value.

One test per problem a probe of the pipeline found only after all the solves had run
(issue 36, "Observation problems found only after the solves", "A python model whose
module or function does not exist", "Unbounded cost accepted")."""

from __future__ import annotations

import os
import struct
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import ConfigError, deep_merge, load_yaml, merge_layers
from bayescalib.study import Study

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = load_yaml(ROOT / "config" / "config.yaml")  # the fsi model, an active design
ANALYTIC = load_yaml(ROOT / "tests" / "data" / "analytic_study.yaml")  # a python model
#: the default colony (half-ellipse 0.6 mm x 0.4 mm at x = 1 mm), in mm
COLONY_MM = [(0.7, 0.0), (0.8, 0.298), (1.0, 0.4), (1.2, 0.298), (1.3, 0.0)]


def _csv(path: Path, points, scale: float = 1.0) -> Path:
    path.write_text("x,y\n" + "".join(f"{x * scale!r},{y * scale!r}\n" for x, y in points))
    return path


def _files(base: dict, *entries: dict, **observations) -> dict:
    return deep_merge(base, {"observations": {"source": "files", "files": list(entries),
                                              **observations}})


def _refused(cfg: dict) -> str:
    with pytest.raises(ConfigError) as exc:
        Study(cfg, where="mine.yaml")
    msg = str(exc.value)
    assert msg.startswith("mine.yaml: "), msg
    return msg


# ------------------------------------------------------------------ observations
def test_a_file_in_metres_read_as_mm_is_refused_for_a_model_without_known_geometry(tmp_path):
    """A python model's geometry is known only from a solve; a colony 0.6 mm wide written
    in metres and read as mm spans 0.6 um, less than the likelihood's noise sd: refused,
    naming the key's units and the unit in which it fits."""
    metres = _csv(tmp_path / "scan_m.csv", COLONY_MM, scale=1e-3)
    Study(_files(ANALYTIC, {"path": str(metres), "units": "m"}))  # stated right: accepted
    msg = _refused(_files(ANALYTIC, {"path": str(metres)}))
    assert "observations.files[0]" in msg and "scan_m.csv" in msg, msg
    assert "Check observations.files[0].units" in msg and "(units: m)" in msg, msg
    assert "sigma_N" in msg, msg


def test_a_snapshot_in_other_units_than_the_first_is_refused(tmp_path):
    """Without a reference, the snapshots of one colony are compared with the first one:
    one of them in metres read as mm is 1000 times too small."""
    mm = _csv(tmp_path / "load_1.csv", COLONY_MM)
    metres = _csv(tmp_path / "load_2.csv", COLONY_MM, scale=1e-3)
    loads = {"forward_model": {"loadings": {"parameter": "V", "nominal": 100.0,
                                            "factors": [1.0, 2.0]}}}
    Study(deep_merge(_files(ANALYTIC, {"path": str(mm)}, {"path": str(mm)}), loads))
    msg = _refused(deep_merge(_files(ANALYTIC, {"path": str(mm)}, {"path": str(metres)}), loads))
    assert "observations.files[1]" in msg and "load_2.csv" in msg, msg
    assert "as wide as observations.files[0]" in msg and "(units: m)" in msg, msg


def test_a_file_in_metres_is_refused_against_the_fsi_models_colony(tmp_path):
    metres = _csv(tmp_path / "scan_m.csv", COLONY_MM, scale=1e-3)
    msg = _refused(_files(DEFAULT, {"path": str(metres)}))
    assert "observations.files[0].units" in msg and "(units: m)" in msg, msg


@pytest.mark.parametrize("value", [0, 255])
def test_an_all_black_or_all_white_mask_is_refused_naming_the_file(tmp_path, value):
    from skimage import io

    path = tmp_path / f"mask_{value}.png"
    io.imsave(path, np.full((40, 60), value, np.uint8), check_contrast=False)
    msg = _refused(_files(ANALYTIC, {"path": str(path), "pixel_size": 0.01,
                                     "origin": [0.005, 0.005]}))
    assert "observations.files[0]" in msg and path.name in msg, msg
    assert "all black or all white" in msg, msg


def _png_header(path: Path, width: int, height: int) -> Path:
    """A PNG whose header declares width x height pixels (its data is one row)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    path.write_bytes(b"\x89PNG\r\n\x1a\n"
                     + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\x00" * (width + 1)))
                     + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("size", [(20_000, 20_000), (10_000, 6_000)])
def test_a_huge_image_is_refused_from_its_header_before_decoding(tmp_path, size):
    """A 20000 x 20000 PNG (400 megapixels, above Pillow's own bomb guard) and a
    10000 x 6000 one (60, below it) are refused from their header, naming the key and
    the file: nothing is decoded (the data would not decode)."""
    path = _png_header(tmp_path / "huge.png", *size)
    t0 = time.perf_counter()
    msg = _refused(_files(ANALYTIC, {"path": str(path), "pixel_size": 0.001,
                                     "origin": [0.0005, 0.0005]}))
    assert time.perf_counter() - t0 < 5.0
    assert "observations.files[0]" in msg and "huge.png" in msg, msg
    assert "megapixels" in msg and "refused before decoding" in msg, msg


def test_a_file_of_two_million_points_is_refused_from_its_row_count(tmp_path):
    """A 2,000,000-row CSV is refused from its row count, without parsing it (reading it
    took 8 s; the study is read at every start of the workflow), naming the key, the file
    and what the RKHS measure resolves."""
    path = tmp_path / "dense.csv"
    path.write_bytes(b"x,y\n" + b"1.0,0.5\n" * 2_000_000)
    t0 = time.perf_counter()
    msg = _refused(_files(ANALYTIC, {"path": str(path)}))
    assert time.perf_counter() - t0 < 2.0
    assert "observations.files[0]" in msg and "dense.csv" in msg, msg
    assert "more than the 250,000 points" in msg and "resample" in msg, msg


def test_a_file_too_fine_for_the_rkhs_cost_guard_is_refused_naming_it(tmp_path):
    """Below the row limit, the RKHS measure's own guard (measure.rkhs.max_pairs) is applied
    to the observed interface when the study is read, naming the file, instead of in every
    discrepancy job."""
    t = np.linspace(0.0, np.pi, 20_000)
    dense = np.column_stack([1.0 - 0.3 * np.cos(t), 0.4 * np.sin(t)])
    path = _csv(tmp_path / "fine.csv", dense.tolist())
    cfg = _files(ANALYTIC, {"path": str(path)})
    Study(cfg)  # 20000 points: within the default limit of 1e10 pairs
    msg = _refused(deep_merge(cfg, {"measure": {"rkhs": {"max_pairs": 1.0e7}}}))
    assert "observations.files[0]" in msg and "fine.csv" in msg, msg
    assert "measure.rkhs.max_pairs" in msg and "kernel pairs" in msg, msg
    # resolution: a spacing that would resample it into more elements than the measure takes
    msg = _refused(deep_merge(cfg, {"measure": {"rkhs": {"spacing": 1.0e-7}}}))
    assert "fine.csv" in msg and "measure.rkhs.spacing" in msg, msg


@pytest.mark.parametrize("points, problem", [
    ([(0.7, 0.0), (1.3, 0.0)], "has 2 points"),
    ([(0.7, 0.0), (1.0, 0.0), (1.3, 0.0)], "lie on one straight line"),
])
def test_a_curve_of_too_few_points_is_refused_with_the_minimum(tmp_path, points, problem):
    """A two-point CSV was accepted: all solves ran, then the posterior figure failed with
    NaN. At least 3 points not on one line are needed, and the message says why."""
    path = _csv(tmp_path / "short.csv", points)
    for base in (ANALYTIC, DEFAULT):
        msg = _refused(_files(base, {"path": str(path)}))
        assert "observations.files[0]" in msg and "short.csv" in msg, msg
        assert problem in msg and "at least 3 points" in msg, msg


# ------------------------------------------------------------------ models
def _python(function: str, **options) -> dict:
    return deep_merge(ANALYTIC, {"forward_model": {"python": {"function": function,
                                                              "options": options}}})


@pytest.mark.parametrize("function, problem", [
    ("no_such_module_xyz:interface", "cannot import module 'no_such_module_xyz'"),
    ("bayescalib.models.analytic:interfaces", "has no 'interfaces' (did you mean 'interface'"),
    ("bayescalib.models.analytic:__all__", "'__all__' in module 'bayescalib.models.analytic'"),
])
def test_a_python_model_that_cannot_be_called_is_refused(function, problem):
    """A missing module or function was found by the solves (failed run records, then
    "the forward solve at the ground truth failed"): now refused when the study is read."""
    msg = _refused(_python(function))
    assert "forward_model.python.function" in msg and problem in msg, msg


def test_a_python_model_option_its_function_does_not_take_is_refused():
    Study(_python("bayescalib.models.analytic:interface", fail_below_E=130.0))
    msg = _refused(_python("bayescalib.models.analytic:interface", fail_below=130.0))
    assert "forward_model.python.options" in msg and "'fail_below'" in msg, msg


def test_a_python_module_that_fails_to_import_is_refused(tmp_path, monkeypatch):
    (tmp_path / "broken_model_xyz.py").write_text("import no_such_dependency_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    msg = _refused(_python("broken_model_xyz:interface"))
    assert "forward_model.python.function" in msg and "no_such_dependency_xyz" in msg, msg


def _command(tmp_path: Path, argv: list[str]) -> dict:
    template = tmp_path / "input.j2"
    template.write_text("E = {{ E }}\n")
    return deep_merge(ANALYTIC, {"forward_model": {"type": "command", "command": {
        "template": str(template), "command": argv}}})


def test_a_command_model_whose_program_is_missing_is_refused(tmp_path):
    """The command's program is looked up when the study is read: a name on PATH, an
    absolute path to an executable file; a relative path is refused (the command runs in
    each solve's work folder)."""
    Study(_command(tmp_path, [sys.executable, "solver.py", "{input}", "{output}"]))
    Study(_command(tmp_path, [Path(sys.executable).name, "solver.py", "{input}"]))
    script = tmp_path / "solver.sh"
    script.write_text("#!/bin/sh\n")
    script.chmod(0o644)
    cases = [
        (["no-such-solver-xyz", "{input}"], "'no-such-solver-xyz' is not found on PATH"),
        ([str(tmp_path / "missing.sh")], "missing.sh' does not exist"),
        ([str(script)], "solver.sh' is not executable"),
        ([os.path.relpath(script)], "is a relative path"),
    ]
    for argv, problem in cases:
        msg = _refused(_command(tmp_path, argv))
        assert "forward_model.command.command[0]" in msg and problem in msg, msg
    script.chmod(0o755)
    Study(_command(tmp_path, [str(script), "{input}"]))


# ------------------------------------------------------------------ cost
@pytest.mark.parametrize("base", [DEFAULT, ANALYTIC], ids=["default", "analytic"])
def test_a_million_gp_restarts_are_refused_naming_the_key(base):
    msg = _refused(deep_merge(base, {"surrogate": {"restarts": 1_000_000}}))
    assert msg.startswith("mine.yaml: surrogate.restarts = 1000000: the GP fits would take"), msg
    assert "MAX_GP_HOURS" in msg and "the schema's default is 3" in msg, msg


@pytest.mark.parametrize("base", [DEFAULT, ANALYTIC], ids=["default", "analytic"])
def test_ten_million_smc_sweeps_are_refused_naming_the_key(base):
    msg = _refused(deep_merge(base, {"smc": {"n_rej": 10_000_000}}))
    assert msg.startswith("mine.yaml: smc.n_rej = 10000000: one tempering step"), msg
    assert "MAX_SMC_STEP_MINUTES" in msg and "the schema's default is 20" in msg, msg


def test_the_active_rounds_smc_is_refused_by_its_own_key():
    msg = _refused(deep_merge(DEFAULT, {"design": {"active": {"smc": {"n_rej": 10_000_000}}}}))
    assert msg.startswith("mine.yaml: design.active.smc.n_rej = 10000000"), msg


@pytest.mark.parametrize("change, key", [
    ({"design": {"strategy": "fixed", "n_train": 100_000_000}}, "design.n_train"),
    ({"design": {"active": {"max_solves": 100_000_000}}}, "design.active.max_solves"),
    ({"design": {"strategy": "fixed", "n_train": 64, "n_test": 100_000_000},
      "convergence": {"enabled": True, "n_train": [16, 64]}}, "design.n_test"),
    # within the design limit, but a GP fit on 10000 points takes days
    ({"design": {"strategy": "fixed", "n_train": 10_000}}, "design.n_train"),
])
def test_a_design_too_large_is_refused_naming_the_design_key(change, key):
    """The refusal of a design of 1e8 points named smc.n_particles (the SMC's memory);
    it names the design's key."""
    msg = _refused(deep_merge(DEFAULT, change))
    assert msg.startswith(f"mine.yaml: {key} = "), msg
    assert "smc.n_particles" not in msg, msg


def _shipped_studies():
    cfg = ROOT / "config"
    studies = {p.stem: [DEFAULT, load_yaml(p)] for p in sorted(cfg.glob("*.yaml"))}
    hetero = load_yaml(cfg / "heterogeneous.yaml")
    for name in ("heterogeneous_fixed", "heterogeneous_outputs"):  # layered on heterogeneous
        studies[name] = [DEFAULT, hetero, load_yaml(cfg / f"{name}.yaml")]
    common = load_yaml(cfg / "concealed" / "common.yaml")
    for p in sorted((cfg / "concealed").glob("*.yaml")):
        if p.stem != "common":
            studies[f"concealed/{p.stem}"] = [DEFAULT, common, load_yaml(p)]
    studies["examples/oct_colony"] = [DEFAULT, load_yaml(ROOT / "examples" / "oct_colony" /
                                                         "study.yaml")]
    for p in sorted((ROOT / "tests" / "data").glob("*.yaml")):
        studies[f"tests/data/{p.stem}"] = [load_yaml(p)]
    return studies


@pytest.mark.parametrize("layers", list(_shipped_studies().values()),
                         ids=list(_shipped_studies()))
def test_every_shipped_study_passes_the_read_checks(layers, monkeypatch):
    """The limits are generous: every study of config/, config/concealed/, examples/ and
    tests/data/ (as its header says to layer it) is read without a refusal."""
    monkeypatch.chdir(ROOT)  # their paths are relative to the checkout
    Study(merge_layers(layers))


@pytest.mark.parametrize("parameters, surrogate", [
    (2, {}),
    (3, {}),  # an inflow rate's box starts at 0: log inputs are a choice too
    (3, {"kernel": "matern32", "output": "loglik"}),
    (3, {"frame": "axes", "inputs": "log"}),
    (2, {"ard": False}),
])
def test_the_time_guard_counts_the_candidate_models_a_search_fits(parameters, surrogate):
    """The GP estimate's count of candidate models (kernel x output x input scale x
    frame) is that of the search it estimates (the same function decides both)."""
    from bayescalib.config import validate
    from bayescalib.inference.gp.selection import _search_settings, search_size
    from bayescalib.inference.parameters import ParameterSpace

    params = load_yaml(ROOT / "config" / "uncertain_inflow.yaml").get("parameters") \
        if parameters == 3 else DEFAULT["parameters"]
    cfg = validate(deep_merge({**DEFAULT, "parameters": params}, {"surrogate": surrogate}),
                   "study")
    bounds = ParameterSpace.from_config(cfg["parameters"]).bounds
    rng = np.random.default_rng(0)
    X = bounds[:, 0] + rng.random((12, len(bounds))) * (bounds[:, 1] - bounds[:, 0])
    y = -np.sum(((X - X.mean(axis=0)) / X.std(axis=0)) ** 2, axis=1)
    _, candidates = _search_settings(X, y, cfg["surrogate"], bounds, 0.0)
    assert search_size(cfg["surrogate"], bounds) == len(candidates) > 0


def test_the_euclidean_measures_points_file_is_read_when_the_study_is_read(tmp_path):
    """Every discrepancy job reads measure.euclidean.points: a missing or broken file is
    refused when the study is read."""
    good = tmp_path / "points.csv"
    good.write_text("x,y\n0.8,0.3\n1.0,0.4\n1.2,0.3\n")
    euclid = {"measures": ["euclidean"], "measure": {"euclidean": {"points": str(good)}}}
    Study(deep_merge(ANALYTIC, euclid))
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n0.8,abc\n")
    for path, problem in ((tmp_path / "missing.csv", "does not exist"),
                          (bad, "non-numeric value")):
        msg = _refused(deep_merge(ANALYTIC, {**euclid, "measure": {"euclidean": {
            "points": str(path)}}}))
        assert "measure.euclidean.points" in msg and path.name in msg and problem in msg, msg


# ------------------------------------------- a user's own OCT recording (new-user probe)
OCT = ROOT / "examples" / "oct_colony"


def _oct_study(**files) -> dict:
    """The OCT example's study (examples/oct_colony/study.yaml) with absolute paths; the
    keyword ``files`` replaces observation entries by index, e.g. ``f0={...}``."""
    import copy

    study = copy.deepcopy(load_yaml(OCT / "study.yaml"))
    scan = study["forward_model"]["fsi"]["geometry"]["scan"]
    scan["path"] = str(ROOT / scan["path"])
    for e in study["observations"]["files"]:
        e["path"] = str(ROOT / e["path"])
    for k, change in files.items():
        study["observations"]["files"][int(k[1:])].update(change)
    return merge_layers([DEFAULT, study])


def _oct_pixels(i: int) -> np.ndarray:
    from PIL import Image

    return np.array(Image.open(OCT / f"scan_{i}.png"))


def _png16(path: Path, img: np.ndarray) -> str:
    from PIL import Image

    Image.fromarray(np.clip(img, 0, 65535).astype(np.uint16)).save(path)
    return str(path)


@pytest.mark.parametrize("likelihood, given, fix", [
    ({"sigma_n": 2.0}, "likelihood.sigma_n = 2 mm", "sigma_n: 0.002"),
    ({"sigma_n2": 4.0}, "likelihood.sigma_n2 = 4 mm^2", "sigma_n2: 4e-06"),
])
def test_a_noise_sd_given_in_um_is_refused_against_the_colonys_height(likelihood, given, fix):
    """sigma_N = 2 um written as sigma_n: 2.0 (mm) is five times the colony's height: the
    data could tell nothing, and the study was accepted (a flat posterior after all the
    solves)."""
    study = _oct_study()
    study["likelihood"] = {"sigma_n2": None, "sigma_n": None, **likelihood}
    msg = _refused(study)
    assert given in msg and fix in msg and "0.38 mm" in msg, msg


def test_an_inverted_observation_scan_is_refused(tmp_path):
    """An observed B-scan with the contrast inverted (fluid bright) was accepted: the
    trace of the bright fluid's edge ran along the floor to both image sides, and those
    floor nodes were taken for the colony's interface."""
    inv = _png16(tmp_path / "inv_1.png", 65535 - _oct_pixels(1).astype(np.int64))
    msg = _refused(_oct_study(f0={"path": inv}))
    assert "observations.files[0]" in msg and "inv_1.png" in msg and "inverted" in msg, msg


def test_an_observation_scan_cut_by_the_image_border_is_refused(tmp_path):
    """An observed B-scan cropped through the colony's upstream flank was accepted (the
    zero-flow scan so cropped is refused): the model's interface beyond the cut would
    be compared with the trace's cut end."""
    crop = _png16(tmp_path / "crop_1.png", _oct_pixels(1)[:, 40:])
    Study(_oct_study(f0={"path": _png16(tmp_path / "whole_1.png", _oct_pixels(1))}))
    msg = _refused(_oct_study(f0={"path": crop, "origin": [682.0, -30.0]}))
    assert "observations.files[0]" in msg and "crop_1.png" in msg, msg
    assert "left border" in msg and "cut by the field of view" in msg, msg


def test_an_oct_volume_observed_for_the_2d_model_is_refused_as_a_volume(tmp_path):
    """A multi-page TIFF in a 2D study was refused asking for a voxel size of three
    numbers (a volume's), which would lead to a 3D surface for a 2D model."""
    import tifffile

    stack = tmp_path / "stack_1.tif"
    tifffile.imwrite(stack, np.stack([_oct_pixels(1)] * 3), photometric="minisblack")
    msg = _refused(_oct_study(f0={"path": str(stack)}))
    assert "observations.files[0]" in msg and "is an OCT volume" in msg, msg
    assert "geometry.dim: 2" in msg and "voxel size" not in msg, msg


def test_a_2d_scans_two_pixel_sizes_are_refused_saying_to_resample():
    """An OCT B-scan's axial and lateral pixel sizes (4 um across, 2.9 um deep) given as
    a pair for the 2D model: refused, saying that the pixels must be square and what the
    axial size in the sample is; the same for the zero-flow scan."""
    msg = _refused(_oct_study(f0={"pixel_size": [4.0, 2.9]}))
    assert "observations.files[0].pixel_size" in msg, msg
    assert "square pixels" in msg and "refractive index" in msg, msg
    study = _oct_study()
    study["forward_model"]["fsi"]["geometry"]["scan"]["pixel_size"] = [4.0, 2.9]
    msg = _refused(study)
    assert "geometry.scan.pixel_size" in msg and "square pixels" in msg, msg


def test_observation_pixels_other_than_the_zero_flow_scans_are_noted():
    """A pixel size of the observed scans other than the zero-flow scan's (4.4 um against
    4 um: the colony 10 % larger) passes the placement check; it is noted."""
    assert not any("pixel_size:" in n for n in Study(_oct_study()).notes)
    notes = Study(_oct_study(f0={"pixel_size": 4.4}, f2={"pixel_size": 4.4})).notes
    note = [n for n in notes if "pixel_size:" in n]
    assert len(note) == 1, notes
    assert "observations.files[0] 4.4 um, observations.files[2] 4.4 um" in note[0], note
    assert "has 4 um pixels" in note[0], note


def test_an_observation_scan_without_its_floor_is_refused_naming_floor():
    """Without floor: auto the example's bright substrate band is segmented with the
    colony and its top traced from one image side to the other; the trace is refused
    naming the key that cuts it, not as a colony cut by the field of view."""
    study = _oct_study()
    study["observations"]["files"][1].pop("floor")
    msg = _refused(study)
    assert "observations.files[1].floor: auto" in msg and "bright band" in msg, msg
    assert "field of view" not in msg, msg


def test_an_observation_scans_origin_in_um_under_units_mm_names_the_origin():
    """The observed scans' origin copied in um under units: mm (pixel size converted):
    their size fits the domain, their place not, and the message said "unit
    mismatch?" with no hint; it names the origin now."""
    msg = _refused(_oct_study(f0={"units": "mm", "pixel_size": 0.004}))
    assert "observations.files[0]" in msg and "its size fits the domain" in msg, msg
    assert "origin" in msg and "unit mismatch" not in msg, msg


def test_a_closed_observed_outline_is_refused_for_the_2d_model(tmp_path):
    """An observed interface written as the colony's closed outline (the first point
    repeated last) was accepted: its base along the floor is no part of the model's
    interface, and the RKHS distance counts it (0.14 -> 0.17 on the example's data)."""
    rows = (OCT / "truth_1.csv").read_text().strip().splitlines()
    (tmp_path / "open_1.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "closed_1.csv").write_text("\n".join(rows + [rows[1]]) + "\n")
    entry = {"units": "um", "pixel_size": None, "origin": None, "floor": None}
    Study(_oct_study(f0={**entry, "path": str(tmp_path / "open_1.csv")}))
    msg = _refused(_oct_study(f0={**entry, "path": str(tmp_path / "closed_1.csv")}))
    assert "observations.files[0]" in msg and "closed_1.csv" in msg, msg
    assert "closed outline" in msg and "leave out the base" in msg, msg


def _two_colonies(path: Path) -> dict:
    """A mask (10 um pixels, the floor at the image bottom) with the default model's
    colony (half-ellipse 0.6 x 0.4 mm at x = 1 mm) and a larger one at x = 2 mm."""
    from skimage import io

    x = -0.195 + 0.01 * np.arange(330)  # pixel centres, mm
    y = 0.005 + 0.01 * np.arange(60)[::-1]  # row 0 at the top
    X, Y = np.meshgrid(x, y)
    mask = ((X - 1.0) / 0.3) ** 2 + (Y / 0.4) ** 2 <= 1.0
    mask |= ((X - 2.0) / 0.45) ** 2 + (Y / 0.42) ** 2 <= 1.0
    io.imsave(path, (255 * mask).astype(np.uint8), check_contrast=False)
    return {"path": str(path), "pixel_size": 10.0, "units": "um", "origin": [-195.0, 5.0]}


def test_the_colony_traced_in_an_observation_image_is_the_one_the_model_meshes(tmp_path):
    """An image with two colonies is traced along the largest; when that is not the
    model's colony the study is refused naming the colonies and the ``colony`` x-range
    that traces the model's (before the extent check, which took it for a unit slip);
    with that range the study is read, and a note says which colony was traced."""
    entry = _two_colonies(tmp_path / "two.png")
    msg = _refused(_files(DEFAULT, entry))
    assert "observations.files[0] ('" in msg and "holds 2 colonies" in msg, msg
    assert "is not the colony the model meshes" in msg, msg
    assert "give observations.files[0].colony: [" in msg, msg
    given = msg.split("give observations.files[0].colony: [")[1].split("]")[0]
    lo, hi = (float(v) for v in given.split(","))
    assert 690 <= lo <= 710 and 1290 <= hi <= 1310, given  # um: the model's colony
    study = Study(_files(DEFAULT, {**entry, "colony": [lo, hi]}), where="mine.yaml")
    note = next(n for n in study.notes if "2 colonies in the image" in n)
    assert "observations.files[0]" in note and f"traced: x {lo:.6g}" in note, note


def test_an_observation_images_colony_range_picks_the_colony_to_trace(tmp_path):
    """The reader traces the colony with the most pixels in ``colony`` (the file's
    units), the largest without it; the record lists the colonies, largest first."""
    from bayescalib.io.observations import ObservationError, read_interface_info

    entry = _two_colonies(tmp_path / "two.png")
    opts = {"pixel_size": 10.0, "units": "um", "origin": [-195.0, 5.0]}
    big, info = read_interface_info(entry["path"], **opts)
    small, info_s = read_interface_info(entry["path"], colony=[800.0, 1200.0], **opts)
    assert np.ptp(big.points[:, 0]) == pytest.approx(0.9, abs=0.02)
    assert big.points[:, 0].min() > 1.5
    assert np.ptp(small.points[:, 0]) == pytest.approx(0.6, abs=0.02)
    assert small.points[:, 0].max() < 1.4
    assert info["colony_index"] == 0 and info_s["colony_index"] == 1
    assert [round(v, 2) for v in info["colonies_mm"][1]] == pytest.approx([0.7, 1.3], abs=0.02)
    with pytest.raises(ObservationError, match="no colony lies in the given x-range"):
        read_interface_info(entry["path"], colony=[-150.0, -100.0], **opts)
    with pytest.raises(ObservationError, match="applies to 2D images"):
        read_interface_info(_csv(tmp_path / "c.csv", COLONY_MM), colony=[0.0, 1.0])


def test_snapshots_listed_in_the_reverse_order_of_the_loadings_are_refused():
    """The OCT example's scans lie 2.2, 5.6 and 10.4 um from the zero-flow colony at 50,
    100 and 150 mm^2/s: listed in the reverse order without their loads they would be
    compared with the solves at the wrong flows; refused, naming the distances. In order,
    or reversed with each file's load stating its flow (the loads are then checked
    against the loadings), they are read."""
    cfg = _oct_study()
    files = cfg["observations"]["files"]
    bare = [{k: v for k, v in e.items() if k != "load"} for e in files]
    Study(deep_merge(cfg, {"observations": {"files": bare}}), where="mine.yaml")
    msg = _refused(deep_merge(cfg, {"observations": {"files": bare[::-1]}}))
    assert "reverse order of forward_model.loadings.factors" in msg, msg
    assert "observations.files[2] 2.24" in msg and "at factor 0.5" in msg, msg
    msg = _refused(deep_merge(cfg, {"observations": {"files": files[::-1]}}))
    assert "load" in msg and "reverse order" not in msg, msg  # the loads' own check


# ------------------------------------------------------------------ the channel's ends
def _moved(study: dict, dx_um: float, length: float) -> dict:
    """``study`` (the OCT example's) with every scan moved ``dx_um`` downstream in a
    channel ``length`` mm long."""
    import copy

    study = copy.deepcopy(study)
    geo = study["forward_model"]["fsi"]["geometry"]
    for entry in [geo["scan"], *study["observations"]["files"]]:
        entry["origin"][0] += dx_um
    geo["length"] = length
    study["observations"].pop("domain")
    return study


def test_the_end_effect_is_the_measured_table_and_falls_with_the_clearance():
    """Between the measured clearances (benchmarks/channel_clearance.py) the change is
    interpolated; it falls as the colony moves away from either end."""
    from bayescalib.models.fsi.geometry import END_EFFECT, end_effect

    for end, table in END_EFFECT.items():
        for c, e in table:
            assert end_effect(c, end) == pytest.approx(e, rel=1e-12)
        grid = np.linspace(0.0, 3.0, 61)
        change = [end_effect(c, end) for c in grid]
        assert np.all(np.diff(change) <= 0.0), end
    assert end_effect(1.0, "inlet") < 0.04 < end_effect(0.75, "inlet")


def test_a_colony_near_the_channels_inlet_is_refused_with_the_length_that_fits():
    """The example's colony 0.1 mm (0.1 channel heights) from the inlet: the imposed
    inflow profile changes its deformation by over 100 % and the solves failed there
    (measured); refused when the study is read, with the length and shift that put it
    1.5 channel heights from both ends. At 0.3 channel heights it is read."""
    base = _oct_study()
    msg = _refused(_moved(base, -1400.0, 2.0))  # the colony at x = 0.1 to 0.9 mm
    assert "forward_model.fsi.geometry" in msg and "upstream foot is 0.1 mm" in msg, msg
    assert "over 128 % off" in msg and "at least 0.3 channel heights" in msg, msg
    assert "geometry.length: 3.8 with the colony 1.4 mm further downstream" in msg, msg
    assert "geometry.scan and of every observation file + 1.4 mm" in msg, msg
    Study(_moved(base, -1195.0, 2.0))  # 0.305 mm: read (with a note)


def test_a_colony_near_an_end_of_the_channel_is_noted_for_observed_data():
    """The example's colony 0.6 mm from both ends of a 2 mm channel (as the recording was
    made before): a note names both ends with the measured change (14 % at the inlet,
    7 % at the outlet) and the advised length. In the example's own 3.8 mm channel
    (1.5 channel heights) there is none; a synthetic study, whose data share the
    model's channel, gets none either."""
    moved = Study(_moved(_oct_study(), -900.0, 2.0)).notes
    note = [n for n in moved if "near the end of the modelled channel" in n]
    assert len(note) == 1, moved
    assert "upstream foot is 0.6 mm from the channel's inlet" in note[0], note
    assert "(0.6 channel heights: the deformation 14 % off)" in note[0], note
    assert "downstream foot is 0.6 mm from the channel's outlet" in note[0], note
    assert "(0.6 channel heights: the deformation 7 % off)" in note[0], note
    assert "geometry.length: 3.8 with the colony 0.9 mm further downstream" in note[0], note
    assert not [n for n in Study(_oct_study()).notes if "modelled channel" in n]
    synthetic = deep_merge(DEFAULT, {"forward_model": {"fsi": {"geometry": {"centre": 0.6}}}})
    assert not [n for n in Study(synthetic).notes if "modelled channel" in n]


def test_a_half_ellipse_at_the_inlet_is_refused_naming_its_centre():
    """The default half-ellipse (0.6 mm wide) centred 0.4 mm from the inlet: its foot 0.1
    mm from it; refused, naming geometry.centre's value that fits."""
    msg = _refused(deep_merge(DEFAULT, {"forward_model": {"fsi": {"geometry": {
        "centre": 0.4}}}}))
    assert "upstream foot is 0.1 mm" in msg and "geometry.centre 1.8" in msg, msg


# ------------------------------------------------------------------ 2D images' placement
@pytest.mark.parametrize("dy", [33.0, 12.0, -20.0])
def test_an_observed_scans_substrate_off_the_floor_is_refused_with_the_origin(dy):
    """The example's loaded scans with their origin's y off by dy um: the substrate
    (floor: auto) lies dy um from y = 0, the traced interface that far above or below
    the model's (33 um is 16 sigma_N); the placement check let it through (a quarter of
    the colony's height); refused, naming the origin that puts it on y = 0."""
    study = _oct_study()
    for e in study["observations"]["files"]:
        e["origin"][1] += dy
    msg = _refused(study)
    assert "observations.files[0]" in msg and f"lies at y = {dy:.3g} um" in msg, msg
    assert "With origin [1422, -30] um it would lie there" in msg, msg


def _mirrored(tmp_path: Path, which: list[int], scan: bool) -> dict:
    study = _oct_study()
    for k in which:
        e = study["observations"]["files"][k]
        e["path"] = _png16(tmp_path / f"m{k}.png", _oct_pixels(k + 1)[:, ::-1])
    if scan:
        study["forward_model"]["fsi"]["geometry"]["scan"]["path"] = _png16(
            tmp_path / "m_scan_0.png", _oct_pixels(0)[:, ::-1])
    return study


def test_an_observed_image_mirrored_against_the_zero_flow_scan_is_refused(tmp_path):
    """One loaded scan with its columns reversed: its lobed colony lies 31.8 um from the
    model's (placement allows a quarter of the height) and 1.6 um from it mirrored back;
    refused, naming the file and asking for its columns reversed."""
    msg = _refused(_mirrored(tmp_path, [0], scan=False))
    assert "observations.files[0]" in msg and "m0.png" in msg, msg
    assert "is the image mirrored against the zero-flow scan" in msg, msg


def test_scans_whose_flow_runs_against_x_are_refused(tmp_path):
    """Every scan with its columns reversed, the zero-flow one included (the flow running
    from the image's right to its left): each loaded colony has moved upstream of the
    model's (-1.1, -2.6, -4.9 um, the example as is +1.1, +2.6, +4.9); refused."""
    msg = _refused(_mirrored(tmp_path, [0, 1, 2], scan=True))
    assert "moved upstream of the model's undeformed biofilm" in msg, msg
    assert "Reverse the columns of every scan" in msg, msg
    Study(_oct_study())  # as recorded: read
