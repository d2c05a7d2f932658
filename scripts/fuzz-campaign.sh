#!/usr/bin/env bash
# A fuzzing campaign over every cargo-fuzz target of fuzz/ (needs a nightly toolchain and
# cargo-fuzz; installs cargo-fuzz when missing).
#
#   scripts/fuzz-campaign.sh [SECONDS_PER_TARGET] [TARGET…]     (default: 600 s, every target)
#
# For each target: fuzz for the given time from a copy of its committed corpus
# (fuzz/corpus/<target>/), merge the inputs that reach new coverage back into the committed
# corpus (libFuzzer's -merge=1 keeps only inputs that add coverage, i.e. a minimised merge),
# and print one line: executions, executions per second, coverage (edges), corpus size before
# and after, and crashes (files under fuzz/artifacts/<target>/). Exits 1 if any target crashed.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
secs="${1:-600}"
shift || true
if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "installing cargo-fuzz" >&2
  cargo install --locked cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz
fi
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo +nightly fuzz list)
fi
printf '%-24s %12s %10s %8s %8s %8s %8s\n' target execs exec/s cov corpus merged crashes
crashed=0
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t" "artifacts/$t"
  before=$(find "corpus/$t" -type f | wc -l)
  crashes_before=$(find "artifacts/$t" -type f | wc -l)
  work=$(mktemp -d)
  cp -r "corpus/$t/." "$work/" 2>/dev/null || true
  log=$(mktemp)
  if ! cargo +nightly fuzz run "$t" "$work" -- -max_total_time="$secs" -rss_limit_mb=2048 \
      -print_final_stats=1 >/dev/null 2>"$log"; then
    crashed=1
  fi
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  # Merge what adds coverage into the committed corpus (minimised: only new-coverage inputs).
  cargo +nightly fuzz run "$t" "corpus/$t" "$work" -- -merge=1 >/dev/null 2>&1 || true
  after=$(find "corpus/$t" -type f | wc -l)
  crashes=$(( $(find "artifacts/$t" -type f | wc -l) - crashes_before ))
  [ "$crashes" -gt 0 ] && crashed=1
  printf '%-24s %12s %10s %8s %8s %8s %8s\n' "$t" "${execs:-?}" "${rate:-?}" "${cov:-?}" \
    "$before" "+$((after - before))" "$crashes"
  rm -rf "$work" "$log"
done
exit "$crashed"
