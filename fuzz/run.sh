#!/usr/bin/env bash
# Fuzzing of cloudcontrol's readers (fuzz/README.md).
#   fuzz/run.sh ci        every target FUZZ_SECONDS (default 30) s, FUZZ_JOBS (default 2) at
#                         a time, after a build of the targets; fails when nightly or
#                         cargo-fuzz is missing (a fuzz run skipped is a fuzz run failed)
#   fuzz/run.sh release   the acceptance runs: each target until its executions recorded in
#                         fuzz/target/executions.tsv reach FUZZ_RUNS (default 1 000 000),
#                         in chunks of at most FUZZ_CHUNK_SECONDS (default 1800) s
#   fuzz/run.sh release las csv_points   ... only the named targets (also for ci)
#   fuzz/run.sh build     the build alone (timed), as `ci` builds it
#   fuzz/run.sh table     the executions recorded per target, as fuzz/EXECUTIONS.md's table
# Every run appends its target's executions, exec/s, peak RSS, seconds, date and commit to
# fuzz/target/executions.tsv (not committed); its log is fuzz/target/logs/<target>.log.
# libFuzzer flags of every run: -rss_limit_mb=2048 (also the malloc limit) -timeout=10
# (per input); ASan and LeakSanitizer on, debug assertions and overflow checks on (cargo
# fuzz's defaults). FUZZ_NICE (default 0; 19 for background runs) sets the priority.
# Exits non-zero when a target crashes, leaks, runs out of memory or times out; the
# reproducer is left in fuzz/artifacts/<target>/.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGETS=(colmap_bin colmap_txt blocks_exchange dcp_manifest dcp_package las ply_points
         csv_points odm_gcp project_toml project_check camera_json fiducial_io
         image_header image_decode task_files)
mode="${1:-}"
shift || true
if [ $# -gt 0 ]; then TARGETS=("$@"); fi

TRIPLE=x86_64-unknown-linux-gnu
BIN="fuzz/target/$TRIPLE/release"
LEDGER=fuzz/target/executions.tsv
NICE="${FUZZ_NICE:-0}"

have_fuzz() {
    cargo +nightly --version >/dev/null 2>&1 && cargo +nightly fuzz --version >/dev/null 2>&1
}

require_fuzz() {
    if ! have_fuzz; then
        echo "fuzz: FAILED: the nightly toolchain and cargo-fuzz are needed" \
             "(rustup toolchain install nightly; cargo install cargo-fuzz --locked)" >&2
        exit 1
    fi
}

# The sanitizer build of every target (cargo fuzz's defaults: ASan, release with debug
# assertions, one codegen unit). Prints its time. The targets are built and linked
# without debug information (-Cdebuginfo=0, after cargo fuzz's line tables on the rustc
# command line, so it wins; -Cstrip=debuginfo for the standard library's): it was 93 % of
# each 130 MB binary, 2 GB for the sixteen, and ran CI's disk full, and the line tables
# stripped at the link had still been generated for every crate. A crash report still
# names the functions (the symbol table stays); its reproducer replays with file and
# line through tests/fuzz_replay.rs.
#
# The optimisation level is build's argument: 1 for the CI path (`ci` and `build`, which
# share fuzz/target), 3 (cargo fuzz's) for `release`; FUZZ_OPT_LEVEL overrides it. Measured on 2 cores from an empty
# fuzz/target: level 3 built in 24 min 26 s (32 CPU min), level 1 in 16 min 5 s (22 CPU
# min), the library itself 14 → 5 min; level 1 runs at 43–97 % of level 3's exec/s
# (image_decode 341/798, colmap_txt 1047/1422, dcp_package 513/644, las 253/262; 30 s
# each, side by side). For CI's 30 s a target, the build is most of the cost.
build() {
    local t0=$SECONDS opt="${FUZZ_OPT_LEVEL:-$1}"
    CARGO_PROFILE_RELEASE_OPT_LEVEL="$opt" RUSTFLAGS="${RUSTFLAGS:+$RUSTFLAGS }-Cdebuginfo=0 -Cstrip=debuginfo" \
        nice -n "$NICE" cargo +nightly fuzz build --target "$TRIPLE"
    echo "fuzz: targets built at opt-level $opt in $((SECONDS - t0)) s"
}

# Per-target libFuzzer flags: inputs of the slow readers bounded in size (seeds longer are
# read truncated).
target_flags() {
    case "$1" in
        # LAS/LAZ: the seeds are 40-point files (< 4 KB); the fixed reproducers reach 18 KB.
        las) echo "-max_len=20000" ;;
        # Images: the seeds are < 7 KB; a decoder's cost is per pixel, and a bomb (a small
        # file claiming a large image) fits in 8 KB.
        image_decode) echo "-max_len=8192" ;;
    esac
}

