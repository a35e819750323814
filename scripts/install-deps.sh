#!/usr/bin/env bash
# Installs Penumbra's build and run dependencies from Debian's packages (idempotent: packages
# already present are not downloaded again).
set -euo pipefail
packages=(build-essential cmake libopenvdb-dev libboost-iostreams-dev libopenimageio-dev
          libtbb-dev libglm-dev catch2 libcli11-dev nlohmann-json3-dev libopenvdb-tools
          openimageio-tools gnuplot-nox
          python3-dev pybind11-dev python3-pybind11 python3-numpy python3-pytest
          python3-openimageio)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
    exit 0
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
echo "penumbra: installing ${missing[*]}" >&2
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
