//! `lj9da-bridge run`: the tokio shell around the sans-IO parts. It opens the MAVLink links
//! and the buses named in the mapping file, carries messages, goals, events and statuses
//! between [`BridgeCore`] and the bus drivers, and stops cleanly on request.
//!
//! A run has three parts: start-up (`Bridge::start`: links, signing, flight record, buses,
//! the tasks that feed the loop), the loop (`Bridge::serve`: one input, and the messages
//! already waiting behind it, into the core, then its outputs out: goals to the buses,
//! messages to the links' writers, the view), and shutdown (`Bridge::stop`). The links'
//! readers and writers are in `links`.
//!
//! All decisions live in [`BridgeCore`] and [`crate::bus::BusMaster`]; this module only moves
//! data and waits.

mod buses;
pub(crate) mod can;
pub mod governor;
pub(crate) mod links;
pub mod service;
mod udp;

use crate::bus::{BusEvent, BusHandle, BusStatus, Health, ShutdownForce};
use crate::can_node::CanNode;
use crate::config::edit::MappingFile;
use crate::config::{Config, ForceAction};
use crate::dronecan::frame::CanFrame;
use crate::mavlink::outbox::Queued;
use crate::mavlink::param_server::ParamSet;
use crate::mavlink::signing::{self, DropCounts};
use crate::mavlink::{BridgeCore, LinkId, ServoReport};
use crate::protocol::ServoId;
use crate::record::{RecordHandle, RecordLimits, RecordServo, Recorder, RecorderOptions};
use ::mavlink::MavHeader;
use ::mavlink::dialects::common::MavMessage;
use buses::{Buses, bridge_event, forward_bus_events};
pub use buses::{FRESH_FOR, report_of};
use links::{KnownAutopilot, Link, LinkWriter, SharedSigning};
use service::{Verdict, Watchdog};
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;
use thiserror::Error;
use tokio::sync::{mpsc, watch};

/// Per bus, the goals of the inputs of one turn of the loop, in order: `(is an output
/// message, its goals)` (see [`BusHandle::pass_goals`]).
type GoalBatches = Vec<(bool, Vec<(ServoId, crate::bus::Goal)>)>;

/// At most this many messages already waiting are taken after an input, in the same turn.
const READY_MESSAGES: usize = 8;

/// How often the view is refreshed at most.
const VIEW_PERIOD: std::time::Duration = std::time::Duration::from_millis(50);
/// How long after the start the bridge first says that it has heard no autopilot yet; the
/// interval then doubles, up to [`NO_AUTOPILOT_NOTE_MAX`].
const NO_AUTOPILOT_NOTE: std::time::Duration = std::time::Duration::from_secs(10);
const NO_AUTOPILOT_NOTE_MAX: std::time::Duration = std::time::Duration::from_secs(60);

/// How old the view may grow while nothing else wakes the loop (no autopilot yet, or one that
/// went quiet): the live table redraws five times a second.
const VIEW_STALE: std::time::Duration = std::time::Duration::from_millis(200);

