//! Writes the board's memory map, `board_memory.x`, into the build's
//! OUT_DIR and puts that directory on the linker's search path: the
//! top-level `memory.x`, where cortex-m-rt's `link.x` looks for it,
//! includes it.

/// The memory map `memory.x` includes, per board.
const QEMU_MEMORY: &str = "/* lm3s6965evb: 256 KiB flash at 0, 64 KiB SRAM; mps2-an386 has more of
   both at the same addresses, so this fits it too (and thumbv6m builds). */
MEMORY
{
  FLASH : ORIGIN = 0x00000000, LENGTH = 256K
  RAM   : ORIGIN = 0x20000000, LENGTH = 64K
}
";
const F411_MEMORY: &str = "/* STM32F411RE (RM0383 section 2.3): 512 KiB flash, 128 KiB SRAM. The
   image gets sectors 0-6 (384 KiB); sector 7 (0x08060000, 128 KiB) is the
   settings store (firmware/src/hardware/nucleo_f411re/store.rs). */
MEMORY
{
  FLASH : ORIGIN = 0x08000000, LENGTH = 384K
  RAM   : ORIGIN = 0x20000000, LENGTH = 128K
}
";

fn main() {
    // The map depends on the features alone; the linker reads memory.x.
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=../memory.x");
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let board = if std::env::var_os("CARGO_FEATURE_BOARD_F411").is_some() {
        F411_MEMORY
    } else {
        QEMU_MEMORY
    };
    std::fs::write(out.join("board_memory.x"), board).unwrap();
    println!("cargo:rustc-link-search={}", out.display());
}
