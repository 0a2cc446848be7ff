#!/usr/bin/env bash
# The full test command (the README's, and what CI runs). Installs what a fresh
# machine lacks, then: format, lints, rustdoc and the book, firmware builds for the three targets,
# and the host test suite, which runs the firmware in QEMU and compares it
# byte for byte with the host twin.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s\n' "$*"; }

# Where cargo builds (CARGO_TARGET_DIR, if set, as cargo reads it: relative
# to this directory); the real board's images get directories of their own
# beneath it, as `needle` gives them.
target_dir=$(realpath -m "${CARGO_TARGET_DIR:-target}")

step "prerequisites"
# rust-toolchain.toml names the thumb targets; `rustup target add` is a no-op
# when they are there and installs them when not.
rustup target add thumbv6m-none-eabi thumbv7m-none-eabi thumbv7em-none-eabihf
rustup component add rustfmt clippy llvm-tools
apt_install() {
    local sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update
    $sudo apt-get install -y --no-install-recommends "$@"
}
command -v qemu-system-arm >/dev/null || apt_install qemu-system-arm
qemu-system-arm --version | head -n 1
# The live view's browser test drives Debian's Chromium through its ChromeDriver.
{ command -v chromium && command -v chromedriver; } >/dev/null || apt_install chromium chromium-driver
chromedriver --version
if ! command -v defmt-print >/dev/null; then
    cargo install defmt-print --version 1.2.0 --locked
fi
defmt-print --version
if ! command -v mdbook >/dev/null; then
    cargo install mdbook --version 0.4.52 --locked --no-default-features
fi
mdbook --version

step "format"
cargo fmt --all -- --check

step "lints (host, and firmware for each board)"
cargo clippy --workspace --all-targets -- -D warnings
cargo clippy --target thumbv7m-none-eabi -p needle-wire -p needle-holder -p needle-holder-firmware -- -D warnings
cargo clippy --target thumbv7em-none-eabihf -p needle-wire -p needle-holder -p needle-holder-firmware --features needle-holder-firmware/board-mps2 -- -D warnings
cargo clippy --target thumbv7em-none-eabihf -p needle-holder-firmware --features board-f411 --target-dir "$target_dir/f411" -- -D warnings
cargo clippy --target thumbv7em-none-eabihf -p needle-holder-firmware --features f411-replay --target-dir "$target_dir/f411-replay" -- -D warnings

step "docs (rustdoc with warnings denied, the book, a README of at most 150 lines)"
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --workspace
mdbook build book --dest-dir "$target_dir/book"
readme_lines=$(wc -l < README.md)
if [ "$readme_lines" -gt 150 ]; then
    echo "README.md has $readme_lines lines: the front door stays at 150 at most; the rest goes in the book" >&2
    exit 1
fi

step "firmware builds"
cargo fw-m0
cargo fw-m3
cargo fw-m4
cargo fw-f411 --target-dir "$target_dir/f411"

step "tests (host, QEMU, twin comparison)"
log=$(mktemp)
status=0
cargo test --workspace --no-fail-fast 2>&1 | tee "$log" || status=$?
# One closing line over all suites (cargo ends with the doc-test suite, which
# may hold no test, and that last line is not the whole story), printed
# whether or not a suite failed. A test binary that started ("Running",
# "Doc-tests") and printed no result crashed: it counts as a failure.
awk '/^ *(Running|Doc-tests) / { started++ }
     /^test result:/ { p += $4; f += $6; ended++ }
     END { crashed = started - ended
           printf "\ntotal: %d passed, %d failed", p, f + crashed
           if (crashed > 0) printf " (%d test binaries crashed)", crashed
           printf "\n" }' "$log"
exit "$status"
