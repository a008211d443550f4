"""`hec calibrate` end to end on the default simulated dataset: the printed report, the JSON, every method
side by side, the leave-one-frame-out figures, and clear errors for bad priors and too few frames.

The dataset is copied once per module (the first run detects and writes its cache; the rest reuse it).
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hec.calibration.loo import LOO_KEY, format_loo
from hec.calibration.report import write_json
from hec.cli import main
from hec.estimator.geometry.transforms import pose_error
from hec.estimator.io.dataset import load_dataset
from hec.estimator.observe.observations import CACHE_FILE, load_observations, save_observations
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.cross_validation import CrossValidation, FoldPrediction, SkippedFold
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.problem import CalibrationInputError
from tests.hec_cli import run_hec

JSON_KEYS = {
    "method",
    "T_flange_cam",
    "covariance",
    "covariance_convention",
    "sigma_translation_mm",
    "sigma_rotation_deg",
    "residual_rms_px",
    "error_translation_mm",
    "error_rotation_deg",
    "translation_mm",
    "quaternion_wxyz",
    "rotation_vector_rad",
    "rpy_deg",
    "T_base_board",
    "observations_used",
    "observations_rejected",
    "frame_residuals",
    "marker_residuals",
    "iterations",
    "time_s",
    "observability",
    "leave_one_frame_out",
    "warnings",
}
LOO_LINE = re.compile(
    r"leave-one-frame-out prediction: (\d+\.\d\d) px RMS, (\d+\.\d\d) mm RMS in the base frame "
    r"\(17 folds, \d+\.\d s\)"
)


@pytest.fixture(scope="module")
def dataset(default_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the default dataset without a detections cache."""
    copy = tmp_path_factory.mktemp("calibrate") / "default"
    shutil.copytree(default_dataset, copy)
    (copy / CACHE_FILE).unlink(missing_ok=True)
    return copy


@pytest.fixture(scope="module")
def first_run(dataset: Path) -> tuple[int, str, str, Path]:
    """`hec calibrate DATASET --json OUT --verbose` on the copy: detects, caches, calibrates with ekf."""
    out = dataset.parent / "ekf.json"
    return (*run_hec(["calibrate", str(dataset), "--json", str(out), "--quiet", "--verbose"]), out)


def test_first_run_detects_and_caches_then_reuses_the_cache(dataset: Path, first_run) -> None:
    code, stdout, stderr, _ = first_run
    assert code == 0, stderr
    assert "no detections cache" in stderr
    assert (dataset / CACHE_FILE).is_file()
    code, stdout, stderr = run_hec(["calibrate", str(dataset), "--quiet", "--verbose"])
    assert code == 0, stderr
    assert f"observations from {dataset / CACHE_FILE}" in stdout
    assert "detecting" not in stderr


def test_prints_the_transform_its_meaning_uncertainty_and_errors(first_run) -> None:
    code, stdout, stderr, _ = first_run
    assert code == 0, stderr
    for text in (
        "method: ekf",
        "in the flange (tool0) frame; OpenCV's cam2gripper",
        "T_base_cam = T_base_flange @ T_flange_cam",
        "translation [mm]:",
        "quaternion (w x y z):",
        "rotation vector [rad]:",
        "roll-pitch-yaw [deg] (about the fixed flange axes x, y, z",
        "uncertainty (1 sigma): translation [mm] along flange x y z:",
        "Cramer-Rao bound",
        "residuals (at the reported flange poses): RMS",
        "worst frames:",
        "vs ground truth: translation error",
        "depth: used; it agrees with the pixels",
    ):
        assert text in stdout
    # Every observation is counted; the learning pass may leave out a few (never silently).
    used, rejected = map(int, re.search(r"observations: (\d+) used, (\d+) rejected", stdout).groups())
    total = _observation_count(stdout)
    assert total >= 17 * 7 and used + rejected == total and rejected <= 0.1 * total
    matrix_rows = [line for line in stdout.splitlines() if line.startswith("  [")]
    assert len(matrix_rows) == 4 and matrix_rows[3].split() == [
        "[+0.000000",
        "+0.000000",
        "+0.000000",
        "+1.000000]",
    ]


