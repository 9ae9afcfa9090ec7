"""Configuration: loading, schema validation with defaults, and dotted overrides.

Every configuration (a whole study, or one section such as the forward model)
is validated against a JSON schema shipped with the package
(``bayescalib/schemas/*.yaml``). Validation fills in the schema defaults, so
the rest of the code can rely on every documented key being present.

Errors never surface as a traceback from deep inside: they are raised as
:class:`ConfigError` whose message names the offending key by its dotted path
(``forward_model.fsi.mesh.h_interface``), the bad value, and what was expected.
Unknown keys are reported with the closest known key as a suggestion.

Schemas may reference each other by file name (``$ref: fsi.schema.yaml``), so
that each section has one home.
"""

from __future__ import annotations

import copy
import difflib
import json
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

__all__ = [
    "ConfigError",
    "apply_overrides",
    "deep_merge",
    "defaults",
    "load_yaml",
    "merge_layers",
    "parse_override",
    "schema",
    "set_dotted",
    "sorted_keys",
    "validate",
]


class ConfigError(ValueError):
    """A configuration is malformed; the message names the key and the problem."""


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML (or JSON) mapping from ``path``.

    Raises
    ------
    ConfigError
        If the file does not exist, is not valid YAML, or is not a mapping.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file '{p}' does not exist")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file '{p}' is not valid YAML: {exc}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"config file '{p}' must hold a mapping of keys to values, got {type(data).__name__}"
        )
    return data


