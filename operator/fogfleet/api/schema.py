"""Structural OpenAPI v3 (what a CRD may hold) from a pydantic model's JSON schema.

``convert`` walks the JSON schema generically and rewrites it into the OpenAPI v3 subset the
API server accepts as *structural* (every node typed, ``$ref`` inlined, no ``anyOf`` except the
int-or-string pattern, no titles or defaults: STYLE.md "Custom resources and status"):

- ``Optional[X]`` (``anyOf: [X, null]``) becomes X with ``nullable: true``, except for enums:
  the API server checks a null against the enum and no enum entry can match it, so an optional
  enum stays non-nullable and the API server prunes a null there (the model then sees the field
  unset, which is what ``None`` means);
- ``base.Quantity`` (``x-kubernetes-int-or-string``) becomes the int-or-string pattern with a
  non-negative quantity ``pattern`` for strings and ``minimum: 0`` for integers;
- ``additionalProperties: false`` is dropped (the API server prunes unknown fields, and rejects
  them under ``kubectl``'s default strict field validation); ``uniqueItems`` (forbidden in
  CRDs) becomes ``x-kubernetes-list-type: set``;
- pairs of integer fields ``minX``/``maxX`` get a CEL rule ``minX <= maxX`` wherever they occur
  (e.g. a scaling spec's ``minReplicas``/``maxReplicas``);
- every field's description is the docstring under it in the model (``FogModel`` reads
  attribute docstrings), with ``Default: X.`` appended where the model has a default.

A construct with no structural equivalent (a true union) raises ``CrdGenerationError`` naming
the field, instead of emitting a schema the API server refuses.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Mapping
from typing import Any

__all__ = ["QUANTITY_PATTERN", "CrdGenerationError", "convert", "deep_update", "node_at"]

Json = dict[str, Any]
QUANTITY_PATTERN = r"^\+?([0-9]+(\.[0-9]*)?|\.[0-9]+)(([KMGTPE]i)|[numkMGTPE]|([eE][+-]?[0-9]+))?$"
"""A non-negative Kubernetes quantity ("500m", "2", "1.5Gi", "1e3"), as base.parse_quantity."""


class CrdGenerationError(ValueError):
    """A model field has no structural OpenAPI equivalent; the message names the field."""


# JSON-schema keywords copied as they are; everything else is either translated below,
# dropped on purpose (_DROPPED) or refused, so a new pydantic construct cannot slip through.
_COPIED = {
    "description", "enum", "format", "maximum", "minimum", "maxLength", "minLength",
    "maxItems", "minItems", "maxProperties", "minProperties", "multipleOf", "pattern",
}  # fmt: skip
_DROPPED = {"title", "default", "examples", "$defs", "additionalProperties", "const", "readOnly"}
_FORMATS = {"int32", "int64", "float", "double", "byte", "date", "date-time", "duration"}


def _resolve(node: Json, defs: Json) -> Json:
    """Inline a ``$ref`` (and a single-item ``allOf``), keeping the referrer's own keywords."""
    while True:
        if "$ref" in node:
            target = defs[str(node["$ref"]).rsplit("/", 1)[-1]]
            node = {**target, **{k: v for k, v in node.items() if k != "$ref"}}
        elif "allOf" in node and len(node["allOf"]) == 1:
            node = {**node["allOf"][0], **{k: v for k, v in node.items() if k != "allOf"}}
        else:
            return node


def _is_int_or_string(branches: list[Json]) -> bool:
    return sorted(str(b.get("type")) for b in branches) == ["integer", "string"] and all(
        set(b) == {"type"} for b in branches
    )


def _int_or_string(node: Json) -> Json:
    out: Json = {
        "anyOf": [{"type": "integer"}, {"type": "string"}],
        "x-kubernetes-int-or-string": True,
        "pattern": node.get("pattern", QUANTITY_PATTERN),
        "minimum": node.get("minimum", 0),
    }
    if "maximum" in node:
        out["maximum"] = node["maximum"]
    if "description" in node:
        out["description"] = node["description"]
    return out


def _default_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return ", ".join(_default_text(v) for v in value)
    return str(value)


def _with_default(description: str, node: Json) -> str:
    """The description plus ``Default: X.`` for a field with a non-empty default (the CRD
    carries no defaults: the models apply them, so ``kubectl explain`` must say them)."""
    description = " ".join(description.split())  # docstrings wrap; kubectl explain re-wraps
    value = node.get("default")
    if value is None or value in ([], {}, "") or "default" in description.lower():
        return description
    return f"{description} Default: {_default_text(value)}."


