//! `lj9da-bridge sitl`: the whole chain in software. Simulated LJ9DA41 servos on
//! pseudo-terminals (the `lj9da-sim` crate), a simulated autopilot — or a real autopilot SITL
//! with `--autopilot` — and the bridge between them over real MAVLink on UDP, with a live
//! table of what the bridge sees and its telemetry served to a ground station.

pub mod autopilot;

use crate::config::Config;
use crate::runtime::{self, BridgeView, RunError};
use crate::ui::{live, table};
use lj9da_sim::{SimBus, SimConfig};
use std::collections::HashMap;
use std::io::IsTerminal;
use std::net::UdpSocket;
use std::path::PathBuf;
use std::time::Duration;
use thiserror::Error;
use tokio::sync::watch;

/// Where the bridge's telemetry goes for a ground station, unless the mapping file says.
pub const DEFAULT_GCS: &str = "udpout:127.0.0.1:14550";

#[derive(Debug, Clone, Default)]
pub struct SitlOptions {
    /// The airframe's mapping file; `None`: the embedded default (four servos).
    pub config: Option<Config>,
    /// Where that file is (the flight record goes beside it); `None`: the current folder.
    pub config_path: Option<PathBuf>,
    /// A real autopilot's MAVLink address instead of the simulated one.
    pub autopilot: Option<String>,
    /// Stop after this long; `None`: run until Ctrl-C.
    pub seconds: Option<Duration>,
    /// Where to serve telemetry for a ground station.
    pub gcs: Option<String>,
    /// Print the table as plain snapshots once a second instead of the live view.
    pub plain: bool,
}

