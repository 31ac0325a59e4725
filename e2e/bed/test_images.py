"""Image recipes: what invalidates a cached image (no build needed for these)."""

from __future__ import annotations

from pathlib import Path

import pytest

from e2e.bed import images


def test_dockerignore_last_match_wins_and_negation_re_includes() -> None:
    patterns = ["*", "!pyproject.toml", "!operator/", "**/__pycache__", "**/*.pyc"]
    assert images._ignored("e2e/bed/harness.py", patterns)
    assert not images._ignored("pyproject.toml", patterns)
    assert not images._ignored("operator/fogfleet/commandline/cli/__init__.py", patterns)
    assert images._ignored("operator/fogfleet/__pycache__/cli.cpython-311.pyc", patterns)


def test_the_operator_recipe_reads_the_package_and_not_the_tests() -> None:
    recipe = next(r for r in images.RECIPES if r.name == "operator")
    files = {str(p.relative_to(images.REPO_ROOT)) for p in images._context_files(recipe)}
    assert "operator/fogfleet/commandline/cli/__init__.py" in files and "pyproject.toml" in files
    assert not any(f.startswith(("tests/", "e2e/")) for f in files)


def test_a_changed_source_file_changes_the_image_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "app").mkdir()
    (tmp_path / "app" / "main.py").write_text("print(1)\n")
    (tmp_path / "Dockerfile").write_text("FROM base\nCOPY app/ /app/\n")
    monkeypatch.setattr(images, "REPO_ROOT", tmp_path)
    recipe = images.Recipe("t", "localhost/t:1", "Dockerfile")
    base = tmp_path / "base.tar"
    before = images.recipe_key(recipe, base)
    assert images.recipe_key(recipe, base) == before
    (tmp_path / "app" / "main.py").write_text("print(2)\n")
    assert images.recipe_key(recipe, base) != before


def test_copy_from_a_stage_reads_nothing_from_the_context(tmp_path: Path) -> None:
    dockerfile = tmp_path / "Dockerfile"
    dockerfile.write_text(
        "FROM a AS build\nCOPY pyproject.toml README.md ./\nCOPY --from=build /opt /opt\n"
    )
    assert images._copy_sources(dockerfile) == ["pyproject.toml", "README.md"]