@pytest.fixture(scope="module")
def realistic_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The realistic cell (arm kinematics, intrinsics, lens, depth, board print off), rendered."""
    out = tmp_path_factory.mktemp("realistic") / "realistic"
    code, _, stderr = run_hec(["simulate", "--out", str(out), "--scenario", "realistic", "--quiet"])
    assert code == 0, stderr
    return out


@pytest.mark.parametrize(("cell", "grade"), [("ideal", "good"), ("realistic", "usable")])
def test_the_default_output_is_short_and_leads_with_the_verdict(
    dataset: Path, realistic_dataset: Path, cell: str, grade: str
) -> None:
    """At most 20 lines, the transform and the pick error first, the verdict in the first 10 lines,
    then at most three findings, each a cause and a fix; on the realistic cell the board's bend is
    one of them."""
    path = dataset if cell == "ideal" else realistic_dataset
    code, stdout, stderr = run_hec(["calibrate", str(path), "--quiet"])
    assert code == 0, stderr
    lines = stdout.splitlines()
    assert len(lines) <= 20, stdout
    verdict = next(i for i, line in enumerate(lines) if line.startswith("verdict: "))
    assert verdict < 10 and lines[verdict].startswith(f"verdict: {grade}: "), stdout
    assert lines[0].startswith("T_flange_cam by ekf") and "pick error at the working distance" in stdout
    findings = [line for line in lines if line.startswith("  - ")]
    assert len(findings) <= 3 and all(len(f) < 300 for f in findings), findings
    if cell == "realistic":
        assert any("the board is bent out of its plane" in f and "mount it flat" in f for f in findings)
    else:
        assert not findings and "as well as their own noise allows" in lines[verdict]
    assert "inf" not in stdout and "chi-square" not in stdout


@pytest.mark.needs("sim")
def test_robot_states_a_frame_off_fail_at_the_check_before_any_estimation(
    realistic_dataset: Path, tmp_path: Path
) -> None:
    """Each frame given the next frame's pose and joints: Park finds no mount at all, the other closed
    forms a bad one; `hec calibrate` says the poses do not fit (it crashed in the self-calibration)."""
    from hec.bench.calibrate import unexplained_copy

    shifted = unexplained_copy(realistic_dataset, tmp_path / "shifted")
    code, stdout, stderr = run_hec(["calibrate", str(shifted), "--quiet"])
    assert code != 0 and "Traceback" not in stderr, stderr
    assert "the robot poses do not fit the images at any mount" in stderr, stderr
    assert "check the pairing of images and poses" in stderr and not stdout


def _observation_count(stdout: str) -> int:
    """The marker observations of the problem, from the printed header."""
    return int(re.search(r"problem: \d+ frames, (\d+) marker observations", stdout)[1])


def test_json_has_the_keys_and_ekf_is_within_1mm_and_0_1deg(dataset: Path, first_run) -> None:
    code, stdout, stderr, out = first_run
    assert code == 0, stderr
    data = json.loads(out.read_text())
    assert JSON_KEYS <= set(data), JSON_KEYS - set(data)
    assert data["method"] == "ekf"
    T = np.array(data["T_flange_cam"])
    dt, dr = pose_error(T, load_dataset(dataset).ground_truth.T_flange_cam)
    assert dt < 1e-3 and np.degrees(dr) < 0.1, (1e3 * dt, np.degrees(dr))
    assert data["error_translation_mm"] == pytest.approx(1e3 * dt)
    assert data["error_rotation_deg"] == pytest.approx(np.degrees(dr))
    cov = np.array(data["covariance"])
    assert cov.shape == (6, 6)
    assert data["sigma_translation_mm"] == pytest.approx(1e3 * np.sqrt(np.diag(cov)[:3]))
    assert "flange axes" in data["covariance_convention"] and "camera axes" in data["covariance_convention"]
    assert data["translation_mm"] == pytest.approx(1e3 * T[:3, 3])
    assert len(data["marker_residuals"]) == _observation_count(stdout) and len(data["frame_residuals"]) == 17
    assert data["observability"]["observable"] is True
    check = data["noise"]["depth_check"]
    assert check["used"] is True and check["p_value"] > 1e-3, check
    assert not list(out.parent.glob(f".{out.name}.*")), "temporary file left behind"


def test_method_all_prints_a_row_per_method_and_a_failure_row(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(problem, options, observations):
        raise CalibrationInputError("opencv-tsai: the views do not span two axes")

    monkeypatch.setitem(METHODS, "opencv-tsai", broken)
    out = tmp_path / "all.json"
    code, stdout, stderr = run_hec(
        ["calibrate", str(dataset), "--method", "all", "--json", str(out), "--quiet", "--no-loo"]
    )
    assert code == 0, stderr
    lines = stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("method "))
    assert "err mm" in lines[header] and "sigma_t mm" in lines[header]
    rows = {line.split()[0]: line for line in lines[header + 1 : header + 1 + len(METHODS)]}
    assert list(rows) == list(METHODS)
    assert rows["opencv-tsai"].endswith("failed: the views do not span two axes")
    assert "failed" not in rows["ekf"] and "failed" not in rows["batch"]
    assert "loo px" in lines[header] and "loo mm" in lines[header]
    assert rows["ekf"].split()[9:11] == ["-", "-"]  # after x y z, the sigmas, residual, chi2/dof, used/rej
    assert "loo px, loo mm: not run (--no-loo)" in stdout
    results = json.loads(out.read_text())["results"]
    assert [r["method"] for r in results] == list(METHODS)
    assert results[list(METHODS).index("opencv-tsai")] == {
        "method": "opencv-tsai",
        "error": "opencv-tsai: the views do not span two axes",
    }
    assert JSON_KEYS <= set(results[list(METHODS).index("ekf")])


def test_prints_and_writes_the_leave_one_frame_out_figures(first_run) -> None:
    code, stdout, stderr, out = first_run
    assert code == 0, stderr
    match = LOO_LINE.search(stdout)
    assert match, stdout
    data = json.loads(out.read_text())
    loo = data["leave_one_frame_out"]
    assert data["leave_one_frame_out_settings"] == {"enabled": True, "budget_s": 30.0}
    assert data["leave_one_frame_out_not_run"] is None
    assert loo["folds_run"] == 17 and loo["folds_skipped"] == 0 and loo["skipped"] == []
    assert [f["frame"] for f in loo["frames"]] == list(range(17))
    assert set(loo["frames"][0]) == {"frame", "rms_px", "rms_mm", "floor_px", "floor_mm", "corners", "time_s"}
    px, mm = map(float, match.groups())
    assert px == pytest.approx(loo["rms_px"], abs=0.005) and mm == pytest.approx(loo["rms_mm"], abs=0.005)
    # An unseen view is predicted worse than the fitted ones, and here about as well as its noise allows.
    assert data["residual_rms_px"] < loo["rms_px"] < 1.5 * loo["floor_px"], loo
    assert 0.05 < loo["rms_mm"] < 1.5 * loo["floor_mm"], loo
    assert "a new view's own noise alone (corners, robot pose, its PnP pose) gives" in stdout


def test_no_loo_skips_the_folds_and_says_so(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.json"
    code, stdout, stderr = run_hec(
        ["calibrate", str(dataset), "--no-loo", "--json", str(out), "--quiet", "--verbose"]
    )
    assert code == 0, stderr
    assert "leave-one-frame-out prediction: not run (--no-loo)" in stdout and not LOO_LINE.search(stdout)
    data = json.loads(out.read_text())
    assert data["leave_one_frame_out"] is None and data["leave_one_frame_out_settings"]["enabled"] is False
    assert data["leave_one_frame_out_not_run"] == "not run (--no-loo)"


def test_methods_whose_folds_would_take_too_long_are_not_cross_validated(
    dataset: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The budget: 17 folds of a method that takes 2 s are 34 s, over 30 s; --loo-all runs them anyway."""
    ekf = METHODS["ekf"]

    def slow(problem, options, observations):
        result = ekf(problem, options, observations)
        result.diagnostics["time_s"] = 2.0
        return result

    monkeypatch.setitem(METHODS, "ekf", slow)
    code, stdout, stderr = run_hec(["calibrate", str(dataset), "--quiet", "--verbose"])
    assert code == 0, stderr
    assert (
        "leave-one-frame-out prediction: not run: about 34 s (17 folds x 2.0 s), over the 30 s budget; "
        "--loo-all runs it"
    ) in stdout
    code, stdout, stderr = run_hec(["calibrate", str(dataset), "--quiet", "--verbose", "--loo-all"])
    assert code == 0, stderr
    assert LOO_LINE.search(stdout), stdout


