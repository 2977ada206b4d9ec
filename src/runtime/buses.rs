//! The running bridge's buses as the loop sees them: started from the mapping file, their
//! statuses as the MAVLink side's servo reports and the view's rows, their events as the MAVLink
//! side announces them.

use super::ServoView;
use crate::bus::{
    BusConfig, BusEvent, BusHandle, BusStatus, Health, ServoSetup, spawn_bus, spawn_bus_observed,
};
use crate::config::Config;
use crate::mavlink::{BridgeEvent, ServoEvent, ServoReport, ServoState, TemperatureReading};
use crate::protocol::ServoId;
use crate::record::{RecordHandle, RecordServo, StatusFeed};
use crate::serial::rs485::Rs485Mode;
use std::collections::HashMap;
use std::path::PathBuf;
use tokio::sync::mpsc;

/// The running bridge's buses, in the order of the mapping file's `[[bus]]` tables, and where
/// each servo lives.
pub(super) struct Buses {
    pub(super) handles: Vec<BusHandle>,
    /// For each servo (mapping order): its bus index and ID.
    pub(super) servo_at: Vec<(usize, ServoId)>,
}

impl Buses {
    /// Start every bus; with a flight record, each bus thread records its own statuses (every
    /// telemetry sample, without waking another thread for it).
    pub(super) fn spawn(
        cfg: &Config,
        ports: &HashMap<String, PathBuf>,
        record: Option<&RecordHandle>,
    ) -> Self {
        let mut handles = Vec::new();
        for bus in &cfg.buses {
            let setups = cfg
                .servos
                .iter()
                .filter(|s| s.bus == bus.name)
                .map(|s| ServoSetup {
                    id: s.id,
                    name: s.name.clone(),
                    goal_time: s.goal_time(),
                    max_force: s.max_force_percent,
                })
                .collect();
            let mut bus_cfg = BusConfig::new(bus.name.clone(), bus.baud, setups);
            if let Some(ms) = bus.turnaround_ms {
                bus_cfg.turnaround = std::time::Duration::from_secs_f32(ms / 1000.0);
            }
            bus_cfg.telemetry_min_interval = bus.telemetry.min_interval();
            bus_cfg.soft_start_speed_mm_s = bus.soft_start_mm_s;
            if let Some(w) = crate::config::warnings::telemetry_beyond_wire(cfg, bus) {
                tracing::warn!("{}", w.trim_start_matches("warning: "));
            }
            let port = ports
                .get(&bus.name)
                .cloned()
                .unwrap_or_else(|| bus.port.clone());
            tracing::info!(bus = %bus.name, port = %port.display(), baud = %bus.baud, "opening bus");
            bus_cfg.rs485 = rs485_mode(bus, ports.contains_key(&bus.name));
            handles.push(match record {
                Some(r) => {
                    let mut feed = StatusFeed::new(r.clone(), &RecordServo::from_config(cfg));
                    spawn_bus_observed(bus_cfg, port, Box::new(move |s| feed.observe(s)))
                }
                None => spawn_bus(bus_cfg, port),
            });
        }
        let servo_at = cfg
            .servos
            .iter()
            .map(|s| {
                let bus = cfg.buses.iter().position(|b| b.name == s.bus).unwrap_or(0);
                (bus, s.id)
            })
            .collect();
        Buses { handles, servo_at }
    }

    pub(super) fn reports(&self, cfg: &Config) -> (Vec<ServoReport>, Vec<ServoView>) {
        let statuses: Vec<BusStatus> = self.handles.iter().map(BusHandle::status).collect();
        self.reports_of(cfg, &statuses)
    }

    pub(super) fn reports_of(
        &self,
        cfg: &Config,
        statuses: &[BusStatus],
    ) -> (Vec<ServoReport>, Vec<ServoView>) {
        let mut reports = Vec::with_capacity(self.servo_at.len());
        let mut views = Vec::with_capacity(self.servo_at.len());
        for (i, (bus, id)) in self.servo_at.iter().enumerate() {
            let bus_status = statuses.get(*bus);
            let port_open = bus_status.is_some_and(|b| b.port_open);
            let status = bus_status.and_then(|b| b.servos.iter().find(|s| s.id == *id));
            let (report, goal_mm, health) = match status {
                Some(s) => (report_of(s, port_open), s.goal.map(|g| g.mm()), s.health),
                None => (ServoReport::default(), None, Health::Starting),
            };
            reports.push(report);
            let sc = &cfg.servos[i];
            views.push(ServoView {
                name: sc.name.clone(),
                bus: sc.bus.clone(),
                id: *id,
                channel: sc.channel,
                report,
                goal_mm,
                health,
            });
        }
        (reports, views)
    }
}

/// The RS485 mode bus `bus` of a mapping file asks of its port (`None` when the port is a
/// simulation's pseudo-terminal, `simulated`, which has no RS485 mode to set), having said once
/// what the mode asks of the servos.
fn rs485_mode(bus: &crate::config::BusSection, simulated: bool) -> Option<Rs485Mode> {
    let mode = bus.rs485.filter(|_| !simulated);
    if mode.is_some()
        && let Some(w) = crate::config::warnings::rs485_hold_after_send(bus)
    {
        tracing::warn!("{}", w.trim_start_matches("warning: "));
    }
    mode
}

