#!/usr/bin/env bash
# Installs the Debian packages progskin builds with, when any is missing.
set -euo pipefail
PKGS=(build-essential cmake pkg-config libasio-dev libflatbuffers-dev flatbuffers-compiler
      libglm-dev libeigen3-dev libtinygltf-dev nlohmann-json3-dev libgtest-dev libbenchmark-dev
      libegl-dev libgl-dev libegl-mesa0 libgl1-mesa-dri libstb-dev gnuplot-nox libsodium-dev libssl-dev
      libhwy-dev)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
