"""`hec sweep` and `hec report`: Monte-Carlo grids of calibration trials and their reports."""
