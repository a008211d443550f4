"""`hec calibrate`: estimate T_flange_cam from a dataset and report it."""
