//! Command-line arguments of the commissioning subcommands and their glue: open the port, run
//! the subcommand, print its report. Exit codes: 0 done, 1 failed part-way, 2 refused with
//! nothing written (or a usage error).

use super::CommissionError;
use super::info::info;
use super::link::Link;
use super::monitor::{MonitorOptions, monitor};
use super::motion::{MoveOptions, move_to, set_force};
use super::print;
use super::reset::{factory_reset, preflight};
use super::scan::{ScanOptions, scan};
use super::set::{SetOptions, set};
use super::settings::Setting;
use crate::protocol::{BaudRate, ForceMode, MmCenti, Ms10, ServoId};
use crate::serial::rs485::{MAX_DELAY_MS, Rs485Mode};
use crate::ui::terminal::{TextScreen, quit_key};
use clap::{Args, Subcommand, ValueEnum};
use std::io::{BufRead, IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;
use tokio::runtime::Runtime;

/// Exit code of a command refused before anything was written.
pub const EXIT_REFUSED: u8 = 2;
/// Exit code of a command that failed part-way.
pub const EXIT_FAILED: u8 = 1;

/// The serial port every commissioning subcommand talks through.
#[derive(Debug, Clone, Args)]
pub struct PortArgs {
    /// Serial device of the RS485 adapter (e.g. /dev/ttyUSB0). Stop the bridge first: only one
    /// program may talk on a bus.
    #[arg(long, value_name = "DEV")]
    pub port: PathBuf,
    /// Baud rate of the bus, bit/s (one of the LJ9DA41's rates; the factory default is 115200).
    #[arg(long, value_name = "B", default_value = "115200", value_parser = parse_baud)]
    pub baud: BaudRate,
    /// Margin added to each reply's wire time before giving up, ms (default 50; for `scan`,
    /// the margin of each ping, default 12). Raise it for adapters with a high latency timer.
    #[arg(long, value_name = "MS", value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub timeout_ms: Option<u64>,
    /// Put a UART in the kernel's RS485 mode (its transceiver's driver enable on RTS), as a
    /// bus's `rs485` does in a mapping file: `--rs485` alone is RTS high while sending;
    /// `--rs485=after-send,before=1,after=0,rx-during-tx` spells out the rest (delays in ms,
    /// 0–100). Not for USB adapters, which switch by themselves.
    #[arg(
        long,
        value_name = "MODE",
        num_args = 0..=1,
        require_equals = true,
        default_missing_value = "on-send",
        value_parser = parse_rs485
    )]
    pub rs485: Option<Rs485Mode>,
}

/// `on-send` or `after-send`, then `before=MS`, `after=MS`, `rx-during-tx`, separated by commas.
fn parse_rs485(text: &str) -> Result<Rs485Mode, String> {
    let mut mode = Rs485Mode::default();
    let delay = |v: &str| -> Result<u32, String> {
        v.trim()
            .parse::<u32>()
            .ok()
            .filter(|ms| *ms <= MAX_DELAY_MS)
            .ok_or_else(|| format!("`{v}` is not a delay of 0–{MAX_DELAY_MS} ms"))
    };
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        match part.split_once('=') {
            None if part == "on-send" => (mode.rts_on_send, mode.rts_after_send) = (true, false),
            None if part == "after-send" => (mode.rts_on_send, mode.rts_after_send) = (false, true),
            None if part == "rx-during-tx" => mode.rx_during_tx = true,
            Some(("before", v)) => mode.delay_before_send_ms = delay(v)?,
            Some(("after", v)) => mode.delay_after_send_ms = delay(v)?,
            _ => {
                return Err(format!(
                    "`{part}` is not part of an RS485 mode; use on-send or after-send, \
                     before=MS, after=MS, rx-during-tx (e.g. --rs485=on-send,before=1)"
                ));
            }
        }
    }
    Ok(mode)
}

fn parse_baud(text: &str) -> Result<BaudRate, String> {
    let bps: u32 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a speed in bit/s (e.g. 115200)"))?;
    BaudRate::from_bits_per_second(bps).map_err(|e| e.to_string())
}

