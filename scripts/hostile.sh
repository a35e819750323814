#!/usr/bin/env bash
# Reruns the memory cases of the hostile-input sweep (docs/errors.md, issue 15) under an
# address-space limit: each must be refused within seconds, with one line and a non-zero exit,
# instead of allocating what a corrupt or absurd input claims. Uses the build in build/ (or
# $PENUMBRA). Usage: scripts/hostile.sh [LIMIT_KB=2097152]
set -uo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${PENUMBRA:-$root/build/penumbra}"
limit="${1:-2097152}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
body='"lights": [{"corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0]}],
 "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1]}]'
cat > base.json <<JSON
{"camera": {"eye": [0,-6,3], "look_at": [0,0,1], "width": 8, "height": 8}, $body,
 "obstacles": [{"type": "sphere", "center": [0,0,1], "radius": 0.4}],
 "level_set": {"voxel_size": 0.05}}
JSON
"$bin" bake base.json -o full.vdb -q || exit 1
failures=0
check() {  # NAME EXPECTED_EXIT COMMAND...
    local name="$1" want="$2"
    shift 2
    local start end rc
    start=$(date +%s%N)
    (ulimit -v "$limit"; "$@" > out.txt 2> err.txt)
    rc=$?
    end=$(date +%s%N)
    local secs=$(( (end - start) / 1000000 ))ms
    if [ "$rc" -ne "$want" ] || [ "$(wc -l < err.txt)" -ne 1 ]; then
        echo "FAIL $name: exit $rc (want $want), $(wc -l < err.txt) stderr lines, ${secs}"
        cat err.txt
        failures=$((failures + 1))
    else
        echo "ok   $name: exit $rc in ${secs}: $(cut -c1-150 err.txt)"
    fi
}
for n in 300 600 1000 5000; do
    head -c "$n" full.vdb > cut.vdb
    echo "{\"camera\": {\"width\": 8, \"height\": 8}, $body, \"obstacles\": [{\"type\": \"vdb\", \"file\": \"cut.vdb\"}]}" > cut.json
    check "vdb truncated to $n bytes" 2 "$bin" render cut.json -o o.exr -q
done
echo "{\"camera\": {\"width\": 8, \"height\": 8}, $body, \"obstacles\": [{\"type\": \"sphere\", \"center\": [0,0,1], \"radius\": 0.4}], \"level_set\": {\"voxel_size\": 0.02, \"half_width\": 1000}}" > band.json
check "level_set.half_width 1000" 2 "$bin" render band.json -o o.exr -q
echo "{$body, \"obstacles\": [{\"type\": \"box\", \"center\": [0,0,1], \"size\": [1000,1000,1000], \"analytic\": true}]}" > box.json
check "bake of a 1000-unit analytic box" 2 "$bin" bake box.json -o box.vdb -q
python3 - <<'PY'
import struct, zlib
def chunk(t, d): return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0)) \
    + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")
open("huge.png", "wb").write(png)
PY
check "compare of a PNG declaring 30000 x 30000" 2 "$bin" compare huge.png huge.png
echo "$failures failure(s)"
[ "$failures" -eq 0 ]
