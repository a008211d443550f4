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


def test_the_method_names_the_command_line_offers_are_the_registry() -> None:
    """The parsers list the methods without loading the estimators; the names must be the registry's."""
    from hec.estimator.solve.baselines import OPENCV_METHODS
    from hec.estimator.solve.method_names import DEFAULT_METHOD, METHOD_NAMES, OPENCV_METHOD_NAMES
    from hec.estimator.solve.methods import METHODS

    # As sets: a test that removes a method and puts it back (monkeypatch) moves it to the end.
    assert set(METHODS) == set(METHOD_NAMES) and len(METHOD_NAMES) == len(METHODS)
    assert set(OPENCV_METHODS) == set(OPENCV_METHOD_NAMES) and DEFAULT_METHOD in METHOD_NAMES


def _modules_loaded_by(*argv: str) -> set[str]:
    code = (
        "import sys\nfrom hec.cli import main\n"
        f"try:\n    main({list(argv)!r})\nexcept SystemExit:\n    pass\n"
        "print('\\n'.join(sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return set(proc.stdout.split())


def test_help_and_version_start_without_the_libraries() -> None:
    """hec --help and --version load no numpy; hec export --help neither scipy's rotations nor an
    estimator nor OpenCV (python -m hec.bench.startup measures the times)."""
    for argv in (["--help"], ["--version"]):
        assert "numpy" not in _modules_loaded_by(*argv), argv
    loaded = _modules_loaded_by("export", "--help")
    assert "hec.commands.export" in loaded
    assert not {"scipy.spatial", "cv2", "hec.estimator.solve.methods", "hec.estimator.solve.problem"} & loaded
