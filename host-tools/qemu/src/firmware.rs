//! Building the firmware and running it in QEMU, installing QEMU first
//! when it is missing (a fresh machine of this kind has apt-get and root).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::Duration;

use anyhow::{bail, Context, Result};
use wait_timeout::ChildExt;

/// A QEMU board and the firmware build that runs on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// lm3s6965evb, Cortex-M3 image (thumbv7m-none-eabi): the CI board.
    Lm3s6965,
    /// lm3s6965evb running the Cortex-M0 image (thumbv6m-none-eabi): the M3
    /// executes the v6-M subset, so this measures the M0 build.
    Lm3s6965M0,
    /// mps2-an386, Cortex-M4F image (thumbv7em-none-eabihf).
    Mps2An386,
    /// The real board's image (Nucleo-F411RE) with the replay source in
    /// place of the ADS1220 and encoder (feature `f411-replay`), on QEMU's
    /// netduinoplus2 (an STM32F405: same USART2, TIM2 and memory map).
    NucleoF411re,
}

impl Board {
    pub fn target(self) -> &'static str {
        match self {
            Board::Lm3s6965 => "thumbv7m-none-eabi",
            Board::Lm3s6965M0 => "thumbv6m-none-eabi",
            Board::Mps2An386 | Board::NucleoF411re => "thumbv7em-none-eabihf",
        }
    }

    /// Its image's name (the firmware crate's binary).
    pub fn image(self) -> &'static str {
        match self {
            Board::Lm3s6965 | Board::Lm3s6965M0 => "lm3s6965",
            Board::Mps2An386 => "mps2-an386",
            Board::NucleoF411re => "nucleo-f411re",
        }
    }

    fn features(self) -> &'static [&'static str] {
        match self {
            Board::Mps2An386 => &["--features", "board-mps2"],
            Board::NucleoF411re => &["--features", "f411-replay"],
            _ => &[],
        }
    }

    /// Its own directory under the workspace's target directory where it
    /// shares a target with another board, so that building one never
    /// overwrites the other's image.
    fn target_subdir(self) -> Option<&'static str> {
        match self {
            Board::NucleoF411re => Some("f411-replay"),
            _ => None,
        }
    }

    fn machine_args(self) -> &'static [&'static str] {
        match self {
            Board::Lm3s6965 | Board::Lm3s6965M0 => {
                &["-machine", "lm3s6965evb", "-cpu", "cortex-m3"]
            }
            Board::Mps2An386 => &["-machine", "mps2-an386"],
            // USART2 is the second serial port (the first, USART1, goes
            // nowhere). Virtual time by instruction count, skipping ahead
            // while the core sleeps between TIM2's samples: a replay runs
            // in seconds instead of its own length.
            Board::NucleoF411re => &[
                "-machine",
                "netduinoplus2",
                "-icount",
                "shift=0,sleep=off",
                "-serial",
                "null",
            ],
        }
    }
}

/// The repository root (this crate lives at `host-tools/qemu`, two
/// levels below it).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .nth(2)
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

/// Build the firmware image for `board`; returns the ELF path. Installs the
/// board's Rust target first when the toolchain lacks it.
pub fn build(board: Board) -> Result<PathBuf> {
    build_image(
        board.target(),
        board.image(),
        board.features(),
        board.target_subdir(),
    )
}

/// The real board's image (Nucleo-F411RE, feature `board-f411`, what
/// `cargo fw-f411` builds), in its own target directory (`target/f411`) so
/// it never overwrites the mps2 image of the same target while a test
/// runs that one.
pub fn build_nucleo_f411re() -> Result<PathBuf> {
    build_image(
        "thumbv7em-none-eabihf",
        Board::NucleoF411re.image(),
        &["--features", "board-f411"],
        Some("f411"),
    )
}

/// The workspace's target directory as cargo resolves it
/// (`CARGO_TARGET_DIR`, `build.target-dir` in a cargo config, or
/// `target/`): the image is looked for where cargo put it, never in a
/// `target/` an earlier build left behind. Asked once a run: `demo` and
/// `bench` build several images and write beside them.
pub fn target_directory() -> Result<PathBuf> {
    static FOUND: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    if let Some(dir) = FOUND.get() {
        return Ok(dir.clone());
    }
    let dir = ask_cargo_for_target_directory(&repo_root())?;
    Ok(FOUND.get_or_init(|| dir).clone())
}

