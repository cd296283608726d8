#!/usr/bin/env bash
# The test command: set-up (idempotent), build every binary, run every test.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/setup.sh
cargo build --workspace --bins --locked
cargo test --workspace --locked
