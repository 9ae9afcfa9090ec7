"""Property-based fuzzing of the study configuration (hypothesis).

Starting from valid studies (the analytic test study and the shipped default),
one or more keys are changed: a value of a wrong type, a missing key, a value
out of range (including NaN and infinities), an unknown key (also non-string
keys, as YAML allows), or a random value of an allowed type. Every case must
end either in a valid :class:`Study` (whose design the Snakefile can then ask
for) or in a :class:`ConfigError` naming the key -- never another exception.

The schema is walked to find the mutation sites, so new keys are fuzzed
without touching this file. Deterministic (``derandomize=True``); the number of
examples per test is set so that the file runs in a few seconds.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayescalib.config import ConfigError, _load_schema_file, _path_str, deep_merge, load_yaml
from bayescalib.study import Study

ROOT = Path(__file__).resolve().parents[1]
BASES = {
    "analytic": yaml.safe_load((Path(__file__).parent / "data" / "analytic_study.yaml").read_text()),
    "default": load_yaml(ROOT / "config" / "config.yaml"),
    "uncertain": deep_merge(load_yaml(ROOT / "config" / "config.yaml"),
                            load_yaml(ROOT / "config" / "uncertain_inflow.yaml")),
}
FILLED = {name: Study(cfg).config for name, cfg in BASES.items()}

FUZZ = settings(max_examples=300, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
#: examples run per test, for the report (hypothesis may stop early when exhausted)
CASES: dict[str, int] = {}


# ----------------------------------------------------------------------- schema walk
def _resolve(node, base):
    while isinstance(node, dict) and "$ref" in node:
        file, _, frag = node["$ref"].partition("#")
        base = file or base
        doc = _load_schema_file(base)
        for part in (p for p in frag.split("/") if p):
            doc = doc[part]
        node = doc
    return node, base


def _sites(value, node, base="study.schema.yaml", path=()):
    """(path, value, schema node) for every value of a config the schema describes."""
    node, base = _resolve(node, base)
    yield path, value, node
    if isinstance(value, dict) and isinstance(node, dict):
        props = node.get("properties", {})
        for k, v in value.items():
            if k in props:
                yield from _sites(v, props[k], base, (*path, k))
    elif isinstance(value, list) and isinstance(node, dict) and isinstance(node.get("items"), dict):
        for i, v in enumerate(value):
            yield from _sites(v, node["items"], base, (*path, i))


SITES = {name: list(_sites(cfg, _load_schema_file("study.schema.yaml"))) for name, cfg in
         FILLED.items()}


def _json_types(v) -> set[str]:
    if v is None:
        return {"null"}
    if isinstance(v, bool):
        return {"boolean"}
    if isinstance(v, int):
        return {"integer", "number"}
    if isinstance(v, float):
        return {"number", "integer"} if v.is_integer() else {"number"}
    if isinstance(v, str):
        return {"string"}
    if isinstance(v, list):
        return {"array"}
    if isinstance(v, dict):
        return {"object"}
    return {"?"}


def _allowed(node) -> set[str] | None:
    t = node.get("type")
    if t is None:
        return None
    return {t} if isinstance(t, str) else set(t)


def _wrong_type(node, v) -> bool:
    if "enum" in node:
        return not any(v == e and type(v) is type(e) for e in node["enum"])
    allowed = _allowed(node)
    return allowed is not None and not (_json_types(v) & allowed)


def _set(cfg, path, value):
    out = copy.deepcopy(cfg)
    node = out
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return out


def _delete(cfg, path):
    out = copy.deepcopy(cfg)
    node = out
    for p in path[:-1]:
        node = node[p]
    del node[path[-1]]
    return out


def _exercise(cfg):
    """What the Snakefile does with a study: construct it, then ask the DAG's questions.

    Returns the ConfigError raised, or None for a valid study.
    """
    try:
        study = Study(cfg, where="config.yaml")
    except ConfigError as exc:
        assert str(exc).strip(), "empty ConfigError message"
        return exc
    study.forward_section()
    study.ground_truth()
    study.prior_centre()
    assert study.root.endswith(study.name)
    if study.n_sobol <= 20_000:
        assert set(study.point(study.n_sobol - 1)) == set(study.targets())
    return None


def _count(name):
    CASES[name] = CASES.get(name, 0) + 1


# ----------------------------------------------------------------------- strategies
ANY_VALUE = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**12), 10**12),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.lists(st.one_of(st.integers(-5, 5), st.floats(-10, 10), st.text(max_size=3)), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)
BASE = st.sampled_from(sorted(FILLED))


def _site(base, predicate):
    return st.sampled_from([s for s in SITES[base] if s[0] and predicate(*s)])


@FUZZ
@given(data=st.data())
def test_wrong_type_is_a_config_error_naming_the_key(data):
    base = data.draw(BASE)
    path, _, node = data.draw(_site(base, lambda p, v, n: "enum" in n or _allowed(n) is not None))
    value = data.draw(ANY_VALUE.filter(lambda v: _wrong_type(node, v)))
    _count("wrong type")
    exc = _exercise(_set(FILLED[base], path, value))
    assert exc is not None, f"{_path_str(path)} = {value!r} was accepted"
    assert _path_str(path) in str(exc), (path, value, str(exc))


def _out_of_range(node, draw):
    allowed = _allowed(node) or set()
    if allowed & {"number", "integer"}:
        bad = [math.nan, math.inf, -math.inf] if "integer" not in allowed else []
        if "minimum" in node:
            bad.append(node["minimum"] - draw(st.integers(1, 10**6)))
        if "exclusiveMinimum" in node:
            bad.append(node["exclusiveMinimum"] - draw(st.integers(0, 10**6)))
        if "maximum" in node:
            bad.append(node["maximum"] + draw(st.integers(1, 10**6)))
        if "exclusiveMaximum" in node:
            bad.append(node["exclusiveMaximum"] + draw(st.integers(0, 10**6)))
        if "integer" not in allowed:
            bad = [float(b) if not isinstance(b, float) else b for b in bad]
        if not bad:
            return None
        return draw(st.sampled_from(bad))
    if "array" in allowed and ("minItems" in node or "maxItems" in node):
        sizes = []
        if node.get("minItems", 0) > 0:
            sizes.append(node["minItems"] - 1)
        if "maxItems" in node:
            sizes.append(node["maxItems"] + 1)
        n = draw(st.sampled_from(sizes))
        item = node.get("items", {})
        sample = {"number": 1.0, "integer": 2, "string": "x"}.get(
            (_allowed(item) or {"?"}).pop() if isinstance(item, dict) else "?",
            item.get("enum", [None])[0] if isinstance(item, dict) and "enum" in item else 1.0)
        return [sample] * n
    if "string" in allowed and ("pattern" in node or "minLength" in node):
        return draw(st.sampled_from(["", "has space", "a/b", "../up", "x\n", "é"]
                                    if "pattern" in node else [""]))
    return None


def _has_range(p, v, n):
    return any(k in n for k in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum",
                                "minItems", "maxItems", "pattern", "minLength")) or (
        isinstance(v, float) and not isinstance(v, bool))


@FUZZ
@given(data=st.data())
def test_out_of_range_is_a_config_error_naming_the_key(data):
    base = data.draw(BASE)
    path, value, node = data.draw(_site(base, _has_range))
    bad = _out_of_range(node, data.draw)
    if bad is None and isinstance(value, float):
        bad = data.draw(st.sampled_from([math.nan, math.inf, -math.inf]))
    if bad is None:
        return
    _count("out of range")
    exc = _exercise(_set(FILLED[base], path, bad))
    assert exc is not None, f"{_path_str(path)} = {bad!r} was accepted"
    assert _path_str(path) in str(exc), (path, bad, str(exc))


KEYS = st.one_of(st.text(min_size=1, max_size=12), st.integers(-5, 5), st.booleans(), st.none(),
                 st.floats(allow_nan=False, min_value=-5, max_value=5))


def _closed(p, v, n):
    return isinstance(v, dict) and n.get("additionalProperties") is False


@FUZZ
@given(data=st.data())
def test_unknown_key_is_a_config_error_naming_it(data):
    base = data.draw(BASE)
    candidates = [s for s in SITES[base] if _closed(*s)]
    path, _, node = data.draw(st.sampled_from(candidates))
    key = data.draw(KEYS.filter(lambda k: k not in node.get("properties", {})))
    _count("unknown key")
    cfg = copy.deepcopy(FILLED[base])
    target = cfg
    for p in path:
        target = target[p]
    target[key] = data.draw(ANY_VALUE)
    exc = _exercise(cfg)
    assert exc is not None, f"unknown key {key!r} under {_path_str(path)} was accepted"
    full = str(key) if not path else f"{_path_str(path)}.{key}"
    assert f"unknown key '{full}'" in str(exc), (path, key, str(exc))


def _required_keys(node, value) -> set:
    req = set(node.get("required", []))
    for cond in node.get("allOf", []):  # if/then conditional requirements (priors)
        const = cond.get("if", {}).get("properties", {})
        if all(isinstance(value, dict) and value.get(k) == c.get("const") for k, c in const.items()):
            req |= set(cond.get("then", {}).get("required", []))
    return req


@FUZZ
@given(data=st.data())
def test_missing_key_is_valid_or_a_config_error_naming_it(data):
    base = data.draw(BASE)
    path, _, _ = data.draw(_site(base, lambda p, v, n: isinstance(p[-1], str)))
    parent_path = path[:-1]
    parent = FILLED[base]
    for p in parent_path:
        parent = parent[p]
    parent_node = next(n for p, v, n in SITES[base] if p == parent_path)
    _count("missing key")
    exc = _exercise(_delete(FILLED[base], path))
    if path[-1] in _required_keys(parent_node, parent):
        assert exc is not None, f"required key {_path_str(path)} may be left out?"
    if exc is not None:
        msg = str(exc)
        assert f"'{path[-1]}'" in msg or _path_str(path) in msg or str(path[-1]) in msg, (path, msg)



def _valid_typed(node, draw):
    """A random value of an allowed type (in range or not)."""
    if "enum" in node:
        return draw(st.sampled_from(node["enum"]))
    allowed = sorted(_allowed(node) or [])
    kind = draw(st.sampled_from(allowed))
    if kind == "integer":
        return draw(st.integers(-3, 5000))
    if kind == "number":
        return draw(st.one_of(st.floats(-1e6, 1e6), st.sampled_from([0.0, -0.0, 1e-300, 1e300])))
    if kind == "string":
        return draw(st.text(max_size=10))
    if kind == "boolean":
        return draw(st.booleans())
    if kind == "null":
        return None
    if kind == "array":
        item = node.get("items", {})
        typed = isinstance(item, dict) and ("enum" in item or _allowed(item))
        return [_valid_typed(item, draw) if typed else 1.0
                for _ in range(draw(st.integers(0, 4)))]
    if kind == "object":
        return draw(st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))
    return None


@FUZZ
@given(data=st.data())
def test_any_value_of_an_allowed_type_is_valid_or_a_config_error(data):
    base = data.draw(BASE)
    path, _, node = data.draw(_site(base, lambda p, v, n: "enum" in n or _allowed(n) is not None))
    value = _valid_typed(node, data.draw)
    _count("allowed type, any value")
    _exercise(_set(FILLED[base], path, value))


@FUZZ
@given(data=st.data())
def test_several_changes_at_once(data):
    base = data.draw(BASE)
    cfg = copy.deepcopy(FILLED[base])
    changed = []
    for _ in range(data.draw(st.integers(2, 4))):
        sites = [s for s in _sites(cfg, _load_schema_file("study.schema.yaml")) if s[0]]
        path, _, node = data.draw(st.sampled_from(sites))
        how = data.draw(st.sampled_from(["value", "delete", "any"]))
        if how == "delete" and isinstance(path[-1], str):
            cfg = _delete(cfg, path)
        elif how == "value" and ("enum" in node or _allowed(node)):
            cfg = _set(cfg, path, _valid_typed(node, data.draw))
        else:
            cfg = _set(cfg, path, data.draw(ANY_VALUE))
        changed.append(path)
    _count("several changes")
    exc = _exercise(cfg)
    if exc is not None:
        msg = str(exc)
        # an element of a list may be refused as part of its list (e.g. duplicates in a
        # list of unique names): then the message names the list
        assert any(str(p[-1]) in msg or _path_str(p) in msg
                   or (isinstance(p[-1], int) and _path_str(p[:-1]) in msg) for p in changed) or \
            "parameters" in msg or "observations" in msg, (changed, msg)


@pytest.mark.parametrize("config", [None, [], [1, 2], "study: x", 3, {1: 2}, {None: 1}])
def test_a_config_that_is_no_mapping_of_names(config):
    with pytest.raises(ConfigError):
        Study(config)