/// Why the bridge could not start.
#[derive(Debug, Error)]
pub enum RunError {
    #[error("cannot open the MAVLink connection {address:?}: {source}")]
    Mavlink {
        address: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Signing(#[from] signing::TimestampFileError),
}

/// One servo as the live table shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoView {
    pub name: String,
    pub bus: String,
    pub id: ServoId,
    pub channel: u8,
    pub report: ServoReport,
    pub goal_mm: Option<f64>,
    pub health: Health,
}

/// Everything the live table and the tests may want to see, refreshed after every step.
#[derive(Debug, Clone, Default)]
pub struct BridgeView {
    pub servos: Vec<ServoView>,
    pub autopilot: Option<(u8, u8)>,
    pub failsafe: bool,
    pub output_rate_hz: f32,
    /// The output rate received per message port (SERVO_OUTPUT_RAW port 0: channels 1–16,
    /// port 1: 17–32; ACTUATOR_OUTPUT_STATUS: 0) over the last measurement; empty before it.
    pub outputs_received_hz: Vec<(u8, f32)>,
    /// Each bus's status, in the order of the mapping file's `[[bus]]` tables.
    pub buses: Vec<BusStatus>,
    /// The latest STATUSTEXTs sent, oldest first (at most [`VIEW_TEXTS`]).
    pub texts: Vec<String>,
    /// With signing on: per link (the autopilot's, then the ground station's) the incoming
    /// messages dropped as unsigned, badly signed or replayed. Empty with signing off.
    pub signing_drops: Vec<DropCounts>,
    /// Per link (the autopilot's, then the ground station's): outgoing messages dropped
    /// because the link did not keep up (see [`crate::mavlink::outbox`]).
    pub send_drops: Vec<u64>,
    /// Per link: incoming datagrams the kernel dropped because the bridge did not read them in
    /// time (counted on `udpin` links; 0 on the others).
    pub receive_drops: Vec<u64>,
    /// Parameter changes handed to the mapping file's writer since the start (each one
    /// rewrite of the file, or a refusal by its reader).
    pub mapping_writes: u64,
}

/// How many of the latest STATUSTEXTs the view keeps.
pub const VIEW_TEXTS: usize = 6;

/// How a run differs from the mapping file alone.
#[derive(Debug, Default)]
pub struct RunOptions {
    /// Replaces the port of the named buses (the simulation puts its pseudo-terminals there).
    pub ports: HashMap<String, PathBuf>,
    /// Refreshed after every step (at most every 50 ms) for the live table and tests.
    pub view: Option<watch::Sender<BridgeView>>,
    /// Where to keep the flight record; `None`: no record.
    pub record_dir: Option<PathBuf>,
    /// A run on the aircraft (the `run` command): check each bus port's USB latency timer first
    /// (real adapters only), lock memory, and ask real-time scheduling for the loop and links.
    pub check_latency: bool,
    /// The mapping file that parameter changes from a ground station are saved into;
    /// `None`: parameters can be read but not changed.
    pub mapping: Option<MappingFile>,
    /// Run as a systemd service: say when ready and stopping, feed the watchdog (see
    /// [`service`]; nothing happens where systemd did not ask for it).
    pub service: bool,
}

/// The mapping file that parameter changes go into: the file at `path`, or the built-in
/// airframe of `sitl` held in memory. `None` (said in the log): parameters are read-only.
pub fn mapping_file(path: Option<&std::path::Path>) -> Option<MappingFile> {
    let file = match path {
        Some(path) => MappingFile::open(path),
        None => MappingFile::in_memory(
            crate::config::SITL_DEFAULT_TOML,
            crate::config::SITL_DEFAULT_ORIGIN,
        ),
    };
    match file {
        Ok(file) => Some(file),
        Err(e) => {
            tracing::warn!("parameters are read-only: {e}");
            None
        }
    }
}

type EditResult = (ParamSet, Result<Config, String>);

/// The least time between two writes of the mapping file: at most 10 a second, whoever sends
/// PARAM_SETs and however fast the disk. Changes that come meanwhile wait in the core, one per
/// parameter, the latest winning (see [`crate::mavlink::param_server`]): a burst of sets costs
/// about one write per parameter it names and per 100 ms it lasts, and a ground station
/// loading twenty parameters at once has them all answered within about 2 s.
pub const MAPPING_WRITE_SPACING: std::time::Duration = std::time::Duration::from_millis(100);

/// Parameter changes are written into the mapping file on a thread of their own: syncing a
/// file to an SD card can take tens of milliseconds, which the goals must not wait for. The
/// changes are made one after the other, in the order they came; the core hands over one at a
/// time (see [`crate::mavlink::param_server`]), so one place each way is all the channels
/// hold. Without a file the sender is closed and the caller refuses them.
fn spawn_mapping_writer(
    mapping: Option<MappingFile>,
) -> (mpsc::Sender<ParamSet>, mpsc::Receiver<EditResult>) {
    let (edit_tx, mut edit_rx) = mpsc::channel::<ParamSet>(1);
    let (done_tx, done_rx) = mpsc::channel::<EditResult>(1);
    match mapping {
        None => edit_rx.close(),
        Some(mut file) => {
            let spawned = std::thread::Builder::new()
                .name("mapping-writer".into())
                .spawn(move || {
                    let mut last_write: Option<Instant> = None;
                    while let Some(set) = edit_rx.blocking_recv() {
                        if let Some(wait) = last_write.map(|at| {
                            (at + MAPPING_WRITE_SPACING).saturating_duration_since(Instant::now())
                        }) {
                            std::thread::sleep(wait);
                        }
                        last_write = Some(Instant::now());
                        let result = file.apply(&set.edits).map_err(|e| {
                            tracing::warn!("parameter {} = {} refused: {e}", set.name, set.value);
                            e.reason()
                        });
                        if done_tx.blocking_send((set, result)).is_err() {
                            return;
                        }
                    }
                });
            if let Err(e) = spawned {
                tracing::warn!("parameters are read-only: cannot start the file writer: {e}");
            }
        }
    }
    (edit_tx, done_rx)
}

/// Start the flight record, or say why there is none and carry on without it.
fn start_record(cfg: &Config, dir: &std::path::Path) -> Option<RecordHandle> {
    let servos = RecordServo::from_config(cfg);
    let limits = RecordLimits::with_total(cfg.record.max_total_bytes());
    let aircraft = cfg.record.aircraft.clone().or_else(host_name);
    if cfg.record.aircraft.is_none()
        && let Some(name) = aircraft.as_deref().filter(|n| is_image_default(n))
    {
        tracing::warn!(
            "the flight record names this aircraft {name:?}, the host name its system image gives \
             every computer: a fleet's records would be taken for one aircraft's (`record trend`, \
             the fleet's SQL). Set [record] aircraft in the mapping, or give the computer a host \
             name of its own"
        );
    }
    let options = RecorderOptions {
        aircraft,
        ..RecorderOptions::default()
    };
    match Recorder::start_with(dir, &servos, limits, options) {
        Ok(handle) => {
            tracing::info!(file = ?handle.path(), "flight record started");
            Some(handle)
        }
        Err(e) => {
            tracing::warn!(
                "flight record disabled: cannot write in {}: {e}",
                dir.display()
            );
            None
        }
    }
}

/// Host names that system images give every computer they are written to (Raspberry Pi OS,
/// Debian's and Ubuntu's images, the common single-board computers' own): as an aircraft's
/// name they would make a fleet one aircraft.
const IMAGE_HOST_NAMES: [&str; 12] = [
    "raspberrypi",
    "debian",
    "ubuntu",
    "localhost",
    "orangepi",
    "nanopi",
    "rockpi",
    "radxa",
    "odroid",
    "beaglebone",
    "tegra-ubuntu",
    "jetson",
];

/// Whether `name` is a host name an image gives every computer ([`IMAGE_HOST_NAMES`], any
/// case, with or without a domain).
fn is_image_default(name: &str) -> bool {
    let short = name.split('.').next().unwrap_or(name).to_ascii_lowercase();
    IMAGE_HOST_NAMES.contains(&short.as_str())
}

/// The computer's host name, the aircraft's name when the mapping gives none.
fn host_name() -> Option<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname").ok()?;
    Some(name.trim().to_string()).filter(|n| !n.is_empty())
}

