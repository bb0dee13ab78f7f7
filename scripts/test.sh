#!/bin/sh
# The formatting check, clippy (warnings are errors), the API docs, then every test of the
# workspace, then the loop guard's shader sweep (README command 2, after
# scripts/install-deps.sh; CI runs it via .ci/run). With cargo-nextest 0.9.91 or newer (on the
# CI machines) every test runs in its own process, the tests of all binaries share the cores and
# the slowest start first (.config/nextest.toml), so the accuracy matrix overlaps the rest;
# doctests then run with cargo test. Without it: plain `cargo test`, one test binary after the other (the same tests,
# slower). PENUMBRA_PLAIN_CARGO_TEST=1 forces that.
set -eu
cd "$(dirname "$0")/.."
nextest_ok() {
    v=$(cargo nextest --version 2>/dev/null | head -n 1 | sed -n 's/^cargo-nextest \([0-9]*\)\.\([0-9]*\)\.\([0-9]*\).*/\1 \2 \3/p')
    [ -n "$v" ] || return 1
    set -- $v
    # test priorities need 0.9.91
    [ "$1" -gt 0 ] || [ "$2" -gt 9 ] || { [ "$2" -eq 9 ] && [ "$3" -ge 91 ]; }
}
# Formatting first (seconds): rustfmt.toml's style, `cargo fmt` fixes it.
if cargo fmt --version >/dev/null 2>&1; then
    cargo fmt --all --check || { echo "scripts/test.sh: the code is not formatted: run 'cargo fmt'" >&2; exit 1; }
else
    echo "scripts/test.sh: warning: rustfmt is not installed (rustup component add rustfmt): formatting not checked" >&2
fi
# Lints next (a check build, no code generation): clippy's warnings are errors; the few lints
# allowed workspace-wide are in Cargo.toml's [workspace.lints.clippy], each with its reason.
if cargo clippy --version >/dev/null 2>&1; then
    cargo clippy --workspace --all-targets --quiet -- -D warnings || { echo "scripts/test.sh: clippy found problems (cargo clippy --workspace --all-targets)" >&2; exit 1; }
else
    echo "scripts/test.sh: warning: clippy is not installed (rustup component add clippy): lints not checked" >&2
fi
# API documentation builds without warnings (broken or private intra-doc links fail; libraries
# only: the CLI's binary shares the facade's name, which rustdoc cannot tell apart).
RUSTDOCFLAGS="${RUSTDOCFLAGS:-} -D warnings" cargo doc --workspace --no-deps --lib --quiet || { echo "scripts/test.sh: cargo doc found problems (cargo doc --workspace --no-deps --lib)" >&2; exit 1; }
if [ -z "${PENUMBRA_PLAIN_CARGO_TEST:-}" ] && nextest_ok; then
    cargo nextest run --workspace --no-fail-fast "$@"
    cargo test --workspace --doc
else
    cargo test --workspace "$@"
fi
# The loop guard's sweep (tools/tests/cli.rs: two tests side by side, isg's two modes and the
# rest, about 3 minutes; ignored in plain `cargo test`) against the binary just built for the
# tests: it counts shader loop iterations on lavapipe, where the CPU-side profile makes no
# difference. Until session 38 this leg built the release binary (5 minutes on 2 cores, the
# same code as the checked build) and ran the CLI's tests again against it; with the accuracy
# matrix and cold shader caches that made the suite 25.5 minutes on a fresh 2-core machine.
# PENUMBRA_SKIP_LOOP_GUARD=1 skips this leg (a quicker local run).
if [ -z "${PENUMBRA_SKIP_LOOP_GUARD:-}" ]; then
    if [ -z "${PENUMBRA_PLAIN_CARGO_TEST:-}" ] && nextest_ok; then
        cargo nextest run -p penumbra-tools --test cli --no-fail-fast --run-ignored only -E 'test(/^no_shader_reaches_the_loop_limit/)'
    else
        cargo test -p penumbra-tools --test cli -- --ignored no_shader_reaches_the_loop_limit
    fi
fi
