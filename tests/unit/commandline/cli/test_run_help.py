"""``fogfleet run --help`` lists every setting with its variable and default (issue 36)."""

from __future__ import annotations

import pytest

from fogfleet.commandline.cli import main
from fogfleet.settings import Settings, settings_help


def _help(capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as done:
        main(["run", "--help"])
    assert done.value.code == 0
    return capsys.readouterr().out


def test_run_help_lists_every_setting_with_its_variable_and_default(
    capsys: pytest.CaptureFixture[str],
) -> None:
    text = _help(capsys)
    lines = text.splitlines()
    for name, field in Settings.model_fields.items():
        variable = f"FOGFLEET_{name.upper()}"
        line = next((ln for ln in lines if ln.strip().startswith(f"{variable} ")), None)
        assert line is not None, f"{variable} is missing from `fogfleet run --help`"
        assert "(default: " in line, line
        assert field.description and field.description in text, name


def test_the_defaults_shown_are_the_settings_defaults(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in Settings.model_fields:
        monkeypatch.delenv(f"FOGFLEET_{name.upper()}", raising=False)
    settings = Settings()
    shown = {variable: default for variable, default, _ in settings_help()}
    assert shown["FOGFLEET_LOG_LEVEL"] == settings.log_level == "INFO"
    assert shown["FOGFLEET_WATCH_CACHE"] == "true" and settings.watch_cache is True
    assert shown["FOGFLEET_DRIFT_INTERVAL_SECONDS"] == "60"
    assert shown["FOGFLEET_PROMETHEUS_URL"] == "unset" and settings.prometheus_url is None
    for name in Settings.model_fields:
        default = shown[f"FOGFLEET_{name.upper()}"]
        value = getattr(settings, name)
        if isinstance(value, bool):
            assert default == str(value).lower(), name
        elif isinstance(value, int | float) or (
            isinstance(value, str) and name != "leader_election_identity"
        ):
            # what the environment would say to get the default back
            monkeypatch.setenv(f"FOGFLEET_{name.upper()}", default)
            assert getattr(Settings(), name) == value, name
            monkeypatch.delenv(f"FOGFLEET_{name.upper()}")


def test_a_hub_without_this_clusters_name_is_refused_naming_the_variable(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pydantic import ValidationError

    for name in Settings.model_fields:
        monkeypatch.delenv(f"FOGFLEET_{name.upper()}", raising=False)
    monkeypatch.setenv("FOGFLEET_HUB_KUBECONFIG", "/etc/fogfleet/hub/kubeconfig")
    with pytest.raises(ValidationError, match="FOGFLEET_CLUSTER_NAME: needed with"):
        Settings()
    monkeypatch.setenv("FOGFLEET_CLUSTER_NAME", "site")
    assert Settings().cluster_name == "site"
