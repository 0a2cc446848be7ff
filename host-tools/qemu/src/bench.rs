//! `needle bench`: exact instruction counts of the per-sample path under
//! QEMU, and the firmware's flash and static RAM.
//!
//! QEMU runs the firmware one instruction per translation block with every
//! block logged (`-singlestep -d exec,nochain`), so the log holds one line
//! per executed instruction with its address. The firmware calls
//! `needle_bench_begin` before and `needle_bench_end` after each sample's
//! `Device::tick` (ADC read to frame bytes on the UART); this counts the
//! instructions between them, subtracts the markers' own cost (an empty
//! begin/end pair the firmware runs at boot), and averages over a recorded
//! insertion. The Cortex-M0 image runs on the same lm3s6965evb model, whose
//! M3 executes the v6-M instruction subset one for one.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::model::params::LIVER1;
use object::{Object, ObjectSection, ObjectSymbol, SectionKind};

use crate::firmware::{self, Board, Serial};
use needle_analysis::sim::{self, Plan};

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Print the figures as one JSON line at the end.
    #[arg(long)]
    pub json: bool,
}

/// Instruction counts of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct InstructionCounts {
    /// Cost of an empty begin/end pair.
    pub overhead: u64,
    /// Instructions of each measured region, overhead subtracted.
    pub per_region: Vec<u64>,
}

impl InstructionCounts {
    pub fn mean(&self) -> f64 {
        self.per_region.iter().sum::<u64>() as f64 / self.per_region.len().max(1) as f64
    }
    pub fn max(&self) -> u64 {
        self.per_region.iter().copied().max().unwrap_or(0)
    }
}

/// Flash and static RAM of an image, bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageSize {
    /// Everything loaded into flash: vector table, code, read-only data,
    /// and the initial values of `.data`.
    pub flash_bytes: u64,
    /// Statically allocated RAM: `.data`, `.bss`, `.uninit` (the stack and
    /// anything on it come on top).
    pub ram_bytes: u64,
}

/// The real board's fastest sample rate and its core clock.
const F411_FASTEST_HZ: f64 = 2000.0;
const F411_CLOCK_HZ: f64 = 100e6;

pub fn run(args: &BenchArgs) -> Result<()> {
    firmware::ensure_qemu()?;
    let dir = firmware::target_directory()?.join("bench");
    std::fs::create_dir_all(&dir)?;
    let replay_path = dir.join("liver1.replay");
    let (trial, _, replay) = sim::insertion_replay(&LIVER1, &Plan::PAPER);
    std::fs::write(&replay_path, replay)?;
    needle_io::out!(
        "recorded insertion: liver 1, 3 mm/s, {} samples at 500 Hz",
        trial.len()
    )?;

    let capture = dir.join("liver1.frames");
    let mut means = Vec::new();
    let mut bytes_per_sample = 0.0;
    for (board, core) in [
        (Board::Lm3s6965, "cortex-m3"),
        (Board::Lm3s6965M0, "cortex-m0"),
        (Board::NucleoF411re, "cortex-m4f"),
    ] {
        let elf = firmware::build(board)?;
        let started = Instant::now();
        let counts = count_instructions(board, &elf, &replay_path, &capture)?;
        if board == Board::Lm3s6965 {
            // Everything the CI board sent for the insertion (header,
            // configuration, snapshots, batches, events, status) over its
            // samples: what the link must carry.
            let sent = std::fs::metadata(&capture)?.len();
            bytes_per_sample = sent as f64 / counts.per_region.len().max(1) as f64;
            needle_io::out!(
                "stream: {sent} bytes for {} samples = {bytes_per_sample:.2} bytes per sample ({:.0} Bd at 500 Hz, {:.0} Bd at 2 kHz, 10 bits a byte)",
                counts.per_region.len(),
                bytes_per_sample * 500.0 * 10.0,
                bytes_per_sample * 2000.0 * 10.0
            )?;
        }
        needle_io::out!(
            "{core:>9} ({}): {:.1} instructions per sample (max {}, marker overhead {} subtracted), {} samples, counted in {:.0} s",
            board.target(),
            counts.mean(),
            counts.max(),
            counts.overhead,
            counts.per_region.len(),
            started.elapsed().as_secs_f64()
        )?;
        means.push((core, counts.mean().round() as u64));
    }
    let relaxing = dir.join("skin_dwell.replay");
    std::fs::write(&relaxing, sim::relaxing_dwell_replay()?.1)?;
    let elf = firmware::build(Board::Lm3s6965)?;
    let counts = count_instructions(Board::Lm3s6965, &elf, &relaxing, &dir.join("skin.frames"))?;
    needle_io::out!(
        "cortex-m3 with relaxation on (skin_phantom, 20 mm, a 5 s dwell): {:.1} instructions per sample (max {}: the sample that computes the decay factors), {} samples",
        counts.mean(),
        counts.max(),
        counts.per_region.len()
    )?;
    means.push(("cortex-m3-relaxation", counts.mean().round() as u64));
    let size = image_size(&elf)?;
    needle_io::out!(
        "CI board image: {} bytes flash, {} bytes static RAM",
        size.flash_bytes,
        size.ram_bytes
    )?;
    // The real board's load at its fastest rate: its per-sample
    // instructions (the same board code, replay in place of the sensors)
    // taken as cycles — the M4 issues about one instruction a cycle, and
    // the F411's flash accelerator hides most of its wait states at
    // 100 MHz — times 2000 samples a second, over 100 MHz.
    let m4 = means
        .iter()
        .find(|(k, _)| *k == "cortex-m4f")
        .map_or(0, |m| m.1);
    let load_percent = m4 as f64 * F411_FASTEST_HZ / F411_CLOCK_HZ * 100.0;
    needle_io::out!(
        "nucleo-f411re at {F411_FASTEST_HZ} Hz: {m4} instructions a sample ≈ {load_percent:.2} % of its {} MHz",
        F411_CLOCK_HZ / 1e6
    )?;
    if args.json {
        let json = serde_json::json!({
            "instructions_per_sample": means.iter().map(|(k, v)| (k.to_string(), serde_json::Value::from(*v))).collect::<serde_json::Map<_, _>>(),
            "bytes_per_sample": (bytes_per_sample * 100.0).round() / 100.0,
            "flash_bytes": size.flash_bytes,
            "ram_bytes": size.ram_bytes,
            "nucleo_f411re_cpu_load_at_2khz_percent": load_percent,
        });
        needle_io::out!("{json}")?;
    }
    Ok(())
}

