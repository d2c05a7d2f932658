#!/usr/bin/env bash
# What recording costs: run the release `ima demo` N times without and N times with
# `--record` (alternating, so a busy machine weighs on both alike) and print the CPU time
# (user + sys) of each, the mean and its standard error, the extra CPU relative to the demo's
# own and in points of one core, the recorder thread's own CPU (exact, as the demo reports it),
# the time the robot's threads spent in logging calls (as the demo reports it), their sum as a
# share of the demo's own CPU, max RSS, and the file size per wall minute.
# Usage: scripts/record-cpu.sh [N] (default 10; each run lasts ~16 s).
# Needs GNU time (/usr/bin/time) and python3. user+sys is the process's CPU time as the
# kernel's scheduler charged it (its total is the exact run time; only the split between user
# and sys is sampled at ticks). Where `perf` works the script also reads perf's `task-clock`,
# a second clock: on a VM it reads well below user+sys for work that sleeps and wakes a lot
# (this demo, 30 runs: 0.82 s by task-clock, 1.04 s by user+sys; a 0.5 ms sleep loop: 0.16 s
# and 0.27 s; a busy loop: 1.09 s by both), so both are printed. PIN=CPU runs every demo on
# that one CPU (`taskset`), which halves the run-to-run scatter on a VM. REC_ARGS adds
# options to the recording runs, e.g. REC_ARGS='--record-exclude /*/camera'.
set -euo pipefail
cd "$(dirname "$0")/.."
n="${1:-10}"
cargo build --release --quiet --bin ima
bin="$(pwd)/${CARGO_TARGET_DIR:-target}/release/ima"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cd "$out"
pre=()
if [ -n "${PIN:-}" ]; then pre=(taskset -c "$PIN"); fi
# Split on blanks, never globbed (`/*/camera` stays as written).
read -r -a rec_args <<< "${REC_ARGS:-}"
perf_ok=0
if perf stat -x, -e task-clock -o probe.p true > /dev/null 2>&1; then perf_ok=1; fi
run() { # run KIND I ARGS...: one demo, timed
    local kind="$1" i="$2"
    shift 2
    local p=()
    if [ "$perf_ok" = 1 ]; then p=(perf stat -x, -e task-clock -o "$kind-$i.p"); fi
    "${p[@]}" /usr/bin/time -f '%U %S %e %M' -o "$kind-$i.t" "${pre[@]}" "$bin" demo --json \
        "$@" 2> /dev/null | tail -1 > "$kind-$i.json"
}
for i in $(seq "$n"); do
    run base "$i" --svg base.svg
    run rec "$i" --svg rec.svg --record "rec-$i.mcap" "${rec_args[@]}"
    stat -c %s "rec-$i.mcap" > "rec-$i.size"
    rm -f "rec-$i.mcap"
done
python3 - "$n" "$perf_ok" "${PIN:-}" <<'PY'
import statistics as st, sys
n, perf_ok, pin = int(sys.argv[1]), sys.argv[2] == "1", sys.argv[3]
print(f"{n} runs each, alternating{f', pinned to CPU {pin}' if pin else ''}")
def runs(kind):
    rows = [open(f"{kind}-{i}.t").read().split()[-4:] for i in range(1, n + 1)]
    return [(float(u) + float(s), float(e), int(m)) for u, s, e, m in rows]
base, rec = runs("base"), runs("rec")
size = [int(open(f"rec-{i}.size").read()) for i in range(1, n + 1)]
def cpu(r): return [c for c, _, _ in r]
def se(x): return st.stdev(x) / len(x) ** 0.5 if len(x) > 1 else 0.0  # standard error
def show(name, r):
    c = cpu(r)
    print(f"{name}: CPU {st.mean(c):.3f} ± {se(c):.3f} s (median {st.median(c):.3f}, "
          f"{min(c):.2f}–{max(c):.2f}), wall {st.mean(e for _, e, _ in r):.1f} s, "
          f"max RSS {max(m for _, _, m in r) / 1024:.1f} MB")
show("without --record", base)
show("with --record   ", rec)
wall = st.mean(e for _, e, _ in base + rec)
def extra(clock, xb, xr):  # one clock's runs without and with --record, paired by index
    b, r = st.mean(xb), st.mean(xr)
    d = se([y - x for x, y in zip(xb, xr)])  # the paired differences' mean is r - b
    print(f"extra CPU ({clock}): {b:.3f} ± {se(xb):.3f} s → {r:.3f} ± {se(xr):.3f} s: "
          f"{(r / b - 1) * 100:+.1f} ± {d / b * 100:.1f} % of the demo's own CPU time "
          f"(paired difference {(r - b) * 1000:+.0f} ± {d * 1000:.0f} ms); "
          f"{b / wall * 100:.1f} % → {r / wall * 100:.1f} % of one core "
          f"({(r - b) / wall * 100:+.2f} points)")
extra("user+sys", cpu(base), cpu(rec))
if perf_ok:
    def tc(kind):
        return [float(next(l for l in open(f"{kind}-{i}.p") if "task-clock" in l).split(",")[0])
                / 1000 for i in range(1, n + 1)]
    extra("task-clock", tc("base"), tc("rec"))
import json
recs = [json.load(open(f"rec-{i}.json"))["recording"] for i in range(1, n + 1)]
own = [r["thread_cpu_s"] for r in recs if r.get("thread_cpu_s") is not None]
calls = [r["calls_s"] for r in recs if r.get("calls_s") is not None]
if own:
    print(f"the recorder's own thread: {st.mean(own) * 1000:.0f} ± {se(own) * 1000:.0f} ms CPU per run "
          f"(exact, from the kernel)")
if calls:
    print(f"logging calls on the robot's threads: {st.mean(calls) * 1000:.0f} ± {se(calls) * 1000:.0f} ms "
          f"per run (their summed time: CPU, or a little more)")
if own and calls:
    work = st.mean(own) + st.mean(calls)
    b = st.mean(cpu(base))
    print(f"the recording's own work (thread + calls): {work * 1000:.0f} ms per run = "
          f"{work / b * 100:.1f} % of the demo's own CPU time (user+sys); the whole-process "
          f"difference above also holds its indirect costs (caches, memory) and the machine's "
          f"scatter")
mb = st.mean(size) / 1e6
print(f"file: {mb:.2f} MB per run, {mb / wall * 60:.1f} MB per wall minute")
PY
