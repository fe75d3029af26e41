#!/usr/bin/env bash
# Sets up cloudcontrol on a fresh Debian machine (run as root): system packages, a Python
# venv with the independent readers the tests use, and the release build of the library
# and CLI. Idempotent: what is already there is not installed again.
#   ./setup.sh           everything the product and its tests need
#   ./setup.sh --bench   also the peers the benchmarks compare with (OpenCV, Open3D)
set -euo pipefail
cd "$(dirname "$0")"

want_bench=0
[[ "${1:-}" == "--bench" ]] && want_bench=1

# GDAL/PROJ for rasters and CRSs, libclang for bindgen, gdal-bin for gdalinfo in tests,
# chromium to render the HTML report in tests.
packages=(build-essential pkg-config libgdal-dev libproj-dev libclang-dev clang gdal-bin proj-bin python3-venv python3-dev chromium)
(( want_bench )) && packages+=(libusb-1.0-0 libgomp1)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if (( ${#missing[@]} )); then
  echo "setup: installing ${missing[*]}"
  SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

command -v cargo >/dev/null || { echo "setup: cargo (Rust toolchain) is required" >&2; exit 1; }

if [[ ! -x .venv/bin/python ]]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -r bindings/python/requirements-test.txt
(( want_bench )) && .venv/bin/python -m pip install -q -r benches/requirements.txt
.venv/bin/python -m pip install -q -e bindings/python

# --all-targets: the test build then reuses these artefacts (dev-dependencies change feature
# unification, so a plain build followed by `cargo test` would compile the graph twice).
cargo build --release --all-targets
echo "setup: done (binary: target/release/cloudcontrol, library: target/release/libcloudcontrol.so)"
