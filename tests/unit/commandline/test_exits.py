"""``fogfleet.commandline.exits``: both commands, ``fogfleet`` and ``kubectl fogfleet``, end an
error with the one exit code decided there, and print it the same way."""

from __future__ import annotations

import argparse

import pytest

from fogfleet.commandline import cli
from fogfleet.commandline.exits import BAD_INPUT, FAILED, exit_code, positive
from fogfleet.commandline.kubectl.cli import main as plugin_main
from fogfleet.errors import (
    DanglingReference,
    DependencyUnavailable,
    FogfleetError,
    Infeasible,
    InvalidSpec,
)

ERRORS: list[tuple[FogfleetError, int]] = [
    (InvalidSpec("RobotFleet/f", "spec.x", "bad"), BAD_INPUT),
    (DanglingReference("RobotFleet/f", "spec.robots[0]", "does not exist"), BAD_INPUT),
    (Infeasible("RobotFleet/f", "", "no placement fits"), BAD_INPUT),
    (DependencyUnavailable("the cluster did not answer"), FAILED),
    (FogfleetError("something else"), FAILED),
]


@pytest.mark.parametrize(("error", "code"), ERRORS)
def test_each_error_has_one_exit_code(error: FogfleetError, code: int) -> None:
    assert exit_code(error) == code
    assert (BAD_INPUT, FAILED) == (2, 1)  # what docs/operations.md and the plugin's doc say


@pytest.mark.parametrize(("error", "code"), ERRORS)
def test_both_commands_end_an_error_alike(
    error: FogfleetError,
    code: int,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    def fail(*_: object) -> int:
        raise error

    monkeypatch.setattr(cli, "cmd_validate", fail)
    assert cli.main(["validate", "x"]) == code
    from_cli = capsys.readouterr().err
    assert plugin_main(["top", "f"], connect=fail) == code
    assert capsys.readouterr().err == from_cli == f"error: {error}\n"


def test_a_bug_in_the_plugin_is_not_called_bad_input() -> None:
    def broken(*_: object) -> object:
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        plugin_main(["top", "f"], connect=broken)  # type: ignore[arg-type]


@pytest.mark.parametrize("text", ["0", "-1", "nan"])
def test_positive_refuses_zero_negative_and_nan(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="greater than zero"):
        positive(float)(text)
    assert positive(int)("3") == 3
