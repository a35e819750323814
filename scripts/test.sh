#!/usr/bin/env bash
# Installs dependencies, builds, and runs the whole test suite: Catch2 through CTest, then the
# Python module's pytest suite (tests/python) with the build directory on PYTHONPATH.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
"$root/scripts/build.sh" -DPENUMBRA_BUILD_PYTHON=ON
jobs="$(nproc 2>/dev/null || echo 2)"
cd "$root/build"
ctest --output-on-failure -j"$jobs"
# The interpreter the module was built for (Debian's python3, where python3-numpy lives).
python="$(sed -n 's/^Python_EXECUTABLE:[A-Z]*=//p' "$root/build/CMakeCache.txt")"
cd "$root"
PYTHONPATH="$root/build" "${python:-/usr/bin/python3}" -m pytest -q -p no:cacheprovider \
    tests/python
