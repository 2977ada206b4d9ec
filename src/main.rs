//! `lj9da-bridge`: MAVLink autopilot outputs → Futaba LJ9DA41 servos on RS485, and servo health
//! back to the ground station.

use clap::{Parser, Subcommand};
use lj9da_bridge::commission::cli::Commission;
use lj9da_bridge::config::Config;
use lj9da_bridge::deploy::DeployCommand;
use lj9da_bridge::record::RecordCommand;
use lj9da_bridge::runtime;
#[cfg(feature = "sitl")]
use lj9da_bridge::simulation::{self, SitlOptions};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "lj9da-bridge",
    version,
    about = "Bridge between MAVLink autopilots (PX4, ArduPilot) and Futaba LJ9DA41 RS485 linear servos",
    after_help = "Examples:\n  lj9da-bridge sitl                          # the whole chain in simulation, no hardware\n  lj9da-bridge ports                         # which serial port is which\n  lj9da-bridge scan --port /dev/ttyUSB0      # commissioning: every servo that answers (bridge stopped)\n  lj9da-bridge check --config mappings/ardupilot-plane.toml\n  lj9da-bridge run --config /etc/lj9da-bridge/bridge.toml\n\nLogs: set RUST_LOG (e.g. RUST_LOG=lj9da_bridge=debug)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the bridge: autopilot outputs over MAVLink → servos on the buses of the mapping file.
    Run {
        /// The mapping file (see mappings/).
        #[arg(long, short)]
        config: PathBuf,
    },
    /// Validate a mapping file and print the resolved table.
    Check {
        /// The mapping file to check (see mappings/); exit 2 if it is refused.
        #[arg(long, short)]
        config: PathBuf,
    },
    /// The whole chain in simulation: simulated servos on pseudo-terminals, a simulated
    /// autopilot (or a real autopilot SITL), the bridge between them over MAVLink/UDP.
    #[command(
        after_help = "Examples:\n  lj9da-bridge sitl --seconds 20\n  lj9da-bridge sitl --config bridge.toml --autopilot udpin:0.0.0.0:14560\n      (ArduPilot SITL: arduplane … --serial0=tcp:0 --serial1=udpclient:127.0.0.1:14560)\n  lj9da-bridge sitl --config mappings/px4-vtol.toml --autopilot udpin:0.0.0.0:14540 --gcs udpout:127.0.0.1:14551\n      (PX4 SITL: its onboard link sends to UDP 14540)\n  The autopilot's parameters for these mappings: docs/autopilot.md, \"SITL with the example mapping\".\n\nThe bridge's telemetry is served on udpout:127.0.0.1:14550 for QGroundControl or MAVProxy."
    )]
    Sitl {
        /// An airframe's mapping file; its buses get simulated servos instead of their ports.
        #[arg(long, short)]
        config: Option<PathBuf>,
        /// A real autopilot's MAVLink address (replaces the simulated autopilot).
        #[arg(long)]
        autopilot: Option<String>,
        /// Stop after this many seconds (default: run until Ctrl-C).
        #[arg(long, value_name = "S", value_parser = parse_seconds)]
        seconds: Option<Duration>,
        /// Where to serve telemetry for a ground station.
        #[arg(long)]
        gcs: Option<String>,
        /// Print the table once a second instead of redrawing it in place.
        #[arg(long)]
        plain: bool,
    },
    /// Look at flight records: summary, plots, CSV, wear across flights (trend), and Parquet
    /// for a fleet's tools.
    #[command(
        after_help = "Examples:\n  lj9da-bridge record summary records/20260302T143000Z.lj9rec\n  lj9da-bridge record plot records/20260302T143000Z.lj9rec --out plots/\n  lj9da-bridge record csv records/20260302T143000Z.lj9rec > flight.csv\n  lj9da-bridge record trend records/                 # wear across flights (--json, --html wear.html)\n  lj9da-bridge record parquet records/ --out fleet/  # a fleet's table for DuckDB or Spark (docs/fleet.md)"
    )]
    Record {
        #[command(subcommand)]
        cmd: RecordCommand,
    },
    /// Installation on the companion computer: systemd unit, udev rule, latency check.
    Deploy {
        #[command(subcommand)]
        cmd: DeployCommand,
    },
    /// List the serial ports and what each one is: USB vendor and product, serial number,
    /// driver, FTDI latency timer, and the /dev/serial/by-id name to put in a mapping file.
    #[command(
        after_help = "Examples:\n  lj9da-bridge ports\n  lj9da-bridge ports --json\n\nNothing is opened or changed: the ports are read from sysfs and /dev."
    )]
    Ports {
        /// Print JSON for scripts instead of text.
        #[arg(long)]
        json: bool,
        /// Read sysfs here instead of /sys (for tests).
        #[arg(long, hide = true, default_value = "/sys")]
        sysfs_root: PathBuf,
        /// Read device names here instead of /dev (for tests).
        #[arg(long, hide = true, default_value = "/dev")]
        dev_root: PathBuf,
        /// Read processes here instead of /proc (for tests).
        #[arg(long, hide = true, default_value = "/proc")]
        proc_root: PathBuf,
    },
    /// Commissioning: scan, info, set, move, force, factory-reset, monitor.
    #[command(flatten)]
    Commission(Commission),
}

