//! `lj9da-bridge`: MAVLink autopilot outputs → Futaba LJ9DA41 servos on RS485, and servo health back.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "lj9da-bridge", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the whole chain in simulation: simulated autopilot → bridge → simulated servos.
    Sitl,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Sitl => {
            eprintln!("lj9da-bridge: the simulated chain is not wired yet; only the protocol core exists");
            ExitCode::from(2)
        }
    }
}
