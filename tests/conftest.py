"""Choose the headless OpenGL backend before any test module imports mujoco, share
simulated datasets between test modules (rendering one takes a few seconds), take Ctrl-C
even when the suite was started in the background, and skip what needs an extra that is not
installed (the core's tests run in a virtualenv without the extras)."""

import importlib.abc
import importlib.util
import signal
import sys
from pathlib import Path

import pytest

import hec.sim as sim  # noqa: F401  (selects EGL or OSMesa before mujoco loads)
from hec.support.extras import EXTRA_OF_MODULE

MISSING_EXTRAS = {
    extra for module, extra in EXTRA_OF_MODULE.items() if importlib.util.find_spec(module) is None
}


class _SkipModulesOfMissingExtras(importlib.abc.MetaPathFinder):
    """Last on the import path while the tests are collected: a test module that imports an optional
    library that is not installed (directly or through hec) is skipped, naming the extra."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        extra = EXTRA_OF_MODULE.get(name.split(".")[0])
        if extra in MISSING_EXTRAS:
            raise pytest.skip.Exception(
                f"needs hec[{extra}] ({name} is not installed)", allow_module_level=True
            )


_COLLECTING = _SkipModulesOfMissingExtras()


def pytest_collectstart(collector: pytest.Collector) -> None:
    if MISSING_EXTRAS and _COLLECTING not in sys.meta_path:
        sys.meta_path.append(_COLLECTING)


def pytest_collection_finish(session: pytest.Session) -> None:
    if _COLLECTING in sys.meta_path:
        sys.meta_path.remove(_COLLECTING)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "needs(*extras): the test needs these extras (hec[sim], ...)")


def pytest_runtest_setup(item: pytest.Item) -> None:
    for marker in item.iter_markers("needs"):
        missing = sorted(MISSING_EXTRAS.intersection(marker.args))
        if missing:
            pytest.skip(f"needs hec[{','.join(missing)}], not installed")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> pytest.TestReport:
    """A test (or its fixture) that imports an optional library that is not installed is skipped,
    naming the extra; the same import error with the extra installed fails as any error does."""
    report = yield
    error = call.excinfo.value if call.excinfo is not None else None
    if isinstance(error, ModuleNotFoundError):
        extra = EXTRA_OF_MODULE.get((error.name or "").split(".")[0])
        if extra in MISSING_EXTRAS:
            report.outcome = "skipped"
            report.longrepr = (
                str(item.path),
                item.location[1] or 0,
                f"needs hec[{extra}] ({error.name} is not installed)",
            )
    return report


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
    from hec.sim.scenario import load_scenario
    from hec.sim.simulate import simulate

    out = tmp_path_factory.mktemp("datasets") / "default"
    return simulate(load_scenario(None), out, TEST_SEED, progress=False).out_dir