fn ask_cargo_for_target_directory(root: &Path) -> Result<PathBuf> {
    #[derive(serde::Deserialize)]
    struct Metadata {
        target_directory: PathBuf,
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // From the caller's directory, as cargo itself reads a relative
    // `CARGO_TARGET_DIR`; the manifest names the workspace.
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .arg("--manifest-path")
        .arg(root.join("Cargo.toml"))
        .stderr(Stdio::inherit())
        .output()
        .context("cannot run `cargo metadata` to find the target directory")?;
    if !out.status.success() {
        bail!("`cargo metadata` failed ({})", out.status);
    }
    let meta: Metadata =
        serde_json::from_slice(&out.stdout).context("`cargo metadata` gave no target directory")?;
    Ok(meta.target_directory)
}

fn build_image(
    target: &str,
    image: &str,
    features: &[&str],
    subdir: Option<&str>,
) -> Result<PathBuf> {
    let root = repo_root();
    ensure_target(&root, target)?;
    let base = target_directory()?;
    let target_dir = subdir.map_or_else(|| base.clone(), |d| base.join(d));
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut command = Command::new(cargo);
    command
        .current_dir(&root)
        .args([
            "build",
            "--profile",
            "firmware",
            "-p",
            "needle-holder-firmware",
            "--bin",
            image,
            "--target",
            target,
        ])
        .args(features)
        .arg("--target-dir")
        .arg(&target_dir);
    let status = command
        .status()
        .context("cannot run cargo to build the firmware")?;
    if !status.success() {
        bail!("firmware build for {target} {features:?} failed ({status})");
    }
    let elf = target_dir.join(target).join("firmware").join(image);
    if !elf.exists() {
        bail!("firmware build succeeded but {} is missing", elf.display());
    }
    Ok(elf)
}

/// What to do about a Rust target, given `rustup target list --installed`.
#[derive(Debug, PartialEq, Eq)]
pub enum TargetAction {
    /// The toolchain has it.
    Present,
    /// It must be added with `rustup target add`.
    Install,
}

/// Decide from rustup's list of installed targets (one triple a line).
pub fn target_action(installed: &str, target: &str) -> TargetAction {
    if installed.lines().any(|line| line.trim() == target) {
        TargetAction::Present
    } else {
        TargetAction::Install
    }
}

/// Make sure the toolchain that builds the firmware (the one
/// `rust-toolchain.toml` pins, run from `root`) has `target`. rustup only
/// applies that file's `targets` when it installs the toolchain itself, so
/// a machine that already had the toolchain lacks the thumb targets.
pub fn ensure_target(root: &Path, target: &str) -> Result<()> {
    ensure_target_using(Path::new("rustup"), root, target)
}

/// [`ensure_target`] with another rustup program (the tests use a stand-in).
pub fn ensure_target_using(rustup: &Path, root: &Path, target: &str) -> Result<()> {
    let listed = Command::new(rustup)
        .current_dir(root)
        .args(["target", "list", "--installed"])
        .output();
    let installed = match listed {
        Ok(out) if out.status.success() => String::from_utf8_lossy(&out.stdout).into_owned(),
        // No rustup: cargo may still have the target (a distro toolchain);
        // the build says so if not, and this says what to run.
        _ => {
            needle_io::note!(
                "needle: cannot ask rustup whether {target} is installed; if the build fails, run `rustup target add {target}`"
            );
            return Ok(());
        }
    };
    if target_action(&installed, target) == TargetAction::Present {
        return Ok(());
    }
    needle_io::note!("needle: the Rust target {target} is missing: installing it with `rustup target add {target}`");
    let status = Command::new(rustup)
        .current_dir(root)
        .args(["target", "add", target])
        .status()
        .context("cannot run rustup")?;
    if !status.success() {
        bail!("`rustup target add {target}` failed ({status}); run it by hand, then try again");
    }
    Ok(())
}

/// Make sure `qemu-system-arm` is on PATH, installing Debian's package if not.
pub fn ensure_qemu() -> Result<()> {
    if which("qemu-system-arm") {
        return Ok(());
    }
    needle_io::note!("qemu-system-arm is missing: installing it with apt-get");
    let sudo: &[&str] = if is_root() { &[] } else { &["sudo"] };
    for args in [
        &["apt-get", "update"][..],
        &[
            "apt-get",
            "install",
            "-y",
            "--no-install-recommends",
            "qemu-system-arm",
        ],
    ] {
        let all: Vec<&str> = sudo.iter().chain(args).copied().collect();
        let status = Command::new(all[0])
            .args(&all[1..])
            .status()
            .with_context(|| format!("cannot run {}", all.join(" ")))?;
        if !status.success() {
            bail!(
                "`{}` failed ({status}); install qemu-system-arm by hand",
                all.join(" ")
            );
        }
    }
    if !which("qemu-system-arm") {
        bail!("qemu-system-arm still not on PATH after installing it");
    }
    Ok(())
}

fn which(program: &str) -> bool {
    std::env::var_os("PATH")
        .map(|paths| std::env::split_paths(&paths).any(|dir| dir.join(program).is_file()))
        .unwrap_or(false)
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| o.stdout.trim_ascii() == b"0")
        .unwrap_or(false)
}

