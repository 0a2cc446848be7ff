//! Properties of the firmware images themselves: no floating point in the
//! Cortex-M0/M3 builds, sizes within budget, and the instruction counter
//! sees every sample. These build the images and run QEMU for real.

use std::path::PathBuf;

use host_tools::bench::{count_instructions, image_size};
use host_tools::firmware::{self, Board};
use host_tools::sim::{self, Plan};
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;
use object::{Object, ObjectSymbol};

fn elf(board: Board) -> PathBuf {
    firmware::build(board).expect("firmware build")
}

/// Soft-float runtime routines: what the compiler calls for `f32`/`f64`
/// arithmetic on cores without an FPU.
fn is_soft_float(name: &str) -> bool {
    const PREFIXES: [&str; 8] = [
        "__aeabi_d",
        "__aeabi_f",
        "__aeabi_i2",
        "__aeabi_ui2",
        "__aeabi_l2",
        "__aeabi_ul2",
        "__float",
        "__fix",
    ];
    const SUFFIXES: [&str; 6] = ["sf3", "df3", "sf2", "df2", "sfdf2", "dfsf2"];
    PREFIXES.iter().any(|p| name.starts_with(p))
        || (name.starts_with("__") && SUFFIXES.iter().any(|s| name.ends_with(s)))
}

#[test]
fn cortex_m0_and_m3_images_contain_no_floating_point_code() {
    assert!(
        is_soft_float("__aeabi_dmul")
            && is_soft_float("__addsf3")
            && !is_soft_float("__aeabi_lmul")
    );
    for board in [Board::Lm3s6965M0, Board::Lm3s6965] {
        let data = std::fs::read(elf(board)).unwrap();
        let file = object::File::parse(&*data).unwrap();
        let floats: Vec<String> = file
            .symbols()
            .filter_map(|s| s.name().ok().map(str::to_owned))
            .filter(|n| is_soft_float(n))
            .collect();
        assert!(
            floats.is_empty(),
            "{board:?} links soft-float routines: {floats:?}"
        );
    }
}

#[test]
fn the_ci_board_image_fits_the_budget() {
    let size = image_size(&elf(Board::Lm3s6965)).unwrap();
    assert!(
        size.flash_bytes > 4096,
        "{size:?}: implausibly small, sections missed?"
    );
    assert!(size.flash_bytes <= 32 * 1024, "{size:?}");
    assert!(size.ram_bytes <= 8 * 1024, "{size:?}");
}

#[test]
fn the_instruction_counter_sees_every_sample() {
    firmware::ensure_qemu().unwrap();
    let plan = Plan {
        depth_m: 0.0,
        surface_x_m: 0.001,
        dwell_s: 0.0,
        ..Plan::PAPER
    };
    let (trial, _) = sim::insertion(&LIVER1, &plan);
    let config = DeviceConfig::default();
    let dir = tempfile::tempdir().unwrap();
    let replay = dir.path().join("short.replay");
    std::fs::write(
        &replay,
        sim::to_replay(&trial, 500, &config.load_cell, &config.encoder),
    )
    .unwrap();
    let counts = count_instructions(Board::Lm3s6965, &elf(Board::Lm3s6965), &replay).unwrap();
    assert_eq!(counts.per_region.len(), trial.len());
    // The markers themselves cost a handful of instructions, a sample at
    // least the frame it sends (tens of bytes).
    assert!(counts.overhead < 20, "{}", counts.overhead);
    assert!(
        counts.per_region.iter().all(|&n| n > 100),
        "{:?}",
        &counts.per_region[..5]
    );
}