fn parse_id(text: &str) -> Result<ServoId, String> {
    let id: u16 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a servo ID (1–127)"))?;
    u8::try_from(id)
        .map_err(|_| format!("servo id {id} is outside 1–127"))
        .and_then(|id| ServoId::new(id).map_err(|e| e.to_string()))
}

/// A list of servo IDs given as `1,2,3`, `1-4` or a mix (`1-3,7`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IdList(pub Vec<ServoId>);

fn parse_id_list(text: &str) -> Result<IdList, String> {
    let mut ids = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        if let Some((a, b)) = part.split_once('-') {
            let (a, b) = (parse_id(a)?, parse_id(b)?);
            if a > b {
                return Err(format!("range `{part}` runs backwards"));
            }
            ids.extend(ServoId::all().filter(|id| (a..=b).contains(id)));
        } else {
            ids.push(parse_id(part)?);
        }
    }
    if ids.is_empty() {
        return Err("give at least one servo ID (e.g. 1,2,3 or 1-4)".into());
    }
    let mut seen = Vec::with_capacity(ids.len());
    for id in ids {
        if !seen.contains(&id) {
            seen.push(id);
        }
    }
    Ok(IdList(seen))
}

fn parse_mm(text: &str) -> Result<MmCenti, String> {
    let mm: f64 = text
        .trim()
        .trim_end_matches("mm")
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a position in mm (e.g. 12.5 or -3)"))?;
    MmCenti::from_mm(mm).map_err(|e| e.to_string())
}

/// `scan` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge scan --port /dev/ttyUSB0
  lj9da-bridge scan --port /dev/ttyUSB0 --all-bauds
  lj9da-bridge scan --port /dev/ttyUSB0 --baud 460800 --ids 1-16 --timeout-ms 20

Every new servo is ID 1 at 115200 bit/s: connect new servos one at a time and give each its
own ID with `set`. A servo in PWM/S.BUS mode does not answer on RS485. Each ID gets one ping
with a 12 ms margin beyond wire time (127 IDs at 115200 bit/s in under 2 s); raise it with
--timeout-ms for servos with a Return Delay Time or adapters with a high latency timer.
--all-bauds over 127 IDs takes about 22 s.")]
pub struct ScanArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// Try every baud rate of the servo's table (9600 … 460800 bit/s).
    #[arg(long)]
    pub all_bauds: bool,
    /// IDs to ping (e.g. 1-16 or 1,2,5).
    #[arg(long, value_name = "IDS", default_value = "1-127", value_parser = parse_id_list)]
    pub ids: IdList,
}

/// `info` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge info --port /dev/ttyUSB0 --id 1
  lj9da-bridge info --port /dev/ttyUSB0 --id 3 --baud 230400 --json > servo3.json")]
pub struct InfoArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// The servo's ID.
    #[arg(long, value_parser = parse_id)]
    pub id: ServoId,
    /// Print JSON for scripts instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// `set` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Keys:
  id=N               new servo ID, 1–127 (refused if a servo already answers there)
  reverse=0|1        1: extend = − (the limits are mirrored too)
  baud=B             new baud rate in bit/s (9600 … 460800) or a register code (0x00–0x0A)
  return-delay=MS    reply delay, 0–255 ms
  plus-limit=MM      0 … +25.00 mm        minus-limit=MM   −25.00 … 0 mm
  plus-margin=N      compliance margins, ≈0.01 mm, 0–255 (also minus-margin)
  plus-slope=N       compliance slopes, 0.1 mm, 0–255 (also minus-slope)
  punch=N            minimum drive current, 0–0x7FFF (0.00208 % steps)
  max-force=P        0–100 % (RAM only: --save does not keep it)

