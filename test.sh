#!/usr/bin/env bash
# Runs every test: Rust (unit, integration, C ABI, header drift), the C program, the header
# as C++, and the Python binding's tests. Sets up what is missing first.
set -euo pipefail
cd "$(dirname "$0")"
t0=$SECONDS

# The sanitizer build of the fuzz targets (fuzz/target, the fuzz crate's own workspace)
# overlaps everything before the fuzz runs, at the tests' priority. It needs neither
# setup's packages (GDAL is opened at run time, not linked) nor its build, so it starts
# first and fills the cores while setup waits on apt and pip. Half of it is the library,
# one codegen unit on one core (714 of 1,495 CPU s, cargo --timings from an empty
# fuzz/target): at nice 19 the tests left it almost nothing, so it ran after them with
# the other core idle (529 s of waiting in a full run). Its log is printed before the
# fuzz runs, which wait for it.
mkdir -p fuzz/target
FUZZ_NICE=0 fuzz/run.sh build > fuzz/target/ci-build.log 2>&1 &
fuzz_build=$!
# A step that fails stops the script; what still runs in the background stops with it.
trap 'kill $(jobs -p) 2>/dev/null || true' EXIT

./setup.sh
echo "== setup took $((SECONDS - t0)) s"

# Each part prints its time: CI's log is cut at its time limit, and the times say where
# the limit went. The Python tests run beside the Rust tests: neither suite keeps two
# cores busy on its own (1.7 and 1.5 cores on average, idle machine), and the synthetic
# blocks both share are made once, under a lock (tests/common/mod.rs `shared_folder`).
# Their log is printed after the Rust tests.
t0=$SECONDS
echo "== Rust tests, with the Python binding's tests beside them"
CLOUDCONTROL_LIB="$PWD/target/release/libcloudcontrol.so" .venv/bin/python -m pytest -q \
    -p no:cacheprovider bindings/python/tests > target/python-tests.log 2>&1 &
python_tests=$!
rust_status=0
cargo test --release || rust_status=$?
echo "== Rust tests took $((SECONDS - t0)) s"
python_status=0
wait "$python_tests" || python_status=$?
echo "== Python binding tests"
cat target/python-tests.log
echo "== Rust and Python tests together took $((SECONDS - t0)) s"
if (( rust_status || python_status )); then
    echo "tests failed: Rust exit status $rust_status, Python $python_status"
    exit 1
fi

echo "== C program against the library"
mkdir -p bindings/c/build
gcc -std=c99 -Wall -Wextra -Werror -pedantic -Iinclude bindings/c/check_projection.c \
    -Ltarget/release -lcloudcontrol -lm -o bindings/c/build/check_projection
LD_LIBRARY_PATH=target/release bindings/c/build/check_projection
printf '#include "cloudcontrol.h"\nint main() { return CCP_STATUS_OK; }\n' > bindings/c/build/header.cpp
g++ -std=c++11 -Wall -Wextra -Werror -pedantic -Iinclude bindings/c/build/header.cpp -o bindings/c/build/header_cpp
echo "header compiles as C++"

echo "== Fuzz targets: every target ${FUZZ_SECONDS:-30} s, two at a time, ASan, -rss_limit_mb=2048 (fuzz/README.md)"
t0=$SECONDS
if ! wait "$fuzz_build"; then
    cat fuzz/target/ci-build.log
    echo "fuzz: the background build failed; fuzz/run.sh ci builds again"
fi
tail -n 1 fuzz/target/ci-build.log
echo "fuzz: waited $((SECONDS - t0)) s for the background build"
fuzz/run.sh ci
