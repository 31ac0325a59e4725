"""A small validator for the schema subsets fogfleet uses, for tests (no jsonschema needed).

``dialect="crd"`` follows the API server's structural-schema semantics: a field the schema does
not describe is an error (what ``kubectl``'s default strict field validation reports; without
it the field would be silently pruned), null is kept where ``nullable`` and pruned elsewhere
(as the API server's PruneNonNullableNullsWithoutDefaults), ``x-kubernetes-int-or-string``
accepts integers and strings, ``pattern`` applies to strings only and ``minimum`` to numbers
only, and list-type map/set entries must be unique. Root ``metadata`` belongs to the API
server and is not checked. CEL rules (``x-kubernetes-validations``) are not evaluated here: the
real API server does that in e2e.

``dialect="jsonschema"`` is the draft-07 subset of charts/fogfleet/values.schema.json: type
lists, ``additionalProperties`` true by default, local ``$ref``.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["validate"]

_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, int | float) and not isinstance(v, bool),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


def validate(value: Any, schema: dict[str, Any], *, dialect: str = "crd") -> list[str]:
    """Every violation as ``path: reason`` (empty list: valid)."""
    errors: list[str] = []
    _check(value, schema, "", errors, dialect, schema)
    return errors


def _resolve(schema: dict[str, Any], root: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        node: Any = root
        for part in str(schema["$ref"]).lstrip("#/").split("/"):
            node = node[part]
        schema = node
    return schema


def _check(
    value: Any, schema: dict[str, Any], path: str, errors: list[str], dialect: str, root: Any
) -> None:
    schema = _resolve(schema, root)
    where = path or "<root>"
    if value is None and dialect == "crd":
        # nullable: null is kept and valid (an enum would reject it; crdgen never emits that);
        # otherwise the API server prunes the null before validation.
        if schema.get("nullable") and "enum" in schema:
            errors.append(f"{where}: null is not one of {schema['enum']}")
        return
    if schema.get("x-kubernetes-int-or-string"):
        if not (_TYPES["integer"](value) or _TYPES["string"](value)):
            errors.append(f"{where}: must be an integer or a string, not {type(value).__name__}")
            return
    elif "type" in schema:
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if not any(_TYPES[t](value) for t in types):
            errors.append(f"{where}: must be of type {'/'.join(types)}, not {type(value).__name__}")
            return
    if "enum" in schema and value not in schema["enum"]:
        errors.append(f"{where}: {value!r} is not one of {schema['enum']}")
    if isinstance(value, str):
        if "pattern" in schema and not re.search(schema["pattern"], value):
            errors.append(f"{where}: {value!r} does not match {schema['pattern']}")
        if len(value) < schema.get("minLength", 0):
            errors.append(f"{where}: shorter than {schema['minLength']}")
        if "maxLength" in schema and len(value) > schema["maxLength"]:
            errors.append(f"{where}: longer than {schema['maxLength']}")
    elif _TYPES["number"](value):
        if "minimum" in schema and (
            value < schema["minimum"]
            or (schema.get("exclusiveMinimum") is True and value == schema["minimum"])
        ):
            errors.append(f"{where}: {value} is less than the minimum {schema['minimum']}")
        if "maximum" in schema and (
            value > schema["maximum"]
            or (schema.get("exclusiveMaximum") is True and value == schema["maximum"])
        ):
            errors.append(f"{where}: {value} is more than the maximum {schema['maximum']}")
    elif isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            errors.append(f"{where}: needs at least {schema['minItems']} items")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            errors.append(f"{where}: has more than {schema['maxItems']} items")
        list_type = schema.get("x-kubernetes-list-type")
        keys = schema.get("x-kubernetes-list-map-keys", [])
        seen: set[str] = set()
        for k, item in enumerate(value if list_type in ("map", "set") else []):
            key = repr([item.get(n) for n in keys]) if list_type == "map" else repr(item)
            if key in seen:
                errors.append(f"{path}[{k}]: duplicate value {key}")
            seen.add(key)
        if "items" in schema:
            for k, item in enumerate(value):
                _check(item, schema["items"], f"{path}[{k}]", errors, dialect, root)
    elif isinstance(value, dict):
        _check_object(value, schema, path, errors, dialect, root)


def _check_object(
    value: dict[str, Any],
    schema: dict[str, Any],
    path: str,
    errors: list[str],
    dialect: str,
    root: Any,
) -> None:
    props = schema.get("properties", {})
    for name in schema.get("required", []):
        if name not in value:
            errors.append(f"{path + '.' if path else ''}{name}: required field is missing")
    extra = schema.get("additionalProperties", dialect != "crd")
    open_object = dialect == "crd" and schema.get("x-kubernetes-preserve-unknown-fields")
    for name, sub in value.items():
        child = f"{path}.{name}" if path else name
        if dialect == "crd" and not path and name == "metadata":
            continue
        if name in props:
            _check(sub, props[name], child, errors, dialect, root)
        elif isinstance(extra, dict):
            _check(sub, extra, child, errors, dialect, root)
        elif not (extra is True or open_object):
            errors.append(f"{child}: unknown field")
