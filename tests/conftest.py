"""Choose the headless OpenGL backend before any test module imports mujoco."""

import sim  # noqa: F401
