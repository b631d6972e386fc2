#!/usr/bin/env bash
# The project's test command (README "The two commands"; run by .ci/run): formatting, lints,
# documentation and every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."

section() { printf '\n==== %s ====\n' "$1"; }

# The Bevy plugin (crates/treelod-bevy, built by every `--workspace` command below) depends on Bevy 0.20,
# whose shader compiler `wesl` 0.6 declares Rust 1.97.1 as its minimum; it builds and passes with
# the workspace's 1.95, and this flag lets cargo build it there. Our own crates declare 1.95.
msrv=--ignore-rust-version

section "cargo fmt --check"
cargo fmt --all --check

section "cargo clippy (warnings denied)"
cargo clippy --workspace --all-targets --locked "$msrv" -- -D warnings

section "cargo doc (warnings denied)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked "$msrv"

section "tests"
if cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run --workspace --locked "$msrv" --no-fail-fast
    section "doctests"
    cargo test --workspace --doc --locked "$msrv"
else
    cargo test --workspace --locked "$msrv" --no-fail-fast
fi
