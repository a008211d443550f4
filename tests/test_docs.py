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
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    functions = (
        "load_dataset",
        "detect",
        "calibrate",
        "verdict",
        "findings",
        "write_report",
        "save_calibration",
    )
    for name in (*functions, "import_dataset", "verify", "export", "plan", "ImportOptions", "ViewPlan"):
        assert f'id="hec.api.{name}"' in api, name  # rendered from the docstrings (mkdocstrings)


def test_every_results_page_is_written_by_its_benchmark() -> None:
    """The pages under docs/pages/results hold measured figures: each names the benchmark command
    that wrote it (hec.support.results_page), so none is typed by hand."""
    pages = sorted((PAGES / "results").glob("*.md"))
    assert pages
    for page in pages:
        lines = page.read_text().splitlines()
        written_by = re.match(r"Written by `(python -m hec\.bench\.|hec )", lines[2])
        assert lines[0].startswith("# ") and written_by, page


def test_the_guides_state_the_thresholds_the_code_uses() -> None:
    from hec.calibration.loo import MISFIT_RATIO
    from hec.calibration.run import CHECK_METHODS
    from hec.calibration.summary import REDO_RATIO
    from hec.estimator.solve.baselines import MISFIT_RESIDUAL_PX
    from hec.estimator.solve.methods import MAX_CORNER_RMS_PX

    verdict = (PAGES / "is-my-result-good.md").read_text()
    assert f"above {MISFIT_RESIDUAL_PX:.0f} px RMS" in verdict
    assert f"Within {MISFIT_RATIO:g}x the floor" in verdict and f"above {REDO_RATIO:g}x" in verdict
    assert f"{MISFIT_RATIO:g}x-{REDO_RATIO:g}x" in verdict
    trouble = " ".join((PAGES / "troubleshooting.md").read_text().split())
    assert f"more than {MAX_CORNER_RMS_PX:.0f} px RMS" in trouble
    names = [m.removeprefix("opencv-").capitalize() for m in CHECK_METHODS]
    assert f"({names[0]}, then {names[1]} and {names[2]})" in trouble


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


@pytest.mark.parametrize("page", [README, PAGES / "index.md"])
def test_the_figures_the_front_page_quotes_are_the_benchmarks_own(page: Path) -> None:
    """Every table row under "Where it stands" is a line of a results page a benchmark wrote (the
    header and separator lines included), so the front page cannot drift from what was measured."""
    section = page.read_text().split("## Where it stands", 1)[1].split("\n## ", 1)[0]
    quoted = [line for line in section.splitlines() if line.startswith("|")]
    written = {line for path in (PAGES / "results").glob("*.md") for line in path.read_text().splitlines()}
    assert len(quoted) >= 8
    assert [line for line in quoted if line not in written] == []
