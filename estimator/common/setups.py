"""The two set-ups hec calibrates, by the names files and commands use.

eye-in-hand: the camera on the flange, the board fixed in the cell; the unknowns are T_flange_cam
and T_base_board. eye-to-hand: the camera fixed in the cell, the board on the flange; the unknowns
are T_base_cam and T_flange_board.
"""

from __future__ import annotations

EYE_IN_HAND = "eye-in-hand"
EYE_TO_HAND = "eye-to-hand"
SETUPS = (EYE_IN_HAND, EYE_TO_HAND)
# The transform a calibration estimates, and the board's pose it estimates with it, by set-up.
HAND_EYE_NAMES = {EYE_IN_HAND: "T_flange_cam", EYE_TO_HAND: "T_base_cam"}
BOARD_POSE_NAMES = {EYE_IN_HAND: "T_base_board", EYE_TO_HAND: "T_flange_board"}
# What it is, in words, and how to use it.
HAND_EYE_MEANINGS = {
    EYE_IN_HAND: "camera optical frame in the flange frame, OpenCV's cam2gripper; "
    "T_base_cam = T_base_flange @ T_flange_cam",
    EYE_TO_HAND: "camera optical frame in the robot base frame, the camera fixed in the cell (eye-to-hand; "
    "OpenCV's cam2base from calibrateHandEye on inverted robot poses); "
    "the board on the flange is T_flange_board",
}