/// How long a servo's latest reading is passed on to the ground station (and quoted in a
/// STATUSTEXT). A servo that answers is read tens of times a second, so a reading this old
/// belongs to a servo that has stopped answering; repeating it would show a past value as
/// the present one.
pub const FRESH_FOR: std::time::Duration = std::time::Duration::from_secs(1);

/// The MAVLink view of one servo's bus status. Its telemetry goes out whenever the latest
/// reading is fresh (younger than [`FRESH_FOR`] when the status was taken), whatever the
/// servo's health: a servo in temperature error (force off) is still read, and that is when
/// the operator most needs to watch its temperature fall and see where the rod stopped.
/// A servo on a bus whose port is closed (the adapter unplugged, a port that never opened)
/// cannot be reached: it is offline, whatever its last health was.
pub fn report_of(s: &crate::bus::ServoStatus, port_open: bool) -> ServoReport {
    let state = match s.health {
        _ if !port_open => ServoState::Offline,
        Health::Starting => ServoState::Starting,
        Health::Online => ServoState::Online,
        Health::Stale => ServoState::Stale,
        Health::Offline => ServoState::Offline,
        Health::WrongModel | Health::TemperatureError => ServoState::Fault,
    };
    let fresh = s.age.is_some_and(|age| age < FRESH_FOR);
    let t = s.telemetry.filter(|_| fresh);
    ServoReport {
        state: Some(state),
        position_mm: t.map(|t| t.present_position.mm() as f32),
        current_a: t.map(|t| t.present_load.amps() as f32),
        temperature_c: t.map(|t| f32::from(t.present_temperature.0)),
        voltage_v: t.map(|t| t.present_voltage.volts() as f32),
        temperature_alarm: s.flags.temperature_alarm(),
        temperature_error: s.flags.temperature_error() || s.health == Health::TemperatureError,
        stalled: s.stalled,
        error_count: s.timeouts.min(u64::from(u32::MAX)) as u32,
        model: s.identity.model,
        firmware: s.identity.firmware,
        degraded: s.degraded,
    }
}

/// A bus event as the MAVLink side announces it (`None`: logged only).
pub(super) fn bridge_event(
    cfg: &Config,
    buses: &Buses,
    bus: usize,
    event: &BusEvent,
) -> Option<BridgeEvent> {
    let bus_name = cfg
        .buses
        .get(bus)
        .map(|b| b.name.clone())
        .unwrap_or_default();
    let servo = event.servo().and_then(|id| {
        buses
            .servo_at
            .iter()
            .position(|(b, i)| *b == bus && *i == id)
    });
    // The temperature quoted with an alarm or error: the latest reading, if it is fresh, and
    // its age now. The all-clear quotes none: after a power cycle the last reading can predate
    // the restart.
    let reading = || {
        let id = event.servo()?;
        let status = buses.handles.get(bus)?.status();
        let servo = status.servos.iter().find(|s| s.id == id)?;
        let age = servo.telemetry_at?.elapsed();
        (age < FRESH_FOR).then_some(TemperatureReading {
            celsius: servo.telemetry?.present_temperature.0,
            age,
        })
    };
    let servo_event = match event {
        BusEvent::ServoLost { .. } => ServoEvent::Lost,
        BusEvent::ServoBack { .. } => ServoEvent::Back,
        BusEvent::TemperatureAlarm { on, .. } => ServoEvent::TemperatureAlarm {
            on: *on,
            reading: if *on { reading() } else { None },
        },
        BusEvent::TemperatureError { .. } => ServoEvent::TemperatureError {
            last_read: reading(),
        },
        BusEvent::Stalled { on, .. } => ServoEvent::Stalled { on: *on },
        BusEvent::WrongModel { found, .. } => ServoEvent::WrongModel { found: *found },
        BusEvent::FlashWriteError { .. } => ServoEvent::FlashWriteError,
        BusEvent::RepliesDegraded { percent, .. } => {
            ServoEvent::RepliesDegraded { percent: *percent }
        }
        BusEvent::RepliesOk { .. } => ServoEvent::RepliesOk,
        BusEvent::PortLost { .. } => return Some(BridgeEvent::PortLost { bus: bus_name }),
        BusEvent::PortBack => return Some(BridgeEvent::PortBack { bus: bus_name }),
        BusEvent::ServoOnline { .. }
        | BusEvent::ServoRestarted { .. }
        | BusEvent::ForceRefused { .. } => {
            return None;
        }
    };
    Some(BridgeEvent::Servo {
        servo: servo?,
        event: servo_event,
    })
}

/// A task that passes bus `i`'s events to the loop (and to the flight record).
pub(super) fn forward_bus_events(
    cfg: &Config,
    i: usize,
    bus: &BusHandle,
    record: Option<RecordHandle>,
    to_loop: mpsc::UnboundedSender<(usize, BusEvent)>,
) -> tokio::task::JoinHandle<()> {
    // The first subscription: it holds every event since the bus started, a port refused at
    // once included (see `BusHandle::events`).
    let mut events = bus.events();
    let feed = record.map(|r| StatusFeed::new(r, &RecordServo::from_config(cfg)));
    let bus_name = bus.name().to_string();
    tokio::spawn(async move {
        loop {
            match events.recv().await {
                Ok(e) => {
                    if let Some(feed) = &feed {
                        feed.bus_event(&bus_name, &e);
                    }
                    if to_loop.send((i, e)).is_err() {
                        return;
                    }
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    tracing::warn!(bus = i, "{n} bus events dropped");
                }
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
            }
        }
    })
}