Every value is checked before anything is written, and read back after. Without --save the
new values are lost at power-off; --save writes flash, waits, reboots the servo and checks that
every value survived (the reboot switches the servo's force off). A new ID or baud rate is written first, then saved, then the servo is
rebooted (never combined, as the manual requires), and the tool talks to the servo at its new
ID and rate to prove it.

Examples:
  lj9da-bridge set --port /dev/ttyUSB0 --id 1 id=3 --save
  lj9da-bridge set --port /dev/ttyUSB0 --id 3 plus-limit=20.0 minus-limit=-20.0 punch=0x120
  lj9da-bridge set --port /dev/ttyUSB0 --id 3 baud=460800 --save
  lj9da-bridge set --port /dev/ttyUSB0 --baud 460800 --id 3 max-force=80")]
pub struct SetArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// The servo's ID now.
    #[arg(long, value_parser = parse_id)]
    pub id: ServoId,
    /// Write flash, reboot and verify that the values survived.
    #[arg(long)]
    pub save: bool,
    /// Settings as key=value (see Keys below).
    #[arg(value_name = "KEY=VALUE", required = true, num_args = 1..)]
    pub settings: Vec<String>,
}

/// `move` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge move --port /dev/ttyUSB0 --id 1 --mm 10 --force-on
  lj9da-bridge move --port /dev/ttyUSB0 --id 1 --mm -5.5 --time-ms 2000

The servo clamps a goal beyond its position limits to the limit; the output says so.")]
pub struct MoveArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// The servo's ID.
    #[arg(long, value_parser = parse_id)]
    pub id: ServoId,
    /// Goal position, mm (−25.00 … +25.00; 0 is mid-stroke, + extends).
    #[arg(long, value_name = "X", allow_negative_numbers = true, value_parser = parse_mm)]
    pub mm: MmCenti,
    /// Travel time, ms (default: as fast as the servo can).
    #[arg(long, value_name = "T")]
    pub time_ms: Option<u32>,
    /// Switch force on first if it is off (force on holds the present position: no jump).
    #[arg(long)]
    pub force_on: bool,
    /// Return once the goal is written, without waiting for arrival.
    #[arg(long)]
    pub no_wait: bool,
}

/// Force Enable values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ForceArg {
    On,
    Off,
    Brake,
}

/// `force` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge force --port /dev/ttyUSB0 --id 1 on
  lj9da-bridge force --port /dev/ttyUSB0 --id 1 brake     # rod moves by hand with light resistance
  lj9da-bridge force --port /dev/ttyUSB0 --id 1 off

Force on is refused by the servo while the rod is outside its limits or after a temperature
error; the output says which.")]
pub struct ForceArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// The servo's ID.
    #[arg(long, value_parser = parse_id)]
    pub id: ServoId,
    /// on, off or brake.
    #[arg(value_enum)]
    pub mode: ForceArg,
}

/// `factory-reset` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge factory-reset --port /dev/ttyUSB0 --id 3
  lj9da-bridge factory-reset --port /dev/ttyUSB0 --id 3 --baud 460800 --yes

Restores registers 4–29 (ID 1, 115200 bit/s, limits ±25.00 mm, …) and saves them to flash.
Refused while another servo answers at ID 1.")]
pub struct ResetArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// The servo's ID now.
    #[arg(long, value_parser = parse_id)]
    pub id: ServoId,
    /// Do not ask for confirmation.
    #[arg(long)]
    pub yes: bool,
}

/// `monitor` arguments.
#[derive(Debug, Clone, Args)]
#[command(after_help = "Examples:
  lj9da-bridge monitor --port /dev/ttyUSB0 --ids 1,2,3
  lj9da-bridge monitor --port /dev/ttyUSB0 --ids 1-4 --interval-ms 100 --seconds 30 --plain")]
pub struct MonitorArgs {
    #[command(flatten)]
    pub port: PortArgs,
    /// Servo IDs (e.g. 1,2,3 or 1-4).
    #[arg(long, value_name = "IDS", value_parser = parse_id_list)]
    pub ids: IdList,
    /// Time between samples, ms.
    #[arg(long, value_name = "MS", default_value_t = 250)]
    pub interval_ms: u64,
    /// Stop after this many samples.
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// Print each sample below the last instead of redrawing the table.
    #[arg(long)]
    pub plain: bool,
}

