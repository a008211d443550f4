"""hec's version: the installed distribution's, or ``0+unknown`` in a source tree never installed."""

from __future__ import annotations

from importlib import metadata

try:
    VERSION = metadata.version("hec")
except metadata.PackageNotFoundError:
    VERSION = "0+unknown"