def set_dotted(cfg: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``cfg["a"]["b"]["c"] = value`` for ``dotted = "a.b.c"`` in place, creating
    missing sections; a path through a value is a :class:`ConfigError` naming it."""
    parts = dotted.split(".")
    node = cfg
    for i, part in enumerate(parts[:-1]):
        if node.get(part) is None:
            node[part] = {}
        nxt = node[part]
        if not isinstance(nxt, dict):
            raise ConfigError(f"override '{dotted}': '{'.'.join(parts[: i + 1])}' is a value, "
                              "not a section")
        node = nxt
    node[parts[-1]] = value


def _schema_dir():
    return resources.files("bayescalib") / "schemas"


@cache
def _load_schema_file(name: str) -> dict[str, Any]:
    text = (_schema_dir() / name).read_text()
    # libyaml's loader where PyYAML has it: the schemas are read on every Snakefile parse
    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


@cache
def _registry():
    from referencing import Registry, Resource
    from referencing.jsonschema import DRAFT7

    resources_ = []
    for entry in _schema_dir().iterdir():
        if entry.name.endswith(".schema.yaml"):
            contents = _load_schema_file(entry.name)
            resources_.append((entry.name, Resource(contents=contents, specification=DRAFT7)))
    return Registry().with_resources(resources_)


def load_schemas() -> None:
    """Read and compile the packaged schemas now (they are cached per process): a
    process that forks many validating children, the job server, calls it once."""
    _registry()
    _validator_class()


def schema(name: str) -> dict[str, Any]:
    """The schema ``name`` (e.g. ``"fsi"`` for ``fsi.schema.yaml``)."""
    return copy.deepcopy(_load_schema_file(f"{name}.schema.yaml"))


def schema_limits(schema_name: str, dotted: str) -> tuple[float | None, float | None]:
    """The numeric range the schema ``schema_name`` allows for the dotted key (its
    ``minimum``/``exclusiveMinimum`` and ``maximum``/``exclusiveMaximum``, None where it
    sets none or has no such key), e.g. ``schema_limits("fsi", "material.nu")`` is
    (-1, 0.5): the limits of the model itself, which no prior can widen."""
    node: Any = _load_schema_file(f"{schema_name}.schema.yaml")
    for part in dotted.split("."):
        props = node.get("properties") if isinstance(node, dict) else None
        if not isinstance(props, dict) or part not in props:
            return None, None
        node = props[part]
    if not isinstance(node, dict):
        return None, None
    lo = node.get("minimum", node.get("exclusiveMinimum"))
    hi = node.get("maximum", node.get("exclusiveMaximum"))
    return (None if lo is None else float(lo)), (None if hi is None else float(hi))


def defaults(schema_name: str, definition: str) -> dict[str, Any]:
    """The schema's default of each property of ``#/definitions/<definition>`` in schema
    ``schema_name`` that has one (a deep copy), e.g. ``defaults("inference",
    "surrogate")["restarts"]``: what a library function taking one such setting as a
    keyword falls back to, so that the default lives in the schema only."""
    props = _load_schema_file(f"{schema_name}.schema.yaml")["definitions"][definition]
    return {k: copy.deepcopy(v["default"]) for k, v in props["properties"].items()
            if isinstance(v, dict) and "default" in v}


def _validator_class():
    from jsonschema import Draft7Validator, ValidationError, validators

    base_props = Draft7Validator.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, sch):
        if isinstance(instance, dict):
            for key, sub in properties.items():
                if isinstance(sub, dict) and "default" in sub and key not in instance:
                    instance[key] = copy.deepcopy(sub["default"])
        yield from base_props(validator, properties, instance, sch)

    def anchored_pattern(validator, pattern, instance, sch):
        # Python's re lets "$" match before a final newline, so "^name$" would accept
        # "name\n" (a study name, a folder, with a newline): anchor at the very end.
        if not validator.is_type(instance, "string"):
            return
        rx = pattern[:-1] + r"\Z" if pattern.endswith("$") and not pattern.endswith("\\$") \
            else pattern
        if not re.search(rx, instance):
            yield ValidationError(f"{instance!r} does not match {pattern!r}")

    return validators.extend(Draft7Validator, {"properties": set_defaults,
                                               "pattern": anchored_pattern})


def _path_str(path: Iterable[Any]) -> str:
    parts: list[str] = []
    for p in path:
        if isinstance(p, int):
            parts.append(f"[{p}]")
        else:
            parts.append(("." if parts else "") + str(p))
    return "".join(parts) or "<top level>"


def _format_error(err, where: str) -> str:
    key = _path_str(err.absolute_path)
    prefix = f"{where}: " if where else ""
    if err.validator == "additionalProperties":
        allowed = sorted((err.schema.get("properties") or {}).keys())
        extra = (sorted(set(err.instance) - set(allowed), key=repr)
                 if isinstance(err.instance, dict) else [])
        msgs = []
        for e in extra:
            full = e if key == "<top level>" else f"{key}.{e}"
            # YAML keys may be numbers, booleans or null: only names get a suggestion
            close = difflib.get_close_matches(e, allowed, n=1) if isinstance(e, str) else []
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            msgs.append(f"unknown key '{full}'{hint}; allowed here: {', '.join(allowed)}")
        return prefix + "; ".join(msgs)
    if err.validator == "required":
        return prefix + f"missing required key under '{key}': {err.message}"
    if err.validator == "enum":
        return (
            prefix
            + f"key '{key}': value {err.instance!r} is not one of {err.validator_value}"
        )
    if err.validator in {"minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"}:
        return prefix + f"key '{key}': value {err.instance!r} is out of range ({err.message})"
    if err.validator == "type":
        hint = ""
        expected = err.validator_value if isinstance(err.validator_value, list) \
            else [err.validator_value]
        if isinstance(err.instance, str) and {"number", "integer"} & set(expected) \
                and _numeric_text(err.instance):
            hint = (f": YAML reads {err.instance} as text; write "
                    f"{_yaml_float(float(err.instance))} (a dot in the number and a sign "
                    "in the exponent)")
        return (
            prefix
            + f"key '{key}': value {err.instance!r} has the wrong type (expected "
            f"{err.validator_value}){hint}"
        )
    if err.validator in {"oneOf", "anyOf"} and err.context:
        # "is not valid under any of the given schemas" says nothing of the forms: each
        # form's objection, and the key's description (e.g. pixel_size: one number for an
        # image, three for a volume)
        forms = "; ".join(dict.fromkeys(e.message for e in err.context))
        desc = str(err.schema.get("description") or "").strip()
        return (prefix + f"key '{key}': value {err.instance!r} fits none of its allowed "
                f"forms ({forms})" + (f"; {key}: {desc}" if desc else ""))
    return prefix + f"key '{key}': {err.message}"


def validate(config: Mapping[str, Any], schema_name: str, *, where: str = "") -> dict[str, Any]:
    """Validate ``config`` against schema ``schema_name`` and fill in defaults.

    Parameters
    ----------
    config
        The configuration mapping (not modified).
    schema_name
        Name of a packaged schema, e.g. ``"study"`` or ``"fsi"``.
    where
        Prefix for error messages (e.g. the config file name).

    Returns
    -------
    dict
        A deep copy of ``config`` with all defaults filled in.

    Raises
    ------
    ConfigError
        Naming the first offending key (all problems are listed, one per line).
    """
    prefix = f"{where}: " if where else ""
    if not isinstance(config, Mapping):
        raise ConfigError(
            f"{prefix}the configuration must be a mapping of keys to values, "
            f"got {type(config).__name__}"
        )
    cfg = copy.deepcopy(dict(config))
    cls = _validator_class()
    validator = cls(_load_schema_file(f"{schema_name}.schema.yaml"), registry=_registry())
    # Fill defaults first (a validation pass), then collect errors on the filled config.
    errors = sorted(validator.iter_errors(cfg), key=lambda e: list(map(str, e.absolute_path)))
    lines: list[str] = []
    for e in errors:
        msg = _format_error(e, where)
        if msg not in lines:
            lines.append(msg)
    # JSON schema lets NaN pass every range check and has no notion of infinity
    for path, value in _non_finite(cfg):
        lines.append(prefix + f"key '{_path_str(path)}': value {value!r} is not a finite number")
    if lines:
        raise ConfigError("\n".join(lines))
    return cfg


def _non_finite(obj: Any, path: tuple = ()) -> Iterable[tuple[tuple, float]]:
    """Paths of the NaN and infinite numbers in a nested config."""
    if isinstance(obj, float) and not math.isfinite(obj):
        yield path, obj
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            yield from _non_finite(v, (*path, k))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from _non_finite(v, (*path, i))


_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _numeric_text(text: str) -> bool:
    """True for a number written as YAML 1.2 reads it (``1e-4``, ``2E5``, ``-3.``) that
    YAML 1.1 (PyYAML, Snakemake) reads as a string."""
    return bool(_NUMBER.match(text.strip()))


def _yaml_float(value: float) -> str:
    """``value`` written so that YAML 1.1 reads a float (``1.0e-04``)."""
    mantissa, _, exponent = f"{value:.6e}".partition("e")
    mantissa = mantissa.rstrip("0")
    mantissa += "0" if mantissa.endswith(".") else ""
    return f"{mantissa}e{exponent}"


def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse ``KEY=VALUE`` with a dotted key; the value is parsed as YAML.

    ``mesh.h_interface=0.02`` -> (["mesh", "h_interface"], 0.02);
    ``material.law=neo_hooke`` -> (["material", "law"], "neo_hooke").
    """
    if "=" not in text:
        raise ConfigError(f"override '{text}' must have the form KEY=VALUE")
    key, _, raw = text.partition("=")
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"override '{text}': empty key or key part")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    if isinstance(value, str) and _numeric_text(value):  # 1e-4: a number on the command line
        value = float(value)
    return key.split("."), value


