#!/usr/bin/env bash
# The one test command: formatting, lints, and every test in release mode.
# CI runs exactly this (.ci/run). The tests read ../shared/meshes when it exists;
# under CI=true its absence is a failure.
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== cargo fmt --check"
cargo fmt --all -- --check

echo "== cargo clippy (warnings are errors)"
cargo clippy --workspace --all-targets --release -- -D warnings

echo "== cargo test (release)"
cargo test --workspace --release

echo "== the README's first command: the whole pipeline on the bundled phantom"
cargo run --release --quiet -p tissue-cli -- demo --output-dir target/ci-demo
