"""Benchmark: the session's planner (hec.estimator.geometry.move_plan: a short visit order, least-swing
IK branches, every move checked along its joint path against the joint limits, the wrist's cable limit
and the cell model) on simulated cells, as `hec record --sim` plans them (SimulatedCell.plan), every
planned move then checked again at steps of at most 1 mm at the flange and 0.5 degree per joint:
against the cell model (hec.estimator.geometry.cell_model, the checks of the real session) and
MuJoCo's contacts of the arm and the camera with the cell (wall, floor, table, board), the joint
limits and the cable limit; and each move's largest single-joint swing.

    python -m hec.bench.paths [--placements 50] [--seed 0] [--page docs/pages/results/paths.md]

Cells: the default and the realistic scenario, then `--placements` random placements of the board
(+-0.1 m along each base axis, turned +-10 degrees about its normal: it lies flat on its table, into
which a tilted board would sink and hide its markers) and the mount (+-20 mm, +-10 degrees about
each axis) around the default. The arm starts at the rehearsal's home joints.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.cell_model import CellModel
from hec.estimator.geometry.joint_path import CABLE_LIMIT_RAD, PATH_STEP_RAD, joint_path
from hec.estimator.geometry.kinematics import URKinematics, forward
from hec.rehearsal.rig import HOME_JOINTS
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.session_cell import SimulatedCell
from hec.sim.simulate import scenario_waypoints
from hec.support.results_page import markdown_table, write_results_page

CHECK_STEP_M = 0.001  # the verification's largest flange step, metres
COUNTS = ("cell model", "MuJoCo contact", "joint limit", "cable limit")  # what a planned move may break


def random_placement(base: Scenario, rng: np.random.Generator) -> Scenario:
    """base with the board and the mount moved at random (module doc). The default board lies face
    up, its normal along the base's y: its pitch (about base y) turns it in its plane."""
    board, mount = base.board, base.mount
    board = board.model_copy(
        update={
            "translation_m": tuple(np.add(board.translation_m, rng.uniform(-0.1, 0.1, 3))),
            "rotation_rpy_deg": tuple(np.add(board.rotation_rpy_deg, [0.0, rng.uniform(-10, 10), 0.0])),
        }
    )
    mount = mount.model_copy(
        update={
            "translation_m": tuple(np.add(mount.translation_m, rng.uniform(-0.02, 0.02, 3))),
            "rotation_rpy_deg": tuple(np.add(mount.rotation_rpy_deg, rng.uniform(-10, 10, 3))),
        }
    )
    return base.model_copy(update={"board": board, "mount": mount})


