#!/usr/bin/env bash
# What `make docs-check` needs beyond .venv: Debian's Chromium, its WebDriver (chromedriver) and
# the Liberation fonts (the metrics of Arial and Courier, which the theme's font stacks fall back
# to), so that widths are measured as a reader's browser lays the pages out. Installs them when
# they are missing and we can (root on Debian/Ubuntu); says in one line what to install otherwise.
# Quick when they are there: one dpkg query.
set -u
pkgs="chromium chromium-driver fonts-liberation"
if command -v dpkg-query >/dev/null; then
  # shellcheck disable=SC2086
  if [ "$(dpkg-query -W -f='${Status}\n' $pkgs 2>/dev/null | grep -c 'install ok installed')" = 3 ]; then
    exit 0
  fi
elif command -v chromium >/dev/null && command -v chromedriver >/dev/null; then
  exit 0
fi
if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
  echo "installing $pkgs for the docs check"
  # shellcheck disable=SC2086
  if (apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
      apt-get install -y -qq --no-install-recommends $pkgs) >/dev/null 2>&1; then
    exit 0
  fi
  echo "error: could not install $pkgs (apt-get install $pkgs)" >&2
elif command -v apt-get >/dev/null; then
  echo "error: the docs check needs Chromium and its driver: sudo apt-get install $pkgs" >&2
else
  echo "error: the docs check needs Chromium, chromedriver and the Liberation fonts" >&2
fi
exit 1
