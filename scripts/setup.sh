#!/usr/bin/env bash
# Install panorecon into ./.venv on a fresh machine.
#   bash scripts/setup.sh        -> runtime install
#   bash scripts/setup.sh dev    -> runtime + test dependencies
# torch is installed first and pinned: an unpinned torch would pull a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-}"

# open3d's PyPI wheel needs libusb at import time.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if command -v apt-get >/dev/null; then
        SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
        $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "panorecon setup: open3d needs libusb-1.0 (libusb-1.0.so.0); install it with your package manager" >&2
        exit 1
    fi
fi

# dev: the browser tests (report.html, `panorecon view`) drive Debian's chromium through playwright
if [ "$extras" = "dev" ] && [ ! -x /usr/bin/chromium ]; then
    if command -v apt-get >/dev/null; then
        SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
        $SUDO apt-get update -qq && $SUDO apt-get install -y -qq chromium >/dev/null
    else
        echo "panorecon setup: the browser tests need chromium at /usr/bin/chromium; install it" >&2
        exit 1
    fi
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
PIP=".venv/bin/python -m pip"
$PIP install -q --upgrade pip
$PIP install -q "torch==2.13.0"
if [ "$extras" = "dev" ]; then
    $PIP install -q -e ".[dev]"
else
    $PIP install -q -e .
fi
# build the C++ rasterizer now rather than on first use (it falls back to the torch backend if it cannot)
.venv/bin/python -m panorecon.splat.rasterize.build
echo "panorecon installed in $(pwd)/.venv"
