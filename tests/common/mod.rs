//! The whole chain for integration tests: simulated servos on real pseudo-terminals, the
//! bridge in this process, the simulated autopilot and a ground station on real UDP sockets.
#![allow(dead_code)]

use lj9da_bridge::config::Config;
use lj9da_bridge::runtime::{self, BridgeView};
use lj9da_bridge::simulation::autopilot::{self, AutopilotConfig, AutopilotHandle};
use lj9da_sim::{SimBus, SimConfig};
use mavlink::dialects::common::MavMessage;
use mavlink::{AsyncMavConnection, MavHeader};
use std::collections::HashMap;
use std::path::PathBuf;
use std::net::UdpSocket;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio::task::JoinHandle;

pub fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Everything a ground station heard, with the time it arrived.
#[derive(Clone, Default)]
pub struct Heard(Arc<Mutex<Vec<(Instant, MavHeader, MavMessage)>>>);

impl Heard {
    pub fn all(&self) -> Vec<(Instant, MavHeader, MavMessage)> {
        self.0.lock().unwrap().clone()
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
    let mut conn = mavlink::connect_async::<MavMessage>(&format!("udpin:127.0.0.1:{port}"))
        .await
        .unwrap();
    conn.set_allow_recv_any_version(true);
    let heard = Heard::default();
    let h = heard.clone();
    let task = tokio::spawn(async move {
        while let Ok((header, msg)) = conn.recv().await {
            h.0.lock().unwrap().push((Instant::now(), header, msg));
        }
    });
    (heard, task)
}

pub struct Chain {
    pub sims: Vec<SimBus>,
    pub autopilot: AutopilotHandle,
    pub gcs: Heard,
    pub view: watch::Receiver<BridgeView>,
    pub autopilot_port: u16,
    /// The folder of this run's flight record.
    pub record_dir: PathBuf,
    stop: watch::Sender<bool>,
    bridge: Option<JoinHandle<Result<(), runtime::RunError>>>,
    tasks: Vec<JoinHandle<()>>,
}

impl Chain {
    /// Start the chain for `mapping` (its buses get simulated servos). With `autopilot` false
    /// the test plays the autopilot itself on `udpout:127.0.0.1:<autopilot_port>`.
    pub async fn start(mapping: &str, autopilot: bool) -> Chain {
        Self::start_with(mapping, autopilot, None).await
    }

    /// As [`Chain::start`]; with `gcs_port` the bridge's telemetry goes to that port (for an
    /// outside ground station) and `gcs` hears nothing.
    pub async fn start_with(mapping: &str, autopilot: bool, gcs_port: Option<u16>) -> Chain {
        let mut cfg = Config::parse(mapping, "test mapping").expect("test mapping is valid");
        let mut sims = Vec::new();
        let mut ports = HashMap::new();
        for bus in &cfg.buses {
            let ids = cfg.servos_on(&bus.name).map(|s| s.id.get()).collect();
            let sim = SimBus::spawn_pty(SimConfig {
                ids,
                baud: bus.baud.bits_per_second(),
                ..SimConfig::default()
            })
            .expect("simulated servos start");
            ports.insert(bus.name.clone(), sim.path());
            sims.push(sim);
        }
        let autopilot_port = free_udp_port();
        cfg.mavlink.connection = format!("udpin:127.0.0.1:{autopilot_port}");
        let (gcs, gcs_task) = match gcs_port {
            Some(port) => {
                cfg.mavlink.gcs = Some(format!("udpout:127.0.0.1:{port}"));
                (Heard::default(), tokio::spawn(async {}))
            }
            None => {
                let port = free_udp_port();
                cfg.mavlink.gcs = Some(format!("udpout:127.0.0.1:{port}"));
                ground_station(port).await
            }
        };
        let (stop, stop_rx) = watch::channel(false);
        let (view_tx, view) = watch::channel(BridgeView::default());
        let record_dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("records-{autopilot_port}"));
        let _ = std::fs::remove_dir_all(&record_dir);
        let opts = runtime::RunOptions {
            ports,
            view: Some(view_tx),
            record_dir: Some(record_dir.clone()),
            check_latency: false,
        };
        let bridge = tokio::spawn(runtime::run(cfg.clone(), opts, stop_rx.clone()));
        let handle = AutopilotHandle::default();
        let mut tasks = vec![gcs_task];
        if autopilot {
            let ap = AutopilotConfig {
                connection: format!("udpout:127.0.0.1:{autopilot_port}"),
                channels: cfg
                    .servos
                    .iter()
                    .map(|s| s.channel)
                    .filter(|c| *c <= 16)
                    .collect(),
                ..Default::default()
            };
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
            stop,
            bridge: Some(bridge),
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
            assert!(
                Instant::now() < deadline,
                "timed out after {timeout:?} waiting for {what}: {:#?}",
                *self.view.borrow()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
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
    }
}
