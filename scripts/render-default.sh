#!/usr/bin/env bash
# Installs dependencies, builds, and renders the default scene to out/default.png (plus an EXR
# and the render statistics). Extra arguments go to `penumbra render`.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/build.sh"
mkdir -p "$root/out"
"$root/build/penumbra" render "$root/vdb_scenes/default.json" -o "$root/out/default.png" \
    --stats "$root/out/default.stats.json" "$@"
echo "wrote $root/out/default.png and $root/out/default.stats.json"
