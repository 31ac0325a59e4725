"""Read CR YAML (files or folders) into typed objects, with errors that name object and field."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from fogfleet.errors import InvalidSpec

from .kubeyaml import read_documents
from .v1alpha1.computenode import ComputeNode
from .v1alpha1.robotfleet import RobotFleet
from .v1alpha1.softwaremodule import SoftwareModule

__all__ = ["Catalog", "describe_validation_error", "load_paths", "parse_object"]

KINDS: dict[str, type[ComputeNode] | type[SoftwareModule] | type[RobotFleet]] = {
    "ComputeNode": ComputeNode,
    "SoftwareModule": SoftwareModule,
    "RobotFleet": RobotFleet,
}


@dataclass
class Catalog:
    """Every fogfleet object read, by kind; SoftwareModules keyed by (namespace, name)."""

    nodes: dict[str, ComputeNode] = field(default_factory=dict)
    modules: dict[tuple[str, str], SoftwareModule] = field(default_factory=dict)
    fleets: list[RobotFleet] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)
    sources: dict[tuple[str, str, str], str] = field(default_factory=dict)
    """(kind, namespace, name) -> where it was read (a file), to name both places of a
    duplicate."""

    def add(self, obj: ComputeNode | SoftwareModule | RobotFleet, source: str = "") -> None:
        """Add ``obj``; the same kind, namespace and name twice is refused, naming both
        sources (the API server would keep only the last one applied)."""
        ns = "" if isinstance(obj, ComputeNode) else (obj.metadata.namespace or "default")
        key = (obj.kind, ns, obj.metadata.name)
        if key in self.sources:
            where = f"{self.sources[key] or 'an earlier document'} and {source or 'a later one'}"
            raise InvalidSpec(
                f"{obj.kind}/{obj.metadata.name}", "metadata.name", f"defined twice: in {where}"
            )
        self.sources[key] = source
        if isinstance(obj, ComputeNode):
            self.nodes[obj.metadata.name] = obj
        elif isinstance(obj, SoftwareModule):
            self.modules[(ns, obj.metadata.name)] = obj
        else:
            self.fleets.append(obj)

    def module(self, namespace: str, name: str) -> SoftwareModule | None:
        return self.modules.get((namespace, name))


def _loc(loc: Iterable[int | str]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("function-after", "function-before", "function-plain", "tagged-union"):
            continue
        elif "[" in str(part) and "]" in str(part):
            continue  # pydantic's union branch labels such as 'str' or 'int'
        else:
            out += ("." if out else "") + str(part)
    return out


def describe_validation_error(exc: ValidationError) -> tuple[str, str]:
    """The first error's dotted field path and a readable reason."""
    err = exc.errors(include_url=False)[0]
    path = _loc(err["loc"])
    msg = str(err["msg"])
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
        if ": " in msg and not path.endswith(msg.split(": ", 1)[0]):
            sub, msg = msg.split(": ", 1)
            if " " not in sub:
                path = f"{path}.{sub}" if path else sub
    if err["type"] == "extra_forbidden":
        msg = "unknown field"
    elif err["type"] == "missing":
        msg = "required field is missing"
    return path, msg


def parse_object(doc: Mapping[str, Any]) -> ComputeNode | SoftwareModule | RobotFleet:
    """Validate one CR dict; raise InvalidSpec naming Kind/name and the field."""
    kind = str(doc.get("kind", ""))
    meta = doc.get("metadata") or {}
    name = meta.get("name", "?") if isinstance(meta, Mapping) else "?"
    model = KINDS.get(kind)
    if model is None:
        raise InvalidSpec(f"{kind or '<no kind>'}/{name}", "kind", f"unknown kind {kind!r}")
    if doc.get("apiVersion") != "fogfleet.io/v1alpha1":
        raise InvalidSpec(
            f"{kind}/{name}",
            "apiVersion",
            f"must be fogfleet.io/v1alpha1, not {doc.get('apiVersion')!r}",
        )
    try:
        return model.model_validate(dict(doc))
    except ValidationError as exc:
        path, msg = describe_validation_error(exc)
        raise InvalidSpec(f"{kind}/{name}", path, msg) from exc


def _files(paths: Iterable[str | Path]) -> list[Path]:
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = (q for q in p.rglob("*") if q.suffix in (".yaml", ".yml") and q.is_file())
            out.extend(sorted(found))
        elif p.exists():
            out.append(p)
        else:
            raise InvalidSpec(str(p), "", "no such file or directory")
    unique: dict[Path, Path] = {}  # a file named and inside a named folder is read once
    for q in out:
        unique.setdefault(q.resolve(), q)
    return list(unique.values())


def _objects(doc: Any, where: str) -> Iterator[tuple[str, Mapping[str, Any]]]:
    """The objects of one YAML document with where each sits: itself, or the ``items`` of a
    ``kind: List`` or ``<Kind>List`` (what ``kubectl get -o yaml`` writes), as kubectl reads
    them."""
    if not isinstance(doc, Mapping):
        return  # an empty document (or a scalar): nothing to apply
    kind = doc.get("kind")
    items = doc.get("items")
    if isinstance(kind, str) and kind.endswith("List") and "items" in doc:
        if not isinstance(items, list):
            raise InvalidSpec(f"{kind} in {where}", "items", "must be a list of objects")
        for k, item in enumerate(items):
            if not isinstance(item, Mapping):
                raise InvalidSpec(f"{kind} in {where}", f"items[{k}]", "must be an object")
            yield from _objects(item, where)
        return
    yield where, doc


def _parse_in(obj: Mapping[str, Any], where: str) -> ComputeNode | SoftwareModule | RobotFleet:
    try:
        return parse_object(obj)
    except InvalidSpec as exc:  # the same error, naming the file too
        raise type(exc)(exc.obj, exc.field, f"{exc.message} (in {where})") from exc


def _name_of(doc: Mapping[str, Any]) -> str:
    meta = doc.get("metadata")
    return f"{doc.get('kind')}/{meta.get('name') if isinstance(meta, Mapping) else None}"


def load_paths(paths: Iterable[str | Path], errors: list[InvalidSpec] | None = None) -> Catalog:
    """Read every fogfleet object from YAML files or folders; other kinds are ignored.

    Without ``errors`` the first bad input raises :class:`InvalidSpec`; with it, every bad file
    or object is appended there and the rest is still read (``fogfleet validate``)."""
    catalog = Catalog()

    def refuse(exc: InvalidSpec) -> None:
        if errors is None:
            raise exc
        errors.append(exc)

    try:
        files = _files(paths)
    except InvalidSpec as exc:
        refuse(exc)
        return catalog
    for path in files:
        try:
            docs = read_documents(path)
        except InvalidSpec as exc:
            refuse(exc)
            continue
        for doc in docs:
            try:
                for where, obj in _objects(doc, str(path)):
                    if str(obj.get("apiVersion", "")).split("/")[0] != "fogfleet.io":
                        catalog.ignored.append(_name_of(obj))
                        continue
                    catalog.add(_parse_in(obj, where), where)
            except InvalidSpec as exc:
                refuse(exc)
    return catalog
