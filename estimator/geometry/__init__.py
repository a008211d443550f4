"""SE(3) transforms and the perturbation convention, the camera model, the UR arm's kinematics, waypoints."""
