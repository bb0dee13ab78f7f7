#!/bin/sh
# Every test of the workspace (README command 2, after scripts/install-deps.sh; CI runs it via
# .ci/run). With cargo-nextest (on the CI machines) every test runs in its own process and the
# tests of all binaries share the cores, so the long GPU tests (the accuracy matrix, avs, isg)
# overlap the rest; doctests then run with cargo test. Without nextest: plain `cargo test`, one
# test binary after the other (the same tests, slower). PENUMBRA_PLAIN_CARGO_TEST=1 forces it.
set -eu
cd "$(dirname "$0")/.."
if [ -z "${PENUMBRA_PLAIN_CARGO_TEST:-}" ] && cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run --workspace --no-fail-fast "$@"
    cargo test --workspace --doc
else
    cargo test --workspace "$@"
fi
