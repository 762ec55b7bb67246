#!/usr/bin/env bash
# System packages the project needs beyond PyPI, installed from Debian's archive.
# Idempotent: installs only what `dpkg -s` reports missing. Called by `make setup`.
#   libegl1 libegl-mesa0 libgl1-mesa-dri: headless OpenGL (EGL on Mesa llvmpipe) for
#   atacama_sim's renderer (moderngl); no GPU or display needed.
set -euo pipefail
PKGS=(libegl1 libegl-mesa0 libgl1-mesa-dri)
missing=()
for p in "${PKGS[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
echo "[setup] installing system packages for headless OpenGL rendering: ${missing[*]}"
if ! command -v apt-get >/dev/null 2>&1; then
  echo "[setup] ERROR: apt-get not found; install ${missing[*]} (Mesa EGL) with your package manager" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "[setup] ERROR: need root (or sudo) to install ${missing[*]}" >&2; exit 1; fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq || { echo "[setup] ERROR: apt-get update failed" >&2; exit 1; }
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null || {
  echo "[setup] ERROR: apt-get install ${missing[*]} failed" >&2; exit 1; }
echo "[setup] installed: ${missing[*]}"
