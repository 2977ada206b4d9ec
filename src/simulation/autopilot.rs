//! A simulated autopilot for the default run and the tests: it speaks MAVLink over a real
//! socket like ArduPilot Plane does, so the bridge cannot tell it from the real thing on the
//! points that matter:
//! - HEARTBEAT at 1 Hz from component 1 (fixed wing, ArduPilot), and SYS_STATUS with it (the
//!   safety switch off, as Plane's EXTENDED_STATUS stream sends at 1 Hz);
//! - SERVO_OUTPUT_RAW for channels 1–16 (port 0) at a low default rate (4 Hz, as Plane's
//!   RC_CHAN stream group in SITL) until MAV_CMD_SET_MESSAGE_INTERVAL asks for more;
//! - a requested rate above 0.8 × the loop rate is DENIED, as ArduPilot does;
//! - unassigned channels read 0; assigned channels sweep like a flight.
//!
//! It can stop and resume its output stream on request, for failsafe tests. With a signing key
//! (the mapping's) it signs everything and ignores unsigned messages, as ArduPilot does on a
//! port after `signing setup`.

use crate::mavlink::outputs::servo_output_raw;
use crate::mavlink::signing::SigningKey;
use mavlink::dialects::common::{
    COMMAND_ACK_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavResult,
    MavState, MavType,
};
use mavlink::{AsyncMavConnection, MavHeader, SigningConfig};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// How the simulated autopilot behaves.
#[derive(Debug, Clone)]
pub struct AutopilotConfig {
    /// Where to send (e.g. `udpout:127.0.0.1:14560`, the bridge's `udpin`).
    pub connection: String,
    pub system_id: u8,
    pub component_id: u8,
    /// Main loop rate; requests above 0.8 × this are denied (ArduPilot's rule).
    pub loop_rate_hz: f32,
    /// SERVO_OUTPUT_RAW rate before anyone asks for another.
    pub default_rate_hz: f32,
    /// Channels (1–16) with an output function; the others read 0.
    pub channels: Vec<u8>,
    /// MAVLink 2 signing with this key, as an autopilot after `signing setup`: everything sent
    /// is signed, unsigned or badly signed messages are ignored. `None`: no signing.
    pub signing_key: Option<SigningKey>,
}

impl Default for AutopilotConfig {
    fn default() -> Self {
        Self {
            connection: "udpout:127.0.0.1:14560".into(),
            system_id: 1,
            component_id: 1,
            loop_rate_hz: 50.0,
            default_rate_hz: 4.0,
            channels: vec![1, 2, 3, 4],
            signing_key: None,
        }
    }
}

impl AutopilotConfig {
    /// Whether a SERVO_OUTPUT_RAW rate of `hz` is granted: up to 0.8 × the loop rate, as
    /// ArduPilot does.
    pub fn grants(&self, hz: f32) -> bool {
        hz <= 0.8 * self.loop_rate_hz
    }

    /// The simulated autopilot for a mapping: it sends to `udpout:127.0.0.1:<port>` and drives
    /// the channels (1–16) the mapping's servos listen to.
    pub fn for_mapping(cfg: &crate::config::Config, port: u16) -> Self {
        AutopilotConfig {
            connection: format!("udpout:127.0.0.1:{port}"),
            channels: cfg
                .servos
                .iter()
                .map(|s| s.channel)
                .filter(|c| *c <= 16)
                .collect(),
            signing_key: cfg.mavlink.signing.as_ref().map(|s| s.key.clone()),
            ..Default::default()
        }
    }
}

/// Control and counters of a running simulated autopilot.
#[derive(Debug, Clone, Default)]
pub struct AutopilotHandle {
    inner: Arc<Shared>,
}

#[derive(Debug, Default)]
struct Shared {
    outputs_paused: AtomicBool,
    outputs_sent: AtomicU64,
    /// Current SERVO_OUTPUT_RAW rate, in mHz.
    rate_mhz: AtomicU64,
    denied: AtomicU64,
}

impl AutopilotHandle {
    /// Stop (true) or resume (false) the output stream; heartbeats go on.
    pub fn pause_outputs(&self, paused: bool) {
        self.inner.outputs_paused.store(paused, Ordering::SeqCst);
    }
    pub fn outputs_sent(&self) -> u64 {
        self.inner.outputs_sent.load(Ordering::SeqCst)
    }
    pub fn output_rate_hz(&self) -> f32 {
        self.inner.rate_mhz.load(Ordering::SeqCst) as f32 / 1000.0
    }
    /// How many SET_MESSAGE_INTERVAL requests were denied as too fast.
    pub fn denied_requests(&self) -> u64 {
        self.inner.denied.load(Ordering::SeqCst)
    }
}

/// The output of `channel` at `t` seconds into the flight: a slow sweep around trim, a
/// different rhythm per channel, within 1100–1940 µs.
pub fn sweep_us(channel: u8, t: f64) -> u16 {
    let c = f64::from(channel);
    let phase = c * 1.3;
    let freq = 0.15 + 0.07 * c;
    let amplitude = 300.0 + 40.0 * (c % 3.0);
    (1520.0 + amplitude * (std::f64::consts::TAU * freq * t + phase).sin()).round() as u16
}

