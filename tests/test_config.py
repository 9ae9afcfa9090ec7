"""Configuration loading, validation with defaults, and overrides."""

import pytest

from bayescalib.config import (
    ConfigError,
    apply_overrides,
    deep_merge,
    load_yaml,
    parse_override,
    validate,
)


def test_parse_override_parses_yaml_values():
    assert parse_override("mesh.h=0.02") == (["mesh", "h"], 0.02)
    assert parse_override("material.law=neo_hooke") == (["material", "law"], "neo_hooke")
    assert parse_override("flag=true") == (["flag"], True)
    assert parse_override("xs=[1, 2]") == (["xs"], [1, 2])
    # exponents without a dot are numbers on the command line (YAML 1.1 reads text)
    assert parse_override("physics.attachment.phi=1e-4") == (["physics", "attachment", "phi"],
                                                           1e-4)
    assert parse_override("x=2E5") == (["x"], 2e5)
    assert parse_override("name=e5") == (["name"], "e5")


def test_a_number_that_yaml_reads_as_text_gets_an_error_with_the_fix(tmp_path):
    """In a config file 1e-4 is a string to YAML 1.1 (PyYAML, Snakemake): the error
    names the key and says how to write it so that it reads as a number."""
    from bayescalib.study import Study

    cfg = load_yaml(_write(tmp_path / "c.yaml", "likelihood: {sigma_n: 2e-3}\n"))
    with pytest.raises(ConfigError) as exc:
        Study(cfg, where="c.yaml")
    msg = str(exc.value)
    assert "likelihood.sigma_n" in msg and "'2e-3'" in msg and "write 2.0e-03" in msg
    assert load_yaml(_write(tmp_path / "d.yaml", "x: 2.0e-03\n"))["x"] == 2e-3


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("bad", ["novalue", "=3", "a..b=1", ".a=1"])
def test_parse_override_rejects_malformed(bad):
    with pytest.raises(ConfigError):
        parse_override(bad)


def test_apply_overrides_creates_and_replaces_nested_keys():
    cfg = {"a": {"b": 1}}
    out = apply_overrides(cfg, ["a.b=2", "a.c.d=x"])
    assert out == {"a": {"b": 2, "c": {"d": "x"}}}
    assert cfg == {"a": {"b": 1}}, "the input must not be modified"


def test_apply_overrides_refuses_to_descend_into_a_value():
    with pytest.raises(ConfigError, match="'a.b' is a value"):
        apply_overrides({"a": {"b": 1}}, ["a.b.c=2"])


def test_deep_merge_merges_mappings_and_replaces_the_rest():
    assert deep_merge({"a": {"x": 1, "y": 2}, "l": [1]}, {"a": {"y": 3}, "l": [2]}) == {
        "a": {"x": 1, "y": 3},
        "l": [2],
    }


def test_load_yaml_errors_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="bad.yaml.*not valid YAML"):
        load_yaml(bad)
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="list.yaml.*mapping"):
        load_yaml(lst)


def test_the_configuration_reference_is_in_sync_with_the_schemas():
    """docs/config.md is generated from the schemas; regenerate it with
    ``bayescalib config-reference --out docs/config.md`` after changing a schema."""
    from pathlib import Path

    from bayescalib.config_reference import reference_markdown

    text = reference_markdown()
    doc = Path(__file__).resolve().parents[1] / "docs" / "config.md"
    assert doc.read_text() == text, "docs/config.md is stale: run bayescalib config-reference --out docs/config.md"
    # every key of the validated default study is documented
    from bayescalib.config import load_yaml
    from bayescalib.study import Study

    cfg = Study(load_yaml(doc.parents[1] / "config" / "config.yaml")).config

    def keys(obj, path=""):
        for k, v in obj.items():
            p = f"{path}.{k}" if path else k
            yield p
            if isinstance(v, dict) and k not in ("hidden", "options"):
                yield from keys(v, p)

    missing = [k for k in keys(cfg) if f"`{k}`" not in text]
    assert not missing, missing


def test_a_value_that_fits_none_of_a_keys_forms_says_why_and_what_the_key_is():
    """pixel_size: [4.0, 4.0] in a 2D study (one number for an image, three for a
    volume) was refused as "[4.0, 4.0] is not valid under any of the given schemas"."""
    with pytest.raises(ConfigError) as exc:
        validate({"geometry": {"shape": "scan", "scan": {"path": "a.png",
                                                         "pixel_size": [4.0, 4.0]}}},
                 "fsi", where="mine.yaml")
    msg = str(exc.value)
    assert "key 'geometry.scan.pixel_size'" in msg and "is too short" in msg, msg
    assert "the size of one pixel" in msg and "[dx, dy, dz]" in msg, msg
    assert "not valid under any of the given schemas" not in msg, msg
