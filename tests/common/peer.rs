//! The autopilot played by the test (rather than the chain's simulated one): the `mavlink`
//! crate's `udpout` to the bridge's autopilot link on a real UDP socket, sending what the test
//! says when it says it, or a stream of HEARTBEAT and outputs at a rate.

use lj9da_bridge::mavlink::core::sys_status;
use lj9da_bridge::mavlink::outputs::servo_output_raw;
use mavlink::dialects::common::{HEARTBEAT_DATA, MavAutopilot, MavMessage, MavType};
use mavlink::{AsyncConnection, AsyncMavConnection, MavHeader, MavlinkVersion};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// An autopilot's HEARTBEAT: a `mavtype` run by `autopilot`, every other field its default.
pub fn heartbeat_of(mavtype: MavType, autopilot: MavAutopilot) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype,
        autopilot,
        ..Default::default()
    })
}

/// An ArduPilot fixed wing's HEARTBEAT (see [`heartbeat_of`]).
pub fn heartbeat() -> MavMessage {
    heartbeat_of(
        MavType::MAV_TYPE_FIXED_WING,
        MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
    )
}

/// SERVO_OUTPUT_RAW of port 0: channel 1 at `us[0]` µs, channel 2 at `us[1]`, …; the channels
/// after them 0 ("no output").
pub fn outputs(us: &[u16]) -> MavMessage {
    let mut raw = [0u16; 16];
    raw[..us.len()].copy_from_slice(us);
    servo_output_raw(0, raw, 0)
}

/// Who the autopilot is and how it speaks.
#[derive(Clone)]
pub struct AutopilotOptions {
    /// Its system and component ids.
    pub ids: (u8, u8),
    /// The HEARTBEAT it sends.
    pub heartbeat: MavMessage,
    /// The MAVLink version it frames its messages in.
    pub version: MavlinkVersion,
}

impl Default for AutopilotOptions {
    /// System 1, component 1, an ArduPilot fixed wing ([`heartbeat`]), MAVLink 2.
    fn default() -> Self {
        AutopilotOptions {
            ids: (1, 1),
            heartbeat: heartbeat(),
            version: MavlinkVersion::V2,
        }
    }
}

/// The autopilot, played by the test on `udpout:127.0.0.1:<port>`.
pub struct Autopilot {
    conn: Arc<AsyncConnection<MavMessage>>,
    header: MavHeader,
    heartbeat: MavMessage,
    /// The outputs the stream sends, once [`Autopilot::stream`] started it.
    outputs: Option<watch::Sender<MavMessage>>,
    paused: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    tasks: Vec<JoinHandle<()>>,
}

impl Autopilot {
    /// The autopilot of [`AutopilotOptions::default`] on the bridge's autopilot link `port`.
    /// It sends nothing yet.
    pub async fn connect(port: u16) -> Autopilot {
        Self::connect_with(port, AutopilotOptions::default()).await
    }

    /// The autopilot `options` say on the bridge's autopilot link `port`. It sends nothing yet.
    pub async fn connect_with(port: u16, options: AutopilotOptions) -> Autopilot {
        let mut conn = mavlink::connect_async::<MavMessage>(&format!("udpout:127.0.0.1:{port}"))
            .await
            .expect("autopilot socket");
        conn.set_protocol_version(options.version);
        Autopilot {
            conn: Arc::new(conn),
            header: MavHeader {
                system_id: u32::from(options.ids.0),
                component_id: options.ids.1,
                sequence: 0,
            },
            heartbeat: options.heartbeat,
            outputs: None,
            paused: Arc::new(AtomicBool::new(false)),
            sent: Arc::new(AtomicU64::new(0)),
            tasks: Vec::new(),
        }
    }

    /// Send `message` from the autopilot; panics if it cannot be sent.
    pub async fn send(&self, message: &MavMessage) {
        self.conn.send(&self.header, message).await.unwrap();
    }

    /// Send `message` from the autopilot; whether it was sent.
    pub async fn try_send(&self, message: &MavMessage) -> bool {
        self.conn.send(&self.header, message).await.is_ok()
    }

    /// Send the autopilot's HEARTBEAT.
    pub async fn heartbeat(&self) {
        self.send(&self.heartbeat).await;
    }

    /// From now until dropped: the HEARTBEAT at once and then once a second, and `outputs` at
    /// `hz` (and at once whenever [`Autopilot::set`] changes them) unless
    /// [`Autopilot::pause`]d. What the bridge sends the autopilot is read and dropped.
    pub fn stream(&mut self, hz: u32, outputs: MavMessage) {
        assert!(self.outputs.is_none(), "the autopilot streams already");
        let (tx, mut rx) = watch::channel(outputs);
        self.outputs = Some(tx);
        let (c, p, n) = (self.conn.clone(), self.paused.clone(), self.sent.clone());
        let (header, heartbeat) = (self.header, self.heartbeat.clone());
        // ArduPilot sends SYS_STATUS (EXTENDED_STATUS, 1 Hz) beside its HEARTBEAT: the bridge
        // reads its safety switch there.
        let ardupilot = matches!(&heartbeat, MavMessage::HEARTBEAT(hb)
            if hb.autopilot == MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA);
        let sender = tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1) / hz);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            let mut next_heartbeat = Instant::now();
            loop {
                tokio::select! {
                    _ = tick.tick() => {}
                    changed = rx.changed() => {
                        if changed.is_err() {
                            return;
                        }
                    }
                }
                if Instant::now() >= next_heartbeat {
                    next_heartbeat += Duration::from_secs(1);
                    let _ = c.send(&header, &heartbeat).await;
                    if ardupilot {
                        let _ = c.send(&header, &sys_status(false)).await;
                    }
                }
                if !p.load(Ordering::SeqCst) {
                    let outputs = rx.borrow_and_update().clone();
                    if c.send(&header, &outputs).await.is_ok() {
                        n.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        });
        let c = self.conn.clone();
        let drain = tokio::spawn(async move {
            loop {
                if c.recv().await.is_err() {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            }
        });
        self.tasks.extend([sender, drain]);
    }

    /// The outputs the stream sends from now on (sent at once).
    pub fn set(&self, outputs: MavMessage) {
        self.outputs
            .as_ref()
            .expect("a streaming autopilot")
            .send_replace(outputs);
    }

    /// Stop (`true`) or resume the stream's outputs; its HEARTBEAT goes on.
    pub fn pause(&self, paused: bool) {
        self.paused.store(paused, Ordering::SeqCst);
    }

    /// How many outputs the stream has sent.
    pub fn sent(&self) -> u64 {
        self.sent.load(Ordering::Relaxed)
    }
}

impl Drop for Autopilot {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}
