"""Hypothesis strategies that draw fogfleet's custom resources from the CRDs' openAPIV3Schema.

One place for both fuzz suites: the CLI's (tests/integration/test_fuzz_cli.py, no cluster) and
the API server's (e2e/tests/test_faults_fuzz.py). ``custom_resources(kind)`` draws objects that
follow the structural schema (types, enums, bounds, required fields, list-map keys, the
patterns); ``mutated_resources(kind)`` then breaks one thing in such an object: a wrong type, a
missing required field, a value out of range or off its enum, an unknown field. The CEL rules
(``x-kubernetes-validations``) are not modelled, so some schema-shaped objects break them: the
API server refuses those too, and our own validation (``parse_object``) is the judge of "valid".

Pure: no cluster, no kopf; the repository's tests import it (pyproject's ``pythonpath``).
"""

from __future__ import annotations

import copy
import re
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import yaml
from hypothesis import strategies as st

__all__ = [
    "KINDS",
    "Mutation",
    "custom_resources",
    "load_schema",
    "mutated_resources",
    "mutations",
]

ROOT = Path(__file__).resolve().parents[2]
CRDS = ROOT / "crds"
API_VERSION = "fogfleet.io/v1alpha1"
KINDS = {
    "ComputeNode": "computenodes.fogfleet.io.yaml",
    "SoftwareModule": "softwaremodules.fogfleet.io.yaml",
    "RobotFleet": "robotfleets.fogfleet.io.yaml",
}
MAX_ITEMS = 2  # lists stay short: the point is the shapes, not the sizes
MAX_DEPTH = 7

Schema = dict[str, Any]
Obj = dict[str, Any]
Mutation = tuple[str, Callable[[Obj], None]]  # (what was broken, where) and how to break it

QUANTITIES = st.sampled_from(["1", "2", "500m", "250m", "1Gi", "512Mi", "0.5", "2k", "100M"])
NAMES = st.from_regex(r"\A[a-z]([a-z0-9-]{0,10}[a-z0-9])?\Z")


@cache
def load_schema(kind: str) -> Schema:
    """The ``openAPIV3Schema`` of ``kind``'s served version, from crds/."""
    crd = yaml.safe_load((CRDS / KINDS[kind]).read_text())
    version = next(v for v in crd["spec"]["versions"] if v.get("served", True))
    schema: Schema = version["schema"]["openAPIV3Schema"]
    return schema


def _pattern(pattern: str) -> st.SearchStrategy[str] | None:
    try:
        re.compile(pattern)
    except re.error:  # pragma: no cover - an ECMA-only construct
        return None
    return st.from_regex(pattern, fullmatch=True)


def _string(schema: Schema) -> st.SearchStrategy[Any]:
    lo = int(schema.get("minLength", 0))
    hi = min(int(schema.get("maxLength", 24)), max(lo, 24))
    if "pattern" in schema and (strategy := _pattern(schema["pattern"])) is not None:
        return strategy.filter(lambda s: lo <= len(s) <= int(schema.get("maxLength", 10**6)))
    alphabet = st.characters(min_codepoint=97, max_codepoint=122)
    return st.text(alphabet, min_size=max(lo, 1), max_size=max(hi, 1))


def _number(schema: Schema, integer: bool) -> st.SearchStrategy[Any]:
    lo, hi = schema.get("minimum"), schema.get("maximum")
    if integer:
        return st.integers(
            min_value=None if lo is None else int(lo), max_value=None if hi is None else int(hi)
        ).map(lambda n: max(min(n, 10**6), -(10**6)))
    return st.floats(
        min_value=lo,
        max_value=hi,
        exclude_min=bool(schema.get("exclusiveMinimum")),
        allow_nan=False,
        allow_infinity=False,
    ).map(lambda x: round(x, 3) if lo is None or round(x, 3) >= lo else x)


def _array(schema: Schema, depth: int) -> st.SearchStrategy[Any]:
    items = from_schema(schema.get("items", {}), depth + 1)
    lo = int(schema.get("minItems", 0))
    hi = min(int(schema.get("maxItems", MAX_ITEMS)), max(lo, MAX_ITEMS))
    list_type = schema.get("x-kubernetes-list-type")
    if list_type == "map":
        keys = tuple(schema.get("x-kubernetes-list-map-keys", ()))
        return st.lists(
            items, min_size=lo, max_size=hi, unique_by=lambda x: tuple(repr(x.get(k)) for k in keys)
        )
    if list_type == "set":
        return st.lists(items, min_size=lo, max_size=hi, unique_by=repr)
    return st.lists(items, min_size=lo, max_size=hi)


def _forbidden(schema: Schema) -> set[str]:
    """Fields a CEL rule ``!has(self.x)`` refuses (a template's ``nodeSelector`` and such)."""
    rules = (r.get("rule", "") for r in schema.get("x-kubernetes-validations", ()))
    return {m.group(1) for r in rules if (m := re.fullmatch(r"!has\(self\.(\w+)\)", r))}