/// Run the bridge until `stop` turns true.
pub async fn run(
    cfg: Config,
    opts: RunOptions,
    stop: watch::Receiver<bool>,
) -> Result<(), RunError> {
    let service = opts.service;
    let mut bridge = Bridge::start(cfg, opts).await?;
    if service {
        bridge.ready().await;
    }
    bridge.serve(stop).await;
    if service {
        service::notify(&[sd_notify::NotifyState::Stopping]);
    }
    bridge.stop().await;
    Ok(())
}

/// A running bridge: the core, its buses and links, and the channels that feed its loop.
struct Bridge {
    cfg: Config,
    /// The autopilot, for the readers' admission of messages.
    known_autopilot: KnownAutopilot,
    core: BridgeCore,
    buses: Buses,
    record: Option<RecordHandle>,
    signing: Option<SharedSigning>,
    writers: Vec<LinkWriter>,
    /// Each link's admission of messages, for what it dropped (said at the stop).
    admissions: Vec<std::sync::Arc<std::sync::Mutex<crate::mavlink::admission::Admission>>>,
    /// The links (the autopilot's, then the ground station's), for what they count.
    links: Vec<Link>,
    /// The links' readers and the buses' event forwarders.
    tasks: Vec<tokio::task::JoinHandle<()>>,
    messages: mpsc::Receiver<(LinkId, MavHeader, MavMessage)>,
    bus_events: mpsc::UnboundedReceiver<(usize, BusEvent)>,
    edits: mpsc::Sender<ParamSet>,
    edited: mpsc::Receiver<EditResult>,
    mapping_writes: u64,
    view: Option<watch::Sender<BridgeView>>,
    view_at: Instant,
    texts: std::collections::VecDeque<String>,
    /// systemd's watchdog, once the bridge told it that it is ready.
    watchdog: Option<Watchdog>,
    /// Until the autopilot's first output message: since when the bridge waits, and when it
    /// next says so.
    no_autopilot: Option<(Instant, Instant, std::time::Duration)>,
    /// The DroneCAN node and its interface's task, with a `[dronecan]` table.
    can: Option<CanSide>,
}

