"""The calibration session shared by the simulated and the real cell: `hec record`,
`hec run`, `hec teach`, cell files."""
