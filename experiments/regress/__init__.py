"""`hec regress`: the pipeline against a recorded baseline on simulated ground truth."""
