"""Check against the package index that every core dependency (pyproject's [project] dependencies)
has a binary wheel for Python 3.10 (ROS 2 Humble's) on Linux x86-64 and ARM64 and on macOS
(Apple silicon and Intel): the core must install there without a compiler.

Run: .venv/bin/python -m hec.bench.wheels [--python 3.10] [--page PATH.md]
Needs the package index: per platform, pip resolves the core's dependencies and everything they
need from binary wheels only, at any of the platform's listed tags, and prints what it found or
what has no wheel there.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from hec.support.results_page import markdown_table, write_results_page

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
# The platforms the core promises, each with the tags tried (oldest first).
PLATFORMS = {
    "Linux x86-64": ("manylinux2014_x86_64", "manylinux_2_28_x86_64"),
    "Linux ARM64": ("manylinux2014_aarch64", "manylinux_2_28_aarch64"),
    "macOS arm64": ("macosx_11_0_arm64", "macosx_13_0_arm64"),
    "macOS x86-64": ("macosx_10_13_x86_64", "macosx_12_0_x86_64", "macosx_13_0_x86_64"),
}


def core_requirements(python: str) -> list[str]:
    """pyproject's core dependencies that apply to this Python version (markers evaluated simply:
    only `python_version < 'X'` is used in the file)."""
    requirements = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    kept = []
    for requirement in requirements:
        name, _, marker = requirement.partition(";")
        if "python_version <" in marker:
            bound = marker.split("<", 1)[1].strip().strip("'\"")
            if tuple(map(int, python.split("."))) >= tuple(map(int, bound.split("."))):
                continue
        kept.append(name.strip())
    return kept


def platform_wheels(requirements: list[str], python: str, tags: tuple[str, ...]) -> tuple[list[str], str]:
    """The wheels pip downloads for requirements and everything they need, at any of tags (file
    names), and pip's complaint when something has no wheel there ("" when all do)."""
    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "pip", "download", "--quiet", "--only-binary=:all:"]
        command += ["--python-version", python, "-d", folder, *requirements]
        for tag in tags:
            command += ["--platform", tag]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        errors = [line for line in done.stderr.splitlines() if line.startswith("ERROR")]
        return sorted(p.name for p in Path(folder).iterdir()), "; ".join(errors)


def _distribution(requirement: str) -> str:
    """The distribution's name as wheel files spell it (lower case, '_' for '-')."""
    name = requirement
    for stop in "<>=!~[ ":
        name = name.split(stop, 1)[0]
    return name.lower().replace("-", "_")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--python", default="3.10", help="the Python version (default %(default)s)")
    parser.add_argument("--page", type=Path, help="also write the table as this Markdown page")
    args = parser.parse_args(argv)
    requirements = core_requirements(args.python)
    columns, failures = [], []
    for platform, tags in PLATFORMS.items():
        wheels, error = platform_wheels(requirements, args.python, tags)
        print(f"{platform}: {len(wheels)} wheels" + (f"; {error}" if error else ""), flush=True)
        if error:
            failures.append(f"{platform}: {error}")
        columns.append({w.split("-")[0].lower(): w for w in wheels} | {"(all)": f"{len(wheels)} wheels"})
    rows = [[f"`{r}`", *(c.get(_distribution(r), "**none**") for c in columns)] for r in requirements]
    rows.append(["everything they need", *(c["(all)"] for c in columns)])
    if args.page:
        command = f"python -m hec.bench.wheels --python {args.python} --page {args.page}"
        verdict = "every one has a wheel" if not failures else "missing: " + "; ".join(failures)
        intro = (
            f"Every core dependency (`pip install hec` without extras), and what they need in turn,"
            f" resolved by pip from binary wheels only for Python {args.python} per platform:"
            f" {verdict}. `pyzbar` is pure Python and needs the zbar library from the system (Debian"
            " `libzbar0`, Homebrew `zbar`)."
        )
        table = markdown_table(["dependency", *PLATFORMS], rows)
        write_results_page(args.page, "Core wheels per platform", command, [intro, table])
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
