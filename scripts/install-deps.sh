#!/usr/bin/env bash
# Installs pp5echo's build and test dependencies from Debian's packages.
# Idempotent: packages that are already installed are skipped, and apt is not
# touched at all when nothing is missing.
# Usage: scripts/install-deps.sh [--tests]
set -euo pipefail

pkgs=(
  build-essential cmake ninja-build pkg-config
  libopenmpi-dev openmpi-bin
  libglm-dev
  libopenimageio-dev openimageio-tools
  libusb-1.0-0-dev
  umockdev libumockdev-dev
  clang libclang-rt-14-dev
  libopenigtlink-dev
  libcli11-dev
  libtomlplusplus-dev
  libpugixml-dev
  libspdlog-dev libfmt-dev
  zlib1g-dev
  libgif-dev  # giflib: buildup.gif and orbit.gif, whole frames (src/formats/image_io)
  nlohmann-json3-dev
  libboost-dev  # Boost.Beast: the live viewer's HTTP and WebSocket server (src/viewer)
  libturbojpeg0-dev  # the viewer's JPEG images (src/viewer/jpeg)
  libeigen3-dev  # least squares: the bench's cost model (src/benchmark/cost_fit)
  libgtest-dev libgmock-dev
  libbenchmark-dev
  python3-matplotlib  # the plots of `pp5echo bench` (scripts/bench_plots.py)
  chromium  # the viewer's browser test (tests/browser), driven by npm's playwright-core
)
# Node.js and npm for the browser test, unless a node is already there (a
# NodeSource nodejs brings its own npm and conflicts with Debian's).
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then pkgs+=(nodejs npm); fi

# playwright-core from npm (the browser itself is Debian's chromium).
npm_deps() {
  if [ -d tests/browser/node_modules/playwright-core ]; then
    echo "install-deps: playwright-core already installed"
  else
    echo "install-deps: npm ci (tests/browser: playwright-core)" >&2
    (cd tests/browser && npm ci --no-audit --no-fund)
  fi
}
cd "$(dirname "$0")/.."

missing=()
for p in "${pkgs[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#pkgs[@]} packages already installed"
  npm_deps
  exit 0
fi

echo "install-deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
echo "install-deps: apt-get update" >&2
$SUDO apt-get update -q
# -q, not -qq: one line per package as it is unpacked and set up, so a long
# install shows that it is moving.
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
npm_deps
