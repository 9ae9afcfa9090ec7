"""Study configuration: every shipped study validates, rule sections are what
the cache contract needs, and bad studies fail with errors naming the key."""

from pathlib import Path

import numpy as np
import pytest

from bayescalib.config import ConfigError, deep_merge, load_yaml, merge_layers
from bayescalib.study import Study

CONFIG = Path(__file__).resolve().parents[1] / "config"
DEFAULT = load_yaml(CONFIG / "config.yaml")


@pytest.mark.parametrize("path", sorted(CONFIG.glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_study_validates_on_top_of_the_default(path):
    study = Study(deep_merge(DEFAULT, load_yaml(path)), where=path.name)
    assert study.n_points >= study.n_train
    assert set(study.point(0)) == set(study.targets())


def test_design_points_keep_their_values_when_the_design_grows():
    small = Study(deep_merge(DEFAULT, {"design": {"strategy": "fixed", "n_train": 16}}))
    large = Study(deep_merge(DEFAULT, {"design": {"strategy": "fixed", "n_train": 64}}))
    for i in range(16):
        assert small.point(i) == large.point(i)


def test_forward_section_keeps_only_the_chosen_model():
    study = Study(deep_merge(DEFAULT, {"forward_model": {
        "type": "python", "warm_start": "none",
        "python": {"function": "bayescalib.models.analytic:interface"}}}))
    fm = study.forward_section()
    assert "fsi" not in fm and fm["python"]["function"].endswith(":interface")


@pytest.mark.parametrize(
    "change, message",
    [
        ({"smc": {"n_particels": 10}}, "unknown key 'smc.n_particels' (did you mean 'n_particles'?)"),
        ({"design": {"n_train": 0}}, "design.n_train"),
        ({"measures": ["rkhs", "hausdorff"]}, "measures[1]"),
        ({"forward_model": {"fsi": {"material": {"law": "linear"}}}}, "forward_model.fsi.material.law"),
        ({"design": {"strategy": "fixed"}, "convergence": {"enabled": True, "n_train": [10, 5000]}},
         "convergence.n_train"),
        ({"convergence": {"enabled": True}}, "convergence.enabled needs design.strategy: fixed"),
        ({"design": {"active": {"n_initial": 64, "max_solves": 32}}},
         "design.active.n_initial (64) exceeds design.active.max_solves (32)"),
        ({"forward_model": {"type": "python", "warm_start": "none"}},
         "forward_model.python.function is required"),
        ({"forward_model": {"type": "command", "command": {"template": "/nonexistent.j2",
                                                          "command": ["x"]}}},
         "/nonexistent.j2' does not exist"),
        ({"likelihood": {"sigma_n2": -1.0}}, "likelihood.sigma_n2"),
        # its square overflows (a traceback, found by tests/test_config_fuzz.py)
        ({"likelihood": {"sigma_n2": None, "sigma_n": 1e300}}, "likelihood.sigma_n = 1e+300"),
        # a name that is a path: results/.. is the checkout itself
        ({"study": ".."}, "study"),
        ({"study": ".hidden"}, "study"),
        # the cost of the work, known before any job: SMC memory
        ({"smc": {"n_particles": 1_000_000_000}},
         "smc.n_particles = 1000000000 needs about"),
        ({"design": {"active": {"smc": {"n_particles": 1_000_000_000}}}},
         "design.active.smc.n_particles = 1000000000 needs about"),
        ({"design": {"active": {"smc": {"zeta": 1.5}}}}, "design.active.smc.zeta"),
        ({"forward_model": {"type": "command", "command": {
            "template": __file__, "command": ["x"], "output_name": "../../victim.txt"}}},
         "forward_model.command.output_name"),
        ({"forward_model": {"type": "command", "command": {
            "template": __file__, "command": ["x"], "input_name": "/etc/passwd"}}},
         "forward_model.command.input_name"),
    ],
)
def test_bad_study_errors_name_the_key(change, message):
    with pytest.raises(ConfigError) as exc:
        Study(deep_merge(DEFAULT, change), where="config.yaml")
    assert message in str(exc.value)


def test_a_study_layered_on_the_defaults_sets_the_noise_either_way():
    """The defaults give sigma_n2; a study that gives sigma_n (or the other way round)
    replaces it: the later layer wins, there is no conflict to resolve."""
    study = Study(merge_layers([DEFAULT, {"likelihood": {"sigma_n": 0.002}}]))
    assert study.config["likelihood"]["sigma_n"] == 0.002
    assert study.config["likelihood"].get("sigma_n2") is None
    back = merge_layers([DEFAULT, {"likelihood": {"sigma_n": 0.002}},
                         {"likelihood": {"sigma_n2": 1.0e-6}}])
    assert back["likelihood"] == {"sigma_n2": 1.0e-6}
    # within one layer both keys are the user's own: they must agree
    with pytest.raises(ConfigError, match="disagree"):
        Study(merge_layers([DEFAULT, {"likelihood": {"sigma_n": 0.002, "sigma_n2": 1.0}}]))


@pytest.mark.parametrize("warm, expect_note", [(None, False), ("prior_centre", True)])
def test_a_python_study_on_the_defaults_just_works(warm, expect_note):
    """The fsi model's warm start does not apply to another model type: by default it
    is off for it, and asked for explicitly it is ignored with a note."""
    fm = {"type": "python", "python": {"function": "bayescalib.models.analytic:interface"}}
    if warm is not None:
        fm["warm_start"] = warm
    study = Study(merge_layers([DEFAULT, {"forward_model": fm}]))
    assert study.config["forward_model"]["warm_start"] == "none"
    assert bool(study.notes) is expect_note
    if expect_note:
        assert "ignored for the python model" in study.notes[0]
    fsi = Study(DEFAULT)
    assert fsi.config["forward_model"]["warm_start"] == "prior_centre" and not fsi.notes


def test_synthetic_observations_need_a_ground_truth():
    params = [dict(p) for p in DEFAULT["parameters"]]
    params[1] = {k: v for k, v in params[1].items() if k != "ground_truth"}
    with pytest.raises(ConfigError, match="missing for: nu"):
        Study({**DEFAULT, "parameters": params})


def test_parameter_errors_name_the_parameter():
    params = [dict(p) for p in DEFAULT["parameters"]]
    params[0] = {**params[0], "bounds": [800.0, 100.0]}
    with pytest.raises(ConfigError, match="E"):
        Study({**DEFAULT, "parameters": params})


@pytest.mark.parametrize("k, change, message", [
    (1, {"bounds": [-0.5, 0.7]}, r"parameters\[1\] \('nu'\): the upper bound 0.7 .*target 'material.nu'"),
    (0, {"bounds": [-10.0, 800.0]}, r"parameters\[0\] \('E'\): the lower bound -10 .*material.E"),
    (0, {"target": "material.Young"}, r"parameters\[0\].*unknown key 'material.Young'"),
])
def test_a_box_the_fsi_model_cannot_solve_is_refused_before_any_solve(k, change, message):
    """Every value of a design box must be a setting the fsi model accepts: a box past
    the schema's limits (or a target it does not have) would fail its solves one by
    one; it is refused when the study is read, naming the parameter and the bound."""
    params = [dict(p) for p in DEFAULT["parameters"]]
    params[k] = {**params[k], **change}
    if "bounds" in change:
        params[k]["prior"] = {"type": "uniform"}
    with pytest.raises(ConfigError, match=message):
        Study({**DEFAULT, "parameters": params})


def _with_param(k: int, **change) -> dict:
    params = [dict(p) for p in DEFAULT["parameters"]]
    params[k] = {**params[k], **change}
    return {**DEFAULT, "parameters": params}


def test_a_modulus_in_kpa_is_refused_with_its_numbers_in_pa():
    """The fsi model reads material.E in Pa: a prior written in kPa would be read as
    Pa (a biofilm a thousand times softer). The study is refused, naming the key, the
    target and its unit, and the error gives the parameter's numbers in Pa to paste."""
    cfg = _with_param(0, unit="kPa", prior={"type": "uniform", "lo": 0.1, "hi": 0.8},
                      bounds=[0.1, 0.8], ground_truth=0.4)
    with pytest.raises(ConfigError) as exc:
        Study(cfg)
    text = str(exc.value)
    assert "parameters[0].unit: 'kPa'" in text and "material.E in Pa" in text
    assert ("{name: E, unit: Pa, target: material.E, prior: {type: uniform, lo: 100, hi: 800}, "
            "bounds: [100, 800], ground_truth: 400}") in text


@pytest.mark.parametrize("k, unit, message", [
    (0, "-", r"parameters\[0\].unit: '-' .*material.E in Pa .*names none.*write unit: Pa"),
    (1, "Pa", r"parameters\[1\].unit: 'Pa' .*material.nu as a dimensionless number"),
    (0, "Pa s", r"parameters\[0\].unit: 'Pa s' .*material.E in Pa: write unit: Pa"),
])
def test_a_unit_that_is_not_the_targets_is_refused(k, unit, message):
    """A unit of another kind (or none, the default) for a target with a unit cannot be
    converted: the error says which unit to write."""
    with pytest.raises(ConfigError, match=message):
        Study(_with_param(k, unit=unit))


def test_an_inflow_rate_in_um2_per_s_is_refused_with_its_prior_in_mm2_per_s():
    cfg = deep_merge(DEFAULT, {"parameters": DEFAULT["parameters"] + [{
        "name": "V_in", "unit": "um^2/s", "target": "inflow.rate", "uncertain": True,
        "prior": {"type": "beta", "a": 2.6, "b": 1.4, "lo": 0.0, "hi": 1.1e8},
        "ground_truth": 8.8e7}]})
    with pytest.raises(ConfigError, match=(
            r"parameters\[2\].unit: 'um\^2/s' .*inflow.rate in mm\^2/s.*x 1e-06.*"
            r"prior: \{type: beta, lo: 0, hi: 110, a: 2.6, b: 1.4\}, uncertain: true, "
            r"ground_truth: 88\}")):
        Study(cfg)


@pytest.mark.parametrize("k, unit", [(0, "Pa"), (0, "N/m^2"), (1, "-"), (1, ""), (1, "1")])
def test_the_targets_unit_however_spelled_is_accepted(k, unit):
    Study(_with_param(k, unit=unit))


def test_a_physics_phi_has_the_candidates_unit():
    """The permeability's phi is read in um^2 (bayescalib.models.fsi.physics): mm^2 is
    refused with the numbers in um^2; a python model's unit is a free label."""
    fsi = deep_merge(DEFAULT, {"forward_model": {"fsi": {"physics": {
        "permeability": {"enabled": True}}}}})
    perm = {"name": "k", "unit": "mm^2", "target": "physics.permeability.phi",
            "prior": {"type": "uniform", "lo": 0.0, "hi": 2.0e-4}, "ground_truth": 1.0e-4}
    with pytest.raises(ConfigError, match=r"parameters\[2\].unit: 'mm\^2' .*In um\^2 "
                                          r"\(x 1000000\).*lo: 0, hi: 200\}.*ground_truth: 100"):
        Study({**fsi, "parameters": DEFAULT["parameters"] + [perm]})
    Study({**fsi, "parameters": DEFAULT["parameters"] + [
        {**perm, "unit": "um^2", "prior": {"type": "uniform", "lo": 0.0, "hi": 200.0},
         "ground_truth": 100.0}]})
    python = deep_merge(DEFAULT, {"forward_model": {
        "type": "python", "python": {"function": "bayescalib.models.analytic:interface"}}})
    Study(deep_merge(python, {"parameters": _with_param(0, unit="kPa")["parameters"]}))


def test_run_lock_is_exclusive_and_dies_with_its_holder(tmp_path):
    import subprocess
    import sys
    import time

    from bayescalib.study import StudyBusyError, hold_run_lock

    holder = subprocess.Popen(
        [sys.executable, "-c", ("import sys, time\nfrom bayescalib.study import hold_run_lock\n"
         f"hold_run_lock({str(tmp_path)!r}, 's')\nprint('held', flush=True)\ntime.sleep(60)\n")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(StudyBusyError, match=r"study 's' is already being run .*pid"):
            hold_run_lock(tmp_path, "s")
    finally:
        holder.kill()  # SIGKILL: no clean-up, yet the lock is gone with the process
        holder.wait()
    end = time.monotonic() + 5
    while True:
        try:
            assert hold_run_lock(tmp_path, "s") == tmp_path / ".run.lock"
            break
        except StudyBusyError:
            assert time.monotonic() < end
            time.sleep(0.05)
    assert hold_run_lock(tmp_path, "s") == tmp_path / ".run.lock"  # held: a no-op


def test_the_workflow_schemas_are_the_packaged_schemas():
    """workflow/schemas/ (what Snakemake users look at) links to the schemas the library
    validates with; an edit must change both, or defaults would silently differ."""
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    packaged = repo / "src" / "bayescalib" / "schemas"
    shown = sorted((repo / "workflow" / "schemas").glob("*.yaml"))
    assert [p.name for p in shown] == sorted(p.name for p in packaged.glob("*.yaml"))
    for p in shown:
        assert p.read_text() == (packaged / p.name).read_text(), p.name


def test_rule_params_do_not_depend_on_the_order_of_keys():
    """Snakemake compares rule params as text: the same study written with its keys in
    another order (or layered differently) must give the same params, or every solve
    would rerun."""
    def reverse(obj):
        if isinstance(obj, dict):
            return {k: reverse(obj[k]) for k in reversed(list(obj))}
        if isinstance(obj, list):
            return [reverse(v) for v in obj]
        return obj

    a, b = Study(DEFAULT), Study(reverse(DEFAULT))
    assert repr(a.forward_section()) == repr(b.forward_section())
    assert repr(a.config) == repr(b.config)
    assert [p["name"] for p in b.config["parameters"]] == ["E", "nu"]  # lists keep order


def _files_study(tmp_path, entries, **obs):
    return deep_merge(DEFAULT, {"observations": {"source": "files", "files": entries, **obs}})


def test_observation_files_are_checked_before_any_job(tmp_path):
    """A missing, unsupported or implausible observation file is a config error that
    names the key and the file, raised when the study is read (before any solve)."""
    good = tmp_path / "scan.csv"  # on the default colony (half-ellipse 0.6 mm x 0.4 mm at x = 1)
    good.write_text("x,y\n0.7,0.0\n0.8,0.298\n1.0,0.4\n1.2,0.298\n1.3,0.0\n")
    Study(_files_study(tmp_path, [{"path": str(good)}]))  # a readable file passes
    cases = [
        ([{"path": str(tmp_path / "missing.csv")}], "observations.files[0]", "does not exist"),
        ([{"path": str(good)}, {"path": str(tmp_path / "scan.xyz")}], "observations.files[1].path",
         "not a supported interface file"),
        ([{"path": str(tmp_path / "mask.png")}], "observations.files[0].pixel_size", "required"),
        ([], "observations.files", "is empty"),
    ]
    (tmp_path / "scan.xyz").write_text("1 2\n")
    (tmp_path / "mask.png").write_bytes(b"\x89PNG")
    for entries, key, problem in cases:
        with pytest.raises(ConfigError) as exc:
            Study(_files_study(tmp_path, entries), where="mine.yaml")
        assert key in str(exc.value) and problem in str(exc.value), str(exc.value)
    # a file in metres read as mm does not fit the flow cell's domain
    with pytest.raises(ConfigError, match=r"observations.files\[0\]"):
        Study(_files_study(tmp_path, [{"path": str(good), "units": "m"}],
                          domain=[[-1.0, 2.0], [-0.5, 1.0]]))


def test_images_are_read_and_segmented_when_the_study_is_read(tmp_path):
    """An image must state its origin (no silent (0, 0)); an all-black or all-white image,
    or a scan whose segmentation finds no biofilm, is a config error naming the key and
    the file, raised when the study is read; a good scan passes, and its extent is
    checked against observations.domain like a coordinate file's."""
    from skimage import io

    rows, cols = np.mgrid[0:100, 0:200]  # 5 um pixels: the default colony at x = 1 mm
    rng = np.random.default_rng(0)
    colony = ((cols - 100) / 60.0) ** 2 + ((99.5 - rows) / 80.0) ** 2 <= 1.0
    scan = np.clip(40 + 120 * colony + 10 * rng.standard_normal(rows.shape), 0,
                   255).astype(np.uint8)
    io.imsave(tmp_path / "scan.png", scan, check_contrast=False)
    for name, value in (("black.png", 0), ("white.png", 255)):
        io.imsave(tmp_path / name, np.full((30, 40), value, np.uint8), check_contrast=False)
    good = {"path": str(tmp_path / "scan.png"), "pixel_size": 5.0, "units": "um",
            "origin": [502.5, 2.5]}
    Study(_files_study(tmp_path, [good], domain=[[0.0, 2.0], [0.0, 1.0]]))
    cases = [
        ({**good, "origin": None}, "observations.files[0].origin",
         "centre of the bottom-left pixel"),
        ({**good, "path": str(tmp_path / "black.png")}, "observations.files[0]",
         "black.png: the image has a single grey value"),
        ({**good, "path": str(tmp_path / "white.png")}, "observations.files[0]",
         "all black or all white"),
        ({**good, "segmentation": {"threshold": 254}}, "observations.files[0]",
         "scan.png: the segmentation of the scan finds no foreground"),
        ({**good, "units": "mm"}, "observations.files[0]", "unit mismatch"),
    ]
    for entry, key, problem in cases:
        with pytest.raises(ConfigError) as exc:
            Study(_files_study(tmp_path, [entry], domain=[[0.0, 2.0], [0.0, 1.0]]),
                  where="mine.yaml")
        msg = str(exc.value)
        assert msg.startswith("mine.yaml: ") and key in msg and problem in msg, msg
    # the segmentation keys are validated by the schema
    with pytest.raises(ConfigError, match="threshold"):
        Study(_files_study(tmp_path, [{**good, "segmentation": {"threshold": "median"}}]))
    with pytest.raises(ConfigError, match="image"):
        Study(_files_study(tmp_path, [{**good, "image": "photo"}]))


def test_reading_three_scans_adds_little_to_reading_the_study(tmp_path):
    """The study reads and segments every image before any job: for three 600 x 300
    scans this must stay small (measured ~0.1 s on a shared core; bound 2 s)."""
    import time

    from skimage import io

    rows, cols = np.mgrid[0:300, 0:600]
    rng = np.random.default_rng(1)
    entries = []
    for k in range(3):
        film = rows > 250 - 60 * np.exp(-((cols - 300 - 20 * k) / 90.0) ** 2)
        img = 8000 + 20000 * film * rng.gamma(4.0, 0.25, film.shape) \
            + 800 * rng.standard_normal(film.shape)
        io.imsave(tmp_path / f"s{k}.tif", np.clip(img, 0, 65535).astype(np.uint16),
                  check_contrast=False)
        entries.append({"path": str(tmp_path / f"s{k}.tif"), "pixel_size": 0.005,
                        "origin": [0.0025, 0.0025]})
    csvs = []
    for k in range(3):
        (tmp_path / f"c{k}.csv").write_text("x,y\n0.0,0.0\n0.5,0.2\n1.0,0.0\n")
        csvs.append({"path": str(tmp_path / f"c{k}.csv")})
    # the analytic stand-in model: these films are not the fsi model's colony (whose
    # placement check would refuse them); what is timed is reading the images
    python = {"forward_model": {"type": "python",
                                "python": {"function": "bayescalib.models.analytic:interface"}}}
    t0 = time.perf_counter()
    Study(deep_merge(_files_study(tmp_path, csvs), python))
    t1 = time.perf_counter()
    Study(deep_merge(_files_study(tmp_path, entries), python))
    t2 = time.perf_counter()
    added = (t2 - t1) - (t1 - t0)
    print(f"three 600 x 300 scans add {added:.3f} s to reading the study")
    assert added < 2.0


@pytest.mark.parametrize("argv, runs", [
    (["snakemake", "--cores", "2"], True),
    (["snakemake", "--unlock"], True),
    (["snakemake", "--cores", "2", "--rerun-incomplete"], True),
    (["snakemake", "-n"], False),
    (["snakemake", "-np", "--cores", "2"], False),
    (["snakemake", "--report", "results/analytic/report.html"], False),
    (["snakemake", "--dry-run"], False),
    (["snakemake", "--lint"], False),
])
def test_which_command_lines_may_run_jobs(argv, runs):
    from bayescalib.study import runs_jobs

    assert runs_jobs(argv) is runs


def test_the_run_lock_holder_is_seen_without_taking_the_lock(tmp_path):
    import subprocess
    import sys
    import time

    from bayescalib.study import run_lock_holder

    assert run_lock_holder(tmp_path) is None
    code = ("import sys, time; from bayescalib.study import hold_run_lock; "
            f"hold_run_lock({str(tmp_path)!r}, 'x'); print('held', flush=True); time.sleep(30)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        holder = run_lock_holder(tmp_path)
        assert holder == f"snakemake pid {proc.pid}"
    finally:
        proc.kill()
        proc.wait()
    time.sleep(0.1)
    assert run_lock_holder(tmp_path) is None  # released by the kernel with the process


def test_the_rkhs_residual_follows_the_surrogate_target_unless_given():
    """measure.rkhs.residual auto: the field residual where the output emulator learns
    it (surrogate.target outputs), the scalar [D] otherwise; a given value stays."""
    def residual(layer):
        return Study(merge_layers([DEFAULT, layer])).config["measure"]["rkhs"]["residual"]

    assert residual({}) == "scalar"
    assert residual({"surrogate": {"target": "outputs"}}) == "field"
    assert residual({"surrogate": {"target": "outputs"},
                     "measure": {"rkhs": {"residual": "scalar"}}}) == "scalar"
    with pytest.raises(ConfigError, match="field_band"):
        Study(merge_layers([DEFAULT, {"measure": {"rkhs": {"field_band": 3}}}]))
