#!/usr/bin/env bash
# One-command setup: system libraries (Debian's libLLVM >= 16 for Dr.Jit's CPU backend),
# then a virtual environment in .venv with hrvptm and its test extras.
set -euo pipefail
cd "$(dirname "$0")"

have_llvm() {
    ls /usr/lib/*/libLLVM-1[6-9]*.so* /usr/lib/*/libLLVM-2[0-9]*.so* /usr/lib/llvm-1[6-9]/lib/libLLVM*.so* \
        /usr/lib/llvm-2[0-9]/lib/libLLVM*.so* >/dev/null 2>&1
}
if ! have_llvm; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
        $SUDO apt-get update -qq
        $SUDO apt-get install -y -qq libllvm19
    else
        echo "setup.sh: no libLLVM >= 16 found and no apt-get; install LLVM >= 16 and set DRJIT_LIBLLVM_PATH" >&2
        exit 1
    fi
fi
# Xvfb and the X libraries of Qt's xcb platform: the napari plugin's tests draw on a virtual display.
if ! { command -v Xvfb && ldconfig -p | grep libxcb-cursor.so.0; } >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    $SUDO apt-get install -y -qq xvfb libgl1 libegl1 libdbus-1-3 libfontconfig1 libxkbcommon-x11-0 libxcb-cursor0 \
        libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0 libxcb-render-util0 libxcb-shape0 libxcb-xkb1
fi
PY=${PYTHON:-python3}
[ -d .venv ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
echo "hrvptm installed in .venv (activate with: source .venv/bin/activate)"
