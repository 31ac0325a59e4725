"""YAML read the way kubectl reads it, so a file fogfleet accepts is one ``kubectl apply`` takes
the same way.

kubectl turns YAML into JSON with sigs.k8s.io/yaml (go-yaml). PyYAML's ``SafeLoader`` differs
from it in three ways that matter for CR files, which :class:`KubeLoader` changes:

* **Numbers.** go-yaml reads ``5e0``, ``1e3`` and ``1.0e30`` as numbers (YAML 1.2's core
  schema); PyYAML's YAML 1.1 resolver wants a dot and a signed exponent and reads them as
  strings, which a ``number`` field then refuses as "quoted".
* **Duplicate keys.** go-yaml refuses a mapping that repeats a key ("mapping key already
  defined"); PyYAML keeps the last value silently. Here a repeat raises :class:`DuplicateKey`
  with the key and both lines.
* **Timestamps.** go-yaml hands ``2024-01-01`` to JSON as a string; PyYAML makes a ``date``
  (and an impossible date such as ``2024-02-30`` a ``ValueError``). Here it stays a string.

:func:`read_documents` also decodes the bytes itself, so a file that is not UTF-8 is an
:class:`InvalidSpec` naming the file and the byte, never a traceback.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Any

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, Node, ScalarNode

from fogfleet.errors import InvalidSpec

__all__ = ["DuplicateKey", "KubeLoader", "read_documents", "safe_load"]

_FLOAT_TAG = "tag:yaml.org,2002:float"
_TIMESTAMP_TAG = "tag:yaml.org,2002:timestamp"
_MERGE_TAG = "tag:yaml.org,2002:merge"
# go-yaml's yamlStyleFloat (YAML 1.2 core schema): an optional dot, an optional unsigned exponent
_YAML12_FLOAT = re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?$")


class DuplicateKey(ConstructorError):
    """A mapping names the same key twice (kubectl refuses it too)."""

    def __init__(self, key: object, first: Node, again: Node) -> None:
        self.key = key
        self.line = again.start_mark.line + 1
        self.first_line = first.start_mark.line + 1
        super().__init__(
            None,
            None,
            f"duplicate key {key!r} on line {self.line} (first on line {self.first_line})",
            again.start_mark,
        )


class KubeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with go-yaml's numbers, strings for timestamps and no duplicate
    keys (see the module docstring)."""

    def construct_mapping(self, node: Node, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, MappingNode):
            seen: dict[object, Node] = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, ScalarNode) or key_node.tag == _MERGE_TAG:
                    continue  # `<<` merges may be overridden by design
                key = self.construct_object(key_node)
                try:
                    first = seen.setdefault(key, key_node)
                except TypeError:  # unhashable: PyYAML refuses it below, naming it
                    continue
                if first is not key_node:
                    raise DuplicateKey(key, first, key_node)
        mapping: dict[Any, Any] = super().construct_mapping(node, deep=deep)  # type: ignore[arg-type]
        return mapping


KubeLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != _TIMESTAMP_TAG]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
# appended: ints (tried first) keep their meaning, and only what YAML 1.1 left a string changes
KubeLoader.add_implicit_resolver(_FLOAT_TAG, _YAML12_FLOAT, list("-+0123456789."))


def safe_load(text: str) -> Any:
    """One YAML document, read as kubectl reads it."""
    return yaml.load(text, Loader=KubeLoader)  # KubeLoader is a SafeLoader


def read_documents(path: Path) -> list[Any]:
    """Every YAML document of the file ``path``; :class:`InvalidSpec` naming the file (and the
    line) when it is not UTF-8 or not valid YAML."""
    data = path.read_bytes()
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InvalidSpec(
            str(path),
            "",
            f"not UTF-8: byte 0x{data[exc.start]:02x} on line {line} ({exc.reason}); "
            "kubectl reads UTF-8 only, save the file as UTF-8",
        ) from exc
    stream = io.StringIO(text)
    stream.name = str(path)  # error marks name the file
    loader: KubeLoader | None = None
    try:
        loader = KubeLoader(stream)  # it reads (and may refuse) the first characters
        docs = []
        while loader.check_data():  # type: ignore[no-untyped-call]
            docs.append(loader.get_data())
        return docs
    except DuplicateKey as exc:
        raise InvalidSpec(
            str(path),
            f"line {exc.line}",
            f"duplicate key {exc.key!r} (first on line {exc.first_line}); kubectl refuses it too",
        ) from exc
    except yaml.YAMLError as exc:
        raise InvalidSpec(str(path), "", f"not valid YAML: {exc}") from exc
    except RecursionError as exc:
        raise InvalidSpec(str(path), "", "not valid YAML: nested too deeply") from exc
    finally:
        if loader is not None:
            loader.dispose()
