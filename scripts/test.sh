#!/usr/bin/env bash
# The project's test command (README "The two commands"; run by .ci/run): formatting, lints,
# documentation and every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."

section() { printf '\n==== %s ====\n' "$1"; }

section "cargo fmt --check"
cargo fmt --all --check

section "cargo clippy (warnings denied)"
cargo clippy --workspace --all-targets --locked -- -D warnings

section "cargo doc (warnings denied)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked

section "tests"
if cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run --workspace --locked --no-fail-fast
    section "doctests"
    cargo test --workspace --doc --locked
else
    cargo test --workspace --locked --no-fail-fast
fi