/// The DroneCAN node (sans-IO) and the ends of its interface's task.
struct CanSide {
    node: CanNode,
    link: can::CanLink,
}

/// One input of the loop, in the order the loop prefers them.
enum Input {
    Stop,
    Message(LinkId, MavHeader, MavMessage),
    Edited(ParamSet, Result<Config, String>),
    BusEvent(usize, BusEvent),
    /// A CAN frame, and when it came.
    Can(CanFrame, Instant),
    Timeout,
    /// Only the view (nothing happened for [`VIEW_STALE`]), the watchdog's ping or the note
    /// that no autopilot has been heard is due.
    Housekeeping,
}

/// The real-time priority of the thread that runs the MAVLink loop: one below the bus
/// threads' ([`crate::bus::driver::REALTIME_PRIORITY`]), whose replies and deadlines come first.
pub const LOOP_PRIORITY: i32 = crate::bus::driver::REALTIME_PRIORITY - 1;

/// Ask for real-time scheduling (SCHED_FIFO at [`LOOP_PRIORITY`]) of the calling thread, the
/// one that runs the MAVLink loop: it receives the autopilot's output messages and writes their
/// goals to the buses, so a goal waits for no normal thread (a camera's, a logger's, a build)
/// that holds the CPU when the message comes. It reads the links too (no hop between threads for
/// the autopilot's datagram), takes 1–2 % of a core and sleeps between messages; a flood makes
/// it a normal thread while it lasts ([`governor`]). Threads it starts afterwards run as normal
/// ones. Refused without the grant the bus threads need too (their warning says which); then
/// only said at debug level. Returns whether it was granted (the thread then keeps within
/// [`governor::BUDGET`]).
fn request_realtime_loop() -> bool {
    match lj9da_realtime::request_fifo(LOOP_PRIORITY) {
        Ok(()) => {
            tracing::debug!("the MAVLink loop runs at SCHED_FIFO {LOOP_PRIORITY}");
            true
        }
        Err(e) => {
            tracing::debug!("the MAVLink loop runs without real-time scheduling: {e}");
            false
        }
    }
}

impl Bridge {
    /// Open the links and the buses, start the flight record and the tasks that feed the loop.
    async fn start(cfg: Config, opts: RunOptions) -> Result<Self, RunError> {
        let RunOptions {
            ports,
            view,
            record_dir,
            check_latency,
            mapping,
            service: _,
        } = opts;
        let realtime = check_latency && {
            // A run on the aircraft (the `run` command): its adapters and its memory.
            crate::deploy::check_buses(&cfg);
            crate::bus::driver::lock_memory();
            request_realtime_loop()
        };
        let addresses: Vec<String> = std::iter::once(&cfg.mavlink.connection)
            .chain(&cfg.mavlink.gcs)
            .cloned()
            .collect();
        // Sockets, parsing and signatures on the loop's thread (within a budget in `run`: see
        // `governor`); the loop takes only what the readers accepted.
        let mut links = Vec::with_capacity(addresses.len());
        for address in &addresses {
            links.push(links::connect(address).await?);
        }
        tracing::info!(connection = %cfg.mavlink.connection, gcs = ?cfg.mavlink.gcs, "MAVLink links set up; waiting for the autopilot");
        let signing = links::open_signing(&cfg, links.len(), record_dir.as_deref())?;
        let record = record_dir
            .filter(|_| cfg.record.enabled)
            .and_then(|dir| start_record(&cfg, &dir));
        let buses = Buses::spawn(&cfg, &ports, record.as_ref());
        let core = BridgeCore::new(cfg.clone(), Instant::now());

        let (message_tx, messages) = mpsc::channel(1024);
        let mut tasks = Vec::new();
        let mut writers = Vec::new();
        let mut admissions = Vec::new();
        let link_list = links.clone();
        let known_autopilot = KnownAutopilot::default();
        known_autopilot.set(core.autopilot());
        {
            for (link_id, (link, address)) in links.into_iter().zip(addresses).enumerate() {
                writers.push(LinkWriter::spawn(link.clone(), link_id, signing.clone()));
                let reader = links::spawn_reader(
                    link,
                    link_id,
                    address,
                    signing.clone(),
                    known_autopilot.clone(),
                    cfg.mavlink.autopilot_component_id,
                    message_tx.clone(),
                );
                tasks.extend(reader.tasks);
                admissions.push(reader.admission);
            }
        }
        if realtime {
            // From here on: the set-up's own work is not the loop's.
            tasks.push(tokio::spawn(governor::govern(LOOP_PRIORITY)));
        }
        let (event_tx, bus_events) = mpsc::unbounded_channel();
        for (i, bus) in buses.handles.iter().enumerate() {
            tasks.push(forward_bus_events(
                &cfg,
                i,
                bus,
                record.clone(),
                event_tx.clone(),
            ));
        }
        let (edits, edited) = spawn_mapping_writer(mapping);
        let can = cfg.dronecan.as_ref().map(|d| {
            let machine_id = std::fs::read_to_string("/etc/machine-id").ok();
            let unique_id = crate::can_node::unique_id(machine_id.as_deref());
            let node = CanNode::new(&cfg, unique_id, Instant::now())
                .expect("a [dronecan] table makes a node");
            let (link, task) = can::spawn(d.interface.clone());
            tasks.push(task);
            tracing::info!(interface = %d.interface, node_id = %d.node_id, commands = %cfg.bridge.commands, "DroneCAN node set up");
            CanSide { node, link }
        });
        Ok(Bridge {
            cfg,
            known_autopilot,
            core,
            buses,
            record,
            signing,
            writers,
            admissions,
            links: link_list,
            tasks,
            messages,
            bus_events,
            edits,
            edited,
            mapping_writes: 0,
            view,
            view_at: Instant::now(),
            texts: std::collections::VecDeque::with_capacity(VIEW_TEXTS),
            watchdog: None,
            no_autopilot: {
                let now = Instant::now();
                Some((now, now + NO_AUTOPILOT_NOTE, NO_AUTOPILOT_NOTE))
            },
            can,
        })
    }

