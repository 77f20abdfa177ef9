#!/usr/bin/env bash
# Installs what progressive needs on a fresh Debian/Ubuntu machine: Mesa's EGL and
# software OpenGL (llvmpipe) when no OpenGL driver is present, then a virtual
# environment with the package. Sourced by run.sh and test.sh.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || ! ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 >/dev/null
    else
        echo "progressive: OpenGL 4.5 through EGL is needed (Debian: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)" >&2
    fi
fi

# The viewer's tests open real windows on a virtual X server (Xvfb).
if ! command -v Xvfb >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        xvfb libgl1 libglx-mesa0 >/dev/null
fi

# The HTTPS tests make a self-signed certificate with the openssl command.
if ! command -v openssl >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends openssl >/dev/null
fi

# The notebook's browser test drives Debian's Chromium through its WebDriver (Selenium).
if ! command -v chromedriver >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        chromium chromium-driver >/dev/null
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --disable-pip-version-check -e ".[${PROGRESSIVE_EXTRAS:-test}]"
# An editable install leaves the package's own modules without bytecode, and where
# PYTHONDONTWRITEBYTECODE is set (this project's machines set it) every process then
# compiles each one it imports before the first image; a wheel install compiles them.
.venv/bin/python -m compileall -q progressive loaders
