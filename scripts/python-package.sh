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
    "maturin>=1.16,<2" "numpy>=1.21" pytest trimesh meshio
# Built in the workspace's target directory, so that what `cargo build` and
# `cargo test` compiled there is reused (only pyo3, numpy and the module
# itself are built for the wheel): the module links no shared library
# beyond the system's (LZMA is decoded in Rust), so maturin bundles none and
# leaves the built module as cargo made it.
PATH="$(cd "$venv/bin" && pwd):$PATH" maturin build --release \
    --manifest-path crates/tissue-py/Cargo.toml --out target/wheels
"$venv/bin/pip" install --quiet --disable-pip-version-check target/wheels/tissue-*.whl
echo "installed tissue into $venv"
