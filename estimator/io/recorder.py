"""The recorder of a calibration session: a dataset folder (hec.estimator.io.dataset's format)
written frame by frame, so an interruption loses nothing captured before it, and reopened to
resume."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np

from hec.estimator.common.files import open_text, write_atomic
from hec.estimator.common.jsonfile import first_field_difference, read_json_object
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.io.board_file import board_to_dict, load_board
from hec.estimator.io.dataset import (
    FRAME_COLUMNS,
    SESSION_COLUMNS,
    dataset_json,
    dump_json,
    ground_truth_dict,
    read_frames,
    read_ground_truth,
    write_frame_files,
)
from hec.estimator.io.lock import acquire_lock, release_lock
from hec.estimator.io.png import write_png
from hec.estimator.observe.frames import Capture, DatasetError, GroundTruth
from hec.estimator.targets.target import Target


class DatasetRecorder:
    """Write a recorded session straight into ``out_dir``, frame by frame: images first,
    then the frames.csv row (flushed to disk), then dataset.json with the new count, so an
    interruption loses nothing captured before it. ``resume=True`` reopens such a folder
    (same camera intrinsics, depth scale, board and source, or DatasetError) and appends.

    extra: more dataset.json fields; ground_truth (simulation): the cell's truth, its
    per-frame lists filled by add_frame; fixed: keys of extra a resumed session must share.
    """

    def __init__(
        self,
        out_dir: str | Path,
        intrinsics: CameraIntrinsics,
        board: Target,
        depth_scale_m: float,
        source: str,
        extra: dict | None = None,
        ground_truth: GroundTruth | None = None,
        resume: bool = False,
        fixed: tuple[str, ...] = (),
    ) -> None:
        self.root = Path(out_dir)
        self.fixed = fixed
        self.notes: list[str] = []  # said to the user: a stale lock taken over
        self.intrinsics, self.board, self.depth_scale_m = intrinsics, board, depth_scale_m
        self.source, self.extra = source, dict(extra or {})
        self.ground_truth = ground_truth
        self.rows: list[dict] = []
        try:
            if resume:
                self._reopen()
            else:
                self._create()
        except BaseException:  # a session that could not start leaves no lock
            release_lock(self.root)
            raise

    def __enter__(self) -> DatasetRecorder:
        return self

    def __exit__(self, *_: object) -> None:
        release_lock(self.root)  # however the session ended (finish unlocks too)

    def _create(self) -> None:
        if self.root.exists():
            raise FileExistsError(
                f"{self.root} already exists; add --resume to continue that session, or choose another --out"
            )
        self.root.mkdir(parents=True)
        acquire_lock(self.root, "a recording")
        for sub in ("rgb", "depth", "depth_samples"):
            (self.root / sub).mkdir()
        dump_json(self.root / "board.json", board_to_dict(self.board))
        with open_text(self.root / "frames.csv", "w") as f:
            csv.writer(f, lineterminator="\n").writerow((*FRAME_COLUMNS, *SESSION_COLUMNS))
        self._write_metadata("in progress")

    def _reopen(self) -> None:
        """Check that the folder holds a session of this camera and board, drop a frames.csv
        line cut short by the interruption, and read the frames recorded so far."""
        meta_path = self.root / "dataset.json"
        meta = read_json_object(meta_path, DatasetError, "missing: nothing to resume here")
        stale = acquire_lock(self.root, "a recording")
        if stale is not None:
            self.notes.append(stale)
        now = dict(camera=self.intrinsics.to_dict(), depth_scale_m=self.depth_scale_m, source=self.source)
        unrecorded = [key for key in self.fixed if key in self.extra and key not in meta]  # older hec: none
        self.notes += [f"{meta_path} has no '{key}' (an older recording): not checked" for key in unrecorded]
        now |= {key: self.extra.get(key) for key in self.fixed if key not in unrecorded}
        if (difference := first_field_difference(meta, now)) is not None:
            raise DatasetError(f"{meta_path}: cannot resume, {difference}")
        if board_to_dict(load_board(self.root / "board.json")) != board_to_dict(self.board):
            raise DatasetError(f"{self.root / 'board.json'}: cannot resume, the board is another one")
        frames_path = self.root / "frames.csv"
        text = frames_path.read_text()
        if not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]
            frames_path.write_text(text)
        with open(frames_path, newline="") as f:
            header = next(csv.reader(f))
        if tuple(header) != (*FRAME_COLUMNS, *SESSION_COLUMNS):
            raise DatasetError(f"{frames_path}: not written by a recorded session; cannot resume it")
        self.rows = read_frames(frames_path)
        if self.ground_truth is not None and self.rows:
            truth = read_ground_truth(self.root / "ground_truth.json")
            self.ground_truth.T_base_flange[:] = truth.T_base_flange[: len(self.rows)]
            self.ground_truth.joints[:] = truth.joints[: len(self.rows)]
        self._write_metadata("in progress")

    @property
    def recorded_waypoints(self) -> set[int]:
        return {row["waypoint"] for row in self.rows}

    def add_frame(self, capture: Capture, waypoint: int) -> int:
        """Write one captured view of waypoint (its index) now; returns its frame number."""
        index = len(self.rows)
        row = write_frame_files(self.root, index, capture.frame, self.intrinsics, self.depth_scale_m)
        samples_name = ""
        if capture.depth_samples is not None:
            samples_name = f"depth_samples/{index:06d}.png"
            write_png(self.root / samples_name, np.asarray(capture.depth_samples, dtype=np.uint8))
        if self.ground_truth is not None:
            if capture.true_T_base_flange is None or capture.true_joints is None:
                raise DatasetError("a simulated session's capture must carry its true pose and joints")
            self.ground_truth.T_base_flange.append(capture.true_T_base_flange)
            self.ground_truth.joints.append(capture.true_joints)
            write_atomic(self.root / "ground_truth.json", json.dumps(ground_truth_dict(self.ground_truth)))
        with open_text(self.root / "frames.csv", "a") as f:
            csv.writer(f, lineterminator="\n").writerow([*row, str(waypoint), samples_name])
            f.flush()
            os.fsync(f.fileno())
        self.rows.append({"frame": index, "waypoint": waypoint})
        self._write_metadata("in progress")
        return index

    def finish(self, state: str, extra: dict | None = None) -> Path:
        """Write dataset.json once more with the session's end state ('complete' or
        'interrupted') and any more fields, and unlock the folder."""
        self.extra |= extra or {}
        self._write_metadata(state)
        release_lock(self.root)
        return self.root

    def _write_metadata(self, state: str) -> None:
        truth = self.ground_truth if self.rows else None  # its file is written with the first frame
        meta = dataset_json(self.intrinsics, self.depth_scale_m, self.source, len(self.rows), truth)
        text = json.dumps(meta | self.extra | {"recording": state}, indent=2) + "\n"
        write_atomic(self.root / "dataset.json", text)
