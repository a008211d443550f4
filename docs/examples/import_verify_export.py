"""Import a folder of images and robot poses, calibrate, verify on new frames and export for ROS 2.

.venv/bin/python docs/examples/import_verify_export.py IMAGES POSES.csv CAMERA.yaml NEW_FRAMES OUT_DIR
"""

import sys
from pathlib import Path

import numpy as np

import hec

images, poses, camera, new_frames, out = (Path(arg) for arg in sys.argv[1:6])

# poses.csv: an image column and T_base_flange as x y z (m) and a quaternion w x y z (the defaults)
options = hec.ImportOptions(board="hec_8qr", intrinsics=camera, poses=poses)
imported = hec.import_dataset("folder", images, out / "dataset", options)
print(f"imported {imported.images} images into {imported.path}")
for line in imported.checks:  # the detection, the pose convention, the board file
    print(f"  {line}")

dataset = hec.load_dataset(imported.path)
calibration = hec.calibrate(dataset, cross_validate=False)
print(f"T_flange_cam translation [mm]: {np.round(1e3 * calibration.T_flange_cam[:3, 3], 3)}")
print(hec.verdict(calibration).line)
saved = hec.save_calibration(out / "calibration.json", dataset, calibration)

check = hec.verify(saved, new_frames)  # a few frames recorded later: has the camera moved?
print(f"verify: {check.verdict}")

# camera_link, the root of realsense-ros's frames; on a real camera give link_optical_values
# (what `ros2 run tf2_ros tf2_echo camera_link camera_color_optical_frame` prints) instead
launch = hec.export(saved, "ros2-launch", out=out / "handeye.launch.py", assume_zero_offset=True)
print(f"wrote {launch.path} (T_{launch.parent}_{launch.child})")
for note in launch.notes:
    print(note)