/// Logs go to stderr, or into the live view while it owns the terminal.
fn init_logging(live_view: bool) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("warn,lj9da_bridge=info"));
    use std::io::IsTerminal;
    let fmt = tracing_subscriber::fmt().with_env_filter(filter);
    if live_view {
        fmt.with_writer(lj9da_bridge::ui::terminal::LogWriter::default)
            .with_ansi(false)
            .without_time()
            .with_target(false)
            .init();
    } else {
        fmt.with_writer(std::io::stderr)
            .with_ansi(std::io::stderr().is_terminal())
            .init();
    }
}

/// The mapping file at `path`, refused (exit 2) when it does not load or when two of its
/// serial ports are one device.
fn load(path: &Path) -> Result<Config, ExitCode> {
    let cfg = Config::load(path).map_err(|e| {
        eprintln!("error: {e}");
        ExitCode::from(2)
    })?;
    if let Some(shared) = cfg.shared_device(|p| std::fs::canonicalize(p).ok()) {
        eprintln!("error: {}: {shared}", path.display());
        return Err(ExitCode::from(2));
    }
    Ok(cfg)
}

/// `--seconds`: a finite, positive number of seconds (clap says which argument was wrong).
fn parse_seconds(text: &str) -> Result<Duration, String> {
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a number of seconds"))?;
    Duration::try_from_secs_f64(seconds)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| format!("{text} s: give a positive number of seconds, e.g. 20"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let live_view = matches!(cli.command, Command::Sitl { plain: false, .. })
        && std::io::IsTerminal::is_terminal(&std::io::stdout());
    init_logging(live_view);
    // One thread is plenty for MAVLink and the ground station (each bus has a thread of its
    // own), and tasks that hand work to each other then never wake a second thread.
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match cli.command {
        Command::Check { config } => match load(&config) {
            Ok(cfg) => {
                println!("{}: ok", config.display());
                print!("{}", cfg.resolved_table());
                print!("\n{}", lj9da_bridge::mavlink::params::listing(&cfg));
                for warning in cfg.warnings() {
                    println!("\n{warning}");
                }
                ExitCode::SUCCESS
            }
            Err(code) => code,
        },
        Command::Run { config } => {
            let cfg = match load(&config) {
                Ok(cfg) => cfg,
                Err(code) => return code,
            };
            rt.block_on(async {
                let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
                tokio::spawn(async move {
                    runtime::shutdown_signal().await;
                    tracing::info!("stop requested");
                    let _ = stop_tx.send(true);
                });
                let opts = runtime::RunOptions {
                    record_dir: Some(cfg.record.dir_for(Some(&config))),
                    check_latency: true,
                    mapping: runtime::mapping_file(Some(&config)),
                    service: true,
                    ..Default::default()
                };
                match runtime::run(cfg, opts, stop_rx).await {
                    Ok(()) => ExitCode::SUCCESS,
                    Err(e) => {
                        eprintln!("error: {e}");
                        ExitCode::FAILURE
                    }
                }
            })
        }
        Command::Sitl {
            config,
            autopilot,
            seconds,
            gcs,
            plain,
        } => {
            #[cfg(feature = "sitl")]
            {
                let loaded = match config.as_ref().map(|p| load(p)).transpose() {
                    Ok(c) => c,
                    Err(code) => return code,
                };
                let opts = SitlOptions {
                    config: loaded,
                    config_path: config,
                    autopilot,
                    seconds,
                    gcs,
                    plain,
                };
                match rt.block_on(simulation::run(opts)) {
                    Ok(_) => ExitCode::SUCCESS,
                    Err(e) => {
                        eprintln!("error: {e}");
                        ExitCode::FAILURE
                    }
                }
            }
            #[cfg(not(feature = "sitl"))]
            {
                let _ = (config, autopilot, seconds, gcs, plain);
                eprintln!(
                    "error: this build of lj9da-bridge has no simulator (the flight binary, as \
                     packaged, holds only the flight code). Run `sitl` from a clone of the \
                     repository: cargo run --release -- sitl"
                );
                ExitCode::FAILURE
            }
        }
        Command::Ports {
            json,
            sysfs_root,
            dev_root,
            proc_root,
        } => {
            use lj9da_bridge::serial::ports;
            let found = ports::list_in(&sysfs_root, &dev_root, &proc_root);
            let text = if json {
                ports::render_json(&found)
            } else {
                ports::render(&found)
            };
            // A closed pipe (`| head`) is no error worth a panic.
            let mut out = std::io::stdout().lock();
            let _ = std::io::Write::write_all(&mut out, text.as_bytes());
            let _ = std::io::Write::flush(&mut out);
            ExitCode::SUCCESS
        }
        Command::Record { cmd } => lj9da_bridge::record::cli::run(cmd),
        Command::Deploy { cmd } => lj9da_bridge::deploy::run(cmd),
        Command::Commission(command) => lj9da_bridge::commission::cli::run(&rt, command),
    }
}