#[derive(Debug, Error)]
pub enum SitlError {
    #[error("cannot start the simulated servos of bus {bus:?}: {source}")]
    Servos {
        bus: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot find a free UDP port on 127.0.0.1 for the autopilot link: {0}")]
    NoPort(#[source] std::io::Error),
    #[error(transparent)]
    Bridge(#[from] RunError),
}

/// A UDP port on loopback that nobody is using right now.
fn free_udp_port() -> std::io::Result<u16> {
    Ok(UdpSocket::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// The reply allowance `sitl` gives a bus whose mapping sets none (`turnaround_ms`), in ms.
/// Simulated servos cannot keep a real adapter's time on a busy computer: their replies cross
/// the pseudo-terminal through a kernel worker thread at normal priority, and, where real-time
/// scheduling is refused, their own thread waits behind every other program. At the bus
/// master's own 2 ms the bridge would report them lost, or their replies bad, when nothing is
/// wrong; a wider allowance costs time only when a reply really is missing. `run` takes what the
/// mapping says, whatever the port: this is `sitl`'s own choice, said in its log.
pub const SIMULATED_TURNAROUND_MS: f32 = 20.0;

/// Say once when the simulated servos run without real-time scheduling: beside busy programs
/// they then answer late.
async fn tell_realtime(sims: &[SimBus]) {
    let mut refused = false;
    for sim in sims {
        let mut realtime = sim.realtime();
        for _ in 0..100 {
            if realtime.is_some() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
            realtime = sim.realtime();
        }
        refused |= realtime == Some(false);
    }
    if refused {
        tracing::warn!(
            "the simulated servos run without real-time scheduling (this user may not use \
             SCHED_FIFO): on a busy computer they answer late"
        );
    }
}

/// Run the chain until Ctrl-C (or `seconds`). Returns the bridge's last view for a summary.
pub async fn run(opts: SitlOptions) -> Result<BridgeView, SitlError> {
    let mut cfg = opts.config.clone().unwrap_or_else(Config::default_sitl);
    let mut sims = Vec::new();
    let mut ports = HashMap::new();
    for bus in cfg.buses.iter_mut().filter(|b| b.turnaround_ms.is_none()) {
        bus.turnaround_ms = Some(SIMULATED_TURNAROUND_MS);
        tracing::info!(
            bus = %bus.name,
            "simulated servos, whose replies a busy computer passes on late: reply allowance \
             {SIMULATED_TURNAROUND_MS} ms (a real adapter's is 2 ms; turnaround_ms in the \
             mapping sets it)"
        );
    }
    for bus in &cfg.buses {
        let ids: Vec<u8> = cfg.servos_on(&bus.name).map(|s| s.id.get()).collect();
        let sim = SimBus::spawn_pty(SimConfig {
            ids,
            baud: bus.baud.bits_per_second(),
            ..SimConfig::default()
        })
        .map_err(|source| SitlError::Servos {
            bus: bus.name.clone(),
            source,
        })?;
        tracing::info!(bus = %bus.name, port = %sim.path().display(), "simulated servos ready");
        ports.insert(bus.name.clone(), sim.path());
        sims.push(sim);
    }
    tell_realtime(&sims).await;

    let (stop_tx, stop_rx) = watch::channel(false);
    let mut autopilot_task = None;
    match &opts.autopilot {
        Some(address) => cfg.mavlink.connection = address.clone(),
        None => {
            let port = free_udp_port().map_err(SitlError::NoPort)?;
            cfg.mavlink.connection = format!("udpin:127.0.0.1:{port}");
            let ap = autopilot::AutopilotConfig::for_mapping(&cfg, port);
            let stop = stop_rx.clone();
            autopilot_task = Some(tokio::spawn(autopilot::run(
                ap,
                autopilot::AutopilotHandle::default(),
                stop,
            )));
        }
    }
    if let Some(gcs) = opts
        .gcs
        .clone()
        .or_else(|| cfg.mavlink.gcs.clone())
        .or(Some(DEFAULT_GCS.into()))
    {
        cfg.mavlink.gcs = Some(gcs);
    }
    eprintln!(
        "lj9da-bridge sitl: {} servo(s) on {} simulated bus(es); autopilot {}; ground station telemetry on {}",
        cfg.servos.len(),
        cfg.buses.len(),
        opts.autopilot
            .as_deref()
            .unwrap_or("simulated (ArduPilot-like)"),
        cfg.mavlink.gcs.as_deref().unwrap_or("-"),
    );

    let (view_tx, view_rx) = watch::channel(BridgeView::default());
    let plain = opts.plain || !std::io::stdout().is_terminal();
    let mut table_task = if plain {
        tokio::spawn(table::show(view_rx.clone(), true))
    } else {
        let view = view_rx.clone();
        let labels = cfg
            .servos
            .iter()
            .map(|s| (s.name.clone(), s.label.clone()))
            .collect();
        tokio::spawn(async move {
            if let Err(e) = live::show(view.clone(), labels).await {
                // A terminal the view cannot drive still gets the plain table.
                tracing::warn!("live view: {e}; printing the table instead");
                table::show(view, true).await;
            }
        })
    };
    // A mapping that names no record folder records into `records/` of the current folder,
    // not beside the mapping file: `sitl --config mappings/…` must not write into the examples.
    let record_dir = match cfg.record.dir {
        Some(_) => cfg.record.dir_for(opts.config_path.as_deref()),
        None => PathBuf::from("records"),
    };
    let run_opts = runtime::RunOptions {
        ports,
        view: Some(view_tx),
        record_dir: Some(record_dir),
        check_latency: false,
        mapping: match (&opts.config, &opts.config_path) {
            (None, _) => runtime::mapping_file(None),
            (Some(_), Some(path)) => runtime::mapping_file(Some(path)),
            (Some(_), None) => None,
        },
        service: false,
    };
    let bridge = tokio::spawn(runtime::run(cfg, run_opts, stop_rx));

    let deadline = opts.seconds;
    let mut view_ended = false;
    tokio::select! {
        _ = async {
            match deadline {
                Some(d) => tokio::time::sleep(d).await,
                None => std::future::pending().await,
            }
        } => {}
        _ = runtime::shutdown_signal() => {}
        // `q` in the live view.
        _ = &mut table_task, if !plain => view_ended = true,
    }
    let _ = stop_tx.send(true);
    if !view_ended {
        table_task.abort();
        // The view gives the terminal back before the final table is printed.
        let _ = table_task.await;
    }
    let result = bridge.await;
    if let Some(t) = autopilot_task {
        let _ = t.await;
    }
    let last = view_rx.borrow().clone();
    println!("{}", table::render(&last));
    for sim in sims {
        sim.shutdown();
    }
    match result {
        Ok(r) => r.map(|()| last).map_err(SitlError::from),
        Err(join) => panic!("bridge task failed: {join}"),
    }
}