/// Address of a function symbol (Thumb bit cleared).
fn symbol_address(file: &object::File<'_>, name: &str) -> Result<u64> {
    file.symbols()
        .find(|s| s.name() == Ok(name))
        .map(|s| s.address() & !1)
        .with_context(|| format!("symbol {name} not in the firmware image"))
}

/// Flash and static RAM of a firmware ELF, from its allocated sections.
pub fn image_size(elf: &Path) -> Result<ImageSize> {
    let data = std::fs::read(elf).with_context(|| format!("{}: cannot read", elf.display()))?;
    let file =
        object::File::parse(&*data).with_context(|| format!("{}: not an ELF", elf.display()))?;
    let mut size = ImageSize {
        flash_bytes: 0,
        ram_bytes: 0,
    };
    for section in file.sections() {
        let name = section.name().unwrap_or("");
        let bytes = section.size();
        match section.kind() {
            SectionKind::Text | SectionKind::ReadOnlyData | SectionKind::ReadOnlyString => {
                size.flash_bytes += bytes
            }
            SectionKind::Data => {
                size.flash_bytes += bytes;
                size.ram_bytes += bytes;
            }
            SectionKind::UninitializedData => size.ram_bytes += bytes,
            // cortex-m-rt's `.vector_table` and `.uninit` have no standard kind.
            _ if name == ".vector_table" => size.flash_bytes += bytes,
            _ if name == ".uninit" => size.ram_bytes += bytes,
            _ => {}
        }
    }
    Ok(size)
}

/// Run `elf` on `replay` under QEMU's instruction log and count the
/// instructions of every begin/end region; the frames go to `capture`.
pub fn count_instructions(
    board: Board,
    elf: &Path,
    replay: &Path,
    capture: &Path,
) -> Result<InstructionCounts> {
    let data = std::fs::read(elf).with_context(|| format!("{}: cannot read", elf.display()))?;
    let file = object::File::parse(&*data)?;
    let begin = symbol_address(&file, "needle_bench_begin")?;
    let end = symbol_address(&file, "needle_bench_end")?;

    let extra = ["-singlestep", "-d", "exec,nochain", "-D", "/dev/stderr"];
    let mut cmd = firmware::qemu_command(board, elf, replay, Serial::File(capture), &extra);
    let mut child = firmware::spawn_qemu(&mut cmd)?;
    let mut stdout = child.stdout.take().context("no QEMU stdout")?;
    let drain = std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    let log = BufReader::with_capacity(1 << 20, child.stderr.take().context("no QEMU stderr")?);
    let deadline = Instant::now() + Duration::from_secs(600);

    let mut regions = Vec::new();
    let mut counting: Option<u64> = None;
    for line in log.split(b'\n') {
        let line = line?;
        let Some(pc) = trace_pc(&line) else { continue };
        if pc == begin {
            counting = Some(0);
        } else if pc == end {
            if let Some(n) = counting.take() {
                regions.push(n);
            }
        } else if let Some(n) = counting.as_mut() {
            *n += 1;
        }
        if regions.len() % 4096 == 0 && Instant::now() > deadline {
            let _ = child.kill();
            bail!("instruction count did not finish within 600 s");
        }
    }
    let status = child.wait()?;
    let _ = drain.join();
    if !status.success() {
        bail!("QEMU exited with {status} while counting instructions");
    }
    let Some((&overhead, samples)) = regions.split_first() else {
        bail!("no marked regions in the instruction log: is this a firmware image with bench markers?");
    };
    let per_region = samples.iter().map(|n| n.saturating_sub(overhead)).collect();
    Ok(InstructionCounts {
        overhead,
        per_region,
    })
}

/// The guest PC of one `-d exec` line: `Trace N: 0xHOST [xxxxxxxx/PC/...] sym`.
fn trace_pc(line: &[u8]) -> Option<u64> {
    if !line.starts_with(b"Trace ") {
        return None;
    }
    let open = line.iter().position(|&b| b == b'[')?;
    let mut fields = line[open + 1..].split(|&b| b == b'/');
    let _cs_base = fields.next()?;
    let pc = std::str::from_utf8(fields.next()?).ok()?;
    u64::from_str_radix(pc, 16).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_pc_of_a_trace_line() {
        let line = b"Trace 0: 0x7f3a9c000240 [00800400/000018c6/00000110/ff000201] __defmt_default_timestamp";
        assert_eq!(trace_pc(line), Some(0x18c6));
        assert_eq!(trace_pc(b"Timer with period zero, disabling"), None);
    }
}
