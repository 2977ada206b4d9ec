//! The whole chain for integration tests: simulated servos on real pseudo-terminals, the
//! bridge in this process, the simulated autopilot and a ground station on real UDP sockets;
//! [`mapping`] builds the mappings the chains run, [`peer`] plays the autopilot from the test,
//! [`sitl`] runs the `sitl` command.
#![allow(dead_code)]

pub mod mapping;
pub mod netns;
pub mod peer;
pub mod ports;
pub mod python;
pub mod sitl;

pub use ports::free_udp_port;

use lj9da_bridge::config::Config;
use lj9da_bridge::config::edit::MappingFile;
use lj9da_bridge::runtime::{self, BridgeView};
use lj9da_bridge::simulation::autopilot::{self, AutopilotConfig, AutopilotHandle};
use lj9da_sim::{SimBus, SimConfig};
use mavlink::dialects::common::MavMessage;
use mavlink::{AsyncMavConnection, MavHeader};
use std::collections::HashMap;
use std::fmt::Display;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// Everything a ground station heard, with the time it arrived (or, with a filter, what the
/// filter kept; every message is counted either way).
#[derive(Clone, Default)]
pub struct Heard(
    Arc<Mutex<Vec<(Instant, MavHeader, MavMessage)>>>,
    Arc<AtomicU64>,
);

impl Heard {
    pub fn all(&self) -> Vec<(Instant, MavHeader, MavMessage)> {
        self.0.lock().unwrap().clone()
    }

    /// How many messages arrived in all, kept or not.
    pub fn count(&self) -> u64 {
        self.1.load(Ordering::Relaxed)
    }

    /// The kept messages that arrived at or after `since`.
    pub fn since(&self, since: Instant) -> Vec<(Instant, MavHeader, MavMessage)> {
        self.0
            .lock()
            .unwrap()
            .iter()
            .filter(|(t, _, _)| *t >= since)
            .cloned()
            .collect()
    }

    /// Wait until `pred` holds for what was heard, or panic after `timeout` with `what`.
    pub async fn wait_for(
        &self,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&[(Instant, MavHeader, MavMessage)]) -> bool,
    ) {
        let deadline = Instant::now() + timeout;
        loop {
            if pred(&self.0.lock().unwrap()) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "timed out after {timeout:?} waiting for {what}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    pub fn statustexts(&self) -> Vec<(mavlink::dialects::common::MavSeverity, String)> {
        self.all()
            .into_iter()
            .filter_map(|(_, _, m)| match m {
                MavMessage::STATUSTEXT(s) => {
                    Some((s.severity, s.text.to_str().unwrap_or("").to_string()))
                }
                _ => None,
            })
            .collect()
    }
}

/// A ground station: a MAVLink `udpin` socket that records everything it hears.
pub async fn ground_station(port: u16) -> (Heard, JoinHandle<()>) {
    ground_station_keeping(port, None).await
}

/// A ground station that keeps only the messages `keep` accepts (all when `None`) and counts
/// every message: a long run then holds no more than it needs.
pub async fn ground_station_keeping(
    port: u16,
    keep: Option<fn(&MavMessage) -> bool>,
) -> (Heard, JoinHandle<()>) {
    let mut conn = mavlink::connect_async::<MavMessage>(&format!("udpin:127.0.0.1:{port}"))
        .await
        .unwrap();
    conn.set_allow_recv_any_version(true);
    let heard = Heard::default();
    let h = heard.clone();
    let task = tokio::spawn(async move {
        while let Ok((header, msg)) = conn.recv().await {
            h.1.fetch_add(1, Ordering::Relaxed);
            if keep.is_none_or(|keep| keep(&msg)) {
                h.0.lock().unwrap().push((Instant::now(), header, msg));
            }
        }
    });
    (heard, task)
}

