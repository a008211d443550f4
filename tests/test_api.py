"""hec's public API (hec.api, re-exported as hec.*): the example script runs on a rendered dataset, gives
the command line's calibration, and importing hec does not load it."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.hec_cli import run_hec

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "calibrate_a_dataset.py"


def test_hec_offers_every_name_of_its_api() -> None:
    import hec
    from hec import api

    assert sorted(hec.API) == sorted(api.__all__)
    assert all(getattr(hec, name) is getattr(api, name) for name in hec.API)


def test_importing_hec_does_not_load_the_api() -> None:
    code = (
        "import sys, hec; assert 'hec.api' not in sys.modules; hec.calibrate; assert 'hec.api' in sys.modules"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_the_example_script_calibrates_as_the_command_line_does(
    default_dataset: Path, tmp_path: Path
) -> None:
    dataset = tmp_path / "dataset"
    shutil.copytree(default_dataset, dataset)
    ran = subprocess.run(
        [sys.executable, str(EXAMPLE), str(dataset), str(tmp_path / "report")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert ran.returncode == 0, ran.stderr
    assert "T_flange_cam translation [mm]:" in ran.stdout and "verdict: " in ran.stdout
    assert (tmp_path / "report" / "report.html").is_file()
    code, _, stderr = run_hec(["calibrate", str(dataset), "--json", str(tmp_path / "cli.json"), "--quiet"])
    assert code == 0, stderr
    cli = np.array(json.loads((tmp_path / "cli.json").read_text())["T_flange_cam"])

    import hec

    api = hec.calibrate(hec.load_dataset(dataset), cross_validate=False)
    np.testing.assert_allclose(api.T_flange_cam, cli, atol=1e-9)
    assert hec.verdict(api).grade in ("good", "usable", "redo")


def test_the_api_page_shows_the_example_as_it_is() -> None:
    page = (ROOT / "docs" / "pages" / "api.md").read_text()
    shown = page.split("```python\n", 1)[1].split("```", 1)[0]
    assert EXAMPLE.read_text().split('"""\n', 2)[-1].lstrip() == shown
