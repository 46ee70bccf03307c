#!/usr/bin/env bash
# Runs every cargo-fuzz target of fuzz/ for a bounded time, starting from the committed
# seed corpora (fuzz/corpus/<target>) and the inputs of past crashes
# (fuzz/regressions/<target>). New inputs go to a temporary folder, never into the
# committed corpora. A crash fails the script and leaves its input in fuzz/artifacts/.
#
#   scripts/fuzz.sh                  # every target, FUZZ_SECONDS (default 15) each
#   FUZZ_SECONDS=600 scripts/fuzz.sh mesh urdf
#   FUZZ_PROFILE=release FUZZ_RUNS=1000000 FUZZ_SECONDS=3600 scripts/fuzz.sh urdf
#
# Settings: FUZZ_SECONDS (per target), FUZZ_RUNS (stop a target after this many
# executions, whichever of the two comes first; default: no limit), FUZZ_SANITIZER (none |
# address; default none: the targets reach only safe Rust and well-fuzzed C, and the build
# stays short on 2 cores), FUZZ_PROFILE (dev | release; default dev: the shortest build).
# Each target's line: executions, edges covered, new inputs, wall seconds (with any
# rebuild) and libFuzzer's peak RSS.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

seconds="${FUZZ_SECONDS:-15}"
runs_limit="${FUZZ_RUNS:--1}"
sanitizer="${FUZZ_SANITIZER:-none}"
profile="${FUZZ_PROFILE:-dev}"

command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked --version 0.13.2

# cargo fuzz passes unstable compiler flags: a nightly toolchain when the machine has one,
# otherwise the stable one with RUSTC_BOOTSTRAP (the same flags, accepted on stable).
if rustup run nightly rustc --version >/dev/null 2>&1; then
    toolchain=(+nightly)
else
    toolchain=()
    export RUSTC_BOOTSTRAP=1
fi

build_flags=(-s "$sanitizer")
[ "$profile" = dev ] && build_flags+=(--dev)

targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(ls fuzz/fuzz_targets | sed 's/\.rs$//' | sort)
fi

cd fuzz
cargo "${toolchain[@]}" fuzz build "${build_flags[@]}"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
summary=()
for t in "${targets[@]}"; do
    mkdir -p "$work/$t"
    seeds=(corpus/"$t")
    [ -d regressions/"$t" ] && seeds+=(regressions/"$t")
    log="$work/$t.log"
    started=$SECONDS
    if ! cargo "${toolchain[@]}" fuzz run "${build_flags[@]}" "$t" "$work/$t" "${seeds[@]}" -- \
        -max_total_time="$seconds" -runs="$runs_limit" -max_len=65536 -rss_limit_mb=2048 -timeout=10 \
        -print_final_stats=1 >"$log" 2>&1; then
        tail -n 60 "$log"
        # The panic's message (the backtrace above can push it out of the tail).
        grep -m 2 -A 1 "panicked at" "$log" || true
        echo "fuzz target $t FAILED (its input is in fuzz/artifacts/$t/)"
        exit 1
    fi
    runs="$(sed -nE 's/^Done ([0-9]+) runs.*/\1/p' "$log" | tail -n 1)"
    cov="$(grep -oE 'cov: [0-9]+' "$log" | tail -n 1 | grep -oE '[0-9]+' || true)"
    rss="$(sed -nE 's/^stat::peak_rss_mb:[[:space:]]*([0-9]+).*/\1/p' "$log" | tail -n 1)"
    corpus="$(find "$work/$t" -type f | wc -l)"
    summary+=("$(printf '%-16s %10s runs  %6s edges  %5s new inputs  %5ss  peak %4s MB' \
        "$t" "${runs:-?}" "${cov:-?}" "$corpus" "$((SECONDS - started))" "${rss:-?}")")
done
printf '%s\n' "${summary[@]}"