/// The commissioning subcommands.
#[derive(Debug, Clone, Subcommand)]
pub enum Commission {
    /// Find the servos on a bus: every ID 1–127 that answers, with model, firmware, position,
    /// temperature and voltage.
    Scan(ScanArgs),
    /// One servo's whole memory map, decoded with names and units.
    Info(InfoArgs),
    /// Configure one servo (ID, baud rate, limits, compliance, punch, max force), verified.
    Set(SetArgs),
    /// Move one servo to a position.
    Move(MoveArgs),
    /// Switch one servo's force on, off or to brake.
    Force(ForceArgs),
    /// Restore one servo's factory settings (it becomes ID 1 at 115200 bit/s).
    FactoryReset(ResetArgs),
    /// A live table of position, load, temperature and voltage until Ctrl-C.
    Monitor(MonitorArgs),
}

/// Write to stdout; a closed pipe (`| head`) is not an error worth a panic.
fn emit(text: &str) {
    let mut out = std::io::stdout().lock();
    let _ = out.write_all(text.as_bytes());
    let _ = out.flush();
}

fn report_error(error: &CommissionError) -> ExitCode {
    let _ = writeln!(std::io::stderr(), "error: {error}");
    if error.is_refusal() {
        ExitCode::from(EXIT_REFUSED)
    } else {
        ExitCode::from(EXIT_FAILED)
    }
}

async fn open(port: &PortArgs, default_margin: Duration) -> Result<Link, CommissionError> {
    let mut link = Link::open_rs485(&port.port, port.baud, port.rs485).await?;
    link.set_margin(
        port.timeout_ms
            .map_or(default_margin, Duration::from_millis),
    );
    Ok(link)
}

fn finish<T>(result: Result<T, CommissionError>, print: impl FnOnce(&T)) -> ExitCode {
    match result {
        Ok(report) => {
            print(&report);
            ExitCode::SUCCESS
        }
        Err(e) => report_error(&e),
    }
}

/// Run one commissioning subcommand on `rt`.
pub fn run(rt: &Runtime, command: Commission) -> ExitCode {
    match command {
        Commission::Scan(args) => {
            let result = rt.block_on(async {
                let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
                let mut options = ScanOptions::new(args.port.baud, args.all_bauds);
                options.ids = args.ids.0.clone();
                if let Some(ms) = args.port.timeout_ms {
                    options.ping_margin = Duration::from_millis(ms);
                    link.set_margin(Link::DEFAULT_MARGIN.max(options.ping_margin));
                }
                let _ = writeln!(
                    std::io::stderr(),
                    "scanning {} IDs on {} at {} …",
                    options.ids.len(),
                    args.port.port.display(),
                    if args.all_bauds {
                        "every baud rate".to_string()
                    } else {
                        args.port.baud.to_string()
                    }
                );
                scan(&mut link, &options).await
            });
            finish(result, |r| emit(&print::scan_table(r)))
        }
        Commission::Info(args) => {
            let result = rt.block_on(async {
                let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
                info(&mut link, args.id).await
            });
            finish(result, |r| {
                if args.json {
                    emit(&format!("{}\n", r.to_json()));
                } else {
                    emit(&print::info_table(r));
                }
            })
        }
        Commission::Set(args) => {
            // Every argument is parsed and validated before the port is even opened.
            let settings = match Setting::parse_all(&args.settings) {
                Ok(s) => s,
                Err(e) => return report_error(&e),
            };
            let result = rt.block_on(async {
                let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
                set(
                    &mut link,
                    args.id,
                    &settings,
                    SetOptions { save: args.save },
                )
                .await
            });
            finish(result, |r| emit(&print::set_summary(r)))
        }
        Commission::Move(args) => {
            let options = MoveOptions {
                goal: args.mm,
                time: args.time_ms.map(Ms10::from_millis),
                force_on: args.force_on,
                wait: !args.no_wait,
            };
            let result = rt.block_on(async {
                let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
                move_to(&mut link, args.id, options).await
            });
            finish(result, |r| emit(&print::move_summary(r)))
        }
        Commission::Force(args) => {
            let mode = match args.mode {
                ForceArg::On => ForceMode::On,
                ForceArg::Off => ForceMode::Off,
                ForceArg::Brake => ForceMode::Brake,
            };
            let result = rt.block_on(async {
                let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
                set_force(&mut link, args.id, mode).await
            });
            finish(result, |r| emit(&print::force_summary(r)))
        }
        Commission::FactoryReset(args) => run_reset(rt, &args),
        Commission::Monitor(args) => run_monitor(rt, &args),
    }
}

