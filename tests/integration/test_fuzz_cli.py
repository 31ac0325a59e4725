"""Fuzzed input against the CLI (issue 37, item 7): ``fogfleet validate`` and ``fogfleet plan``
on RobotFleet, SoftwareModule and ComputeNode objects drawn from the CRDs' schemas
(e2e/fuzz/strategies.py), valid and broken, next to the single-robot example. Each run ends
with exit 0, or exit 2 and a message that names the object (``Kind/name``) and, for a broken
field, its path; never a traceback. ``main()`` runs in-process, so hundreds fit in seconds.

    pytest tests/integration/test_fuzz_cli.py -q -s     # prints how many were tried
"""

from __future__ import annotations

import shutil
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import yaml
from e2e.fuzz.strategies import KINDS, custom_resources, mutated_resources
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogfleet.api.kubeyaml import safe_load
from fogfleet.api.loader import parse_object
from fogfleet.commandline.cli import main
from fogfleet.errors import InvalidSpec

EXAMPLE = Path(__file__).resolve().parents[2] / "manifests" / "examples" / "single-robot"
TAKEN = {"single-robot", "solo-robot", "solo-edge"}  # keep the example's own names intact

pytestmark = pytest.mark.faults


def _docs() -> st.SearchStrategy[tuple[dict[str, Any], str | None]]:
    """(object, what was broken or None), any kind, about half of them broken."""
    kinds = st.sampled_from(sorted(KINDS))
    whole = kinds.flatmap(custom_resources).map(lambda o: (o, None))
    broken = kinds.flatmap(mutated_resources)
    return st.one_of(whole, broken).filter(lambda d: d[0]["metadata"]["name"] not in TAKEN)


def _folder(doc: dict[str, Any]) -> Path:
    folder = Path(tempfile.mkdtemp(prefix="fogfleet-fuzz-"))
    for f in EXAMPLE.glob("*.yaml"):
        shutil.copy(f, folder / f.name)
    (folder / "fuzzed.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))  # as _check reads it
    return folder


def _check(
    argv: list[str], doc: dict[str, Any], broken: str | None, capsys: Any, tried: Counter[str]
) -> None:
    folder = _folder(doc)
    try:
        code = main([*argv, str(folder)])
    finally:
        shutil.rmtree(folder)
    out, err = capsys.readouterr()
    where = f"{doc['kind']}/{doc['metadata']['name']}"
    assert "Traceback" not in out + err, err
    assert code in (0, 2), f"{where} ({broken}): exit {code}\n{err}"
    try:
        # the object as the CLI reads it back from the file (as kubectl would: an unquoted 08
        # is a number there), not the drawn dict
        parse_object(safe_load(yaml.safe_dump(doc, sort_keys=False)))
        ours: InvalidSpec | None = None
    except InvalidSpec as exc:
        ours = exc
    if ours is not None:  # refused by our validation: the CLI says so, naming object and field
        assert code == 2, f"{where} ({broken}) passed {argv[0]} though: {ours}"
        assert f"{where}: {ours.field}" in err, f"{where} ({broken}): {err}"
    elif code == 2:  # a well-formed object the fleet check refused: still named
        assert ("error: " in err and where in err) or "single-robot" in err, err
    tried[f"{'broken' if broken else 'whole'} {'refused' if code else 'ok'}"] += 1


FUZZ = settings(deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


def _fuzz(argv: list[str], examples: int, capsys: pytest.CaptureFixture[str]) -> Counter[str]:
    """``examples`` fuzzed folders through ``fogfleet ARGV``; how many were tried, by kind.
    Each test counts its own runs, so its check does not hang on the order tests run in."""
    tried: Counter[str] = Counter()

    @settings(FUZZ, max_examples=examples)
    @given(case=_docs())
    def run(case: tuple[dict[str, Any], str | None]) -> None:
        _check(argv, *case, capsys, tried)

    run()
    print(f"\nfuzzed {argv[0]} runs: {sum(tried.values())} ({dict(sorted(tried.items()))})")
    return tried


def test_validate_never_prints_a_traceback(capsys: pytest.CaptureFixture[str]) -> None:
    # its checks (the planning is `plan`'s, fuzzed below)
    tried = _fuzz(["validate", "--no-plan"], 300, capsys)
    # hundreds tried, both valid and broken ones
    assert sum(tried.values()) >= 250, tried
    assert any("broken" in k for k in tried) and any("whole" in k for k in tried), tried


def test_plan_never_prints_a_traceback(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["plan", "--generations", "2", "--population", "6", "--seed", "1"]
    tried = _fuzz(argv, 40, capsys)
    assert sum(tried.values()) >= 30, tried