    /// Tell systemd that the bridge is ready once every bus thread has made its first attempt
    /// at its port (the links are bound already), and start feeding its watchdog.
    async fn ready(&mut self) {
        let waited_from = Instant::now();
        let mut tick = tokio::time::interval(std::time::Duration::from_millis(5));
        while let Some(bus) = self.buses.handles.iter().find(|b| b.turns() == 0) {
            if waited_from.elapsed() >= service::READY_WAIT {
                tracing::warn!(bus = %bus.name(), "bus thread has not tried its port after {:?}: telling systemd the bridge is ready all the same", service::READY_WAIT);
                break;
            }
            tick.tick().await;
        }
        let open = self
            .buses
            .handles
            .iter()
            .filter(|b| b.status().port_open && b.turns() > 0)
            .count();
        let status = format!(
            "{} servos, {open} of {} buses open, autopilot link {}",
            self.cfg.servos.len(),
            self.buses.handles.len(),
            self.cfg.mavlink.connection
        );
        tracing::info!("ready: {status}");
        service::notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(&status),
        ]);
        self.watchdog = Watchdog::from_env(self.bus_turns(), Instant::now());
        self.feed_watchdog();
    }

    /// Every bus thread's turns so far, in bus order.
    fn bus_turns(&self) -> Vec<u64> {
        self.buses.handles.iter().map(BusHandle::turns).collect()
    }

    /// Ping systemd's watchdog if it is due and every bus thread has turned since the last
    /// ping; name a bus thread that has not, once per spell.
    fn feed_watchdog(&mut self) {
        let turns = self.bus_turns();
        let Some(watchdog) = self.watchdog.as_mut() else {
            return;
        };
        match watchdog.check(Instant::now(), &turns) {
            Verdict::NotDue => {}
            Verdict::Alive => {
                watchdog.untold(&[]);
                service::notify(&[sd_notify::NotifyState::Watchdog]);
            }
            Verdict::Stuck(stuck) => {
                for bus in watchdog.untold(&stuck) {
                    tracing::error!(
                        bus = %self.buses.handles[bus].name(),
                        "bus thread stuck: no turn in {:?}; systemd's watchdog is no longer fed",
                        watchdog.period()
                    );
                }
            }
        }
    }

    /// The loop: one input (and the messages already waiting) into the core, then everything
    /// it has to say out, until `stop`.
    async fn serve(&mut self, mut stop: watch::Receiver<bool>) {
        loop {
            match self.next_input(&mut stop).await {
                Input::Stop => return,
                Input::Message(link, header, msg) => {
                    self.core
                        .handle_message(link, &header, &msg, Instant::now());
                }
                Input::Edited(set, result) => {
                    self.core.param_set_done(&set, result, Instant::now());
                }
                Input::BusEvent(bus, event) => {
                    let bus_name = self.buses.handles[bus].name();
                    if event.is_trouble() {
                        tracing::warn!(bus = %bus_name, "{event}");
                    } else {
                        tracing::info!(bus = %bus_name, "{event}");
                    }
                    if let Some(e) = bridge_event(&self.cfg, &self.buses, bus, &event) {
                        self.core.event(e, Instant::now());
                    }
                }
                Input::Can(frame, at) => {
                    if let Some(can) = &mut self.can {
                        let had_id = can.node.node_id().is_some();
                        if let Some(commands) = can.node.handle_frame(&frame, at) {
                            self.core.handle_can_commands(&commands.commands, at);
                        }
                        if let (false, Some(id)) = (had_id, can.node.node_id()) {
                            tracing::info!(
                                node_id = id,
                                "DroneCAN: node id given by the bus's allocator"
                            );
                        }
                    }
                }
                Input::Timeout => {
                    let (reports, _) = self.buses.reports(&self.cfg);
                    let now = Instant::now();
                    self.core.handle_timeout(now, &reports);
                    if let Some(can) = &mut self.can {
                        can.node.handle_timeout(now, &reports);
                    }
                }
                Input::Housekeeping => {}
            }
            let mut goals = vec![Vec::new(); self.buses.handles.len()];
            self.collect_goals(&mut goals);
            // Messages already waiting are taken in this turn (a few at most, without waiting):
            // the messages of one autopilot tick that arrived together then reach each bus
            // under one lock, and its thread is woken once at most.
            for _ in 0..READY_MESSAGES {
                let Ok((link, header, msg)) = self.messages.try_recv() else {
                    break;
                };
                self.core
                    .handle_message(link, &header, &msg, Instant::now());
                self.collect_goals(&mut goals);
            }
            self.pass_param_sets();
            self.known_autopilot.set(self.core.autopilot());
            for (handle, batches) in self.buses.handles.iter().zip(goals) {
                if !batches.is_empty() {
                    handle.pass_goals(batches);
                }
            }
            self.pass_messages();
            self.pass_frames();
            self.say_notes();
            self.refresh_view();
            self.feed_watchdog();
            self.note_no_autopilot();
        }
    }

    /// Say, 10 s after the start and then every doubled interval up to a minute, that no
    /// output message of the autopilot's has been heard yet, and where the bridge listens.
    fn note_no_autopilot(&mut self) {
        let Some((since, next, every)) = self.no_autopilot else {
            return;
        };
        if self.core.outputs_heard() {
            self.no_autopilot = None;
            return;
        }
        let now = Instant::now();
        if now < next {
            return;
        }
        let secs = now.duration_since(since).as_secs();
        match (&self.cfg.dronecan, self.cfg.bridge.commands) {
            (Some(d), crate::config::CommandSource::DroneCan) => tracing::warn!(
                "no ArrayCommand for the servos heard for {secs} s on {}: the buses run \
                 meanwhile; check that the autopilot drives these outputs over DroneCAN \
                 (ArduPilot: CAN_Dn_PROTOCOL 1, CAN_Dn_UC_SRV_BM with the servos' outputs; PX4: \
                 UAVCAN_ENABLE, UAVCAN_SV_FUNCn), that the bus's bit rate is the autopilot's, and \
                 each servo's dronecan_id (ArduPilot numbers from 1, PX4 from 0)",
                d.interface
            ),
            _ => tracing::warn!(
                "no outputs heard from the autopilot for {secs} s on {}: the buses run meanwhile; \
                 check that the autopilot sends MAVLink there (ArduPilot: SERIALn_PROTOCOL = 2 on that \
                 port; PX4: MAV_n_CONFIG, or SER_<port>_PROTO on PX4 main), and that its system and \
                 component IDs are the mapping file's",
                self.cfg.mavlink.connection
            ),
        }
        let every = (every * 2).min(NO_AUTOPILOT_NOTE_MAX);
        self.no_autopilot = Some((since, now + every, every));
    }

    /// Wait for the next input: a stop first, then messages, finished parameter changes, bus
    /// events, and the core's deadline (none before an autopilot is found: the loop sleeps,
    /// waking only to refresh a view, if it has one, every [`VIEW_STALE`], and to ping systemd's
    /// watchdog, if it has one).
    async fn next_input(&mut self, stop: &mut watch::Receiver<bool>) -> Input {
        let core_deadline = self.core.poll_timeout();
        let view_deadline = self.view.as_ref().map(|_| self.view_at + VIEW_STALE);
        let watchdog_deadline = self.watchdog.as_ref().map(Watchdog::due_at);
        let note_deadline = self.no_autopilot.map(|(_, next, _)| next);
        let can_deadline = self.can.as_ref().map(|c| c.node.poll_timeout());
        let due = [core_deadline, can_deadline].into_iter().flatten().min();
        let deadline = [due, view_deadline, watchdog_deadline, note_deadline]
            .into_iter()
            .flatten()
            .min()
            .map(tokio::time::Instant::from_std);
        tokio::select! {
            biased;
            changed = stop.changed() => {
                if changed.is_err() || *stop.borrow() { Input::Stop } else { Input::Timeout }
            }
            Some((link, header, msg)) = self.messages.recv() => Input::Message(link, header, msg),
            Some((frame, at)) = can_frame(&mut self.can) => Input::Can(frame, at),
            Some((set, result)) = self.edited.recv() => Input::Edited(set, result),
            Some((bus, event)) = self.bus_events.recv() => Input::BusEvent(bus, event),
            _ = sleep_until(deadline) => {
                if due.is_some_and(|at| at <= Instant::now()) {
                    Input::Timeout
                } else {
                    Input::Housekeeping
                }
            }
        }
    }

    /// Parameter changes the core accepted go to the mapping file's writer (one at a time:
    /// the core gives the next once the last is done).
    fn pass_param_sets(&mut self) {
        while let Some(set) = self.core.poll_param_set() {
            let why = match self.edits.try_send(set) {
                Ok(()) => {
                    self.mapping_writes += 1;
                    continue;
                }
                Err(mpsc::error::TrySendError::Closed(set)) => (set, "no mapping file to change"),
                Err(mpsc::error::TrySendError::Full(set)) => (set, "the mapping file is busy"),
            };
            self.core
                .param_set_done(&why.0, Err(why.1.into()), Instant::now());
        }
    }

    /// The goals of the input just handled, per bus: an output message that carried a bus's
    /// servos is a tick of that bus's rhythm even when it changed no goal (`true`), and its
    /// goals leave in one long packet; goals no message brought are `false`.
    fn collect_goals(&mut self, per_bus: &mut [GoalBatches]) {
        let mut goals: Vec<Vec<(ServoId, crate::bus::Goal)>> =
            vec![Vec::new(); self.buses.handles.len()];
        let mut ticked = vec![false; self.buses.handles.len()];
        for servo in self.core.take_output_ticks() {
            if let Some((bus, _)) = self.buses.servo_at.get(servo) {
                ticked[*bus] = true;
            }
        }
        while let Some((servo, goal)) = self.core.poll_command() {
            if let Some((bus, id)) = self.buses.servo_at.get(servo) {
                goals[*bus].push((*id, goal));
            }
            if let Some(r) = &self.record {
                r.goal(servo, goal);
            }
        }
        if let Some(clock) = self.core.poll_autopilot_clock()
            && let Some(r) = &self.record
        {
            r.autopilot_clock(clock.at, clock.time_usec, clock.bits);
        }
        for ((batches, goals), ticked) in per_bus.iter_mut().zip(goals).zip(ticked) {
            if ticked || !goals.is_empty() {
                batches.push((ticked, goals));
            }
        }
    }

    /// The DroneCAN node's frames go to its interface's task (never waiting for it: a frame
    /// its queue cannot take is dropped and counted).
    fn pass_frames(&mut self) {
        let Some(can) = &mut self.can else {
            return;
        };
        while let Some(frame) = can.node.poll_frame() {
            if can.link.to_send.try_send(frame).is_err() {
                can.link
                    .dropped
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
        }
    }

    /// The core's messages go to the links' outboxes (never waiting for a link).
    fn pass_messages(&mut self) {
        let Some(header) = self.core.header() else {
            return;
        };
        while let Some(out) = self.core.poll_message() {
            if let MavMessage::STATUSTEXT(t) = &out.message {
                let text = t.text.to_str().unwrap_or("").to_string();
                if let Some(r) = &self.record {
                    r.event(None, t.severity as u8, text.clone());
                }
                if self.texts.len() == VIEW_TEXTS {
                    self.texts.pop_front();
                }
                self.texts.push_back(text);
            }
            let queued = Queued {
                header: out.sender.unwrap_or(header),
                message: out.message,
                relayed: out.sender.is_some(),
            };
            for (i, writer) in self.writers.iter().enumerate() {
                if out.link.is_none_or(|l| l == i) {
                    writer.queue(queued.clone());
                }
            }
        }
    }

    /// What the core has to tell the user about the autopilot link: warnings, and the output
    /// rate received (see [`crate::mavlink::rate`]); in the log and the flight record.
    fn say_notes(&mut self) {
        const WARNING: u8 = mavlink::dialects::common::MavSeverity::MAV_SEVERITY_WARNING as u8;
        const INFO: u8 = mavlink::dialects::common::MavSeverity::MAV_SEVERITY_INFO as u8;
        let notes = self.core.take_notes().into_iter().map(|n| (WARNING, n));
        let news = self.core.take_rate_news().into_iter().map(|n| (INFO, n));
        for (severity, text) in notes.chain(news) {
            if severity == WARNING {
                tracing::warn!("{text}");
            } else {
                tracing::info!("{text}");
            }
            if let Some(r) = &self.record {
                r.event(None, severity, text);
            }
        }
    }

    /// Refresh the view for the live table and the tests, at most every [`VIEW_PERIOD`].
    fn refresh_view(&mut self) {
        let Some(view) = self
            .view
            .as_ref()
            .filter(|_| self.view_at.elapsed() >= VIEW_PERIOD)
        else {
            return;
        };
        self.view_at = Instant::now();
        let statuses: Vec<BusStatus> = self.buses.handles.iter().map(BusHandle::status).collect();
        let (_, servos) = self.buses.reports_of(&self.cfg, &statuses);
        view.send_replace(BridgeView {
            servos,
            autopilot: self.core.autopilot(),
            failsafe: self.core.in_failsafe(),
            output_rate_hz: self.core.requested_rate_hz(),
            outputs_received_hz: self.core.received_rates_hz(),
            buses: statuses,
            texts: self.texts.iter().cloned().collect(),
            // Held by a reader or writer this instant: the counts of the last view stand.
            signing_drops: match self.signing.as_ref().map(SharedSigning::try_lock) {
                None => Vec::new(),
                Some(Some(signing)) => signing.drops(),
                Some(None) => view.borrow().signing_drops.clone(),
            },
            send_drops: self.writers.iter().map(LinkWriter::dropped).collect(),
            receive_drops: self.links.iter().map(Link::lost).collect(),
            mapping_writes: self.mapping_writes,
        });
    }

    /// Leave the servos as the mapping says, stop the tasks, close the flight record.
    async fn stop(self) {
        let leave = match self.cfg.bridge.on_exit {
            ForceAction::Hold => ShutdownForce::AsIs,
            ForceAction::Off => ShutdownForce::Off,
            ForceAction::Brake => ShutdownForce::Brake,
        };
        tracing::info!(?leave, "stopping: closing the buses");
        for bus in &self.buses.handles {
            bus.shutdown(leave).await;
        }
        for task in self.tasks {
            task.abort();
        }
        // The peers' readers live on the loop's runtime, which may outlive the bridge (`sitl`,
        // the tests): their sockets close now.
        for link in &self.links {
            link.close_peers();
        }
        for admission in &self.admissions {
            let summary = admission
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .summary();
            if let Some(summary) = summary {
                tracing::warn!("{summary}");
            }
        }
        if let Some(can) = &self.can {
            let dropped = can.link.dropped.load(std::sync::atomic::Ordering::Relaxed);
            let refused = can.node.refused();
            if dropped > 0 || *refused != crate::dronecan::node::Refused::default() {
                tracing::warn!(
                    dropped,
                    ?refused,
                    "DroneCAN: frames dropped (a queue full, the interface closed) and frames \
                     received that made no transfer, by why"
                );
            }
        }
        let unsent: usize = self.writers.iter().map(LinkWriter::waiting).sum();
        if unsent > 0 {
            tracing::debug!("{unsent} MAVLink messages left unsent at the stop");
        }
        drop(self.writers);
        if let Some(r) = self.record {
            let path = r.path();
            let stats = r.finish();
            tracing::info!(file = ?path, ?stats, "flight record closed");
        }
    }
}

/// The next frame of the DroneCAN interface; without one, never.
async fn can_frame(can: &mut Option<CanSide>) -> Option<(CanFrame, Instant)> {
    match can {
        Some(c) => c.link.received.recv().await,
        None => std::future::pending().await,
    }
}

/// Sleep until `deadline`; with none, forever (until another branch of a `select!` wins).
async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    #[cfg(unix)]
    {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(t) => t,
                Err(_) => return std::future::pending().await,
            };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

#[cfg(test)]
mod tests;
