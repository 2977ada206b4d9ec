//! `lj9da-sim`: run a simulated LJ9DA41 bus on a pseudo-terminal (or TCP) until stopped.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{ArgAction, Parser};
use lj9da_sim::{Fault, Force, SimBus, SimConfig, SimHandle};
use nix::sys::signal::{SigSet, Signal};

const AFTER_HELP: &str = "\
Faults (all can be combined; IDs are the servos' configured IDs):
  --corrupt P | ID:P     flip bits in one byte of a reply, with probability P (1 = every reply)
  --drop P | ID:P        send no reply, with probability P (the servo still acts on the packet)
  --echo                 the adapter echoes every host byte back to the host
  --stall ID             the rod is blocked: no motion, stall current (several A) while force is on
  --load ID:N            external load of N newtons: slower moves, more current, no move above the thrust
  --overheat ID          the servo heats by itself (15 °C/s): alarm at 75 °C, error + force off at 85 °C
  --wrong-model ID:0xNNNN  registers 0-1 report another model number
  --unplug ID            the servo is unplugged: silent, ignores everything

Bit rates: every servo listens at its own rate (register 6, 115200 after a factory reset). The host's rate is
read from the pty's termios whenever bytes arrive (a pty stores the rate the host set), so a host that sets
another rate than a servo's sees noise from it and is not understood, as on a real bus. Over TCP the host is
taken to be at --baud.

Examples:
  lj9da-sim --ids 1,2,3,4 --baud 115200 --pty
  lj9da-sim --ids 1,2 --link /tmp/lj9da0 --status-every 1
  lj9da-sim --ids 1 --tcp 127.0.0.1:5760
  lj9da-sim --ids 1,2,3 --corrupt 0.05 --drop 2:0.5 --seed 7 --echo
  lj9da-sim --ids 1,2 --stall 1 --load 2:150 --overheat 2 --wrong-model 1:0x7511";

/// Simulated bus of Futaba LJ9DA41 RS485 linear servos.
///
/// Prints the device path to open (one line on stdout) and serves it until Ctrl-C or SIGTERM. The servos
/// keep wire time at their bit rate, move at up to 105 mm/s (at 14.8 V), draw current, heat up, keep RAM and
/// flash apart, and answer every reply code of the manual.
#[derive(Debug, Parser)]
#[command(name = "lj9da-sim", version, about, long_about, after_help = AFTER_HELP)]
struct Cli {
    /// Servo IDs on the bus, comma-separated (each 1–127; each servo's flash holds its ID)
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "1",
        value_name = "ID,ID,…"
    )]
    ids: Vec<u8>,
    /// Bit rate stored in every servo's flash: 9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200,
    /// 153600, 230400 or 460800
    #[arg(long, default_value_t = 115_200)]
    baud: u32,
    /// Serve a pseudo-terminal (the default); prints the slave path
    #[arg(long, conflicts_with = "tcp")]
    pty: bool,
    /// Serve TCP on this address instead, one client at a time; prints the bound address
    #[arg(long, value_name = "ADDR")]
    tcp: Option<SocketAddr>,
    /// Also create a symlink at PATH to the pty slave (prints PATH)
    #[arg(long, value_name = "PATH", conflicts_with = "tcp")]
    link: Option<PathBuf>,
    /// Supply voltage of the servos, volts
    #[arg(long, default_value_t = 12.0, value_name = "V")]
    voltage: f32,
    /// Ambient temperature, °C
    #[arg(long, default_value_t = 25.0, value_name = "C")]
    ambient: f32,
    /// Servo processing latency added to the Return Delay Time before a reply, microseconds
    #[arg(long = "latency-us", default_value_t = 150, value_name = "US")]
    latency_us: u64,
    /// Seed of the fault generator (same seed, same faulty replies)
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Corrupt replies with probability P (bus-wide) or ID:P (one servo)
    #[arg(long, value_name = "P|ID:P", value_parser = parse_probability)]
    corrupt: Vec<(Option<u8>, f64)>,
    /// Drop replies with probability P (bus-wide) or ID:P (one servo)
    #[arg(long, value_name = "P|ID:P", value_parser = parse_probability)]
    drop: Vec<(Option<u8>, f64)>,
    /// The adapter echoes every host byte back
    #[arg(long)]
    echo: bool,
    /// Block servo ID's rod (repeatable)
    #[arg(long, value_name = "ID")]
    stall: Vec<u8>,
    /// External load on servo ID, newtons (repeatable)
    #[arg(long, value_name = "ID:N", value_parser = parse_load)]
    load: Vec<(u8, f32)>,
    /// Servo ID heats up quickly until it trips (repeatable)
    #[arg(long, value_name = "ID")]
    overheat: Vec<u8>,
    /// Servo ID reports another model number, e.g. 3:0x7511 (repeatable)
    #[arg(long = "wrong-model", value_name = "ID:MODEL", value_parser = parse_model)]
    wrong_model: Vec<(u8, u16)>,
    /// Servo ID starts unplugged (repeatable)
    #[arg(long, value_name = "ID")]
    unplug: Vec<u8>,
    /// Print a status table of every servo to stderr every SECS seconds
    #[arg(long = "status-every", value_name = "SECS", value_parser = parse_seconds)]
    status_every: Option<Duration>,
    /// More log output on stderr (-v: connections, -vv: every packet); RUST_LOG overrides
    #[arg(short, long, action = ArgAction::Count)]
    verbose: u8,
}

