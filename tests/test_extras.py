"""The core without the extras: the command line starts and the core commands run with every
optional library hidden, and a command that needs one names the extra to install."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hec.support.extras import EXTRA_OF_MODULE

REPO = Path(__file__).resolve().parent.parent
_HIDE_EXTRAS = f"""
import importlib.abc, sys
class Hide(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {sorted(EXTRA_OF_MODULE)!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Hide())
from hec.cli import main
"""


def _hec_without_extras(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    code = _HIDE_EXTRAS + f"sys.exit(main({list(argv)!r}))\n"
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, env=os.environ, timeout=120
    )


def test_help_and_export_run_without_any_extra(tmp_path: Path) -> None:
    proc = _hec_without_extras("export", "--help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "--to" in proc.stdout


def test_a_command_needing_the_simulator_names_the_extra(tmp_path: Path) -> None:
    proc = _hec_without_extras("simulate", "--out", str(tmp_path / "d"), cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "hec simulate needs the simulated cell (mujoco is not installed)" in proc.stderr
    assert "pip install 'hec[sim]'" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "d").exists()
