"""Check README.md and docs/**/*.md against the repository: links, make targets, CLI flags.

Fails (exit 1, one line per problem: ``file:line: what``) when

* a relative Markdown link or image (``[t](path)``, ``![a](path)``, ``[r]: path``, HTML
  ``src``/``href``) names a file that does not exist, or an ``#anchor`` that no heading of the
  target Markdown file makes (GitHub's slug rules);
* ``make TARGET`` in a code span or code block names no target of the Makefile;
* ``fogfleet SUBCOMMAND --flag`` in a code span or block names a subcommand or a flag that the
  real parser (``fogfleet.commandline.cli._parser()``) does not have;
* ``harness.py SUBCOMMAND --flag`` (the bed's harness) does the same; its parser is built
  inside ``main()``, so its flags are read from ``harness.py SUBCOMMAND --help``;
* a column named for ``kubectl get KIND`` of a fogfleet kind (in capitals) is not one of the
  CRD's printer columns (``check_columns.py``).

Only commands are checked: ``make`` and ``fogfleet`` count when they start a command (after
``$``, ``VAR=value`` assignments, ``python -m`` or a path such as ``.venv/bin/``), so prose in
a code span is left alone. ``kubectl`` and ``helm`` passthroughs of the harness are not ours
to check, nor are ``python -m e2e...`` scripts.

Run: ``python tests/docs/check_docs.py [ROOT]`` (``make docs-check``). Needs ``fogfleet``
importable (the venv, or ``PYTHONPATH=operator``).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Problem", "check", "doc_files", "main", "make_targets"]

ROOT = Path(__file__).resolve().parents[2]

FENCE = re.compile(r"^\s*(```+|~~~+)")
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
CODE_SPAN = re.compile(r"(`+)(.+?)(?<!`)\1(?!`)", re.S)
INLINE_LINK = re.compile(
    r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+(?:\"[^\"]*\"|'[^']*'))?\s*\)"
)
REF_DEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)", re.M)
HTML_REF = re.compile(r"""(?:src|href)\s*=\s*["']([^"']+)["']""")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
SEPARATORS = re.compile(r"\|\||&&|[|;()&<>]|\$\(")
FLAG = re.compile(r"(?<![\w-])--[a-zA-Z][\w-]*")
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=\S*$")
TARGET = re.compile(r"^[A-Za-z0-9][\w.-]*$")
WORD = re.compile(r"^[a-z][a-z0-9-]*$")
RULE = re.compile(r"^([A-Za-z0-9_.%/-]+(?:[ \t]+[A-Za-z0-9_.%/-]+)*)[ \t]*::?(?!=)")
HARNESS_PASSTHROUGH = frozenset({"kubectl", "helm"})


@dataclass(frozen=True)
class Problem:
    path: Path
    line: int
    message: str

    def render(self, root: Path) -> str:
        try:
            shown = self.path.relative_to(root)
        except ValueError:
            shown = self.path
        return f"{shown}:{self.line}: {self.message}"


@dataclass(frozen=True)
class Snippet:
    """A piece of a Markdown file: prose (``code=False``) or code (a span or a block)."""

    text: str
    line: int
    code: bool
    block: bool = False


# --- reading Markdown -------------------------------------------------------------------------


def doc_files(root: Path) -> list[Path]:
    """README.md and every Markdown file under docs/."""
    files = [root / "README.md"] if (root / "README.md").exists() else []
    return files + sorted((root / "docs").rglob("*.md"))


def snippets(text: str) -> Iterator[Snippet]:
    """Fenced code blocks (line by line), code spans, and prose with its code spans blanked."""
    lines = text.split("\n")
    fence: str | None = None
    prose: list[tuple[int, str]] = []

    def flush() -> Iterator[Snippet]:
        if not prose:
            return
        first = prose[0][0]
        para = "\n".join(t for _, t in prose)
        prose.clear()
        blanked = []
        last = 0
        for m in CODE_SPAN.finditer(para):
            line = first + para.count("\n", 0, m.start())
            yield Snippet(" ".join(m.group(2).split()), line, code=True)
            blanked.append(para[last : m.start()])
            blanked.append(re.sub(r"[^\n]", " ", m.group(0)))
            last = m.end()
        blanked.append(para[last:])
        yield Snippet("".join(blanked), first, code=False)

    held: tuple[int, str] | None = None  # a code line continued with a backslash
    for no, line in enumerate(lines, 1):
        m = FENCE.match(line)
        if fence is None and m:
            yield from flush()
            fence = m.group(1)[0] * 3
            continue
        if fence is not None:
            if line.strip().startswith(fence):
                fence = None
                if held:
                    yield Snippet(held[1], held[0], code=True, block=True)
                held = None
                continue
            start, text = held if held else (no, "")
            text += line
            if text.endswith("\\"):
                held = (start, text[:-1] + " ")
            else:
                held = None
                yield Snippet(text, start, code=True, block=True)
            continue
        if not line.strip():
            yield from flush()
        else:
            prose.append((no, line))
    yield from flush()


def _heading_text(raw: str) -> str:
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", raw)  # links and images: their text
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML
    return text.replace("`", "").replace("*", "")


def slug(heading: str) -> str:
    """GitHub's anchor for a heading (github-slugger): lower case, punctuation but ``-`` and
    ``_`` dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", _heading_text(heading).strip().lower()).replace(" ", "-")


