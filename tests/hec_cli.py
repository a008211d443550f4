"""Running the `hec` command line inside a test, and small scenarios for it."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from hec.cli import main
from hec.estimator.geometry.waypoints import write_waypoint_file


def scenario_file(folder: Path, views: int = 2, toml: str = "") -> Path:
    """folder/scenario.toml: the first views default views (a waypoint file beside it) plus more
    TOML."""
    from hec.sim.scenario import Scenario  # the simulator loads only for the tests that render
    from hec.sim.simulate import scenario_waypoints

    folder.mkdir(parents=True, exist_ok=True)
    write_waypoint_file(folder / "waypoints.csv", scenario_waypoints(Scenario())[:views])
    (folder / "scenario.toml").write_text('[trajectory]\nkind = "file"\nfile = "waypoints.csv"\n' + toml)
    return folder / "scenario.toml"


def run_hec(argv: list[str]) -> tuple[int, str, str]:
    """main(argv) with stdout and stderr captured (usable from module-scoped fixtures, unlike capsys):
    exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def simulated_dataset(folder: Path, views: int) -> Path:
    """folder/ds: the first views default views rendered by `hec simulate` (scenario_file)."""
    out = folder / "ds"
    code, _, err = run_hec(
        ["simulate", "--out", str(out), "--scenario", str(scenario_file(folder, views)), "--quiet"]
    )
    assert code == 0, err
    return out