# One run of target $1 with libFuzzer flags $2...: new inputs go to the target's work
# corpus (first folder, kept in fuzz/target), the committed seeds and fixed reproducers
# are read too. Prints the summary line (executions, exec/s, peak RSS) and records it.
run_target() {
    local t="$1"; shift
    local work="fuzz/target/work-corpus/$t" log="fuzz/target/logs/$t.log"
    mkdir -p "$work" "$(dirname "$log")" "fuzz/artifacts/$t"
    local dirs=("$work" "fuzz/corpus/$t")
    [ -d "fuzz/artifacts-fixed/$t" ] && dirs+=("fuzz/artifacts-fixed/$t")
    local rc=0 t0=$SECONDS
    # As `cargo fuzz run` does (ASAN_OPTIONS), without its cargo build before each run;
    # GDAL's error messages (one per refused raster or CRS) to /dev/null, not the log.
    CPL_LOG=/dev/null ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_odr_violation=0" \
        nice -n "$NICE" "$BIN/$t" "${dirs[@]}" \
        -rss_limit_mb=2048 -timeout=10 -print_final_stats=1 \
        -artifact_prefix="fuzz/artifacts/$t/" $(target_flags "$t") "$@" >"$log" 2>&1 || rc=$?
    local secs=$((SECONDS - t0)) n eps rss
    n=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    eps=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
    rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$log" | tail -1)
    if [ -z "$n" ]; then
        # No final statistics (a crash or a kill): the last status line's count.
        n=$(sed -n 's/^#\([0-9]*\).*/\1/p' "$log" | tail -1)
        rss=$(sed -n 's/.* rss: \([0-9]*\)Mb.*/\1/p' "$log" | tail -1)
        [ -n "$n" ] && [ "$secs" -gt 0 ] && eps=$((n / secs))
    fi
    mkdir -p "$(dirname "$LEDGER")"
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$t" "${n:-0}" "${eps:-0}" "${rss:-0}" "$secs" \
        "$(date -u +%Y-%m-%dT%H:%M:%SZ)" "$(git rev-parse --short HEAD 2>/dev/null || echo -)" \
        "$([ "$rc" -eq 0 ] && echo ok || echo "exit-$rc")" >>"$LEDGER"
    if [ "$rc" -eq 0 ]; then
        printf 'fuzz: %-16s ok     executions %9s  exec/s %6s  peak RSS %5s MB  %4s s\n' \
            "$t" "${n:-?}" "${eps:-?}" "${rss:-?}" "$secs"
    else
        printf 'fuzz: %-16s FAILED (exit %s) after %s executions, see %s and fuzz/artifacts/%s/\n' \
            "$t" "$rc" "${n:-?}" "$log" "$t"
        grep -m5 -E '^==[0-9]+==ERROR|panicked at|^SUMMARY|Test unit written|out-of-memory|timeout' "$log" || true
    fi
    return "$rc"
}

