# Sourced by the scripts beside it (not run on its own): from the
# repository's root, builds the release `needle` (honouring
# CARGO_TARGET_DIR) into $needle and makes a scratch directory $work,
# removed when the script exits.
cd "$(dirname "${BASH_SOURCE[0]}")/.."
cargo build --release -q -p host-tools
needle=${CARGO_TARGET_DIR:-target}/release/needle
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
