"""Calibrate a recorded dataset from Python and write its report.

.venv/bin/python docs/examples/calibrate_a_dataset.py DATASET [REPORT_DIR]
"""

import sys

import numpy as np

import hec

dataset = hec.load_dataset(sys.argv[1])
calibration = hec.calibrate(dataset)  # ekf, the noise learned from the data, cross-validated

translation_mm = 1e3 * calibration.T_flange_cam[:3, 3]
sigma_mm = np.sqrt(np.diag(calibration.covariance)[:3]) * 1e3
print(f"T_flange_cam translation [mm]: {np.round(translation_mm, 3)} (1 sigma {np.round(sigma_mm, 3)})")
print(hec.verdict(calibration).line)
for finding in hec.findings(calibration):
    print(f"  - {finding}")
if len(sys.argv) > 2:
    print(f"report: {hec.write_report(sys.argv[2], dataset, calibration)}")