/// How QEMU's UART0 is connected.
pub enum Serial<'a> {
    /// Written to a file.
    File(&'a Path),
    /// QEMU connects to a TCP listener on this loopback address.
    Tcp(std::net::SocketAddr),
    /// A pseudo-terminal QEMU makes; it names it on stderr
    /// ([`QemuLive`] reads the name).
    Pty,
}

/// The QEMU command line for `elf` on `board`, replaying `replay`.
pub fn qemu_command(
    board: Board,
    elf: &Path,
    replay: &Path,
    serial: Serial<'_>,
    extra: &[&str],
) -> Command {
    let serial_arg = match serial {
        Serial::File(path) => format!("file:{}", path.display()),
        Serial::Tcp(addr) => format!("tcp:{addr}"),
        Serial::Pty => "pty".into(),
    };
    // Commas in semihosting args must be doubled.
    let replay_arg = replay.display().to_string().replace(',', ",,");
    let mut cmd = Command::new("qemu-system-arm");
    cmd.args(board.machine_args())
        .args(["-nographic", "-monitor", "none", "-serial", &serial_arg])
        .arg("-semihosting-config")
        .arg(format!(
            "enable=on,target=native,arg=needle-holder,arg={replay_arg}"
        ))
        .args(extra)
        .arg("-kernel")
        .arg(elf);
    cmd
}

/// Result of one QEMU run.
#[derive(Debug)]
pub struct QemuRun {
    pub status: ExitStatus,
    /// defmt log bytes (semihosting stdout); decode with `defmt-print -e ELF`.
    pub defmt: Vec<u8>,
    /// QEMU's own messages.
    pub stderr: String,
}

impl QemuRun {
    /// Fail unless QEMU (that is, the firmware) exited 0.
    pub fn success(self) -> Result<Self> {
        if !self.status.success() {
            bail!("QEMU exited with {}: {}", self.status, self.stderr.trim());
        }
        Ok(self)
    }
}

/// Start a prepared QEMU command with stdout (defmt) and stderr piped.
pub fn spawn_qemu(cmd: &mut Command) -> Result<std::process::Child> {
    cmd.stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot start qemu-system-arm")
}

