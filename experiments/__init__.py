"""hec: eye-in-hand calibration of a camera on a robot's flange, proven against a simulated cell.

The library is ``hec.estimator`` (detection, estimation, file formats), the simulated cell
``hec.sim`` (extra ``hec[sim]``) and the real cell ``hec.hardware`` (extras ``hec[ur]`` and
``hec[realsense]``); the ``hec`` command line is ``hec.cli``.
"""

from __future__ import annotations

from hec.support.version import VERSION as __version__

__all__ = ["__version__"]
