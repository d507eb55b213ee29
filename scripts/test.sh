#!/usr/bin/env bash
# The one test command: formatting, lints, and every test in release mode.
# CI runs exactly this (.ci/run). The tests read ../shared/meshes when it exists;
# under CI=true its absence is a failure. The GPU tests run on whatever Vulkan
# driver there is; on a machine without one this installs Mesa's lavapipe (a
# software Vulkan device), so they run rather than skip; some run again on
# Mesa's OpenGL driver (llvmpipe), installed the same way.
set -euo pipefail
cd "$(dirname "$0")/.."

# Debian packages, installed with apt where missing.
apt_install() {
    local sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    export DEBIAN_FRONTEND=noninteractive
    $sudo apt-get install -y --no-install-recommends "$@" ||
        { $sudo apt-get update && $sudo apt-get install -y --no-install-recommends "$@"; }
}
have_vulkan() {
    # No `grep -q`: under pipefail its early exit can fail the pipeline.
    [ -n "$(ldconfig -p | grep 'libvulkan\.so\.1')" ] &&
        { compgen -G '/usr/share/vulkan/icd.d/*.json' >/dev/null ||
            compgen -G '/etc/vulkan/icd.d/*.json' >/dev/null; }
}
# wgpu's other backend on Linux: OpenGL through EGL, here Mesa's llvmpipe
# (its shader compiler is not lavapipe's).
have_gl() {
    [ -n "$(ldconfig -p | grep 'libEGL_mesa\.so\.0')" ] &&
        compgen -G '/usr/lib/*/dri/swrast_dri.so' >/dev/null
}
if ! have_vulkan; then
    echo "== no Vulkan driver found: installing Mesa lavapipe for the GPU tests"
    apt_install mesa-vulkan-drivers libvulkan1
    have_vulkan || { echo "error: lavapipe did not install"; exit 1; }
fi
if ! have_gl; then
    echo "== no Mesa OpenGL driver found: installing llvmpipe's for the GL tests"
    apt_install libegl1 libegl-mesa0 libgl1-mesa-dri
    have_gl || { echo "error: Mesa's OpenGL driver did not install"; exit 1; }
fi
# lavapipe warns about a missing runtime directory; give it one.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

echo "== cargo fmt --check"
cargo fmt --all -- --check

echo "== cargo clippy (warnings are errors)"
cargo clippy --workspace --all-targets --release -- -D warnings

echo "== packaging: every crate's manifest and files as crates.io takes them"
cargo package --workspace --no-verify --allow-dirty --quiet

echo "== cargo test (release)"
cargo test --workspace --release --exclude tissue-gpu --exclude tissue-py

echo "== GPU tests (release; the output names the adapter)"
cargo test -p tissue-gpu --release -- --show-output

echo "== GPU tests on OpenGL (wgpu's GL backend): the kernels' parity and the potential"
WGPU_BACKEND=gl cargo test -p tissue-gpu --release --test parity --test potential -- --show-output

echo "== criterion micro-benchmarks, smoke mode (each kernel once)"
cargo bench --bench kernels -- --test
cargo bench --bench gpu_kernels -- --test

echo "== the README's first command: the whole pipeline on the bundled phantom"
cargo run --release --quiet -p tissue-cli -- demo --output-dir target/ci-demo

echo "== Python package (a fresh virtual environment, the wheel by maturin, pytest)"
scripts/python-package.sh target/python-venv
# From target/, so that `import tissue` is the installed wheel.
(cd target && python-venv/bin/python -m pytest -q ../crates/tissue-py/tests)