/// How a chain is started (see [`Chain::start_opts`]); the default is [`Chain::start`]'s with
/// the test playing the autopilot.
#[derive(Clone, Default)]
pub struct ChainOptions {
    /// Run the simulated autopilot (else the test plays it on `udpout:127.0.0.1:<autopilot_port>`).
    pub autopilot: bool,
    /// Send the bridge's telemetry to this port (for an outside ground station); `gcs` then
    /// hears nothing.
    pub gcs_port: Option<u16>,
    /// Give each simulated bus a stable symlink (in a fresh folder under the target's temporary
    /// directory) and hand the bridge that path, so that the serial device can disappear
    /// (`disconnect_port`) and reappear (`reconnect_port`) and the bridge can reopen it.
    pub stable_links: bool,
    /// The ground station keeps only the messages this accepts (it counts all of them).
    pub gcs_keep: Option<fn(&MavMessage) -> bool>,
    /// The simulators' fault seed (the same seed replays the same corrupted and dropped replies).
    pub sim_seed: Option<u64>,
    /// The file parameter changes are saved into (it must hold `mapping`); `None`: in memory.
    pub mapping_file: Option<PathBuf>,
    /// The ground-station link's address (e.g. `tcpout:127.0.0.1:5760`); `gcs` then hears
    /// nothing. Takes the place of `gcs_port`.
    pub gcs_address: Option<String>,
}

pub struct Chain {
    pub sims: Vec<SimBus>,
    pub autopilot: AutopilotHandle,
    pub gcs: Heard,
    pub view: watch::Receiver<BridgeView>,
    pub autopilot_port: u16,
    /// The folder of this run's flight record.
    pub record_dir: PathBuf,
    /// The folder of the serial devices' symlinks ([`ChainOptions::stable_links`]).
    pub link_dir: Option<PathBuf>,
    stop: watch::Sender<bool>,
    bridge: Option<JoinHandle<Result<(), runtime::RunError>>>,
    /// Why the bridge ended, if it ended with an error before `stop`.
    failed: Arc<Mutex<Option<String>>>,
    tasks: Vec<JoinHandle<()>>,
}

impl Chain {
    /// Start the chain for `mapping` (its text, or a [`mapping::Mapping`]; its buses get
    /// simulated servos). With `autopilot` false the test plays the autopilot itself on
    /// `udpout:127.0.0.1:<autopilot_port>` (see [`peer::Autopilot`]).
    pub async fn start(mapping: impl Display, autopilot: bool) -> Chain {
        Self::start_with(mapping, autopilot, None).await
    }

    /// As [`Chain::start`]; with `gcs_port` the bridge's telemetry goes to that port (for an
    /// outside ground station) and `gcs` hears nothing.
    pub async fn start_with(
        mapping: impl Display,
        autopilot: bool,
        gcs_port: Option<u16>,
    ) -> Chain {
        Self::start_opts(
            mapping,
            ChainOptions {
                autopilot,
                gcs_port,
                ..ChainOptions::default()
            },
        )
        .await
    }