def convert(node: Json, defs: Json, path: str) -> Json:
    node = _resolve(node, defs)
    if "description" in node:
        node = {**node, "description": _with_default(str(node["description"]), node)}
    where = path or "<root>"
    if "anyOf" in node or "oneOf" in node:
        union: list[Json] = node.get("anyOf") or node.get("oneOf") or []
        branches = [_resolve(b, defs) for b in union]
        rest = {k: v for k, v in node.items() if k not in ("anyOf", "oneOf")}
        nullable = any(b.get("type") == "null" for b in branches)
        branches = [b for b in branches if b.get("type") != "null"]
        if node.get("x-kubernetes-int-or-string") or _is_int_or_string(branches):
            out = _int_or_string(rest)
        elif len(branches) == 1:
            out = convert({**branches[0], **rest}, defs, path)
        else:
            raise CrdGenerationError(f"{where}: a union of {len(branches)} types is not structural")
        if nullable and "enum" not in out:
            out["nullable"] = True
        return out
    if node.get("x-kubernetes-int-or-string"):
        return _int_or_string(node)

    out = {}
    for key, value in node.items():
        if key in _DROPPED:
            continue
        if key == "type":
            if value not in ("object", "array", "string", "integer", "number", "boolean"):
                raise CrdGenerationError(f"{where}: type {value!r} is not structural")
            out["type"] = value
        elif key == "format":
            if value in _FORMATS:
                out["format"] = value
        elif key in _COPIED:
            out[key] = copy.deepcopy(value)
        elif key in ("exclusiveMinimum", "exclusiveMaximum"):
            bound = "minimum" if key == "exclusiveMinimum" else "maximum"
            out[bound], out[key] = value, True  # JSON Schema 2020-12 -> OpenAPI 3.0 form
        elif key == "uniqueItems":
            if value:
                out["x-kubernetes-list-type"] = "set"
        elif key.startswith("x-kubernetes-"):
            out[key] = copy.deepcopy(value)
        elif key in ("properties", "items", "required"):
            pass  # below
        else:
            raise CrdGenerationError(f"{where}: JSON-schema keyword {key!r} has no CRD equivalent")
    if "const" in node and "enum" not in out:
        out["enum"] = [node["const"]]
    if "type" not in out:
        raise CrdGenerationError(f"{where}: no type (Any fields are not structural)")

    if out["type"] == "object":
        props: Json = node.get("properties", {})
        if props:
            out["properties"] = {
                name: convert(sub, defs, f"{path}.{name}" if path else name)
                for name, sub in props.items()
            }
            if node.get("required"):
                out["required"] = sorted(node["required"])
        extra = node.get("additionalProperties")
        if isinstance(extra, dict):
            out["additionalProperties"] = convert(extra, defs, f"{path}.*")
        elif not props:
            out["x-kubernetes-preserve-unknown-fields"] = True
        out.update(_minmax_rules(out))
    elif out["type"] == "array":
        if "items" not in node:
            raise CrdGenerationError(f"{where}: an array needs an item type")
        out["items"] = convert(node["items"], defs, f"{path}[]")
    return out


def _minmax_rules(obj: Json) -> Json:
    """CEL ``minX <= maxX`` for every pair of integer properties named so."""
    props = obj.get("properties", {})
    rules = list(obj.get("x-kubernetes-validations", []))
    for name in sorted(props):
        match = re.fullmatch(r"min([A-Z]\w*)", name)
        upper = f"max{match.group(1)}" if match else ""
        if (
            match
            and props[name].get("type") == "integer"
            and props.get(upper, {}).get("type") == "integer"
        ):
            rules.append(
                {
                    "rule": f"!has(self.{name}) || !has(self.{upper}) || "
                    f"self.{name} <= self.{upper}",
                    "message": f"{name} must not exceed {upper}",
                }
            )
    return {"x-kubernetes-validations": rules} if rules else {}


def deep_update(node: Json, extra: Mapping[str, Any]) -> None:
    for key, value in extra.items():
        if isinstance(value, Mapping) and isinstance(node.get(key), dict):
            deep_update(node[key], value)
        else:
            node[key] = value


def node_at(schema: Json, dotted: str) -> Json:
    node = schema
    for part in dotted.split("."):
        try:
            node = node["properties"][part]
        except KeyError as exc:
            raise CrdGenerationError(f"{dotted}: no such field in the schema") from exc
    return node