def test_method_all_has_the_leave_one_frame_out_columns(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every method cross-validated in the same two models, side by side: the self-calibrated one (the
    same for all, learned once on all frames) and the declared one. Without the slow methods (batch's
    17 folds alone take 15-30 s)."""
    for name in ("iekf", "ukf", "batch"):
        monkeypatch.delitem(METHODS, name)
    out = tmp_path / "all.json"
    code, stdout, stderr = run_hec(
        ["calibrate", str(dataset), "--method", "all", "--json", str(out), "--quiet"]
    )
    assert code == 0, stderr
    lines = stdout.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("method "))
    rows = {line.split()[0]: line.split() for line in lines[header + 1 : header + 1 + len(METHODS)]}
    results = {r["method"]: r for r in json.loads(out.read_text())["results"]}
    # andreff and li, which fail on views at one distance, solve the default two-distance views.
    models = set()
    for name in ("ekf", "seed-ekf", "opencv-park", "opencv-andreff", "opencv-li"):
        loo, declared = results[name]["leave_one_frame_out"], results[name]["leave_one_frame_out_declared"]
        assert loo["folds_run"] == declared["folds_run"] == 17
        cells = [loo["rms_px"], loo["rms_mm"], declared["rms_px"], declared["rms_mm"]]
        assert [float(v) for v in rows[name][9:13]] == pytest.approx(cells, abs=6e-4)
        assert loo["rms_mm"] < 1.0 and declared["rms_mm"] < 1.0
        assert declared["model"] == "declared"
        models.add(loo["model"])
    assert len(models) == 1 and models.pop().startswith(
        "self-calibrated on all frames, the held-out one included"
    )
    assert "loo, dec px and mm: leave-one-frame-out prediction RMS" in stdout
    assert "every method's folds in the same model" in stdout


def _with_loo(folds: list[FoldPrediction], skipped: list[SkippedFold]) -> Calibration:
    px = [f.rms_px for f in folds]
    mm = [f.rms_mm for f in folds]
    cv = CrossValidation(
        folds,
        skipped,
        float(np.sqrt(np.mean(np.square(px)))) if px else float("nan"),
        float(np.sqrt(np.mean(np.square(mm)))) if mm else float("nan"),
        0.3,
        0.2,
        "board pose",
        1.0,
    )
    return Calibration("ekf", np.eye(4), None, np.eye(4), None, [], 0, 0, diagnostics={LOO_KEY: cv})


def test_the_report_names_a_frame_that_disagrees_and_the_skipped_folds() -> None:
    folds = [FoldPrediction(i, 0.3, 0.2, 0.3, 0.2, 32, 0.01) for i in range(8)]
    folds[5] = FoldPrediction(5, 6.0, 5.0, 0.3, 0.2, 32, 0.01)
    lines = format_loo(_with_loo(folds, [SkippedFold(9, "the views do not span two axes")]))
    text = "\n".join(lines)
    assert lines[0] == (
        "leave-one-frame-out prediction: 2.14 px RMS, 1.78 mm RMS in the base frame (8 folds, 1.0 s)"
    )
    assert "worst frames: 5 (6.00 px, 5.00 mm), " in text
    assert "skipped folds (1): frame 9: the views do not span two axes" in text
    assert "frame(s) 5 predicted more than 3x worse than the median frame (0.20 mm)" in text
    assert "predicted worse than their noise explains" in text

    quiet = "\n".join(format_loo(_with_loo(folds[:5], [])))
    assert "note:" not in quiet and "skipped" not in quiet
    none_ran = format_loo(_with_loo([], [SkippedFold(0, "2 frames left, need 3")]))
    assert none_ran == [
        "leave-one-frame-out prediction: no fold could calibrate (frame 0: 2 frames left, need 3)"
    ]


def test_a_previous_json_output_is_a_prior(first_run, dataset: Path) -> None:
    code, stdout, stderr = run_hec(["calibrate", str(dataset), "--prior", str(first_run[3]), "--quiet"])
    assert code == 0, stderr
    assert "vs ground truth" in stdout


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (None, "file missing"),
        ("{not json", "not valid JSON"),
        ('{"covariance": null}', "missing field 'T_flange_cam'"),
        ('{"T_flange_cam": [[1, 0, 0], [0, 1, 0]]}', "field 'T_flange_cam' must be a 4x4"),
        ('{"T_flange_cam": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "must have a rotation (orthonormal"),
        (
            '{"T_flange_cam": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "covariance": [[1, 2]]}',
            "field 'covariance' must be a 6x6",
        ),
    ],
)
def test_a_bad_prior_file_exits_2_naming_the_file_and_field(
    dataset: Path, tmp_path: Path, content: str | None, words: str
) -> None:
    prior = tmp_path / "prior.json"
    if content is not None:
        prior.write_text(content)
    code, stdout, stderr = run_hec(["calibrate", str(dataset), "--prior", str(prior), "--quiet"])
    assert code == 2
    assert stderr.startswith(f"hec: error: {prior}: ") and words in stderr, stderr
    assert len(stderr.strip().splitlines()) == 1 and stdout == ""


def test_too_few_frames_is_a_clear_error(dataset: Path, tmp_path: Path) -> None:
    copy = tmp_path / "few"
    shutil.copytree(dataset, copy)
    observations, settings, depth_noise = load_observations(copy)
    kept = [
        o if o.frame < 2 else replace(o, markers=[], problem="left out by the test") for o in observations
    ]
    save_observations(copy, kept, settings, depth_noise)
    code, stdout, stderr = run_hec(["calibrate", str(copy), "--quiet"])
    assert code == 2
    assert "hec: error: too few frames: 2 usable of 17, need at least 3" in stderr, stderr


def test_no_depth_reaches_methods_that_read_depth_from_the_observations(dataset: Path) -> None:
    code, _, stderr = run_hec(["calibrate", str(dataset), "--no-depth", "--method", "seed-ekf", "--quiet"])
    assert code == 2 and "seed-ekf needs depth and no marker has any (image-only data or --no-depth" in stderr


def test_robot_noise_options_override_the_dataset(dataset: Path) -> None:
    argv = [
        "calibrate",
        str(dataset),
        "--robot-sigma-mm",
        "0.5",
        "--robot-sigma-deg",
        "0.05",
        "--quiet",
        "--verbose",
    ]
    code, stdout, stderr = run_hec(argv)
    assert code == 0, stderr
    assert "robot pose noise 0.500 mm, 0.0500 deg (command line)" in stdout
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as exit_info:
        main(["calibrate", str(dataset), "--robot-sigma-mm", "-1"])
    assert exit_info.value.code == 2 and "must be a number >= 0" in err.getvalue()


def test_write_json_keeps_the_old_file_when_writing_fails(tmp_path: Path) -> None:
    path = tmp_path / "out.json"
    write_json(path, {"value": float("nan")})
    assert json.loads(path.read_text()) == {"value": None}
    with pytest.raises(TypeError):
        write_json(path, {"value": object()})
    assert json.loads(path.read_text()) == {"value": None}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_a_dataset_of_tcp_poses_says_so(default_dataset: Path, tmp_path: Path) -> None:
    """A real-cell session recorded with pose_frame 'tcp' calibrates the camera in the TCP
    frame; the report and the JSON say which frame the result is in."""
    copy = tmp_path / "tcp"
    shutil.copytree(default_dataset, copy)
    meta = json.loads((copy / "dataset.json").read_text())
    (copy / "dataset.json").write_text(json.dumps(meta | {"pose_frame": "tcp"}))
    code, out, _ = run_hec(
        ["calibrate", str(copy), "--json", str(tmp_path / "r.json"), "--quiet", "--verbose"]
    )
    assert code == 0 and "robot poses: the controller's TCP, not the flange" in out
    assert json.loads((tmp_path / "r.json").read_text())["pose_frame"] == "tcp"
