"""The docs check: README.md and docs/ agree with the repository, and the checker catches what
it should (links, anchors, make targets, CLI flags) on small bad inputs."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("check_docs", HERE / "check_docs.py")
assert _spec is not None and _spec.loader is not None
check_docs = importlib.util.module_from_spec(_spec)
sys.modules["check_docs"] = check_docs
_spec.loader.exec_module(check_docs)

MAKEFILE = """\
help: ## Show this help
\t@true
venv: $(BIN)/fogfleet ## Create .venv
test: venv lint ## Everything
lint unit: venv
bench-real-report: venv ## tables
$(BIN)/fogfleet: pyproject.toml
\ttouch $@
"""

FAKE_CLI = {
    "": frozenset({"--help"}),
    "plan": frozenset({"--help", "--json", "--seed"}),
    "bench": frozenset({"--help", "--runs", "--json"}),
}


def _repo(tmp_path: Path, readme: str, docs: dict[str, str] | None = None) -> Path:
    (tmp_path / "Makefile").write_text(MAKEFILE)
    (tmp_path / "README.md").write_text(readme)
    for name, text in (docs or {}).items():
        path = tmp_path / "docs" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


def _messages(root: Path, fogfleet=lambda: FAKE_CLI) -> list[str]:
    return [p.render(root) for p in check_docs.check(root, fogfleet=fogfleet)]


def test_the_repository_docs_pass() -> None:
    root = HERE.parents[1]
    problems = check_docs.check(root)
    assert [p.render(root) for p in problems] == []
    assert check_docs.main([str(root)]) == 0


def test_good_links_images_and_anchors_pass(tmp_path: Path) -> None:
    (tmp_path / "pic.svg").write_text("<svg/>")
    root = _repo(
        tmp_path,
        "# Top\n\nSee [concepts](docs/concepts.md#how-it-plans-f1f4), ![plot](pic.svg),\n"
        "[here](#top), [web](https://example.com/x.md) and [ref].\n\n[ref]: docs/concepts.md\n",
        {"concepts.md": "# Concepts\n\n## How it plans (F1\u2013F4)\n\n[back](../README.md#top)\n"},
    )
    assert _messages(root) == []


def test_a_missing_file_is_reported(tmp_path: Path) -> None:
    root = _repo(tmp_path, "# A\n\nRead [the manual](docs/nowhere.md) first.\n")
    assert _messages(root) == [
        "README.md:3: link 'docs/nowhere.md': docs/nowhere.md does not exist"
    ]


def test_a_missing_image_and_reference_are_reported(tmp_path: Path) -> None:
    root = _repo(tmp_path, "# A\n\n![plot](gone.svg)\n\n[r]: ./docs/x.md\n")
    assert len(_messages(root)) == 2


def test_a_missing_anchor_is_reported(tmp_path: Path) -> None:
    root = _repo(
        tmp_path,
        "# A\n\n[x](docs/c.md#no-such-part) and [y](#a) and [z](#b)\n",
        {"c.md": "# C\n\n## Some part\n"},
    )
    assert _messages(root) == [
        "README.md:3: link 'docs/c.md#no-such-part': no heading makes #no-such-part",
        "README.md:3: link '#b': no heading makes #b",
    ]


def test_links_inside_code_are_not_links(tmp_path: Path) -> None:
    root = _repo(tmp_path, "# A\n\n`[x](gone.md)`\n\n```\n[y](gone.md)\n```\n")
    assert _messages(root) == []


def test_github_slugs() -> None:
    assert check_docs.slug("Real nodes: the paper's experiment (`make bench-real`)") == (
        "real-nodes-the-papers-experiment-make-bench-real"
    )
    assert check_docs.slug("How it plans (F1\u2013F4, NSGA-II)") == "how-it-plans-f1f4-nsga-ii"
    assert check_docs.slug("The `status_x` of a [fleet](f.md)") == "the-status_x-of-a-fleet"


def test_repeated_headings_get_numbered_anchors(tmp_path: Path) -> None:
    path = tmp_path / "a.md"
    path.write_text("# Notes\n\n## Notes\n\n```\n# Notes\n```\n")
    assert check_docs.anchors(path) == {"notes", "notes-1"}


def test_makefile_targets(tmp_path: Path) -> None:
    (tmp_path / "Makefile").write_text(MAKEFILE)
    assert check_docs.make_targets(tmp_path / "Makefile") == {
        "help",
        "venv",
        "test",
        "lint",
        "unit",
        "bench-real-report",
    }


@pytest.mark.parametrize(
    ("text", "bad"),
    [
        ("Run `make tests`.", "`make tests`: no such Makefile target"),
        ("```bash\nmake demo-offline   # only the first part\n```", "`make demo-offline`"),
        ("```\nPROFILE=paper make lint nope\n```", "`make nope`"),
        ("`make bench-real SIZES=1`", "`make bench-real`"),
    ],
)
def test_an_unknown_make_target_is_reported(tmp_path: Path, text: str, bad: str) -> None:
    root = _repo(tmp_path, f"# A\n\n{text}\n")
    messages = _messages(root)
    assert len(messages) == 1
    assert bad in messages[0]


def test_known_make_targets_and_prose_pass(tmp_path: Path) -> None:
    root = _repo(
        tmp_path,
        "# A\n\n`make test` and `make lint unit` and `make bench-real-report PROFILE=paper`;\n"
        "`cd x && make help`; the word `make` alone; `we make things`.\n\n"
        "```bash\nmake test    # make everything\n```\n",
    )
    assert _messages(root) == []


@pytest.mark.parametrize(
    ("text", "bad"),
    [
        ("`fogfleet plan x --jsn`", "`fogfleet plan --jsn`: no such option"),
        ("`fogfleet bench scheduling --quick`", "`fogfleet bench --quick`: no such option"),
        ("`fogfleet plna x`", "`fogfleet plna`: no such subcommand"),
        ("```\n.venv/bin/fogfleet plan x \\\n  --seed 1 --plot p.png\n```", "--plot"),
        ("```\npython -m fogfleet plan x --nope | head\n```", "--nope"),
    ],
)
def test_an_unknown_cli_flag_is_reported(tmp_path: Path, text: str, bad: str) -> None:
    root = _repo(tmp_path, f"# A\n\n{text}\n")
    messages = _messages(root)
    assert len(messages) == 1, messages
    assert bad in messages[0]


def test_known_flags_and_other_programs_pass(tmp_path: Path) -> None:
    root = _repo(
        tmp_path,
        "# A\n\n`fogfleet plan x --json | jq --raw-output .`, `fogfleet bench replan --runs 3`,\n"
        "`helm install fogfleet charts/fogfleet --create-namespace`, `fogfleet.io/tier`,\n"
        "`kubectl logs -n fogfleet-system deploy/fogfleet --follow`.\n",
    )
    assert _messages(root) == []


def test_the_real_parser_is_read() -> None:
    commands = check_docs.fogfleet_commands()
    assert {"plan", "simulate", "render", "crds", "run", "twin", "bench"} <= commands.keys()
    assert "--from-prometheus" in commands["simulate"]
    assert "--from-prometheus" not in commands["plan"]


def test_the_real_parser_catches_a_wrong_flag(tmp_path: Path) -> None:
    root = _repo(tmp_path, "# A\n\n`fogfleet plan fleet --from-prometheus http://p:9090`\n")
    messages = _messages(root, fogfleet=check_docs.fogfleet_commands)
    assert messages == [
        "README.md:3: `fogfleet plan --from-prometheus`: no such option",
    ]


def test_harness_flags_are_read_from_its_help(tmp_path: Path) -> None:
    harness = tmp_path / "e2e" / "bed" / "harness.py"
    harness.parent.mkdir(parents=True)
    harness.write_text(
        "import argparse\n"
        "p = argparse.ArgumentParser(prog='harness.py')\n"
        "s = p.add_subparsers(dest='cmd', required=True)\n"
        "s.add_parser('up').add_argument('--profile')\n"
        "s.add_parser('down')\n"
        "p.parse_args()\n"
    )
    root = _repo(
        tmp_path,
        "# A\n\n`python e2e/bed/harness.py up --profile paper`, `harness.py down`,\n"
        "`harness.py kubectl get nodes --show-labels`, `harness.py up --proflie x`,\n"
        "`harness.py sideways`.\n",
    )
    assert _messages(root) == [
        "README.md:4: `harness.py up --proflie`: no such option",
        "README.md:5: `harness.py sideways`: no such subcommand",
    ]


WIDGETS_CRD = """\
apiVersion: apiextensions.k8s.io/v1
kind: CustomResourceDefinition
metadata: {name: widgets.example.io}
spec:
  group: example.io
  names: {kind: Widget, plural: widgets, singular: widget, shortNames: [wd]}
  versions:
  - name: v1
    additionalPrinterColumns:
    - {name: Ready, type: string, jsonPath: .status.ready}
    - {name: Miss, type: string, jsonPath: .status.miss}
    - {name: Fleets, type: string, jsonPath: .status.fleets, priority: 1}
