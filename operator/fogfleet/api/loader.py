"""Read CR YAML and JSON (files or folders) into typed objects, with errors that name object and
field, and remember the objects of other API groups, to name them when a fleet misses one."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from fogfleet.errors import InvalidSpec

from .kubeyaml import read_documents
from .v1alpha1.computenode import ComputeNode
from .v1alpha1.robotfleet import RobotFleet
from .v1alpha1.softwaremodule import SoftwareModule

__all__ = [
    "GROUP",
    "Catalog",
    "Skipped",
    "describe_validation_errors",
    "load_paths",
    "parse_object",
]

GROUP = "fogfleet.io"
API_VERSION = f"{GROUP}/v1alpha1"
# what kubectl reads from a folder (cli-runtime's FileExtensions)
EXTENSIONS = (".json", ".yaml", ".yml")

KINDS: dict[str, type[ComputeNode] | type[SoftwareModule] | type[RobotFleet]] = {
    "ComputeNode": ComputeNode,
    "SoftwareModule": SoftwareModule,
    "RobotFleet": RobotFleet,
}


@dataclass(frozen=True)
class Skipped:
    """An object read but not fogfleet's: its API group is not fogfleet.io (a Namespace, or a
    ComputeNode whose apiVersion is misspelt), so nothing checks or plans it. Kept to be named
    where a fleet misses an object of its name (``Catalog.missing``)."""

    kind: str
    name: str
    api_version: str
    source: str

    def __str__(self) -> str:
        return f"{self.kind}/{self.name}"

    @property
    def why(self) -> str:
        """Why it was skipped, and what fogfleet reads instead: a misspelt apiVersion of one
        of fogfleet's kinds, or a kind that is not fogfleet's."""
        version = self.api_version or "none"
        if self.kind in KINDS:
            return f"apiVersion {version} is not fogfleet's (it reads {API_VERSION})"
        kinds = ", ".join(list(KINDS)[:-1]) + f" and {list(KINDS)[-1]}"
        return (
            f"kind {self.kind or '(none)'} (apiVersion {version}) is not fogfleet's "
            f"(it reads {kinds} of {API_VERSION})"
        )


@dataclass
class Catalog:
    """Every fogfleet object read, by kind; SoftwareModules keyed by (namespace, name)."""

    nodes: dict[str, ComputeNode] = field(default_factory=dict)
    modules: dict[tuple[str, str], SoftwareModule] = field(default_factory=dict)
    fleets: list[RobotFleet] = field(default_factory=list)
    ignored: list[Skipped] = field(default_factory=list)
    """Objects of other API groups, skipped."""
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

    def missing(self, what: str, name: str) -> str:
        """Why a reference to ``name`` (shown as ``what``, e.g. ``ComputeNode 'edge-1'``) finds
        nothing: it does not exist, and each skipped object of that name that may have been
        meant (its group misspelt, or a kind not fogfleet's), with its file and why it was
        skipped; those of fogfleet's kinds first."""
        hints = [
            f"{s.source or 'a file'} defines {s}, skipped: {s.why}"
            for s in sorted(self.ignored, key=lambda s: s.kind not in KINDS)
            if s.name == name
        ]
        return "; ".join([f"{what} does not exist", *hints])


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


def _describe(err: Mapping[str, Any]) -> tuple[str, str]:
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


def describe_validation_errors(exc: ValidationError) -> list[tuple[str, str]]:
    """Every error's dotted field path and a readable reason, one per field (a value that fits
    no branch of a union is one error, not one per branch)."""
    out: dict[str, str] = {}
    for err in exc.errors(include_url=False):
        path, msg = _describe(err)
        out.setdefault(path, msg)
    return list(out.items())


Model = type[ComputeNode] | type[SoftwareModule] | type[RobotFleet]


def _model_of(doc: Mapping[str, Any]) -> tuple[Model, str]:
    """The model of a CR dict and its ``Kind/name``; InvalidSpec for a kind or apiVersion that
    is not fogfleet's."""
    kind = str(doc.get("kind", ""))
    meta = doc.get("metadata") or {}
    name = meta.get("name", "?") if isinstance(meta, Mapping) else "?"
    model = KINDS.get(kind)
    if model is None:
        raise InvalidSpec(f"{kind or '<no kind>'}/{name}", "kind", f"unknown kind {kind!r}")
    if doc.get("apiVersion") != API_VERSION:
        raise InvalidSpec(
            f"{kind}/{name}",
            "apiVersion",
            f"must be {API_VERSION}, not {doc.get('apiVersion')!r}",
        )
    return model, f"{kind}/{name}"


def parse_object(doc: Mapping[str, Any]) -> ComputeNode | SoftwareModule | RobotFleet:
    """Validate one CR dict; raise InvalidSpec naming Kind/name and the (first bad) field."""
    model, obj = _model_of(doc)
    try:
        return model.model_validate(dict(doc))
    except ValidationError as exc:
        path, msg = describe_validation_errors(exc)[0]
        raise InvalidSpec(obj, path, msg) from exc


def _parse_in(
    doc: Mapping[str, Any], where: str
) -> ComputeNode | SoftwareModule | RobotFleet | list[InvalidSpec]:
    """``parse_object``, or every error of the object (each bad field), naming the file too."""
    try:
        model, obj = _model_of(doc)
        return model.model_validate(dict(doc))
    except InvalidSpec as exc:
        return [type(exc)(exc.obj, exc.field, f"{exc.message} (in {where})")]
    except ValidationError as exc:
        return [
            InvalidSpec(obj, path, f"{msg} (in {where})")
            for path, msg in describe_validation_errors(exc)
        ]


def _files(paths: Iterable[str | Path], refuse: Callable[[InvalidSpec], None]) -> list[Path]:
    """The files to read: each path named (whatever its extension, as kubectl) and the
    ``.json``, ``.yaml`` and ``.yml`` files of each folder named and of its subfolders (as
    ``kubectl apply -R -f``), each once; ``refuse`` each path that does not exist."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = (q for q in p.rglob("*") if q.suffix in EXTENSIONS and q.is_file())
            out.extend(sorted(found))
        elif p.exists():
            out.append(p)
        else:
            refuse(InvalidSpec(str(p), "", "no such file or directory"))
    unique: dict[Path, Path] = {}  # a file named and inside a named folder is read once
    for q in out:
        unique.setdefault(q.resolve(), q)
    return list(unique.values())


def _what(value: Any) -> str:
    """What a document that is not an object is, in words."""
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    return f"a {type(value).__name__}"


def _objects(doc: Any, where: str, at: str) -> Iterator[Mapping[str, Any] | InvalidSpec]:
    """The objects of one document of the file ``where`` (``at``: which document), each, or
    why it is not one, in order, as kubectl reads them (cli-runtime's ``StreamVisitor``): an
    empty document is nothing; an object is itself, or the ``items`` of a ``kind: List`` or
    ``<Kind>List`` (what ``kubectl get -o yaml`` writes); any other document (a list, a
    string, a number) is refused, as kubectl's decoder refuses it. A bad item does not hide
    the items after it."""
    if doc is None:
        return  # an empty document (``---`` alone, or ``null``): kubectl skips it too
    if not isinstance(doc, Mapping):
        yield InvalidSpec(where, at, f"is {_what(doc)}, not an object; kubectl refuses it too")
        return
    kind = doc.get("kind")
    items = doc.get("items")
    if isinstance(kind, str) and kind.endswith("List") and "items" in doc:
        if not isinstance(items, list):
            yield InvalidSpec(f"{kind} in {where}", "items", "must be a list of objects")
            return
        for k, item in enumerate(items):
            if isinstance(item, Mapping):
                yield from _objects(item, where, at)
            else:
                yield InvalidSpec(f"{kind} in {where}", f"items[{k}]", "must be an object")
        return
    yield doc


def _untyped(obj: Mapping[str, Any], where: str, at: str) -> InvalidSpec | None:
    """Why ``obj`` (document ``at`` of the file ``where``) is no object to apply, if it lacks
    a kind or an apiVersion. kubectl refuses such an object (apimachinery's decoder: "Object
    'Kind' is missing"; no API serves an empty apiVersion), so it is an error here too, not an
    object of another group to skip."""
    for key in ("kind", "apiVersion"):
        if not obj.get(key):
            skipped = _skipped(obj, where)
            if skipped.kind and skipped.name != "?":
                return InvalidSpec(
                    str(skipped),
                    key,
                    f"missing (in {where}); kubectl refuses an object without one (fogfleet's "
                    f"objects are apiVersion {API_VERSION})",
                )
            return InvalidSpec(
                where,
                f"{at}: {key}",
                "missing: not a Kubernetes object, kubectl refuses it too (keep other files, "
                "such as a saved plan, out of the folders you pass)",
            )
    return None


def _skipped(doc: Mapping[str, Any], where: str) -> Skipped:
    meta = doc.get("metadata")
    name = meta.get("name") if isinstance(meta, Mapping) else None
    return Skipped(
        str(doc.get("kind") or ""), str(name or "?"), str(doc.get("apiVersion") or ""), where
    )


def _read_object(
    catalog: Catalog,
    obj: Mapping[str, Any],
    where: str,
    at: str,
    refuse: Callable[[InvalidSpec], None],
) -> None:
    """Add ``obj`` (document ``at`` of the file ``where``) to ``catalog``: skipped if of
    another group, else parsed; ``refuse`` each error found."""
    untyped = _untyped(obj, where, at)
    if untyped is not None:
        refuse(untyped)
    elif str(obj["apiVersion"]).split("/")[0] != GROUP:
        catalog.ignored.append(_skipped(obj, where))
    elif isinstance(parsed := _parse_in(obj, where), list):
        for bad in parsed:
            refuse(bad)
    else:
        try:
            catalog.add(parsed, where)
        except InvalidSpec as exc:  # defined twice
            refuse(exc)


def load_paths(paths: Iterable[str | Path], errors: list[InvalidSpec] | None = None) -> Catalog:
    """Read every fogfleet object from YAML or JSON files or folders (a folder's ``.yaml``,
    ``.yml`` and ``.json`` files, as ``kubectl apply -R -f``); objects of other API groups
    are skipped, and kept in ``Catalog.ignored``.

    Without ``errors`` the first bad input raises :class:`InvalidSpec`; with it, every bad file
    or field of an object is appended there and the rest is still read (``fogfleet
    validate``)."""
    catalog = Catalog()

    def refuse(exc: InvalidSpec) -> None:
        if errors is None:
            raise exc
        errors.append(exc)

    for path in _files(paths, refuse):
        try:
            docs = read_documents(path)
        except InvalidSpec as exc:
            refuse(exc)
            continue
        for k, doc in enumerate(docs):
            at = f"document {k + 1}"
            for obj in _objects(doc, str(path), at):
                if isinstance(obj, InvalidSpec):
                    refuse(obj)
                else:
                    _read_object(catalog, obj, str(path), at, refuse)
    return catalog
