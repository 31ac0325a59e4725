"""YAML and JSON read the way kubectl reads them, so a file fogfleet accepts is one
``kubectl apply`` takes the same way.

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

:func:`read_documents` also does what kubectl's file reader (cli-runtime's ``FileVisitor`` and
apimachinery's ``YAMLOrJSONDecoder``) does before that:

* **Encodings.** It decodes the bytes as ``unicode.BOMOverride(unicode.UTF8.NewDecoder())``
  does: a UTF-8, UTF-16 LE or UTF-16 BE byte order mark picks the encoding (and is dropped),
  anything else is UTF-8. Where kubectl would put U+FFFD for a byte that does not decode, the
  file is an :class:`InvalidSpec` naming the file and the byte, never a traceback.
* **JSON.** Text whose first non-blank character is ``{`` is a stream of JSON values (one or
  more objects one after the other), read with :mod:`json` (YAML would refuse the tabs JSON
  may be indented with); a key given twice is refused as in YAML, ``NaN`` and ``Infinity``
  are not JSON.
"""

from __future__ import annotations

import codecs
import io
import json
import re
from pathlib import Path
from typing import Any

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, Node, ScalarNode

from fogfleet.errors import InvalidSpec

__all__ = ["DuplicateKey", "KubeLoader", "decode", "read_documents", "safe_load"]

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


# the byte order marks BOMOverride knows, longest first
_BOMS = (
    (codecs.BOM_UTF8, "utf-8", "UTF-8"),
    (codecs.BOM_UTF16_BE, "utf-16-be", "UTF-16 BE"),
    (codecs.BOM_UTF16_LE, "utf-16-le", "UTF-16 LE"),
)


def decode(data: bytes, source: str) -> str:
    """``data`` as text, as kubectl decodes a file: by its byte order mark (UTF-8, UTF-16 BE or
    LE), else UTF-8. :class:`InvalidSpec` naming ``source`` and the byte where a byte does not
    decode (kubectl would read U+FFFD there)."""
    codec, name, body = "utf-8", "UTF-8", data
    for bom, bom_codec, bom_name in _BOMS:
        if data.startswith(bom):
            codec, name, body = bom_codec, bom_name, data[len(bom) :]
            break
    try:
        return body.decode(codec)
    except UnicodeDecodeError as exc:
        line = body[: exc.start].decode(codec, errors="replace").count("\n") + 1
        found = body[exc.start : exc.start + (1 if codec == "utf-8" else 2)].hex()
        raise InvalidSpec(
            source,
            "",
            f"not {name}: byte(s) 0x{found} on line {line} ({exc.reason}); kubectl would read "
            "U+FFFD there. Save the file as UTF-8 (or UTF-16 with a byte order mark)",
        ) from exc


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}; kubectl refuses it too")
        out[key] = value
    return out


def _not_json(constant: str) -> Any:
    raise ValueError(f"{constant} is not a JSON number")


_JSON = json.JSONDecoder(object_pairs_hook=_no_duplicates, parse_constant=_not_json)


def _json_documents(text: str, source: str) -> list[Any]:
    """The values of a JSON stream (``{...} {...}``), as kubectl's JSON decoder reads them."""
    docs: list[Any] = []
    at = 0
    while True:
        while at < len(text) and text[at].isspace():
            at += 1
        if at == len(text):
            return docs
        try:
            doc, at = _JSON.raw_decode(text, at)
        except json.JSONDecodeError as exc:
            raise InvalidSpec(source, f"line {exc.lineno}", f"not valid JSON: {exc.msg}") from exc
        except (ValueError, RecursionError) as exc:  # the hooks' refusals, or nested too deep
            line = text.count("\n", 0, at) + 1
            why = str(exc) if isinstance(exc, ValueError) else "nested too deeply"
            raise InvalidSpec(source, f"line {line}", f"not valid JSON: {why}") from exc
        docs.append(doc)


def read_documents(path: Path) -> list[Any]:
    """Every YAML document (or JSON value) of the file ``path``; :class:`InvalidSpec` naming the
    file (and the line) when it cannot be read, decoded or parsed."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InvalidSpec(str(path), "", f"cannot be read: {exc.strerror or exc}") from exc
    text = decode(data, str(path))
    if text.lstrip().startswith("{"):  # apimachinery's GuessJSONStream: a JSON stream
        return _json_documents(text, str(path))
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