/// Run the simulated autopilot until `stop` turns true.
pub async fn run(
    cfg: AutopilotConfig,
    handle: AutopilotHandle,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let mut conn = mavlink::connect_async::<MavMessage>(&cfg.connection).await?;
    conn.set_allow_recv_any_version(true);
    if let Some(key) = &cfg.signing_key {
        // The `mavlink` crate's own signing: a simulator need not count what it drops.
        conn.setup_signing(Some(SigningConfig::new(*key.bytes(), 0, true, false)));
    }
    let conn = Arc::new(conn);
    let header = MavHeader {
        system_id: u32::from(cfg.system_id),
        component_id: cfg.component_id,
        sequence: 0,
    };
    let started = Instant::now();
    let set_rate = |hz: f32| {
        handle
            .inner
            .rate_mhz
            .store((hz * 1000.0) as u64, Ordering::SeqCst)
    };
    set_rate(cfg.default_rate_hz);

    let receiver = {
        let conn = conn.clone();
        let handle = handle.clone();
        let cfg = cfg.clone();
        tokio::spawn(async move {
            loop {
                let Ok((from, msg)) = conn.recv().await else {
                    continue;
                };
                let MavMessage::COMMAND_LONG(cmd) = msg else {
                    continue;
                };
                if cmd.target_system != cfg.system_id {
                    continue;
                }
                let result = if cmd.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL
                    && cmd.param1 as u32 == 36
                {
                    let hz = match cmd.param2 {
                        0.0 => Some(cfg.default_rate_hz),
                        i if i > 0.0 => Some(1e6 / i),
                        _ => None,
                    };
                    match hz {
                        Some(hz) if !cfg.grants(hz) => {
                            handle.inner.denied.fetch_add(1, Ordering::SeqCst);
                            MavResult::MAV_RESULT_DENIED
                        }
                        Some(hz) => {
                            handle
                                .inner
                                .rate_mhz
                                .store((hz * 1000.0) as u64, Ordering::SeqCst);
                            MavResult::MAV_RESULT_ACCEPTED
                        }
                        None => {
                            handle.inner.rate_mhz.store(0, Ordering::SeqCst);
                            MavResult::MAV_RESULT_ACCEPTED
                        }
                    }
                } else {
                    MavResult::MAV_RESULT_UNSUPPORTED
                };
                let ack = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                    command: cmd.command,
                    result,
                    target_system: u8::try_from(from.system_id).unwrap_or(0),
                    target_component: from.component_id,
                    ..Default::default()
                });
                let _ = conn.send(&header, &ack).await;
            }
        })
    };

    let mut next_heartbeat = tokio::time::Instant::now();
    let mut next_output = tokio::time::Instant::now();
    let result = loop {
        let wake = next_heartbeat.min(next_output);
        tokio::select! {
            _ = stop.changed() => {
                if *stop.borrow() { break Ok(()); }
            }
            _ = tokio::time::sleep_until(wake) => {}
        }
        let now = tokio::time::Instant::now();
        if now >= next_heartbeat {
            next_heartbeat += Duration::from_secs(1);
            let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_FIXED_WING,
                autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            });
            for message in [hb, crate::mavlink::core::sys_status(false)] {
                if let Err(e) = conn.send(&header, &message).await {
                    tracing::debug!("simulated autopilot: {e}");
                }
            }
        }
        if now >= next_output {
            let hz = handle.output_rate_hz();
            next_output = now
                + if hz > 0.0 {
                    Duration::from_secs_f32(1.0 / hz)
                } else {
                    Duration::from_millis(100)
                };
            if hz > 0.0 && !handle.inner.outputs_paused.load(Ordering::SeqCst) {
                let t = started.elapsed().as_secs_f64();
                let mut raw = [0u16; 16];
                for &c in &cfg.channels {
                    if (1..=16).contains(&c) {
                        raw[usize::from(c) - 1] = sweep_us(c, t);
                    }
                }
                let msg = servo_output_raw(0, raw, started.elapsed().as_micros() as u32);
                if conn.send(&header, &msg).await.is_ok() {
                    handle.inner.outputs_sent.fetch_add(1, Ordering::SeqCst);
                }
            }
        }
    };
    receiver.abort();
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_airframe_asks_the_rate_the_simulated_autopilot_grants() {
        let cfg = crate::config::Config::default_sitl();
        let autopilot = AutopilotConfig::for_mapping(&cfg, 14560);
        let asked = cfg.mavlink.output_rate_hz;
        assert!(
            autopilot.grants(asked),
            "the built-in airframe asks {asked} Hz, the simulated autopilot grants up to {} Hz",
            0.8 * autopilot.loop_rate_hz
        );
        // ArduPilot's rule, at stock Plane's loop rate: 40 Hz granted, 50 Hz denied.
        assert!(autopilot.grants(40.0) && !autopilot.grants(50.0));
    }

    #[test]
    fn the_sweep_stays_inside_the_pwm_range() {
        for c in 1..=16u8 {
            for i in 0..2000 {
                let us = sweep_us(c, f64::from(i) * 0.01);
                assert!((1100..=1940).contains(&us), "channel {c}: {us}");
            }
        }
    }
}
