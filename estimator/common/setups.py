"""The two set-ups hec calibrates, by the names files and commands use.

eye-in-hand: the camera on the flange, the board fixed in the cell; the unknowns are T_flange_cam
and T_base_board. eye-to-hand: the camera fixed in the cell, the board on the flange; the unknowns
are T_base_cam and T_flange_board.
"""

from __future__ import annotations

EYE_IN_HAND = "eye-in-hand"
EYE_TO_HAND = "eye-to-hand"
SETUPS = (EYE_IN_HAND, EYE_TO_HAND)