/// Have the child killed when the thread that starts it ends, however
/// it ends: a live replay waits for its host's first command without
/// end, and a `needle live` killed before it could stop QEMU (SIGKILL,
/// or a signal before its handlers are set) left it waiting for ever.
#[cfg(target_os = "linux")]
fn die_with_parent(command: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id();
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent gone already, before the request was made.
            if libc::getppid() as u32 != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn die_with_parent(_: &mut Command) {}

/// The firmware in QEMU as a device on a serial port: a live replay
/// (`--live`: it waits for the host's first command, then samples in real
/// time at the replay's rate) with its UART on a pseudo-terminal that the
/// `serialport` crate opens like `/dev/ttyACM0`. Killed when dropped.
pub struct QemuLive {
    pub child: std::process::Child,
    /// The pseudo-terminal, e.g. `/dev/pts/3`.
    pub port: String,
    /// The defmt bytes QEMU printed (semihosting), once it has exited.
    defmt: std::thread::JoinHandle<Vec<u8>>,
    /// Where QEMU's monitor listens ([`Self::reset`]).
    monitor: tempfile::TempDir,
}

impl QemuLive {
    /// Start `elf` (a QEMU board) replaying `replay` live.
    pub fn start(board: Board, elf: &Path, replay: &Path) -> Result<Self> {
        let cmd = qemu_command(board, elf, replay, Serial::Pty, &[]);
        // A monitor on a socket, so that a test can press reset.
        let monitor = tempfile::tempdir().context("cannot create a temporary directory")?;
        let socket = monitor.path().join("monitor.sock");
        let on_socket = format!("unix:{},server=on,wait=off", socket.display());
        // `--live` goes before the replay's path on the command line.
        let args: Vec<std::ffi::OsString> = cmd
            .get_args()
            .map(|a| {
                let text = a.to_string_lossy();
                if text == "none" {
                    on_socket.clone().into()
                } else if text.starts_with("enable=on,target=native,arg=needle-holder,") {
                    text.replacen("arg=needle-holder,", "arg=needle-holder,arg=--live,", 1)
                        .into()
                } else {
                    a.to_owned()
                }
            })
            .collect();
        let mut cmd = {
            let mut live = Command::new(cmd.get_program());
            live.args(args);
            die_with_parent(&mut live);
            live
        };
        let mut child = spawn_qemu(&mut cmd)?;
        let stdout = child.stdout.take().context("no QEMU stdout")?;
        // QEMU names the terminal on stdout, "char device redirected to
        // /dev/pts/3 (label serial0)", before the guest's semihosting
        // output (defmt) begins.
        let (named, name) = std::sync::mpsc::channel();
        let defmt = std::thread::spawn(move || {
            let mut reader = std::io::BufReader::new(stdout);
            let mut line = Vec::new();
            let _ = std::io::BufRead::read_until(&mut reader, b'\n', &mut line);
            let text = String::from_utf8_lossy(&line);
            let port = text
                .split_once("redirected to ")
                .and_then(|(_, rest)| rest.split_whitespace().next())
                .map(str::to_string);
            let _ = named.send(port);
            let mut buf = Vec::new();
            let _ = reader.read_to_end(&mut buf);
            buf
        });
        let stderr = child.stderr.take().context("no QEMU stderr")?;
        std::thread::spawn(move || std::io::copy(&mut { stderr }, &mut std::io::sink()));
        let port = name.recv_timeout(Duration::from_secs(10)).ok().flatten();
        let Some(port) = port else {
            let _ = child.kill();
            bail!("QEMU did not say which pseudo-terminal it made");
        };
        Ok(Self {
            child,
            port,
            defmt,
            monitor,
        })
    }

    /// Press the board's reset (QEMU's `system_reset`): the firmware
    /// starts again, and a live replay waits for the host's first command
    /// as at power-on.
    pub fn reset(&self) -> Result<()> {
        use std::io::Write;
        let socket = self.monitor.path().join("monitor.sock");
        let mut monitor = std::os::unix::net::UnixStream::connect(&socket)
            .with_context(|| format!("{}: no QEMU monitor", socket.display()))?;
        monitor.set_read_timeout(Some(Duration::from_secs(2)))?;
        // A command sent before the monitor's first prompt is lost.
        let prompt = |monitor: &mut std::os::unix::net::UnixStream| -> Result<()> {
            let mut seen = Vec::new();
            let mut buf = [0u8; 256];
            while !seen.ends_with(b"(qemu) ") {
                let n =
                    std::io::Read::read(monitor, &mut buf).context("QEMU's monitor is silent")?;
                if n == 0 {
                    bail!("QEMU's monitor closed");
                }
                seen.extend_from_slice(&buf[..n]);
            }
            Ok(())
        };
        prompt(&mut monitor)?;
        monitor
            .write_all(b"system_reset\n")
            .context("cannot write to QEMU's monitor")?;
        // The next prompt: done.
        prompt(&mut monitor)
    }

    /// Wait for QEMU to exit (the replay's end); its defmt bytes.
    pub fn wait(mut self, timeout: Duration) -> Result<(ExitStatus, Vec<u8>)> {
        let Some(status) = self.child.wait_timeout(timeout)? else {
            bail!("QEMU did not finish within {} s", timeout.as_secs());
        };
        let defmt = std::mem::replace(&mut self.defmt, std::thread::spawn(Vec::new));
        Ok((status, defmt.join().unwrap_or_default()))
    }
}

impl Drop for QemuLive {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Run a prepared QEMU command to completion, killing it after `timeout`.
/// A non-zero exit is returned, not an error: see [`QemuRun::success`].
pub fn run_qemu(mut cmd: Command, timeout: Duration) -> Result<QemuRun> {
    let mut child = spawn_qemu(&mut cmd)?;
    let mut stdout = child.stdout.take().context("no QEMU stdout")?;
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = stdout.read_to_end(&mut buf);
        buf
    });
    let Some(status) = child.wait_timeout(timeout)? else {
        let _ = child.kill();
        let _ = child.wait();
        bail!(
            "QEMU did not finish within {} s (a wrong memory map hangs silently)",
            timeout.as_secs()
        );
    };
    let defmt = reader.join().unwrap_or_default();
    let mut stderr = String::new();
    if let Some(mut pipe) = child.stderr.take() {
        let _ = pipe.read_to_string(&mut stderr);
    }
    Ok(QemuRun {
        status,
        defmt,
        stderr,
    })
}
