"""From detections to observations: depth at markers, observations and their cache,
overlays, grading against ground truth, synthetic observations."""
