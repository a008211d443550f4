"""Choose the headless OpenGL backend before any test module imports mujoco, share
simulated datasets between test modules (rendering one takes a few seconds), and take Ctrl-C
even when the suite was started in the background."""

import signal
from pathlib import Path

import pytest

import sim  # noqa: F401  (selects EGL or OSMesa before mujoco loads)

# A non-interactive shell starts background jobs with SIGINT ignored and nohup ignores SIGHUP;
# hec (like any program) keeps an ignored signal ignored, so the tests that send these to hec (in
# this process or in the subprocesses it starts, which inherit an ignored signal) would test
# nothing. Ctrl-C is taken back here; a hang-up gets a handler that does nothing, which keeps this
# process running as nohup meant and leaves its subprocesses the default.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
    signal.signal(signal.SIGHUP, lambda signum, frame: None)

# The seed the detector's error floors were measured with is 0; tests grade on others.
TEST_SEED = 7


@pytest.fixture(scope="session")
def default_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default scenario (rotation-rich trajectory, default noise) rendered once."""
    from sim.scenario import load_scenario
    from sim.simulate import simulate

    out = tmp_path_factory.mktemp("datasets") / "default"
    return simulate(load_scenario(None), out, TEST_SEED, progress=False).out_dir
