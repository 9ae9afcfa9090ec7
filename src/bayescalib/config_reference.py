"""The configuration reference (``docs/config.md``), generated from the JSON schemas.

The schemas under ``bayescalib/schemas`` are the one place where every study key,
its type, default, bounds and meaning are defined (the code trusts the validated
config). :func:`reference_markdown` walks the study schema, following ``$ref`` into
the other schema files, and writes one table per top-level section: key (dotted path,
``[]`` for the items of a list), type or allowed values, default, bounds, and the
schema's description. ``bayescalib config-reference --out docs/config.md`` writes it;
a test keeps the committed file in sync with the schemas.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

__all__ = ["reference_markdown"]

_BOUNDS = (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="),
           ("exclusiveMaximum", "<"), ("minItems", "items >="), ("maxItems", "items <="),
           ("minLength", "length >="), ("pattern", "matches"))


def _load(file: str) -> dict[str, Any]:
    from bayescalib.config import schema

    return schema(file.removesuffix(".schema.yaml"))


def _resolve(node: Mapping[str, Any], file: str) -> tuple[dict[str, Any], str]:
    """``node`` with its ``$ref`` replaced by the target (sibling keys win), and the
    file the result lives in."""
    node = dict(node)
    while "$ref" in node:
        ref = node.pop("$ref")
        target_file, _, pointer = ref.partition("#")
        file = target_file or file
        target: Any = _load(file)
        for part in [p for p in pointer.split("/") if p]:
            target = target[part]
        node = {**target, **node}
    return node, file


def _type(node: Mapping[str, Any]) -> str:
    if "enum" in node:
        return " | ".join(json.dumps(v) for v in node["enum"])
    t = node.get("type")
    if isinstance(t, list):
        return " or ".join(t)
    if t is None and "oneOf" in node:
        return " or ".join(_type(o) if "$ref" not in o else "object" for o in node["oneOf"])
    return t or "any"


def _cell(text: Any) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _rows(node: Mapping[str, Any], path: str, file: str, out: list[tuple[str, ...]],
          required: bool = False) -> None:
    node, file = _resolve(node, file)
    branches = [_resolve(o, file) for o in node.get("oneOf", [])]
    objects = [(b, f) for b, f in branches if "properties" in b]
    default = (f"`{json.dumps(node['default'])}`" if "default" in node
               else "*required*" if required else "")
    bounds = ", ".join(f"{sym} {json.dumps(node[k])}" for k, sym in _BOUNDS if k in node)
    out.append((f"`{path}`", _cell(_type(node)), default, _cell(bounds),
                _cell(node.get("description", ""))))
    for obj, f in ([(node, file)] if "properties" in node else []) + objects:
        for key, sub in obj["properties"].items():
            _rows(sub, f"{path}.{key}", f, out, key in obj.get("required", ()))
    items = node.get("items")
    if isinstance(items, Mapping):
        it, f = _resolve(items, file)
        if "properties" in it or "oneOf" in it:
            _rows(it, f"{path}[]", f, out)


def reference_markdown() -> str:
    """The configuration reference of a study, as Markdown (see the module docstring)."""
    root = _load("study.schema.yaml")
    lines = [
        "# Configuration reference",
        "",
        ("Generated from the JSON schemas in `src/bayescalib/schemas/` by "
        "`bayescalib config-reference --out docs/config.md`; do not edit by hand."),
        "",
        _cell(root.get("description", "")),
        "",
        ("A study is a YAML file layered on top of `config/config.yaml` (mappings merge, "
        "lists and values replace; `likelihood.sigma_n` and `likelihood.sigma_n2` are one "
        "setting, the later layer wins). Keys are dotted paths below; `[]` stands for "
        "every item of a list. Units: lengths mm, stresses Pa, inflow rate mm^2/s, time s."),
        "",
    ]
    for key, sub in root["properties"].items():
        rows: list[tuple[str, ...]] = []
        _rows(sub, key, "study.schema.yaml", rows, key in root.get("required", ()))
        node, _ = _resolve(sub, "study.schema.yaml")
        lines += [f"## `{key}`", ""]
        if node.get("description"):
            lines += [_cell(node["description"]), ""]
        lines += ["| key | type | default | bounds | description |",
                  "|---|---|---|---|---|"]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        lines.append("")
    return "\n".join(lines)