"""


def _with_crds(tmp_path: Path, readme: str) -> Path:
    root = _repo(tmp_path, readme)
    (root / "crds").mkdir()
    (root / "crds" / "widgets.example.io.yaml").write_text(WIDGETS_CRD)
    return root


@pytest.mark.parametrize(
    ("text", "bad"),
    [
        ("```bash\nkubectl get widgets -n x   # READY, MISS, SPLIT\n```\n", "SPLIT"),
        ("```\nkubectl get wd  # NAME, FLEETS\n```\n", "FLEETS"),  # a wide column, no -o wide
        (
            "`kubectl get computenodes` is not ours; `kubectl get widgets` adds `FLEETZ`.\n",
            "FLEETZ",
        ),
        ("- `kubectl get widgets` shows `READY`.\n  `-o wide` adds `CPU`.\n", "CPU"),
    ],
)
def test_a_column_the_crd_does_not_print_is_reported(tmp_path: Path, text: str, bad: str) -> None:
    root = _with_crds(tmp_path, text)
    (problem,) = _messages(root)
    line = 2 if text.startswith("```") else 1  # the command's line, or the item's first
    assert problem.startswith(f"README.md:{line}: `kubectl get ") and f"no column {bad} " in problem


def test_real_columns_other_kinds_and_prose_pass(tmp_path: Path) -> None:
    text = (
        "```bash\n"
        "kubectl get widgets.example.io -A   # NAMESPACE, NAME, READY, MISS\n"
        "kubectl get widget -o wide          # READY, FLEETS\n"
        "kubectl get pods -n x               # READY, STATUS, RESTARTS\n"
        "kubectl get widgets                 # see the status below\n"
        "```\n\n"
        "- `kubectl get widgets` shows `READY` and `MISS`; `-o wide` adds `FLEETS`.\n"
        "- `kubectl get pods` shows `STATUS`.\n\n"
        "`DEBUG` logs say more (no kubectl here).\n"
    )
    assert _messages(_with_crds(tmp_path, text)) == []


def test_the_repository_columns_come_from_the_generated_crds() -> None:
    columns = check_docs._columns_checker()
    kinds = columns.kinds_in(HERE.parents[1])
    assert {"MISS", "PLACED"} <= kinds["robotfleets"].columns
    assert "FLEETS" in kinds["cn"].wide and "FLEETS" not in kinds["computenodes"].columns