def _object(schema: Schema, depth: int) -> st.SearchStrategy[Any]:
    forbidden = _forbidden(schema)
    props: dict[str, Schema] = {
        k: v for k, v in schema.get("properties", {}).items() if k not in forbidden
    }
    if not props:
        extra = schema.get("additionalProperties")
        if isinstance(extra, dict) and depth < MAX_DEPTH:
            return st.dictionaries(NAMES, from_schema(extra, depth + 1), max_size=MAX_ITEMS)
        return st.just({})
    required = set(schema.get("required", ()))
    if depth >= MAX_DEPTH:  # deep enough: only what must be there
        props = {k: v for k, v in props.items() if k in required}
    return st.fixed_dictionaries(
        {k: from_schema(v, depth + 1) for k, v in props.items() if k in required},
        optional={k: from_schema(v, depth + 1) for k, v in props.items() if k not in required},
    )


def from_schema(schema: Schema, depth: int = 0) -> st.SearchStrategy[Any]:
    """Values that follow one structural-schema node (CEL rules aside)."""
    if "enum" in schema:
        return st.sampled_from(schema["enum"])
    if schema.get("x-kubernetes-int-or-string"):
        return st.one_of(st.integers(min_value=0, max_value=64), QUANTITIES)
    if "anyOf" in schema and "type" not in schema:
        rest = {k: v for k, v in schema.items() if k != "anyOf"}
        return st.one_of(*(from_schema({**rest, **branch}, depth) for branch in schema["anyOf"]))
    kind = schema.get("type")
    if kind == "object":
        return _object(schema, depth)
    if kind == "array":
        return _array(schema, depth)
    if kind == "string":
        return _string(schema)
    if kind in ("integer", "number"):
        return _number(schema, kind == "integer")
    if kind == "boolean":
        return st.booleans()
    return st.just({})  # x-kubernetes-preserve-unknown-fields and the like


def _spec_schema(kind: str) -> Schema:
    spec: Schema = load_schema(kind)["properties"]["spec"]
    return spec


def custom_resources(kind: str) -> st.SearchStrategy[Obj]:
    """Whole ``kind`` objects whose spec follows the CRD's structural schema."""
    return st.builds(
        lambda name, spec: {
            "apiVersion": API_VERSION,
            "kind": kind,
            "metadata": {"name": name},
            "spec": spec,
        },
        NAMES,
        from_schema(_spec_schema(kind)),
    )


def _wrong_type(schema: Schema) -> Any:
    kind = schema.get("type")
    if schema.get("x-kubernetes-int-or-string"):
        return {"not": "a quantity"}
    return {
        "object": 7,
        "array": "x",
        "string": ["x"],
        "integer": "many",
        "number": "many",
        "boolean": "perhaps",
    }.get(str(kind), [1])


def _setter(path: list[Any], value: Any) -> Callable[[Obj], None]:
    def apply(obj: Obj) -> None:
        target: Any = obj
        for step in path[:-1]:
            target = target[step]
        target[path[-1]] = value

    return apply


def _deleter(path: list[Any]) -> Callable[[Obj], None]:
    def apply(obj: Obj) -> None:
        target: Any = obj
        for step in path[:-1]:
            target = target[step]
        del target[path[-1]]

    return apply


def _dotted(path: list[Any]) -> str:
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")


def mutations(obj: Obj, schema: Schema, path: list[Any] | None = None) -> list[Mutation]:
    """Every single break this object allows, each named by its field path."""
    path = path or []
    found: list[Mutation] = []
    if path:  # the root (the object itself) keeps its shape so the kind stays known
        found.append((f"wrong type at {_dotted(path)}", _setter(path, _wrong_type(schema))))
    if "enum" in schema:
        found.append((f"off the enum at {_dotted(path)}", _setter(path, "no-such-value")))
    if "maximum" in schema:
        found.append((f"above maximum at {_dotted(path)}", _setter(path, schema["maximum"] + 1)))
    if "minimum" in schema:
        found.append((f"below minimum at {_dotted(path)}", _setter(path, schema["minimum"] - 1)))
    if isinstance(obj, dict) and schema.get("properties"):
        props = schema["properties"]
        found.append(
            (
                f"unknown field in {_dotted(path) or '<root>'}",
                _setter([*path, "fuzzUnknownField"], 1),
            )
        )
        for key in sorted(_forbidden(schema)):
            found.append(
                (
                    f"forbidden field {_dotted([*path, key])}",
                    _setter([*path, key], {} if props[key].get("type") == "object" else 1),
                )
            )
        for key, value in obj.items():
            if key not in props:
                continue
            if key in schema.get("required", ()):
                found.append((f"missing required {_dotted([*path, key])}", _deleter([*path, key])))
            found.extend(mutations(value, props[key], [*path, key]))
    if isinstance(obj, list) and "items" in schema:
        for i, item in enumerate(obj):
            found.extend(mutations(item, schema["items"], [*path, i]))
    return found


@st.composite
def mutated_resources(draw: st.DrawFn, kind: str) -> tuple[Obj, str]:
    """A schema-shaped ``kind`` object with one thing broken, and what was broken."""
    obj = draw(custom_resources(kind))
    spec_only = {"type": "object", "properties": {"spec": _spec_schema(kind)}}
    what, apply = draw(st.sampled_from(mutations(obj, spec_only)))
    broken = copy.deepcopy(obj)
    apply(broken)
    return broken, what
