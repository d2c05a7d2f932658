#!/usr/bin/env bash
# Run `ima demo` on the default seed and 20 others; print one line per seed and fail if any
# target of any seed failed. Usage: scripts/demo-seeds.sh [SPEED] (default 4).
set -euo pipefail
cd "$(dirname "$0")/.."
speed="${1:-4}"
cargo build --release --quiet
bin="${CARGO_TARGET_DIR:-target}/release/ima"
out="$(mktemp -d)"
failed=0
for seed in 1 $(seq 101 120); do
    if "$bin" demo --seed "$seed" --speed "$speed" --json --svg "$out/demo-$seed.svg" \
        > "$out/demo-$seed.jsonl" 2> "$out/demo-$seed.err"; then
        status=ok
    else
        status=FAILED
        failed=$((failed + 1))
    fi
    summary="$(grep '"kind":"summary"' "$out/demo-$seed.jsonl" || true)"
    printf 'seed %3s  %-6s %s\n' "$seed" "$status" \
        "$(printf '%s' "$summary" | sed -e 's/.*"done":\([0-9]*\).*"failed":\([0-9]*\).*"wall_time_s":\([0-9.]*\).*/done \1, failed \2, wall \3 s/')"
done
echo "logs and SVGs in $out"
if [ "$failed" -ne 0 ]; then
    echo "$failed seed(s) failed"
    exit 1
fi
echo "all 21 seeds accomplished every target"