def _fine_path(kinematics: URKinematics, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """(N, 6) the moveJ's joint path at steps of at most 0.5 degree per joint and CHECK_STEP_M at
    the flange (the 0.5 degree path's largest flange step, divided down)."""
    coarse = joint_path(q_from, q_to, PATH_STEP_RAD)
    flange = np.array([forward(kinematics, q)[:3, 3] for q in coarse])
    largest = float(np.max(np.linalg.norm(np.diff(flange, axis=0), axis=1), initial=0.0))
    return joint_path(q_from, q_to, PATH_STEP_RAD * min(1.0, CHECK_STEP_M / max(largest, 1e-12)))


def _broken(sim: SimCell, model: CellModel, path: np.ndarray) -> dict[str, bool]:
    """Which of COUNTS the joint path (N, 6) breaks anywhere past its start (an arm may leave
    where it stands) in the simulated cell sim, its cell model model."""
    lower, upper = np.array(model.kinematics.q_lower), np.array(model.kinematics.q_upper)
    tail = path[1:]
    return {
        "cell model": any(model.problem(q) is not None for q in tail),
        "MuJoCo contact": any(sim.collision_at(q) is not None for q in tail),
        "joint limit": bool(np.any((tail < lower) | (tail > upper))),
        "cable limit": bool(np.any(np.abs(tail[:, 5] - HOME_JOINTS[5]) > CABLE_LIMIT_RAD + 1e-9)),
    }


def plan_and_check(scenario: Scenario, seed: int) -> dict:
    """Plan the scenario's trajectory as the simulated session does and check every planned move
    (module doc): counts of waypoints, planned and refused moves, of planned moves breaking each of
    COUNTS, and the swings (degrees)."""
    sim = SimCell(scenario, np.random.default_rng(seed))
    kinematics, model = sim.cell.kinematics, sim.cell_model()
    try:
        sim.set_joints(HOME_JOINTS)
        moves = SimulatedCell(sim, seed).plan(scenario_waypoints(scenario))
        broken = dict.fromkeys(COUNTS, 0)
        swings, q = [], HOME_JOINTS
        for move in moves:
            if move.joints is None:
                continue
            swings.append(np.degrees(move.swing[1]))
            for name, hit in _broken(sim, model, _fine_path(kinematics, q, move.joints)).items():
                broken[name] += hit
            q = move.joints
    finally:
        sim.close()
    return {
        "waypoints": len(moves),
        "planned": sum(m.joints is not None for m in moves),
        "refused": [f"{m.waypoint.index}: {m.problem}" for m in moves if m.joints is None],
        "broken": broken,
        "home_swing_deg": swings[0] if swings else float("nan"),
        "median_swing_deg": float(np.median(swings)) if swings else float("nan"),
        "largest_swing_deg": float(max(swings, default=float("nan"))),
    }


def _row(name: str, result: dict) -> list[str]:
    return [
        name,
        f"{result['planned']}/{result['waypoints']}",
        *(str(result["broken"][c]) for c in COUNTS),
        f"{result['median_swing_deg']:.1f}",
        f"{result['largest_swing_deg']:.1f}",
        f"{result['home_swing_deg']:.1f}",
    ]


HEADER = ["cell", "planned", *(f"{c} [moves]" for c in COUNTS), "median swing [deg]", "largest", "from home"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hec.bench.paths", description=__doc__.split("\n\n")[0])
    parser.add_argument("--placements", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--page", type=Path, help="also write the results as this documentation page")
    args = parser.parse_args(argv)
    default = load_scenario(None)
    cells = [
        ("default", default),
        ("realistic", load_scenario(models_dir() / "scenarios" / "realistic.toml")),
    ]
    rng = np.random.default_rng(args.seed)
    cells += [(f"placement {i}", random_placement(default, rng)) for i in range(args.placements)]
    print(" | ".join(HEADER))
    rows, results, notes = [], [], []
    for name, scenario in cells:
        result = plan_and_check(scenario, args.seed)
        rows.append(_row(name, result))
        results.append(result)
        print(" | ".join(rows[-1]), flush=True)
        for line in result["refused"]:
            print(f"    refused {line}")
            notes.append(f"{name}, waypoint {line}")
    placements = results[2:]
    medians = [r["median_swing_deg"] for r in placements]
    summary = (
        f"{len(cells)} cells, {sum(r['planned'] for r in results)} planned moves of "
        f"{sum(r['waypoints'] for r in results)} waypoints; planned moves that break the cell model, "
        f"touch in MuJoCo, pass a joint limit or the cable limit: "
        + ", ".join(f"{sum(r['broken'][c] for r in results)}" for c in COUNTS)
        + f". Placements: median of the median largest swing per move {np.median(medians):.1f} deg, "
        f"worst median {max(medians, default=float('nan')):.1f} deg, waypoints refused "
        f"{sum(len(r['refused']) for r in placements)}."
    )
    print(summary)
    if args.page is not None:
        argv_text = " ".join(
            [
                "python -m hec.bench.paths",
                f"--placements {args.placements}",
                f"--seed {args.seed}",
                f"--page {args.page}",
            ]
        )
        body = [
            "Every move the session plans (the default trajectory's 17 waypoints, from the rehearsal's "
            "home joints), checked again along its joint path at 1 mm / 0.5 degree steps. A waypoint "
            "the planner refuses is not visited; a planned move must break nothing. Swings are each "
            "move's largest single-joint turn; the first move, from home, is counted with the rest.",
            markdown_table(HEADER, rows),
            summary,
        ]
        if notes:
            body.append("Refused waypoints:\n\n" + "\n".join(f"- {n}" for n in notes))
        print(f"wrote {write_results_page(args.page, 'Planned paths', argv_text, body)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
