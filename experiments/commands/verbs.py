"""The hec verbs in the order `hec --help` lists them, each with its one line of help: what the
command line shows before it loads any command (each command's module adds its options)."""

from __future__ import annotations

HELP = {
    "demo": "the main job: simulate the default cell, detect, calibrate, report against ground truth",
    "simulate": "render a simulated calibration dataset",
    "detect": "detect the board in a dataset, cache the observations (DATASET/detections.json)",
    "calibrate": "estimate T_flange_cam (camera in the flange frame, OpenCV cam2gripper) from a dataset",
    "board": "write a true-scale printable board (PNG or PDF)",
    "import": "write a hec dataset from images and poses, ViSP's layout or easy_handeye2 pose pairs",
    "export": "write a calibration for ROS 2, URDF, easy_handeye2, YAML or JSON",
    "plan": "choose views by the information they add; write a waypoint file",
    "verify": "test whether a calibration still holds on a few new frames (has the camera moved?)",
    "sweep": "run a grid of calibration trials (Monte-Carlo) from a sweep TOML file",
    "report": "rebuild DIR/report.html (tables and plots) and DIR/plots/ from a sweep's saved rows",
    "regress": "render, detect and calibrate a small fixed scenario; compare the errors with the baseline",
    "record": "record a calibration session on the real cell (or --sim) into a dataset",
    "run": "record a calibration session, then calibrate it (OUT/calibration.json)",
    "teach": "store waypoints by moving the real arm by hand (UR teach mode)",
    "rehearse": "run the real-cell session against stand-ins of the UR and the RealSense (simulated cell)",
}