fn parse_probability(text: &str) -> Result<(Option<u8>, f64), String> {
    let (id, probability) = match text.split_once(':') {
        Some((id, probability)) => (Some(parse_id(id)?), probability),
        None => (None, text),
    };
    let probability: f64 = probability
        .trim()
        .parse()
        .map_err(|_| format!("`{probability}` is not a number"))?;
    if !(0.0..=1.0).contains(&probability) {
        return Err(format!("probability {probability} is outside 0…1"));
    }
    Ok((id, probability))
}

fn parse_id(text: &str) -> Result<u8, String> {
    text.trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a servo ID (1–127)"))
}

fn parse_load(text: &str) -> Result<(u8, f32), String> {
    let (id, newtons) = text
        .split_once(':')
        .ok_or_else(|| format!("`{text}`: expected ID:NEWTONS, e.g. 2:150"))?;
    let newtons: f32 = newtons
        .trim()
        .parse()
        .map_err(|_| format!("`{newtons}` is not a load in newtons"))?;
    if !newtons.is_finite() || newtons < 0.0 {
        return Err(format!("load {newtons} N must be ≥ 0"));
    }
    Ok((parse_id(id)?, newtons))
}

fn parse_model(text: &str) -> Result<(u8, u16), String> {
    let (id, model) = text
        .split_once(':')
        .ok_or_else(|| format!("`{text}`: expected ID:MODEL, e.g. 1:0x7511"))?;
    let model = model.trim();
    let parsed = match model
        .strip_prefix("0x")
        .or_else(|| model.strip_prefix("0X"))
    {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => model.parse(),
    };
    let model =
        parsed.map_err(|_| format!("`{model}` is not a 16-bit model number (e.g. 0x7511)"))?;
    Ok((parse_id(id)?, model))
}

fn parse_seconds(text: &str) -> Result<Duration, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a number of seconds"))?;
    Duration::try_from_secs_f64(seconds)
        .ok()
        .filter(|duration| !duration.is_zero())
        .ok_or_else(|| format!("{seconds} s: give a positive number of seconds"))
}

impl Cli {
    fn config(&self) -> SimConfig {
        let mut faults: Vec<(Option<u8>, Fault)> = Vec::new();
        faults.extend(
            self.corrupt
                .iter()
                .map(|&(id, probability)| (id, Fault::CorruptReplies { probability })),
        );
        faults.extend(
            self.drop
                .iter()
                .map(|&(id, probability)| (id, Fault::DropReplies { probability })),
        );
        if self.echo {
            faults.push((None, Fault::Echo));
        }
        faults.extend(self.stall.iter().map(|&id| (Some(id), Fault::Stall)));
        faults.extend(
            self.load
                .iter()
                .map(|&(id, newtons)| (Some(id), Fault::ExternalLoad { newtons })),
        );
        faults.extend(self.overheat.iter().map(|&id| (Some(id), Fault::Overheat)));
        faults.extend(
            self.wrong_model
                .iter()
                .map(|&(id, model)| (Some(id), Fault::WrongModel(model))),
        );
        faults.extend(self.unplug.iter().map(|&id| (Some(id), Fault::Unplugged)));
        SimConfig {
            ids: self.ids.clone(),
            baud: self.baud,
            voltage_v: self.voltage,
            ambient_c: self.ambient,
            processing_latency: Duration::from_micros(self.latency_us),
            return_delay_ms: 0,
            seed: self.seed,
            link: self.link.clone(),
            faults,
        }
    }
}

fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
}

fn status_table(handle: &SimHandle) -> String {
    let mut table = String::from(
        "  ID online force  goal_mm   pos_mm  current_A  temp_C  volt_V  flags      baud\n",
    );
    for servo in handle.snapshots() {
        let force = match servo.force {
            Force::Off => "off",
            Force::On => "on",
            Force::Brake => "brake",
        };
        let mut flags = String::new();
        for (set, name) in [
            (servo.alarm, "A"),
            (servo.error, "E"),
            (servo.flash_error, "F"),
            (servo.stalled, "S"),
        ] {
            if set {
                flags.push_str(name);
            }
        }
        let baud = servo
            .baud
            .map_or_else(|| "invalid".to_string(), |baud| baud.to_string());
        table.push_str(&format!(
            "{:>4} {:>6} {:<5} {:>8.2} {:>8.2} {:>10.2} {:>7.1} {:>7.2}  {:<6} {:>8}\n",
            servo.id,
            if servo.online { "yes" } else { "no" },
            force,
            servo.goal_mm,
            servo.position_mm,
            servo.current_a,
            servo.temperature_c,
            servo.voltage_v,
            flags,
            baud
        ));
    }
    let stats = handle.stats();
    table.push_str(&format!(
        "  packets {} replies {} bad-sums {} garbage {} collisions {} dropped {} corrupted {} damage {}\n",
        stats.packets_rx,
        stats.replies_tx,
        stats.bad_sums,
        stats.garbage_bytes,
        stats.collisions,
        stats.replies_dropped,
        stats.replies_corrupted,
        stats.damage_events
    ));
    table
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(cli.verbose);
    let config = cli.config();
    if let Err(error) = config.validate() {
        eprintln!("lj9da-sim: {error}");
        return ExitCode::from(2);
    }

    // Block the stop signals before any thread starts (threads inherit the mask); the main thread waits.
    let mut stop_signals = SigSet::empty();
    stop_signals.add(Signal::SIGINT);
    stop_signals.add(Signal::SIGTERM);
    if let Err(error) = stop_signals.thread_block() {
        eprintln!("lj9da-sim: cannot block SIGINT/SIGTERM: {error}");
        return ExitCode::FAILURE;
    }

    let spawned = match cli.tcp {
        Some(addr) => SimBus::spawn_tcp(config, addr),
        None => SimBus::spawn_pty(config),
    };
    let bus = match spawned {
        Ok(bus) => bus,
        Err(error) => {
            eprintln!("lj9da-sim: cannot start the simulated bus: {error}");
            return ExitCode::FAILURE;
        }
    };
    let shown = bus
        .local_addr()
        .map_or_else(|| bus.path().display().to_string(), |addr| addr.to_string());
    let mut stdout = std::io::stdout();
    if writeln!(stdout, "{shown}")
        .and_then(|()| stdout.flush())
        .is_err()
    {
        eprintln!("lj9da-sim: serving {shown}");
    }

    if let Some(period) = cli.status_every {
        let handle = bus.handle();
        let _ = std::thread::Builder::new()
            .name("lj9da-sim-status".into())
            .spawn(move || {
                loop {
                    std::thread::sleep(period);
                    eprint!("{}", status_table(&handle));
                }
            });
    }

    match stop_signals.wait() {
        Ok(signal) => tracing::info!(?signal, "stopping"),
        Err(error) => eprintln!("lj9da-sim: waiting for a stop signal failed: {error}"),
    }
    bus.shutdown();
    ExitCode::SUCCESS
}
