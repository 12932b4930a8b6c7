#!/usr/bin/env bash
# System libraries the tests and the optional extras need (Debian / Ubuntu, apt-get):
# - Qt for the GUI (PySide6 on the offscreen platform, and Xvfb with the xcb platform for
#   the screenshot and SLM-window tests): these libraries, Xvfb and a font; for the
#   operator-day test in a real window, a window manager (openbox), xdotool (clicks, keys
#   and typing through the X server) and xprop (x11-utils: the windows' stacking order);
# - Aravis cameras: the libaravis 0.8 typelib, its fake GigE camera (aravis-tools) for the
#   driver tests, and what PyGObject (the hardware extra) needs to build; libX11, which the
#   SLM-window test calls to read the displayed pixels back from Xvfb;
# - ImageJ 1.x (Debian's imagej, with its Java runtime): docs/open-data.md's table of the
#   field's tools opens the TIFF exports in it (tests/instrument/test_open_data_table.py).
# Run as root or with sudo available; installs nothing else.
set -euo pipefail
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends xvfb xauth \
    libegl1 libgl1 libfontconfig1 libdbus-1-3 libxkbcommon0 libxkbcommon-x11-0 \
    libxcb-cursor0 libxcb-icccm4 libxcb-image0 libxcb-keysyms1 libxcb-randr0 \
    libxcb-render-util0 libxcb-shape0 libxcb-xfixes0 libxcb-xinerama0 libxcb-xkb1 \
    fonts-dejavu-core openbox xdotool x11-utils \
    gir1.2-aravis-0.8 aravis-tools libgirepository1.0-dev libcairo2-dev pkg-config \
    libx11-6 imagej >/dev/null
