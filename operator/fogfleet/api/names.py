"""Valid text for the names and label values fogfleet generates, bounded and collision-free
(issue 35); ``render.names`` builds every object name from these pieces (issue 45).

A DNS-1123 label and a label value are at most 63 characters. A text that already is one stays
exactly as it is. Any other text (too long, or changed by making it valid, such as a
robot ``node.1`` whose dot becomes ``-``) is cut and keeps a hash of the whole original text,
as Kubernetes' own name generators do: two long names that differ only at their ends, or two
that differ only in a character the cleaning maps away, never meet.

``shorten`` is the rule for one text; ``dns_label`` and ``label_value`` only say which
characters are valid. ``digest`` is the hash (also of an object's exact identity,
``render.names``).
"""

from __future__ import annotations

import hashlib
import json
import re

__all__ = [
    "DIGEST_CHARS",
    "MAX_NAME",
    "digest",
    "dns_label",
    "dns_text",
    "label_value",
    "shorten",
]

MAX_NAME = 63
"""A DNS label, a label value, a container name and a pod's hostname: at most 63 characters."""
DIGEST_CHARS = 8
_NOT_DNS = re.compile(r"[^a-z0-9-]+")
_NOT_LABEL = re.compile(r"[^A-Za-z0-9_.-]+")
_LABEL_VALUE = re.compile(r"([A-Za-z0-9]([-A-Za-z0-9_.]*[A-Za-z0-9])?)?")
_DNS_LABEL = re.compile(r"[a-z0-9]([-a-z0-9]*[a-z0-9])?")


def digest(*parts: object, n: int = DIGEST_CHARS) -> str:
    """A short stable hash of ``parts`` (hex; sha256 of their compact JSON)."""
    return hashlib.sha256(json.dumps(parts, separators=(",", ":")).encode()).hexdigest()[:n]


def shorten(clean: str, original: str, limit: int = MAX_NAME) -> str:
    """``clean`` (the valid form of ``original``) if it is ``original`` unchanged and fits in
    ``limit``; else its head and ``-<digest(original)>``, within ``limit``."""
    if clean == original and len(clean) <= limit:
        return clean
    tag = digest(original)
    head = clean[: limit - len(tag) - 1].strip("-_.")
    return f"{head}-{tag}" if head else tag


def dns_text(text: str) -> str:
    """``text`` in DNS-label characters (lower case, every run of others one ``-``), not cut."""
    return _NOT_DNS.sub("-", text.lower()).strip("-")


def dns_label(text: str, limit: int = MAX_NAME) -> str:
    """A DNS-1123 label of at most ``limit`` characters naming ``text`` (``text`` itself when it
    is one)."""
    if len(text) <= limit and _DNS_LABEL.fullmatch(text):
        return text
    return shorten(dns_text(text), text, limit)


def label_value(text: str) -> str:
    """A valid label value naming ``text`` (``text`` itself when it is one)."""
    if len(text) <= MAX_NAME and _LABEL_VALUE.fullmatch(text):
        return text
    return shorten(_NOT_LABEL.sub("-", text).strip("-_."), text)