@functools.cache
def anchors(path: Path) -> frozenset[str]:
    """The anchors a Markdown file's headings make, ``-1``, ``-2`` ... for repeats."""
    seen: dict[str, int] = {}
    out: set[str] = set()
    fence: str | None = None
    for line in path.read_text(encoding="utf-8").split("\n"):
        f = FENCE.match(line)
        if fence is None and f:
            fence = f.group(1)[0] * 3
        elif fence is not None:
            if line.strip().startswith(fence):
                fence = None
        elif m := HEADING.match(line):
            base = slug(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return frozenset(out)


# --- what the repository offers ---------------------------------------------------------------


def make_targets(makefile: Path) -> frozenset[str]:
    """Targets of the Makefile's rules (not variables, not pattern rules)."""
    targets: set[str] = set()
    for line in makefile.read_text(encoding="utf-8").splitlines():
        if line.startswith(("\t", "#", " ")):
            continue
        m = RULE.match(line)
        if m:
            targets.update(t for t in m.group(1).split() if "%" not in t and "$" not in t)
    return frozenset(targets)


def _flags_of(parser: argparse.ArgumentParser) -> frozenset[str]:
    return frozenset(s for s in parser._option_string_actions if s.startswith("--"))


def fogfleet_commands() -> dict[str, frozenset[str]]:
    """{subcommand: its --flags} from the real parser; '' holds the top-level flags."""
    from fogfleet.commandline.cli import _parser

    parser = _parser()
    out = {"": _flags_of(parser)}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[name] = _flags_of(sub)
    return out


def find_harness(root: Path) -> Path | None:
    """The bed's harness.py (e2e/bed/ after the e2e split, e2e/cluster/ before it)."""
    found = sorted((root / "e2e").glob("**/harness.py")) if (root / "e2e").is_dir() else []
    return found[0] if found else None


class HarnessFlags:
    """A harness subcommand's flags, read from its ``--help`` (its parser lives in main())."""

    def __init__(self, root: Path, harness: Path | None) -> None:
        self.root = root
        self.harness = harness
        self._cache: dict[str, frozenset[str] | None] = {}

    def _help(self, *args: str) -> str | None:
        assert self.harness is not None
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(self.root / "operator"), str(self.root), env.get("PYTHONPATH")) if p
        )
        done = subprocess.run(
            [sys.executable, str(self.harness), *args, "--help"],
            capture_output=True,
            text=True,
            env=env,
            cwd=self.root,
            timeout=60,
            check=False,
        )
        return done.stdout if done.returncode == 0 else None

    @functools.cached_property
    def subcommands(self) -> frozenset[str]:
        usage = self._help() or ""
        m = re.search(r"\{([\w,-]+)\}", usage)
        return frozenset(m.group(1).split(",")) if m else frozenset()

    def flags(self, sub: str) -> frozenset[str] | None:
        if sub not in self._cache:
            text = self._help(sub)
            self._cache[sub] = None if text is None else frozenset(FLAG.findall(text))
        return self._cache[sub]


# --- the checks -------------------------------------------------------------------------------


def _commands(snip: Snippet) -> Iterator[list[str]]:
    """The token lists of the shell commands in a code snippet (comments and pipes split)."""
    text = snip.text
    if snip.block:
        text = re.sub(r"(^|\s)#.*$", "", text)
    for part in SEPARATORS.split(text):
        try:
            tokens = shlex.split(part)  # make kubectl ARGS="get robotfleets -A": one argument
        except ValueError:  # an unbalanced quote in prose-like code
            tokens = part.split()
        while tokens and (tokens[0] in {"$", "sudo", "env"} or ASSIGNMENT.match(tokens[0])):
            tokens.pop(0)
        if tokens:
            yield tokens


def _program(tokens: list[str], name: str) -> list[str] | None:
    """The arguments after ``name`` when the command runs it, else None."""
    first = tokens[0]
    if first == name or first.endswith("/" + name):
        return tokens[1:]
    if len(tokens) > 2 and re.match(r"^(.*/)?python[0-9.]*$", first):
        if tokens[1] == "-m" and tokens[2] == name:
            return tokens[3:]
        if tokens[1] == name or tokens[1].endswith("/" + name):
            return tokens[2:]
    return None