def apply_overrides(config: Mapping[str, Any], overrides: Iterable[str]) -> dict[str, Any]:
    """Return a copy of ``config`` with dotted ``KEY=VALUE`` overrides applied."""
    cfg = copy.deepcopy(dict(config))
    for text in overrides:
        parts, value = parse_override(text)
        set_dotted(cfg, ".".join(parts), value)
    return cfg


def deep_merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """Recursively merge ``update`` into a copy of ``base`` (mappings merge, others replace)."""
    out = copy.deepcopy(dict(base))
    for k, v in update.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


#: keys of one section that say the same thing in two ways: a layer that sets one of
#: them replaces whatever earlier layers set for any of them
EXCLUSIVE_KEYS: dict[str, tuple[str, ...]] = {"likelihood": ("sigma_n", "sigma_n2")}


def round_smc(smc: Mapping[str, Any], active: Mapping[str, Any]) -> dict[str, Any]:
    """The SMC settings of an active-design round: the validated ``smc`` section with
    the round overrides of ``design.active.smc`` (n_particles, n_rej, zeta) applied.
    Equal to ``smc`` when there are none (the last round's particles are then the
    study's posterior)."""
    return {**dict(smc), **dict(active.get("smc") or {})}


def merge_layers(layers: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Merge config layers in order, later layers winning (:func:`deep_merge`).

    Keys that say the same thing in two ways (:data:`EXCLUSIVE_KEYS`, e.g. the noise as
    ``likelihood.sigma_n`` or ``likelihood.sigma_n2``) are one setting: a layer that
    gives one of them drops what earlier layers gave for the others, so a study that
    sets ``sigma_n`` on top of defaults that set ``sigma_n2`` just works.
    """
    out: dict[str, Any] = {}
    for layer in layers:
        layer = dict(layer or {})
        for section, keys in EXCLUSIVE_KEYS.items():
            given = layer.get(section)
            if isinstance(given, Mapping) and any(k in given for k in keys) \
                    and isinstance(out.get(section), Mapping):
                out[section] = {k: v for k, v in out[section].items() if k not in keys}
        out = deep_merge(out, layer)
    return out


def sorted_keys(obj: Any) -> Any:
    """``obj`` with every mapping's keys in sorted order (lists keep their order).

    Rule params are compared by their text, so the order of keys would otherwise
    decide whether Snakemake reruns a job: with sorted keys, reordering a YAML file or
    layering it differently reruns nothing."""
    if isinstance(obj, Mapping):
        return {k: sorted_keys(obj[k]) for k in sorted(obj, key=str)}
    if isinstance(obj, list):
        return [sorted_keys(v) for v in obj]
    return obj


def canonical_json(obj: Any) -> str:
    """Stable JSON text for hashing/caching (sorted keys, no whitespace)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))