# Runs `$1 <target>` for every target of TARGETS, FUZZ_JOBS (default 2) at a time; the
# summary lines come out as the runs end. Fails when any run failed. (Each run leaves its
# exit status in a file: `wait PID` on a job bash has already reaped fails.)
run_parallel() {
    local cmd="$1" jobs="${FUZZ_JOBS:-2}" t failed=0 dir
    dir=$(mktemp -d)
    for t in "${TARGETS[@]}"; do
        while [ "$(find "$dir" -name '*.running' | wc -l)" -ge "$jobs" ]; do
            sleep 1
        done
        touch "$dir/$t.running"
        (
            rc=0
            "$cmd" "$t" || rc=$?
            echo "$rc" >"$dir/$t.rc"
            rm -f "$dir/$t.running"
        ) &
    done
    wait
    for t in "${TARGETS[@]}"; do
        [ "$(cat "$dir/$t.rc" 2>/dev/null)" = 0 ] || failed=1
    done
    rm -rf "$dir"
    return "$failed"
}

# 30 s a target in CI (60 until 2026-11-30): a smoke run over the committed seeds and the
# fixed reproducers; the acceptance runs are `release`'s million executions.
ci_run() { run_target "$1" -max_total_time="${FUZZ_SECONDS:-30}"; }

# A release run of target $1: what it still needs of FUZZ_RUNS, at most FUZZ_CHUNK_SECONDS.
# A failed target is marked (fuzz/target/logs/<target>.failed) and left out of later
# rounds until the mark is removed.
release_run() {
    local left=$(( ${FUZZ_RUNS:-1000000} - $(recorded "$1") ))
    run_target "$1" -runs="$left" -max_total_time="${FUZZ_CHUNK_SECONDS:-1800}" \
        || { touch "fuzz/target/logs/$1.failed"; return 1; }
}

# Executions recorded for target $1 (every run in the ledger).
recorded() {
    [ -f "$LEDGER" ] || { echo 0; return; }
    awk -F'\t' -v t="$1" '$1 == t { n += $2 } END { print n + 0 }' "$LEDGER"
}

case "$mode" in
ci)
    require_fuzz
    start=$SECONDS
    build 1
    echo "fuzz: ${#TARGETS[@]} targets, ${FUZZ_SECONDS:-30} s each, ${FUZZ_JOBS:-2} at a time," \
         "-rss_limit_mb=2048, ASan"
    rc=0
    run_parallel ci_run || rc=$?
    echo "fuzz: ${#TARGETS[@]} targets built and run in $((SECONDS - start)) s"
    exit "$rc"
    ;;
release)
    require_fuzz
    build 3
    all=("${TARGETS[@]}")
    failed=0
    while :; do
        TARGETS=()
        for t in "${all[@]}"; do
            if [ -e "fuzz/target/logs/$t.failed" ]; then
                failed=1
            elif [ "$(recorded "$t")" -lt "${FUZZ_RUNS:-1000000}" ]; then
                TARGETS+=("$t")
            fi
        done
        [ ${#TARGETS[@]} -eq 0 ] && break
        run_parallel release_run || failed=1
    done
    exit "$failed"
    ;;
build)
    require_fuzz
    build 1
    ;;
table)
    echo "| target | executions | runs | exec/s (last run) | peak RSS MB (max) | last run (UTC) | commit |"
    echo "|---|---:|---:|---:|---:|---|---|"
    for t in "${TARGETS[@]}"; do
        [ -f "$LEDGER" ] || break
        awk -F'\t' -v t="$t" '$1 == t { n += $2; k++; eps = $3; if ($4 > rss) rss = $4; d = $6; c = $7 }
            END { if (k) printf "| %s | %d | %d | %s | %s | %s | %s |\n", t, n, k, eps, rss, d, c }' "$LEDGER"
    done
    ;;
*)
    echo "usage: fuzz/run.sh ci|release|build|table [target...]" >&2
    exit 2
    ;;
esac
