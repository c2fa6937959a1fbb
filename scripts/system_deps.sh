#!/usr/bin/env bash
# Headless MuJoCo rendering needs an EGL implementation (Mesa). Install it when we can (root on
# Debian/Ubuntu); otherwise say in one line what to install. Never fails the build: training and
# tests work without it, only GIFs of MuJoCo scenes need it.
set -u
if ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' && ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0'; then
  exit 0
fi
pkgs="libegl1 libegl-mesa0 libgl1-mesa-dri"
if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  echo "installing $pkgs for headless rendering"
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs) >/dev/null 2>&1 \
    || echo "note: could not install $pkgs; MuJoCo GIFs need them (apt-get install $pkgs)" >&2
elif command -v apt-get >/dev/null; then
  echo "note: MuJoCo GIFs need EGL: sudo apt-get install $pkgs" >&2
else
  echo "note: MuJoCo GIFs need an EGL or OSMesa library (Mesa) from your system's packages" >&2
fi
exit 0
