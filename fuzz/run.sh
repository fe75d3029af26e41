#!/usr/bin/env bash
# Fuzzing of cloudcontrol's readers (fuzz/README.md).
#   fuzz/run.sh ci       short time-boxed run of every target (nightly + cargo-fuzz), or,
#                        where either (or a kept fuzz build) is missing, a message only
#   fuzz/run.sh release  the acceptance runs: 1 M executions per target (100 k for LAS/LAZ)
#   fuzz/run.sh release las csv_points   ... only the named targets
# Environment: FUZZ_SECONDS (ci: seconds per target, default 15); FUZZ_MAX_SECONDS
# (release: stop a target after this many seconds even short of its count).
# Exits non-zero when a target crashes, runs out of memory (2 GB) or times out (10 s per
# input); the reproducer is left in fuzz/artifacts/<target>/.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGETS=(colmap_bin colmap_txt blocks_exchange dcp_manifest dcp_package las ply_points
         csv_points odm_gcp project_toml camera_json image_header)
mode="${1:-}"
shift || true
if [ $# -gt 0 ]; then TARGETS=("$@"); fi

have_fuzz() {
    cargo +nightly --version >/dev/null 2>&1 && cargo +nightly fuzz --version >/dev/null 2>&1
}

# One target: libFuzzer writes new inputs to a scratch corpus (first folder), reads the
# committed seeds and the fixed reproducers; prints executions, exec/s and peak RSS.
run_target() {
    local t="$1"; shift
    local work="fuzz/target/work-corpus/$t" log="fuzz/target/logs/$t.log"
    mkdir -p "$work" "$(dirname "$log")" "fuzz/artifacts/$t"
    local dirs=("$work" "fuzz/corpus/$t")
    [ -d "fuzz/artifacts-fixed/$t" ] && dirs+=("fuzz/artifacts-fixed/$t")
    local rc=0
    cargo +nightly fuzz run "$t" "${dirs[@]}" -- \
        -rss_limit_mb=2048 -timeout=10 -print_final_stats=1 \
        -artifact_prefix="fuzz/artifacts/$t/" "$@" >"$log" 2>&1 || rc=$?
    local n eps rss
    n=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    eps=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
    rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$log" | tail -1)
    if [ "$rc" -eq 0 ]; then
        printf 'fuzz: %-16s ok     executions %9s  exec/s %6s  peak RSS %5s MB\n' "$t" "${n:-?}" "${eps:-?}" "${rss:-?}"
    else
        printf 'fuzz: %-16s FAILED (exit %s), see %s and fuzz/artifacts/%s/\n' "$t" "$rc" "$log" "$t"
        grep -m3 -E 'ERROR|panicked|Test unit written' "$log" || true
    fi
    return "$rc"
}

run_all() {
    local failed=0 start=$SECONDS t
    local t0=$SECONDS
    cargo +nightly fuzz build
    echo "fuzz: targets built in $((SECONDS - t0)) s"
    for t in "${TARGETS[@]}"; do
        run_target "$t" "$@" || failed=1
    done
    echo "fuzz: ${#TARGETS[@]} targets in $((SECONDS - start)) s"
    return "$failed"
}

case "$mode" in
ci)
    # A cold sanitizer build takes ~20 min on 2 cores, beyond the CI budget: the short runs
    # need nightly, cargo-fuzz and a build kept from an earlier run (fuzz/target). The
    # target bodies are built and every seed replayed on stable by tests/fuzz_replay.rs.
    if ! have_fuzz; then
        echo "fuzz: nightly/cargo-fuzz missing, runs skipped (seeds replayed by tests/fuzz_replay.rs)"
    elif ! ls fuzz/target/*/release/colmap_bin >/dev/null 2>&1; then
        echo "fuzz: no fuzz build kept in fuzz/target (cold build ~20 min: cargo +nightly fuzz build), runs skipped"
    else
        run_all -max_total_time="${FUZZ_SECONDS:-15}"
    fi
    ;;
release)
    if ! have_fuzz; then
        echo "fuzz: release runs need the nightly toolchain and cargo-fuzz (cargo install cargo-fuzz --locked)" >&2
        exit 2
    fi
    failed=0
    cargo +nightly fuzz build
    for t in "${TARGETS[@]}"; do
        runs=1000000
        [ "$t" = las ] && runs=100000
        run_target "$t" -runs="$runs" ${FUZZ_MAX_SECONDS:+-max_total_time=$FUZZ_MAX_SECONDS} || failed=1
    done
    exit "$failed"
    ;;
*)
    echo "usage: fuzz/run.sh ci|release [target...]" >&2
    exit 2
    ;;
esac
