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

from fogfleet.api.loader import parse_object
from fogfleet.cli import main
from fogfleet.errors import InvalidSpec

EXAMPLE = Path(__file__).resolve().parents[2] / "manifests" / "examples" / "single-robot"
TAKEN = {"single-robot", "solo-robot", "solo-edge"}  # keep the example's own names intact

pytestmark = pytest.mark.faults

TRIED: Counter[str] = Counter()


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
    (folder / "fuzzed.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return folder


def _check(argv: list[str], doc: dict[str, Any], broken: str | None, capsys: Any) -> None:
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
        parse_object(doc)
        ours: InvalidSpec | None = None
    except InvalidSpec as exc:
        ours = exc
    if ours is not None:  # refused by our validation: the CLI says so, naming object and field
        assert code == 2, f"{where} ({broken}) passed {argv[0]} though: {ours}"
        assert f"{where}: {ours.field}" in err, f"{where} ({broken}): {err}"
    elif code == 2:  # a well-formed object the fleet check refused: still named
        assert ("error: " in err and where in err) or "single-robot" in err, err
    TRIED[f"{argv[0]} {'broken' if broken else 'whole'} {'refused' if code else 'ok'}"] += 1


@settings(
    max_examples=300,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(case=_docs())
def test_validate_never_prints_a_traceback(
    case: tuple[dict[str, Any], str | None], capsys: pytest.CaptureFixture[str]
) -> None:
    _check(["validate"], *case, capsys)


@settings(
    max_examples=40,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(case=_docs())
def test_plan_never_prints_a_traceback(
    case: tuple[dict[str, Any], str | None], capsys: pytest.CaptureFixture[str]
) -> None:
    _check(["plan", "--generations", "2", "--population", "6", "--seed", "1"], *case, capsys)


def test_enough_were_tried() -> None:
    """Runs after the two above (file order): hundreds tried, both valid and broken ones."""
    total = sum(TRIED.values())
    print(f"\nfuzzed CLI runs: {total} ({dict(sorted(TRIED.items()))})")
    if total == 0:
        pytest.skip("run with the two fuzz tests above")
    assert total >= 300, TRIED
    assert any("broken" in k for k in TRIED) and any("whole" in k for k in TRIED), TRIED
