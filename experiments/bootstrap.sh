#!/usr/bin/env bash
# Set up everything the project needs, idempotently, from any working directory:
#   1. the Debian packages behind headless MuJoCo (EGL with Mesa, OSMesa as fallback),
#      pyzbar (libzbar0) and pyrealsense2 (libusb), chromium (the tests open the HTML reports in
#      it, headless), plus python3-venv if needed;
#   2. the virtualenv .venv at the repository root with `pip install -e ".[dev]"`.
# The pip step is skipped when .venv records the sha256 of pyproject.toml it was
# installed from, so a re-run takes seconds.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
STAMP="$VENV/.hec-pyproject.sha256"
PYTHON="${PYTHON:-python3}"
DEB_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libzbar0 libusb-1.0-0 chromium)

say() { echo "hec setup: $*" >&2; }

venv_ok() { [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c '' >/dev/null 2>&1; }

# Create .venv; on failure leave nothing behind and return non-zero.
make_venv() {
    if "$PYTHON" -m venv "$VENV" >/dev/null 2>&1 && venv_ok; then
        return 0
    fi
    rm -rf "$VENV"
    return 1
}

command -v "$PYTHON" >/dev/null 2>&1 || { say "error: $PYTHON not found"; exit 1; }
cd "$REPO"

# --- the virtualenv (tried first: a failure here means python3-venv is missing) ---
need_venv_pkg=0
if ! venv_ok; then
    rm -rf "$VENV"
    say "creating $VENV"
    make_venv || need_venv_pkg=1
fi

# --- Debian packages ---
missing=()
if command -v dpkg-query >/dev/null 2>&1; then
    for pkg in "${DEB_PACKAGES[@]}"; do
        status="$(dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null || true)"
        [ "$status" = "install ok installed" ] || missing+=("$pkg")
    done
    [ "$need_venv_pkg" = 0 ] || missing+=(python3-venv)
else
    say "warning: dpkg-query not found (not Debian?); not checking ${DEB_PACKAGES[*]}"
    if [ "$need_venv_pkg" = 1 ]; then
        say "error: '$PYTHON -m venv' failed; install the venv module for $PYTHON"
        exit 1
    fi
fi

if [ "${#missing[@]}" -gt 0 ]; then
    if [ "$(id -u)" -ne 0 ]; then
        say "missing Debian packages: ${missing[*]}"
        say "run this, then this script again:"
        echo "    sudo apt-get install --no-install-recommends ${missing[*]}" >&2
        exit 1
    fi
    say "installing Debian packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if [ "$need_venv_pkg" = 1 ]; then
    say "creating $VENV"
    make_venv || { say "error: '$PYTHON -m venv $VENV' failed"; exit 1; }
fi

# --- the project, editable, with the dev tools ---
export PIP_DISABLE_PIP_VERSION_CHECK=1
want="$(sha256sum "$REPO/pyproject.toml" | cut -d' ' -f1)"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$want" = "$have" ] && compgen -G "$VENV/lib/python*/site-packages/hec-*.dist-info" >/dev/null; then
    say "virtualenv up to date ($VENV)"
    exit 0
fi

rm -f "$STAMP"
say "upgrading pip"
"$VENV/bin/python" -m pip install --quiet --upgrade pip
say "installing hec (pip install -e \".[dev]\") into $VENV"
"$VENV/bin/python" -m pip install --quiet -e ".[dev]"
echo "$want" >"$STAMP"
say "done"
