"""The documentation: a README short enough to read that points to every page, the pages' site built
strictly (every link and anchor resolves), and no file naming the work's rounds."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = ROOT / "docs" / "pages"
README_MAX_LINES = 300


def test_the_readme_is_short_and_links_every_page() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    linked = set(re.findall(r"\]\(docs/pages/([\w-]+\.md)\)", text))
    pages = {p.name for p in PAGES.glob("*.md")} - {"index.md"}
    assert linked == pages, (sorted(pages - linked), sorted(linked - pages))


def test_the_documentation_site_builds_strictly(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs", reason="mkdocs is a dev tool: pip install -e '.[dev]'")
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "docs" / "mkdocs.yml"),
         "-d", str(tmp_path / "site")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr
    assert (tmp_path / "site" / "calibrate" / "index.html").is_file()


def test_nothing_in_the_repository_names_a_round_of_work() -> None:
    """No file git tracks speaks of the work's rounds (a round and its number): the repository speaks of
    the project."""
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=False)
    paths = [ROOT / name for name in tracked.stdout.splitlines()] if tracked.returncode == 0 else []
    paths = paths or [README, *PAGES.glob("*.md")]  # not a git checkout: the documentation at least
    for path in paths:
        try:
            text = path.read_text()
        except (UnicodeDecodeError, FileNotFoundError):
            continue  # images, data
        found = re.findall(r"(?i)\bstops? \d+\b", text)
        assert not found, f"{path.relative_to(ROOT)}: {found}"
