#!/usr/bin/env bash
# What recording costs: run the release `ima demo` N times without and N times with
# `--record` (alternating, so a busy machine weighs on both alike) and print the CPU time
# (user + sys) of each, the mean and its standard error, the extra CPU relative to the demo's
# own and in points of one core, max RSS, and the file size per wall minute.
# Usage: scripts/record-cpu.sh [N] (default 10; each run lasts ~16 s).
# Needs GNU time (/usr/bin/time) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
n="${1:-10}"
cargo build --release --quiet --bin ima
bin="$(pwd)/${CARGO_TARGET_DIR:-target}/release/ima"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cd "$out"
for i in $(seq "$n"); do
    /usr/bin/time -f '%U %S %e %M' -o "base-$i.t" "$bin" demo --json --svg base.svg > /dev/null 2>&1
    /usr/bin/time -f '%U %S %e %M' -o "rec-$i.t" "$bin" demo --json --svg rec.svg \
        --record "rec-$i.mcap" > /dev/null 2>&1
    stat -c %s "rec-$i.mcap" > "rec-$i.size"
    rm -f "rec-$i.mcap"
done
python3 - "$n" <<'PY'
import statistics as st, sys
n = int(sys.argv[1])
def runs(kind):
    rows = [open(f"{kind}-{i}.t").read().split()[-4:] for i in range(1, n + 1)]
    return [(float(u) + float(s), float(e), int(m)) for u, s, e, m in rows]
base, rec = runs("base"), runs("rec")
size = [int(open(f"rec-{i}.size").read()) for i in range(1, n + 1)]
def cpu(r): return [c for c, _, _ in r]
def show(name, r):
    c = cpu(r)
    se = st.stdev(c) / len(c) ** 0.5 if len(c) > 1 else 0.0
    print(f"{name}: CPU {st.mean(c):.3f} ± {se:.3f} s (median {st.median(c):.3f}, "
          f"{min(c):.2f}–{max(c):.2f}), wall {st.mean(e for _, e, _ in r):.1f} s, "
          f"max RSS {max(m for _, _, m in r) / 1024:.1f} MB")
show("without --record", base)
show("with --record   ", rec)
b, r = st.mean(cpu(base)), st.mean(cpu(rec))
wall = st.mean(e for _, e, _ in base + rec)
print(f"extra CPU: {(r / b - 1) * 100:+.1f} % of the demo's own CPU time; "
      f"{b / wall * 100:.1f} % → {r / wall * 100:.1f} % of one core "
      f"({(r - b) / wall * 100:+.2f} points)")
mb = st.mean(size) / 1e6
print(f"file: {mb:.2f} MB per run, {mb / wall * 60:.1f} MB per wall minute")
PY
