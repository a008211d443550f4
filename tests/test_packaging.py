"""The wheel ships the four packages, the models (as ``hec.models``) and the ``hec`` script.

The wheel is built with ``pip wheel --no-deps`` (build isolation: setuptools comes from
PyPI) from a clean copy of the repository, so that stale ``build/`` output in the work
tree can neither hide a missing file nor be left behind by the test.
"""

from __future__ import annotations

import configparser
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
# Folder -> where it lands in the wheel.
FOLDERS = {"experiments": "hec", "sim": "hec/sim", "estimator": "hec/estimator", "hardware": "hec/hardware"}
MODEL_PATTERNS = ("*.xml", "boards/*.json", "cells/*.toml", "scenarios/*.toml", "scenarios/*.csv")
_NOT_COPIED = shutil.ignore_patterns(
    ".git",
    ".venv",
    "build",
    "dist",
    "*.egg-info",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
    ".benchmarks",
    "runs",
)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(REPO, src, ignore=_NOT_COPIED)
    out = tmp / "dist"
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PIP_NO_INPUT": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(out), str(src)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, f"pip wheel failed:\n{proc.stdout}\n{proc.stderr}"
    wheels = sorted(out.glob("hec-*.whl"))
    assert len(wheels) == 1, f"expected one hec wheel, got {[w.name for w in out.iterdir()]}"
    return wheels[0]


def _names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as zf:
        return set(zf.namelist())


def _dist_info_file(wheel: Path, name: str) -> str:
    with zipfile.ZipFile(wheel) as zf:
        matches = [n for n in zf.namelist() if n.endswith(f".dist-info/{name}") and n.count("/") == 1]
        assert len(matches) == 1, f"{name} not found once in the wheel's .dist-info: {matches}"
        return zf.read(matches[0]).decode()


def test_wheel_ships_the_models(wheel: Path) -> None:
    names = _names(wheel)
    for required in ("hec/models/ur5.xml", "hec/models/cell.xml", "hec/models/boards/hec_8qr.json"):
        assert required in names
    models = REPO / "models"
    for pattern in MODEL_PATTERNS:
        for path in models.glob(pattern):
            assert f"hec/models/{path.relative_to(models).as_posix()}" in names


def test_wheel_ships_every_package_under_hec_alone(wheel: Path) -> None:
    names = _names(wheel)
    for folder, target in FOLDERS.items():
        assert f"{target}/__init__.py" in names
        # Every sub-package and module in the source tree is in the wheel, the benchmarks excepted.
        for path in (REPO / folder).rglob("*.py"):
            relative = path.relative_to(REPO / folder)
            if "__pycache__" not in path.parts and relative.parts[0] != "bench":
                assert f"{target}/{relative.as_posix()}" in names
    assert not any(n.startswith("hec/bench/") for n in names)
    top_level = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top_level == {"hec"}, top_level
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)


def test_wheel_metadata_and_entry_point(wheel: Path) -> None:
    meta = Parser().parsestr(_dist_info_file(wheel, "METADATA"))
    assert meta["Name"] == "hec"
    assert meta["Version"] == "0.1.0"
    assert meta["Requires-Python"] == ">=3.10"
    assert meta["License-Expression"] == "Apache-2.0"
    requires = meta.get_all("Requires-Dist") or []
    core = [r for r in requires if "extra ==" not in r]
    assert any(r.startswith("opencv-python-headless") and "<5" in r for r in core)
    # The simulator, the devices and Dask are extras, not requirements of the core.
    for optional, extra in (("mujoco", "sim"), ("numba", "sim"), ("pyrealsense2", "realsense")):
        assert not any(r.startswith(optional) for r in core), optional
        assert any(r.startswith(optional) and f'extra == "{extra}"' in r for r in requires), optional
    assert not any(r.startswith(("ur-rtde", "ur_rtde", "dask")) for r in core)

    entry_points = configparser.ConfigParser()
    entry_points.read_string(_dist_info_file(wheel, "entry_points.txt"))
    assert entry_points["console_scripts"]["hec"].strip() == "hec.cli:main"


def test_models_found_in_the_installed_wheel(wheel: Path, tmp_path: Path) -> None:
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    code = "from hec.estimator.common.models import models_dir\nprint(models_dir() / 'ur5.xml')\n"
    # -S: no site-packages, so the editable install of the work tree cannot answer instead.
    proc = subprocess.run(
        [sys.executable, "-S", "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(site)},
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert Path(proc.stdout.strip()) == (site / "hec" / "models" / "ur5.xml").resolve()
    assert Path(proc.stdout.strip()).is_file()


@pytest.mark.needs("sim")
def test_installed_wheel_runs_the_demo(wheel: Path, tmp_path: Path) -> None:
    """`hec demo` from the wheel's files alone (not the editable install of the work tree): the
    subpackages, the models and the regression baseline all come from the wheel."""
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    out = tmp_path / "demo"
    code = (
        "import hec, hec.estimator.solve\n"
        "print('FROM', hec.__file__)\n"
        "from hec.cli import main\n"
        f"raise SystemExit(main(['demo', '--out', {str(out)!r}]))\n"
    )
    # -S: site-packages without its .pth files, so the editable install's import hook is not set
    # up; the dependencies are found on PYTHONPATH after the wheel's files.
    dependencies = sysconfig.get_paths()["purelib"]
    proc = subprocess.run(
        [sys.executable, "-S", "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(site), dependencies])},
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"FROM {site / 'hec' / '__init__.py'}" in proc.stdout
    assert "ekf" in proc.stdout and "truth: translation error" in proc.stdout
    assert "realistic.toml" in proc.stdout  # the demo says it is the ideal cell
    assert (out / "dataset.json").is_file() and (out / "detections.json").is_file()
