#!/usr/bin/env bash
# Runs every test: Rust (unit, integration, C ABI, header drift), the C program, the header
# as C++, and the Python binding's tests. Sets up what is missing first.
set -euo pipefail
cd "$(dirname "$0")"
t0=$SECONDS
./setup.sh
echo "== setup took $((SECONDS - t0)) s"

# The sanitizer build of the fuzz targets (fuzz/target, the fuzz crate's own workspace)
# overlaps the tests at their priority. Half of it is the library, one codegen unit on one
# core (714 of 1,495 CPU s, cargo --timings from an empty fuzz/target): at nice 19 the
# tests left it almost nothing, so it ran after them with the other core idle (529 s of
# waiting in a full run). Its log is printed before the fuzz runs, which wait for it.
mkdir -p fuzz/target
FUZZ_NICE=0 fuzz/run.sh build > fuzz/target/ci-build.log 2>&1 &
fuzz_build=$!

# Each part prints its time: CI's log is cut at its time limit, and the times say where
# the limit went.
t0=$SECONDS
echo "== Rust tests"
cargo test --release
echo "== Rust tests took $((SECONDS - t0)) s"

echo "== C program against the library"
mkdir -p bindings/c/build
gcc -std=c99 -Wall -Wextra -Werror -pedantic -Iinclude bindings/c/check_projection.c \
    -Ltarget/release -lcloudcontrol -lm -o bindings/c/build/check_projection
LD_LIBRARY_PATH=target/release bindings/c/build/check_projection
printf '#include "cloudcontrol.h"\nint main() { return CCP_STATUS_OK; }\n' > bindings/c/build/header.cpp
g++ -std=c++11 -Wall -Wextra -Werror -pedantic -Iinclude bindings/c/build/header.cpp -o bindings/c/build/header_cpp
echo "header compiles as C++"

echo "== Python binding tests"
t0=$SECONDS
CLOUDCONTROL_LIB="$PWD/target/release/libcloudcontrol.so" .venv/bin/python -m pytest -q -p no:cacheprovider bindings/python/tests
echo "== Python tests took $((SECONDS - t0)) s"

echo "== Fuzz targets: every target ${FUZZ_SECONDS:-30} s, two at a time, ASan, -rss_limit_mb=2048 (fuzz/README.md)"
t0=$SECONDS
if ! wait "$fuzz_build"; then
    cat fuzz/target/ci-build.log
    echo "fuzz: the background build failed; fuzz/run.sh ci builds again"
fi
tail -n 1 fuzz/target/ci-build.log
echo "fuzz: waited $((SECONDS - t0)) s for the background build"
fuzz/run.sh ci
