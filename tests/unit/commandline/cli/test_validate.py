"""`fogfleet validate`: plan's checks, then the folder planned as `plan` plans it (unless
`--no-plan`), exit 0 or 2, never a traceback (also for random bytes, random text and randomly
broken CR files)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fogfleet.commandline.cli import main

REPO = Path(__file__).resolve().parents[4]
LITE = REPO / "manifests" / "examples" / "warehouse-lite"
LITE_DOCS = [d for f in sorted(LITE.glob("*.yaml")) for d in yaml.safe_load_all(f.read_text()) if d]
FUZZ = settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def validate(capsys: pytest.CaptureFixture[str], *paths: Path) -> tuple[int, str, str]:
    code = main(["validate", *map(str, paths)])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_valid_folder_prints_counts_by_kind_and_exits_0(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = validate(capsys, LITE)
    assert code == 0, err
    assert out.startswith("OK: ") and "1 RobotFleet" in out and "ComputeNode" in out
    assert "SoftwareModule" in out and out.count("\n") == 1


def test_every_error_is_printed_with_object_field_and_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for f in LITE.glob("*.yaml"):
        (tmp_path / f.name).write_text(f.read_text())
    fleet = yaml.safe_load((LITE / "fleet.yaml").read_text())
    fleet["spec"]["robots"].append("no-such-robot")
    (tmp_path / "fleet.yaml").write_text(yaml.safe_dump(fleet))
    (tmp_path / "broken.yaml").write_text("kind: [unclosed\n")
    code, out, err = validate(capsys, tmp_path)
    assert code == 2 and out == ""
    assert "spec.robots[" in err and "no-such-robot" in err and "does not exist" in err
    assert "broken.yaml" in err and "not valid YAML" in err
    assert "2 error(s)" in err


def test_validate_with_no_plan_plans_nothing(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import fogfleet.scheduling.solver as solver

    def refuse(*_: Any, **__: Any) -> None:
        raise AssertionError("validate --no-plan must not plan")

    monkeypatch.setattr(solver, "plan", refuse)
    assert main(["validate", "--no-plan", str(LITE)]) == 0
    assert "not planned (--no-plan)" in capsys.readouterr().out


def test_validate_plans_the_folder_and_says_it_fits(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = validate(capsys, LITE)
    assert code == 0, err
    assert out.rstrip().endswith("planned: it fits")


def _check(code: int, err: str) -> None:
    assert code in (0, 2)
    assert "Traceback" not in err


@FUZZ
@given(data=st.binary(max_size=300))
def test_random_bytes_exit_0_or_2(
    data: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "random.yaml"
    path.write_bytes(data)
    _check(*validate(capsys, path)[::2])


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list(":-[]{},&*!|>'\"#%@` \n\tab1e.0")), max_size=80))
def test_random_yamlish_text_exits_0_or_2(
    text: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "random.yaml"
    path.write_text(text)
    _check(*validate(capsys, path)[::2])


SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["500m", "1Gi", "robot", "edge", "nsga2", "2", "-1", "1e3", "", "default"]),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=10), inner, max_size=3)
    ),
    max_leaves=8,
)


def _mutate(doc: Any, data: st.DataObject) -> Any:
    """``doc`` with one subtree (chosen by walking down at random) replaced or removed."""
    if isinstance(doc, dict) and doc and data.draw(st.integers(0, 3)):
        key = data.draw(st.sampled_from(sorted(doc, key=str)))
        out = dict(doc)
        if data.draw(st.integers(0, 5)) == 0:
            del out[key]
        else:
            out[key] = _mutate(doc[key], data)
        return out
    if isinstance(doc, list) and doc and data.draw(st.integers(0, 3)):
        k = data.draw(st.integers(0, len(doc) - 1))
        return [*doc[:k], _mutate(doc[k], data), *doc[k + 1 :]]
    return data.draw(VALUES)


@pytest.mark.integration  # 300 validations of a whole fleet: about 10 s
@settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_randomly_broken_cr_files_exit_0_or_2_naming_the_object(
    data: st.DataObject, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    docs = list(LITE_DOCS)
    for _ in range(data.draw(st.integers(1, 3))):
        k = data.draw(st.integers(0, len(docs) - 1))
        docs[k] = _mutate(docs[k], data)
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump_all(docs, allow_unicode=True))
    code, _, err = validate(capsys, path)
    _check(code, err)
    if code == 2:
        assert "error: " in err
