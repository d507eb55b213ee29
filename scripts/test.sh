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

echo "== the bundled example, end to end"
cargo run --release --quiet -p tissue-cli -- \
    sample assets/phantom-breast.obj --particles 10000 \
    --output target/ci-model.vtp --report target/ci-report.json
