#!/usr/bin/env bash
# System libraries rodo's Python dependencies need but pip cannot install.
# open3d's wheel links libusb-1.0 (Debian package libusb-1.0-0).
set -euo pipefail
missing=()
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  missing+=(libusb-1.0-0)
fi
[ ${#missing[@]} -eq 0 ] && exit 0
if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "rodo: installing system packages: ${missing[*]}" >&2
  apt-get update -qq >/dev/null
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
else
  echo "rodo: missing system packages: ${missing[*]}" >&2
  echo "      install them (e.g. 'sudo apt-get install ${missing[*]}') and run make again." >&2
  exit 1
fi
