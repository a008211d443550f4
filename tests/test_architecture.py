"""The layout's rules. Everything installs under the one namespace hec (the repository's folders
mapped into it: experiments -> hec, sim -> hec.sim, estimator -> hec.estimator, hardware ->
hec.hardware). Dependencies point one way, between the folders and between the subpackages inside
them (LAYERS); no two modules and no two subpackages import each other in a circle; no project
file is over 500 lines; and the real cell's path runs without MuJoCo or any OpenGL library."""

from __future__ import annotations

import ast
import faulthandler
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tests.test_rtde_loopback import Q_HOME, hang_guard

REPO = Path(__file__).resolve().parent.parent
# Folder -> the name it installs under.
FOLDERS = {"experiments": "hec", "sim": "hec.sim", "estimator": "hec.estimator", "hardware": "hec.hardware"}
MAX_LINES = 500
_ESTIMATOR = ("hec.estimator", "hec.estimator.common", "hec.estimator.geometry")
_ESTIMATOR_ALL = (*_ESTIMATOR, *(f"hec.estimator.{s}" for s in ("targets", "observe", "solve", "io")))
_BELOW_COMMANDS = (
    "hec.support",
    "hec.calibration",
    "hec.session",
    "hec.sweep",
    "hec.regress",
    "hec.rehearsal",
)
# What each unit (a subpackage, or a package's own top-level modules) may import besides itself.
# The estimator's floors: common (file helpers, shared types) at the bottom, then geometry, then
# targets and observe, then solve; file formats (io) above the maths. sim never imports the solver.
LAYERS: dict[str, tuple[str, ...]] = {
    "hec.estimator": (),
    "hec.estimator.common": (),
    "hec.estimator.geometry": ("hec.estimator.common",),
    "hec.estimator.targets": _ESTIMATOR,
    "hec.estimator.observe": (*_ESTIMATOR, "hec.estimator.targets"),
    "hec.estimator.solve": (*_ESTIMATOR, "hec.estimator.targets", "hec.estimator.observe"),
    "hec.estimator.io": _ESTIMATOR_ALL,
    "hec.sim": tuple(u for u in _ESTIMATOR_ALL if u != "hec.estimator.solve"),
    "hec.hardware": _ESTIMATOR_ALL,
    "hec.support": (*_ESTIMATOR_ALL, "hec.sim"),
    "hec.calibration": (*_ESTIMATOR_ALL, "hec.support"),
    "hec.session": (*_ESTIMATOR_ALL, "hec.sim", "hec.hardware", "hec.support", "hec.calibration"),
    "hec.sweep": (*_ESTIMATOR_ALL, "hec.sim", "hec.support", "hec.calibration"),
    "hec.regress": (*_ESTIMATOR_ALL, "hec.sim", "hec.support"),
    # The stand-ins of the real cell (a loopback UR controller, a software RealSense) over the simulated one.
    "hec.rehearsal": (*_ESTIMATOR_ALL, "hec.sim"),
    "hec.commands": (*_ESTIMATOR_ALL, "hec.sim", "hec.hardware", *_BELOW_COMMANDS),
    "hec": (*_ESTIMATOR_ALL, "hec.sim", "hec.hardware", *_BELOW_COMMANDS, "hec.commands"),
    # The benchmarks (not installed) may use anything but the command line.
    "hec.bench": (*_ESTIMATOR_ALL, "hec.sim", "hec.hardware", *_BELOW_COMMANDS, "hec.commands"),
}
REAL_CELL_MODULES = (
    "hec.hardware.cell",
    "hec.hardware.realsense",
    "hec.hardware.ur_robot",
    "hec.session.session",
    "hec.commands.record",
    "hec.session.adaptive",
    "hec.commands.teach",
    "hec.session.cell_config",
    "hec.cli",
    "hec.commands.table",
)
HOST = "127.0.0.7"  # apart from the other loopback tests' addresses


def _module_name(path: Path) -> str:
    folder, *parts = path.relative_to(REPO).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([FOLDERS[folder], *parts])


def project_modules() -> dict[str, Path]:
    """Every module of the project's packages: dotted name under hec -> file."""
    return {
        _module_name(path): path
        for folder in FOLDERS
        for path in sorted((REPO / folder).rglob("*.py"))
        if "__pycache__" not in path.parts
    }


