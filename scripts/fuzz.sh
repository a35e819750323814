#!/usr/bin/env bash
# Builds the scene-loader fuzz target with clang (libFuzzer + ASan + UBSan) in build-fuzz/ and
# runs it for a bounded time, seeded from the scenes in vdb_scenes/ and tests/fuzz_corpus/.
# Usage: scripts/fuzz.sh [SECONDS=60]. Crashes are written to build-fuzz/crashes/; turn each one
# into a test (tests/test_fuzz_regressions.cpp) before fixing it.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
seconds="${1:-60}"
"$root/scripts/install-deps.sh"
CXX=clang++ cmake -S "$root" -B "$root/build-fuzz" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPENUMBRA_BUILD_FUZZ=ON -DPENUMBRA_BUILD_TESTS=OFF -DPENUMBRA_BUILD_BENCH=OFF \
    -DPENUMBRA_SANITIZE=address,undefined \
    -DCMAKE_CXX_FLAGS="-fsanitize-ignorelist=$root/.ci/ubsan_ignorelist.txt" >/dev/null
cmake --build "$root/build-fuzz" -j"$(nproc 2>/dev/null || echo 2)" --target fuzz_scene_loader
corpus="$root/build-fuzz/corpus"
mkdir -p "$corpus" "$root/build-fuzz/crashes"
cp "$root"/vdb_scenes/*.json "$corpus"/ 2>/dev/null || true
cp "$root"/tests/fuzz_corpus/* "$corpus"/ 2>/dev/null || true
cd "$root/build-fuzz"
ASAN_OPTIONS=detect_leaks=1 ./fuzz_scene_loader -max_total_time="$seconds" -rss_limit_mb=4096 \
    -timeout=20 -artifact_prefix=crashes/ -print_final_stats=1 corpus 2>&1 | tail -25
