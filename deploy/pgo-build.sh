#!/usr/bin/env bash
# Builds tessera-worker with profile-guided optimisation (PGO): 1.02-1.14x faster on one core
# than `cargo build --release` on the host measured on 2026-11-25, not faster on every host
# (docs/PERFORMANCE.md, "Output, build and farm"), with the same pixels bit for bit
# (PGO changes code layout, inlining and branch order, never floating-point arithmetic).
#
#   deploy/pgo-build.sh                       # -> target/pgo/release/tessera-worker
#   deploy/pgo-build.sh -p tessera-tests --bin envbench   # also build these with the profile
#
# Steps: an instrumented build of the worker, a training run that renders every scene of
# scenes/ at 4 samples per pixel (the project's own scenes: meshes, spheres, PLY, area, spot
# and environment lights, textures, depth of field, motion blur, path tracing), a merge of the
# profiles with llvm-profdata, and the optimised build. About four minutes on two cores.
#
# Needs llvm-profdata of the LLVM that rustc uses (`rustc -vV` names it): rustup's
# `llvm-tools` component has it (`rustup component add llvm-tools`); or set LLVM_PROFDATA.
# Env: PGO_TARGET_DIR (default target/pgo), PGO_SAMPLES (training samples per pixel, default 4).
# Extra arguments go to the final `cargo build` (more packages or binaries to optimise with the
# same profile); the training always runs the worker.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${PGO_TARGET_DIR:-$ROOT/target/pgo}"
SAMPLES="${PGO_SAMPLES:-4}"
HOST="$(rustc -vV | sed -n 's/^host: //p')"

find_profdata() {
    if [ -n "${LLVM_PROFDATA:-}" ]; then
        echo "$LLVM_PROFDATA"
        return
    fi
    local p
    p="$(rustc --print sysroot)/lib/rustlib/$HOST/bin/llvm-profdata"
    if [ -x "$p" ]; then
        echo "$p"
    fi
}
PROFDATA="$(find_profdata)"
if [ -z "$PROFDATA" ] || [ ! -x "$PROFDATA" ]; then
    echo "pgo-build: llvm-profdata not found; install it with 'rustup component add llvm-tools'" \
        "or set LLVM_PROFDATA to the llvm-profdata of LLVM $(rustc -vV | sed -n 's/^LLVM version: //p')" >&2
    exit 2
fi

cd "$ROOT"
# `--config` adds to the rustflags of .cargo/config.toml (target-cpu) instead of replacing them,
# as RUSTFLAGS would.
flags() { echo "target.$HOST.rustflags=[\"$1\"]"; }

rm -rf "$OUT/profiles" "$OUT/training"
echo "pgo-build: 1/4 instrumented build" >&2
cargo build --release --locked -p tessera-worker --target-dir "$OUT/instrumented" \
    --config "$(flags "-Cprofile-generate=$OUT/profiles")"

echo "pgo-build: 2/4 training on scenes/ at $SAMPLES spp" >&2
shopt -s nullglob
scenes=("$ROOT"/scenes/*.xml)
if [ ${#scenes[@]} -eq 0 ]; then
    echo "pgo-build: no scenes in $ROOT/scenes to train on" >&2
    exit 1
fi
for scene in "${scenes[@]}"; do
    "$OUT/instrumented/release/tessera-worker" render "$scene" --samples "$SAMPLES" --quiet \
        --out "$OUT/training" >/dev/null
done

echo "pgo-build: 3/4 merging profiles" >&2
"$PROFDATA" merge -o "$OUT/merged.profdata" "$OUT/profiles"

echo "pgo-build: 4/4 optimised build" >&2
use="$(flags "-Cprofile-use=$OUT/merged.profdata")"
cargo build --release --locked -p tessera-worker --target-dir "$OUT" --config "$use"
if [ $# -gt 0 ]; then
    # Separately: `--bin X` would otherwise leave out the worker's own binary.
    cargo build --release --locked "$@" --target-dir "$OUT" --config "$use"
fi
echo "pgo-build: done: $OUT/release/tessera-worker" >&2