def check_links(path: Path, snip: Snippet, root: Path) -> Iterator[Problem]:
    text = snip.text
    found = [(m.start(1), m.group(1)) for m in INLINE_LINK.finditer(text)]
    found += [(m.start(1), m.group(1)) for m in REF_DEF.finditer(text)]
    found += [(m.start(1), m.group(1)) for m in HTML_REF.finditer(text)]
    for offset, raw in found:
        line = snip.line + text.count("\n", 0, offset)
        target = raw[1:-1] if raw.startswith("<") else raw
        if not target or SCHEME.match(target) or target.startswith("//"):
            continue
        file_part, _, anchor = target.partition("#")
        file_part = file_part.split("?", 1)[0]
        if file_part.startswith("/"):
            dest = root / file_part.lstrip("/")
        elif file_part:
            dest = path.parent / file_part
        else:
            dest = path
        if not dest.exists():
            yield Problem(path, line, f"link {target!r}: {file_part} does not exist")
            continue
        if anchor and dest.is_file() and dest.suffix == ".md" and anchor not in anchors(dest):
            yield Problem(path, line, f"link {target!r}: no heading makes #{anchor}")


def check_code(
    path: Path,
    snip: Snippet,
    targets: frozenset[str],
    fogfleet: Callable[[], dict[str, frozenset[str]]],
    harness: HarnessFlags,
) -> Iterator[Problem]:
    for tokens in _commands(snip):
        args = _program(tokens, "make")
        if args is not None:
            for arg in args:
                if arg.startswith("-") or ASSIGNMENT.match(arg):
                    continue
                if not TARGET.match(arg):
                    break
                if arg not in targets:
                    yield Problem(path, snip.line, f"`make {arg}`: no such Makefile target")
            continue
        args = _program(tokens, "fogfleet")
        if args is not None:
            yield from _check_cli(path, snip.line, "fogfleet", args, fogfleet())
            continue
        args = _program(tokens, "harness.py")
        if args is not None and harness.harness is not None:
            if not args or not WORD.match(args[0]) or args[0] in HARNESS_PASSTHROUGH:
                continue
            if args[0] not in harness.subcommands:
                yield Problem(path, snip.line, f"`harness.py {args[0]}`: no such subcommand")
                continue
            flags = harness.flags(args[0]) or frozenset()
            for flag in FLAG.findall(" ".join(args[1:])):
                if flag not in flags:
                    yield Problem(path, snip.line, f"`harness.py {args[0]} {flag}`: no such option")


def _check_cli(
    path: Path, line: int, prog: str, args: list[str], commands: dict[str, frozenset[str]]
) -> Iterator[Problem]:
    if not args or not WORD.match(args[0]):
        for flag in FLAG.findall(" ".join(args)):
            if flag not in commands[""]:
                yield Problem(path, line, f"`{prog} {flag}`: no such option")
        return
    sub = args[0]
    if sub not in commands:
        yield Problem(path, line, f"`{prog} {sub}`: no such subcommand")
        return
    for flag in FLAG.findall(" ".join(args[1:])):
        if flag not in commands[sub]:
            yield Problem(path, line, f"`{prog} {sub} {flag}`: no such option")


def check(
    root: Path,
    files: Iterable[Path] | None = None,
    fogfleet: Callable[[], dict[str, frozenset[str]]] | None = None,
) -> list[Problem]:
    """Every problem in the given Markdown files (default: README.md and docs/)."""
    root = root.resolve()
    targets = make_targets(root / "Makefile")
    cli = functools.cache(fogfleet or fogfleet_commands)
    harness = HarnessFlags(root, find_harness(root))
    columns = _columns_checker()
    kinds = columns.kinds_in(root)
    problems: list[Problem] = []
    for path in files if files is not None else doc_files(root):
        path = path.resolve()
        text = path.read_text(encoding="utf-8")
        problems.extend(Problem(path, n, why) for n, why in columns.check_columns(text, kinds))
        for snip in snippets(text):
            if snip.code:
                problems.extend(check_code(path, snip, targets, cli, harness))
            else:
                problems.extend(check_links(path, snip, root))
    return problems


@functools.cache
def _columns_checker() -> Any:
    """check_columns.py beside this file (loaded by path: this file runs as a script too)."""
    spec = importlib.util.spec_from_file_location(
        "check_columns", Path(__file__).with_name("check_columns.py")
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", nargs="?", type=Path, default=ROOT, help="the repository")
    args = ap.parse_args(argv)
    files = doc_files(args.root)
    problems = check(args.root, files)
    for p in problems:
        print(p.render(args.root.resolve()), file=sys.stderr)
    print(f"docs-check: {len(files)} files, {len(problems)} problems", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
