"""The README is a user's guide: short, two set-up commands (the second is CI's), links that resolve,
and results that are the generated ones."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def _setup_commands(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if line.startswith("    python3 -m venv")]


def test_readme_is_a_guide_not_a_notebook():
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines; measurement records belong in docs/notes/"


def test_readme_has_two_setup_commands_and_ci_runs_the_second():
    commands = _setup_commands(README.read_text())
    assert len(commands) == 2, commands
    assert commands[0].endswith("fcmpc-fly"), "the first command installs and runs the main job"
    assert commands[1] in (ROOT / ".ci" / "run").read_text(), ".ci/run must run the README's test command"


@pytest.mark.parametrize("page", [README, *sorted((ROOT / "docs").rglob("*.md"))],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path):
    missing = []
    for target in LINK.findall(page.read_text()):
        if "://" in target or target.startswith("mailto:"):
            continue
        if not (page.parent / target).exists():
            missing.append(target)
    assert not missing, f"{page.relative_to(ROOT)} links to missing files: {missing}"


def test_readme_results_are_the_generated_ones():
    results = ROOT / "docs" / "results.md"
    readme = README.read_text()
    blocks = dict(re.findall(r"<!-- results:(\w+) -->\n(.*?)\n<!-- /results:\1 -->", readme, re.S))
    assert blocks, "README lost its results blocks"
    if not results.exists():
        pytest.fail("docs/results.md missing: run fcmpc-results")
    generated = results.read_text()
    for name, block in blocks.items():
        table_rows = [line for line in block.splitlines() if line.startswith("| ")]
        assert table_rows, f"README results:{name} is not a generated table"
        for line in table_rows:
            assert line in generated, f"README row not in docs/results.md: {line}"
