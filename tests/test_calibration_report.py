"""`hec calibrate --report DIR`: one calibration as a page, opened in a real headless browser (Debian's
chromium, which experiments/bootstrap.sh installs): it renders, every figure decodes, and nothing
goes to the console."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from hec.calibration.html_report import REPORT_FILE
from tests.hec_cli import run_hec

CHROMIUM = shutil.which("chromium")
PLOTS = 3  # residuals per frame, per marker, the poses


def _open_in_chromium(page: Path) -> tuple[str, str]:
    """The page's DOM once loaded, and the browser's log (console messages are lines with CONSOLE)."""
    assert CHROMIUM is not None, "chromium is not installed: run experiments/bootstrap.sh"
    done = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
         "--virtual-time-budget=10000", "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=300, check=True,
    )  # fmt: skip
    return done.stdout, done.stderr


def test_the_report_of_one_calibration_opens_with_every_figure_drawn(
    default_dataset: Path, tmp_path: Path
) -> None:
    dataset = tmp_path / "dataset"
    shutil.copytree(default_dataset, dataset)
    code, stdout, stderr = run_hec(
        ["calibrate", str(dataset), "--report", str(tmp_path / "report"), "--quiet"]
    )
    assert code == 0, stderr
    page = tmp_path / "report" / REPORT_FILE
    assert f"wrote {page}" in stdout
    dom, log = _open_in_chromium(page)
    frames = len(re.findall(r"<figcaption>frame \d+: [\d.]+ px RMS</figcaption>", dom))
    assert frames >= 15  # the default trajectory's 17 views, less any the detector could not use
    figures = re.search(r'data-figures="(\d+)/(\d+)"', dom)
    assert figures is not None, "the page's check did not run"
    assert figures.group(1) == figures.group(2) == str(PLOTS + frames)
    assert "CONSOLE" not in log, log
    for heading in (
        "Residuals per frame",
        "Residuals per marker",
        "The camera around the board",
        "The frames",
    ):
        assert f"<h2>{heading}</h2>" in dom
    assert re.search(r"<p class=\"verdict (good|usable|redo)\"><b>(good|usable|redo)</b>: ", dom), dom[:2000]
    assert "Cramer-Rao bound</th>" in dom


def test_a_report_path_that_is_a_file_is_refused_before_any_work(tmp_path: Path) -> None:
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    code, _, stderr = run_hec(["calibrate", str(tmp_path / "dataset"), "--report", str(taken), "--quiet"])
    assert code != 0
    assert f"{taken}: is a file; --report takes a folder (report.html goes in it)" in stderr
    assert taken.read_text() == "mine"
