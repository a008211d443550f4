"""How the simulator's per-pixel passes are compiled (numba): cached on disk, without the GIL, and
with numpy's floating-point error model (a division by zero gives inf or nan instead of raising),
which lets loops with divisions vectorise (9x on the misregistration's warp)."""

from __future__ import annotations

from pathlib import Path

from numba import njit

_OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy"}

# A compiled pass: @compiled over a function of arrays and numbers.
compiled = njit(**_OPTIONS)
# A helper of a pass, inlined into it (a call per pixel would keep its loop from vectorising).
compiled_inline = njit(**_OPTIONS, inline="always")


# The modules holding compiled passes; numba caches each one's machine code beside it.
COMPILED_MODULES = ("depth_errors", "fast_normal", "lens", "noise")


def first_compile_note() -> str | None:
    """What to tell a user before the first compiled pass runs when numba has cached none of them
    yet (a new install: the first realistic view then takes 15-20 s), else None."""
    cache = Path(__file__).parent / "__pycache__"
    if all(any(cache.glob(f"{module}.*.nbi")) for module in COMPILED_MODULES):
        return None
    return (
        "note: compiling the simulator's image and depth error passes (numba, once per install; "
        "the first realistic view takes 15-20 s)"
    )