def unit(module: str) -> str:
    """The layer a module belongs to: the longest LAYERS key that is the module or a package of it."""
    return max((u for u in LAYERS if module == u or module.startswith(u + ".")), key=len)


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """The project modules a file imports anywhere in it (module level, in functions, and under
    TYPE_CHECKING): for `from a.b import c`, a.b.c when that is a module, else a.b."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [f"{node.module}.{alias.name}" for alias in node.names] + [node.module]
        else:
            continue
        for name in names:
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name:
                found.add(name)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = project_modules()
    known = set(modules)
    return {name: imported_modules(path, known) - {name} for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as [a, b, ..., a], or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                return path[path.index(target) :] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_find_cycle_finds_a_cycle() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_project_modules() -> None:
    graph = import_graph()
    assert len(graph) > 50
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_layers_import_only_downward() -> None:
    wrong = []
    for module, targets in import_graph().items():
        for target in targets:
            if unit(target) != unit(module) and unit(target) not in LAYERS[unit(module)]:
                wrong.append(f"{module} imports {target}")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycle_between_subpackages() -> None:
    graph: dict[str, set[str]] = {}
    for module, targets in import_graph().items():
        graph.setdefault(unit(module), set()).update(unit(t) for t in targets if unit(t) != unit(module))
    assert len(graph) >= len(LAYERS) - 1
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_every_import_goes_through_the_hec_namespace() -> None:
    """No module, test or benchmark imports a folder by its own name (import sim): installed, only hec
    exists, and a module loaded under two names would be two modules."""
    old = {*FOLDERS, "hec_models"}
    wrong = []
    for path in sorted([*(REPO / "tests").rglob("*.py"), *project_modules().values()]):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            wrong += [f"{path.relative_to(REPO)}: {n}" for n in names if n.split(".")[0] in old]
    assert not wrong, "\n".join(wrong)


def test_estimator_and_hardware_never_import_mujoco() -> None:
    for name, path in project_modules().items():
        if unit(name).startswith(("hec.estimator", "hec.hardware")):
            tree = ast.parse(path.read_text())
            names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
            names += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
            assert not [n for n in names if n.split(".")[0] == "mujoco"], name


def test_no_project_file_over_500_lines() -> None:
    long = {
        str(path.relative_to(REPO)): n
        for path in project_modules().values()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert not long, long


_NO_GL = """
import ctypes.util, os, sys
real_find_library = ctypes.util.find_library
GL_NAMES = ("EGL", "OSMesa", "GL", "GLX", "OpenGL")
ctypes.util.find_library = lambda name: None if name in GL_NAMES else real_find_library(name)
os.environ.pop("MUJOCO_GL", None)
os.environ.pop("PYOPENGL_PLATFORM", None)
"""
_REPORT = """
loaded = sorted(m for m in sys.modules if m.split(".")[0] == "mujoco" or m.startswith("hec.sim"))
print("LOADED", loaded)
"""


def _run_python(code: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env, timeout=timeout
    )


def test_the_no_gl_stand_in_really_hides_opengl() -> None:
    """The check below means something only if importing sim fails under the same stand-in."""
    proc = _run_python(_NO_GL + "import hec.sim\n")
    assert proc.returncode != 0 and "NoGLBackendError" in proc.stderr


def test_real_cell_modules_import_neither_mujoco_nor_sim() -> None:
    imports = "".join(f"import {m}\n" for m in REAL_CELL_MODULES)
    proc = _run_python(_NO_GL + imports + _REPORT)
    assert proc.returncode == 0, proc.stderr
    assert "LOADED []" in proc.stdout, proc.stdout


@pytest.fixture
def loopback_ur(tmp_path: Path) -> Iterator[Path]:
    """A loopback UR controller over a simulated cell (in this process), and a cell file for it."""
    from hec.rehearsal.rtde_loopback import LoopbackController
    from hec.sim.cell import SimCell
    from hec.sim.scenario import load_scenario

    hang_guard(120.0)
    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    cell.set_joints(Q_HOME)
    controller = LoopbackController(cell, threading.Lock(), host=HOST, speedup=4.0).start()
    try:
        yield tmp_path
    finally:
        controller.close()
        faulthandler.cancel_dump_traceback_later()


def test_record_dry_run_on_a_robot_pc_without_opengl(loopback_ur: Path) -> None:
    waypoints = loopback_ur / "waypoints.csv"
    q = ",".join(repr(float(v)) for v in Q_HOME)
    waypoints.write_text("q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,label\n" + f"{q},home\n")
    out = loopback_ur / "session"
    argv = ["record", "--robot", HOST, "--waypoints", str(waypoints), "--out", str(out), "--dry-run"]
    code = _NO_GL + f"from hec.cli import main\nrc = main({argv!r})\n" + _REPORT + "sys.exit(rc)\n"
    proc = _run_python(code)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "dry run: nothing moved" in proc.stdout
    assert "LOADED []" in proc.stdout, proc.stdout
    assert not out.exists()