    /// Start the chain for `mapping` as `opts` say.
    pub async fn start_opts(mapping: impl Display, opts: ChainOptions) -> Chain {
        let mapping = &mapping.to_string();
        let ChainOptions {
            autopilot,
            gcs_port,
            stable_links,
            gcs_keep,
            sim_seed,
            mapping_file,
            gcs_address,
        } = opts;
        let mut cfg = Config::parse(mapping, "test mapping").expect("test mapping is valid");
        let mut sims = Vec::new();
        let mut ports = HashMap::new();
        let link_dir = stable_links.then(|| {
            static NEXT: AtomicU64 = AtomicU64::new(0);
            let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!(
                "links-{}-{}",
                std::process::id(),
                NEXT.fetch_add(1, Ordering::Relaxed)
            ));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).expect("folder for the serial device links");
            dir
        });
        for bus in &cfg.buses {
            let ids = cfg.servos_on(&bus.name).map(|s| s.id.get()).collect();
            let defaults = SimConfig::default();
            let sim = SimBus::spawn_pty(SimConfig {
                ids,
                baud: bus.baud.bits_per_second(),
                link: link_dir
                    .as_ref()
                    .map(|d| d.join(format!("bus-{}", bus.name))),
                seed: sim_seed.unwrap_or(defaults.seed),
                ..defaults
            })
            .expect("simulated servos start");
            ports.insert(bus.name.clone(), sim.path());
            sims.push(sim);
        }
        let autopilot_port = free_udp_port();
        cfg.mavlink.connection = format!("udpin:127.0.0.1:{autopilot_port}");
        let (gcs, gcs_task) = match (gcs_address, gcs_port) {
            (Some(address), _) => {
                cfg.mavlink.gcs = Some(address);
                (Heard::default(), tokio::spawn(async {}))
            }
            (None, Some(port)) => {
                cfg.mavlink.gcs = Some(format!("udpout:127.0.0.1:{port}"));
                (Heard::default(), tokio::spawn(async {}))
            }
            (None, None) => {
                let port = free_udp_port();
                cfg.mavlink.gcs = Some(format!("udpout:127.0.0.1:{port}"));
                ground_station_keeping(port, gcs_keep).await
            }
        };
        let (stop, stop_rx) = watch::channel(false);
        let (view_tx, view) = watch::channel(BridgeView::default());
        let record_dir =
            PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("records-{autopilot_port}"));
        let _ = std::fs::remove_dir_all(&record_dir);
        let opts = runtime::RunOptions {
            ports,
            view: Some(view_tx),
            record_dir: Some(record_dir.clone()),
            check_latency: false,
            mapping: Some(match &mapping_file {
                Some(path) => MappingFile::open(path).expect("the mapping file opens"),
                None => MappingFile::in_memory(mapping, "test mapping").expect("valid"),
            }),
            service: false,
        };
        let failed = Arc::new(Mutex::new(None));
        let bridge = tokio::spawn({
            let (cfg, stop_rx, failed) = (cfg.clone(), stop_rx.clone(), failed.clone());
            async move {
                let ran = runtime::run(cfg, opts, stop_rx).await;
                if let Err(e) = &ran {
                    *failed.lock().unwrap() = Some(e.to_string());
                }
                ran
            }
        });
        let handle = AutopilotHandle::default();
        let mut tasks = vec![gcs_task];
        if autopilot {
            let ap = AutopilotConfig::for_mapping(&cfg, autopilot_port);
            let h = handle.clone();
            tasks.push(tokio::spawn(async move {
                let _ = autopilot::run(ap, h, stop_rx).await;
            }));
        }
        Chain {
            sims,
            autopilot: handle,
            gcs,
            view,
            autopilot_port,
            record_dir,
            link_dir,
            stop,
            bridge: Some(bridge),
            failed,
            tasks,
        }
    }

    /// Wait until the bridge's view satisfies `pred`.
    pub async fn wait_view(
        &self,
        what: &str,
        timeout: Duration,
        pred: impl Fn(&BridgeView) -> bool,
    ) {
        let deadline = Instant::now() + timeout;
        loop {
            if pred(&self.view.borrow()) {
                return;
            }
            if let Some(e) = self.failed.lock().unwrap().as_ref() {
                panic!("the bridge stopped while the test waited for {what}: {e}");
            }
            assert!(
                self.bridge_running(),
                "the bridge's task ended (a panic?) while the test waited for {what}"
            );
            assert!(
                Instant::now() < deadline,
                "timed out after {timeout:?} waiting for {what}: {:#?}",
                *self.view.borrow()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Whether the bridge task is still running (it ends only on `stop`, an error or a panic).
    pub fn bridge_running(&self) -> bool {
        self.bridge.as_ref().is_some_and(|b| !b.is_finished())
    }

    pub async fn stop(mut self) {
        let _ = self.stop.send(true);
        if let Some(b) = self.bridge.take() {
            b.await.expect("bridge task").expect("bridge ran");
        }
        for t in self.tasks.drain(..) {
            t.abort();
        }
        for s in self.sims.drain(..) {
            s.shutdown();
        }
        if let Some(dir) = self.link_dir.take() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}
