"""How the simulator's per-pixel passes are compiled (numba): cached on disk, without the GIL, and
with numpy's floating-point error model (a division by zero gives inf or nan instead of raising),
which lets loops with divisions vectorise (9x on the misregistration's warp)."""

from __future__ import annotations

from numba import njit

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy"}

# A compiled pass: @compiled over a function of arrays and numbers.
compiled = njit(**_OPTIONS)
# A helper of a pass, inlined into it (a call per pixel would keep its loop from vectorising).
compiled_inline = njit(**_OPTIONS, inline="always")
