#!/usr/bin/env bash
# The GPU tests and tissue-bench on a machine with a hardware GPU and no
# Rust toolchain (BENCHMARKS.md, "Hardware GPU").
#
#   scripts/device-check.sh pack          here: release build, then the GPU
#                                         test binaries, `tissue` and
#                                         `tissue-bench`, stripped, in
#                                         .dev/device.tar.xz
#   scripts/device-check.sh run [SIZES]   there, from the checkout's root,
#                                         with .dev (and a Vulkan loader in
#                                         .gl/*.deb where the machine has
#                                         none) beside it: every GPU test
#                                         binary in a process of its own,
#                                         then tissue-bench over SIZES
#                                         (default 10000,100000) on both
#                                         backends
#
# `run` writes its logs to $OUT (default .dev/out): tests.log (a line per
# binary, the failures' output, a backtrace of any binary still running at
# its limit), bench.log and bench.json. Set DEVICE_TEST_LIMIT (seconds per
# binary, default 120) and DEVICE_BENCH_LIMIT (seconds, default 300).
set -uo pipefail
cd "$(dirname "$0")/.."

# The test binaries that use the GPU: the GPU crate's, the facade's
# backend and elastic-solve tests, the bench's wall-clock test.
gpu_tests() {
    cargo test --release --workspace --no-run --message-format=json 2>/dev/null |
        python3 -c '
import json, sys
wanted = {("tissue-gpu", None), ("tissue", "backend"), ("tissue", "elastic_solve"),
          ("tissue-bench", "gpu_wall_clock")}
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") != "compiler-artifact" or not m.get("executable") or not m["profile"]["test"]:
        continue
    package = m["package_id"].split("#")[0].rstrip("/").split("/")[-1]
    package = "tissue" if package == "main" else package
    name = m["target"]["name"]
    if (package, None) in wanted or (package, name) in wanted:
        print(package + "." + name, m["executable"])
'
}

pack() {
    cargo build --release --workspace --all-targets || exit 1
    local stage
    stage=$(mktemp -d)
    mkdir -p "$stage/t" .dev
    gpu_tests | while read -r name path; do cp "$path" "$stage/t/$name"; done
    cp target/release/tissue target/release/tissue-bench "$stage/"
    strip --strip-debug "$stage"/t/* "$stage/tissue" "$stage/tissue-bench"
    tar -C "$stage" -cf - . | xz -9 -T2 >.dev/device.tar.xz
    echo ".dev/device.tar.xz: $(du -h .dev/device.tar.xz | cut -f1), $(ls "$stage/t" | wc -l) test binaries"
    rm -rf "$stage"
}

run() {
    local sizes=${1:-10000,100000}
    local out=${OUT:-.dev/out}
    local limit=${DEVICE_TEST_LIMIT:-120}
    mkdir -p "$out"
    if ! ldconfig -p | grep -q libvulkan && compgen -G ".gl/*.deb" >/dev/null; then
        for f in .gl/*.deb; do dpkg -x "$f" / 2>/dev/null; done
        ldconfig
    fi
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    [ -f "$icd" ] && export VK_DRIVER_FILES=$icd
    export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg} RUST_BACKTRACE=1
    mkdir -p "$XDG_RUNTIME_DIR" .dev/x
    tar -C .dev/x -xJf .dev/device.tar.xz || exit 1
    # The test binaries look for their fixtures and for `tissue` and
    # `tissue-bench` where they were built.
    local built=/work/main
    if [ "$(pwd -P)" != "$built" ] && [ ! -e "$built" ]; then
        mkdir -p "$(dirname "$built")" && ln -s "$(pwd -P)" "$built"
    fi
    mkdir -p target/release
    cp .dev/x/tissue .dev/x/tissue-bench target/release/
    nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null
    # Each binary alone, one test at a time; no `wait` without a PID, which
    # would also wait for any process substitution of the caller's.
    for binary in .dev/x/t/*; do
        local name start pid
        name=$(basename "$binary")
        start=$(date +%s)
        "$binary" --test-threads=1 >"/tmp/$name.log" 2>&1 &
        pid=$!
        while kill -0 "$pid" 2>/dev/null && [ $(($(date +%s) - start)) -lt "$limit" ]; do
            sleep 0.5
        done
        if kill -0 "$pid" 2>/dev/null; then
            echo "== $name still running at $limit s; $(grep -c ' ok$' "/tmp/$name.log") tests passed"
            grep -v ' ok$' "/tmp/$name.log" | tail -4
            local debugger
            debugger=$(command -v gdb || command -v cuda-gdb || command -v /usr/local/cuda/bin/cuda-gdb)
            [ -n "$debugger" ] && timeout 30 "$debugger" -batch -p "$pid" \
                -ex 'thread apply all bt 12' 2>/dev/null | grep '^#\|^Thread' | head -60
            kill -9 "$pid"
            wait "$pid" 2>/dev/null
        else
            wait "$pid"
            local rc=$?
            echo "== $name rc=$rc $(($(date +%s) - start)) s $(grep '^test result' "/tmp/$name.log" | tail -1)"
            [ "$rc" = 0 ] || grep -v ' ok$' "/tmp/$name.log" | tail -30
        fi
    done >"$out/tests.log" 2>&1
    grep '^==' "$out/tests.log"
    timeout "${DEVICE_BENCH_LIMIT:-300}" target/release/tissue-bench --sizes "$sizes" \
        --backends cpu,gpu --json "$out/bench.json" >"$out/bench.log" 2>&1
    echo "tissue-bench rc=$?"
    grep -A12 '^## Stage 2: deformation' "$out/bench.log"
}

case "${1:-}" in
pack) pack ;;
run) shift; run "$@" ;;
*)
    sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
