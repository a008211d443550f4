"""A rehearsal of the real cell without one: the real ur_rtde clients against a loopback UR controller
and librealsense's own pipeline against a software D435, both over one simulated cell (`hec rehearse`).
"""
