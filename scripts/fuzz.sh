#!/usr/bin/env bash
# Builds the fuzz targets with clang (libFuzzer + ASan + UBSan) in build-fuzz/ and runs each for
# a bounded time: the scene loader (seeded from vdb_scenes/*.json and tests/fuzz_corpus/*), the
# .vdb reader (tests/fuzz_corpus/vdb/) and the image reader of `compare` (tests/fuzz_corpus/image/).
# Usage: scripts/fuzz.sh [SECONDS=60] (per target). Crashes are written to build-fuzz/crashes/;
# turn each one into a test (tests/test_fuzz_regressions.cpp) before fixing it.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
seconds="${1:-60}"
"$root/scripts/install-deps.sh"
CXX=clang++ cmake -S "$root" -B "$root/build-fuzz" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPENUMBRA_BUILD_FUZZ=ON -DPENUMBRA_BUILD_TESTS=OFF -DPENUMBRA_BUILD_BENCH=OFF \
    -DPENUMBRA_SANITIZE=address,undefined \
    -DCMAKE_CXX_FLAGS="-fsanitize-ignorelist=$root/.ci/ubsan_ignorelist.txt" >/dev/null
cmake --build "$root/build-fuzz" -j"$(nproc 2>/dev/null || echo 2)" \
    --target fuzz_scene_loader fuzz_vdb_reader fuzz_image_reader
mkdir -p "$root/build-fuzz/crashes"
run() {  # TARGET LEAKS SEEDS...
    local target="$1" leaks="$2"
    shift 2
    local corpus="$root/build-fuzz/corpus-$target"
    mkdir -p "$corpus"
    for seed in "$@"; do
        if [ -f "$seed" ]; then cp "$seed" "$corpus"/; fi
    done
    echo "-- $target ($seconds s)"
    (cd "$root/build-fuzz" &&
        ASAN_OPTIONS=detect_leaks=$leaks "./$target" -max_total_time="$seconds" -rss_limit_mb=4096 \
            -timeout=20 -artifact_prefix=crashes/ -print_final_stats=1 "$corpus" 2>&1 | tail -12)
}
# OpenVDB and OpenImageIO leak a little when they throw on a corrupt file (nodes read so far,
# error strings): a refused input ends the process, so the reader targets run without leak
# detection; the scene loader (Penumbra's own code) keeps it.
run fuzz_scene_loader 1 "$root"/vdb_scenes/*.json "$root"/tests/fuzz_corpus/*.json
run fuzz_vdb_reader 0 "$root"/tests/fuzz_corpus/vdb/*
run fuzz_image_reader 0 "$root"/tests/fuzz_corpus/image/*