fn run_reset(rt: &Runtime, args: &ResetArgs) -> ExitCode {
    let mut link = match rt.block_on(async {
        let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
        preflight(&mut link, args.id).await?;
        Ok::<Link, CommissionError>(link)
    }) {
        Ok(link) => link,
        Err(e) => return report_error(&e),
    };
    if !args.yes {
        let _ = write!(
            std::io::stderr(),
            "factory reset of servo {id}: registers 4–29 go back to the factory values (ID 1, 115200 bit/s, limits ±25.00 mm, …).\ntype the servo id ({id}) to confirm: ",
            id = args.id
        );
        let _ = std::io::stderr().flush();
        let mut line = String::new();
        let confirmed = std::io::stdin().lock().read_line(&mut line).is_ok()
            && line.trim() == args.id.to_string();
        if !confirmed {
            return report_error(&CommissionError::Refused {
                reason: "factory reset not confirmed".into(),
            });
        }
    }
    let result = rt.block_on(factory_reset(&mut link, args.id));
    finish(result, |r| emit(&print::reset_summary(r)))
}

fn run_monitor(rt: &Runtime, args: &MonitorArgs) -> ExitCode {
    let duration = match args.seconds {
        Some(s) if s.is_finite() && s >= 0.0 => Some(Duration::from_secs_f64(s.min(1e9))),
        Some(s) => {
            return report_error(&CommissionError::Refused {
                reason: format!("--seconds {s} is not a duration"),
            });
        }
        None => None,
    };
    let options = MonitorOptions {
        interval: Duration::from_millis(args.interval_ms),
        count: args.count,
        duration,
    };
    let redraw = !args.plain && std::io::stdout().is_terminal();
    let result = rt.block_on(async {
        let mut link = open(&args.port, Link::DEFAULT_MARGIN).await?;
        if redraw {
            // Redrawn in place until q, Esc or Ctrl-C (a key in raw mode); the last table
            // stays on the terminal after it is given back.
            let mut screen = TextScreen::open().map_err(|e| {
                CommissionError::Failed(format!("cannot draw on this terminal: {e} (try --plain)"))
            })?;
            let mut last = String::new();
            let taken = monitor(&mut link, &args.ids.0, options, quit_key(), |n, rows| {
                last = print::monitor_table(n, rows);
                let _ = screen.show(&last);
            })
            .await;
            drop(screen);
            println!("{last}");
            return taken;
        }
        let stop = async {
            if tokio::signal::ctrl_c().await.is_err() {
                std::future::pending::<()>().await;
            }
        };
        monitor(&mut link, &args.ids.0, options, stop, |n, rows| {
            let table = print::monitor_table(n, rows);
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "{table}");
            let _ = out.flush();
        })
        .await
    });
    match result {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => report_error(&e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_rs485_mode_is_spelled_as_words_and_delays() {
        assert_eq!(parse_rs485("on-send"), Ok(Rs485Mode::default()));
        assert_eq!(
            parse_rs485("after-send, before=2,after=1,rx-during-tx"),
            Ok(Rs485Mode {
                rts_on_send: false,
                rts_after_send: true,
                delay_before_send_ms: 2,
                delay_after_send_ms: 1,
                rx_during_tx: true,
            })
        );
        assert!(parse_rs485("before=101").unwrap_err().contains("0–100 ms"));
        assert!(parse_rs485("rts").unwrap_err().contains("`rts`"));
    }
}
