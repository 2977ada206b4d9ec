//! The MAVLink links of a running bridge: opening them, their readers (verifying signatures
//! when signing is on) and their writers, all tasks on the loop's own thread (see
//! [`super::governor`] for what keeps a flood from holding it at real-time priority).
//!
//! Each link sends from an [`Outbox`] of its own, emptied by a task of its own: the bridge's
//! loop only queues, so a link whose peer does not read holds neither the other link nor a
//! goal, and loses its oldest telemetry first (counted, see [`LinkWriter::dropped`]).

use crate::config::Config;
use crate::mavlink::LinkId;
use crate::mavlink::admission::{Admission, Sender, Verdict};
use crate::mavlink::outbox::{Outbox, Queued};
use crate::mavlink::signing::{self, Incoming, Signed, Signing, TimestampFile};
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::error::{MessageReadError, MessageWriteError};
use ::mavlink::{
    AsyncMavConnection, MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkReader, Message,
};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tokio::sync::{Notify, mpsc, watch};
use tokio::task::JoinHandle;

use super::RunError;
use super::udp::{self, UdpIn};

/// How long a reader waits after a receive error before it reads again.
const RECEIVE_RETRY: Duration = Duration::from_millis(20);
/// How often a link through the `mavlink` crate that is down is opened again.
const RECONNECT_EVERY: Duration = Duration::from_secs(1);
/// How long after a failed write of a timestamp reservation it is tried again.
const RESERVATION_RETRY: Duration = Duration::from_secs(1);

/// One MAVLink link, carrying raw frames: the bridge numbers, signs and checks them itself.
#[derive(Clone)]
pub enum Link {
    /// `udpin`: the bridge's own socket (see [`UdpIn`]).
    UdpIn(Arc<UdpIn>),
    /// Every other kind of address: the `mavlink` crate's connection, opened again whenever
    /// it fails (see [`CrateLink`]).
    Crate(Arc<CrateLink>),
}

type Connection = Arc<::mavlink::AsyncConnection<MavMessage>>;

/// A link through the `mavlink` crate (`tcpout`, `tcpin`, `udpout`, `udpbcast`, `serial`). The
/// autopilot may not be there yet when the bridge starts (SITL, or a flight controller still
/// booting behind a USB port), and may go away (a reboot ends a TCP connection, a USB port
/// disappears): a task of the link's own opens the connection, and opens it again after a
/// failure, every [`RECONNECT_EVERY`]. Meanwhile the reader waits and the writer's frames are
/// dropped (a link that is down takes nothing).
pub struct CrateLink {
    address: String,
    /// The open connection (`None` while it is down).
    open: watch::Sender<Option<Connection>>,
    /// Wakes the opening task when the connection failed (or the link is dropped).
    failed: Arc<Notify>,
    /// Attempts to open the connection that failed, since the start.
    failed_opens: Arc<std::sync::atomic::AtomicU64>,
}

impl Drop for CrateLink {
    fn drop(&mut self) {
        self.failed.notify_one();
    }
}

impl CrateLink {
    /// The link to `address`, and its opening task (which ends when the link is dropped).
    fn start(address: &str) -> Arc<Self> {
        let link = Arc::new(CrateLink {
            address: address.to_string(),
            open: watch::Sender::new(None),
            failed: Arc::new(Notify::new()),
            failed_opens: Arc::default(),
        });
        let (weak, failed, failed_opens, address) = (
            Arc::downgrade(&link),
            link.failed.clone(),
            link.failed_opens.clone(),
            address.to_string(),
        );
        // The task holds the link only between its waits, so that dropping the link ends it.
        tokio::spawn(async move {
            let mut failures = 0u64;
            loop {
                if weak.strong_count() == 0 {
                    return;
                }
                let opened = ::mavlink::connect_async::<MavMessage>(&address).await;
                let Some(link) = weak.upgrade() else { return };
                match opened {
                    Ok(mut conn) => {
                        conn.set_allow_recv_any_version(true);
                        if failures > 0 {
                            tracing::info!(%address, "MAVLink connection open");
                        }
                        failures = 0;
                        let wait = failed.notified();
                        link.open.send_replace(Some(Arc::new(conn)));
                        drop(link);
                        wait.await;
                    }
                    Err(e) => {
                        if failures == 0 {
                            tracing::warn!(
                                %address,
                                "cannot open the MAVLink connection: {e}; trying again every {} s, the buses run meanwhile",
                                RECONNECT_EVERY.as_secs()
                            );
                        }
                        failures += 1;
                        failed_opens.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        drop(link);
                        tokio::time::sleep(RECONNECT_EVERY).await;
                    }
                }
            }
        });
        link
    }

    /// The open connection, waiting for one while the link is down.
    async fn connection(&self) -> Connection {
        let mut open = self.open.subscribe();
        loop {
            if let Some(conn) = open.borrow_and_update().clone() {
                return conn;
            }
            // The sender lives as long as `self`.
            let _ = open.changed().await;
        }
    }

    /// `conn` failed with `e`: when `e` means the connection is gone, it is dropped (if it is
    /// still the open one) and opened again.
    fn check(&self, conn: &Connection, e: &std::io::Error) {
        if !connection_gone(e) {
            return;
        }
        let dropped = self.open.send_if_modified(|open| {
            let same = open.as_ref().is_some_and(|c| Arc::ptr_eq(c, conn));
            if same {
                *open = None;
            }
            same
        });
        if dropped {
            tracing::warn!(address = %self.address, "MAVLink connection lost: {e}; opening it again");
            self.failed.notify_one();
        }
    }
}

/// Whether an error of a connection's read or write means it is gone for good (the peer
/// closed it, or its device disappeared), rather than one bad moment (a UDP peer not
/// listening yet answers with ECONNREFUSED, and the next datagram may get through).
fn connection_gone(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        UnexpectedEof | ConnectionReset | ConnectionAborted | BrokenPipe | NotConnected
    ) || matches!(
        e.raw_os_error(),
        Some(libc::EIO | libc::ENXIO | libc::ENODEV | libc::EBADF)
    )
}

/// The frames of one UDP datagram, in order; what is not a frame is skipped. A datagram is
/// whole: a start byte whose frame would run past the datagram's end starts no frame, and the
/// frames after it are read. (A byte stream's reader waits there for the rest of that frame;
/// over UDP none comes, and junk or a cut frame before the frames of a datagram would lose
/// them all.)
pub fn frames_of(datagram: &[u8]) -> Vec<MAVLinkMessageRaw> {
    let mut frames = Vec::new();
    let mut at = 0;
    while at < datagram.len() {
        let Some(length) = frame_length(&datagram[at..]).filter(|n| at + n <= datagram.len())
        else {
            at += 1;
            continue;
        };
        // Exactly the bytes of one frame: the reader takes it if its checksum is right.
        let mut reader = MavlinkReader::new(&datagram[at..at + length]);
        match reader.read_any_raw_message::<MavMessage>() {
            Ok(frame) if raw_bytes(&frame).len() == length => {
                frames.push(frame);
                at += length;
            }
            _ => at += 1,
        }
    }
    frames
}

/// The length of the frame that `bytes` starts, from its header (`None`: no start byte, or
/// too few bytes for a header).
fn frame_length(bytes: &[u8]) -> Option<usize> {
    match bytes {
        // MAVLink 1: start, length, sequence, system, component, message id; checksum.
        [0xFE, len, ..] => Some(6 + usize::from(*len) + 2),
        // MAVLink 2: start, length, incompatibility and compatibility flags, sequence, system,
        // component, message id (3); checksum; a signature when the first flag says so.
        [0xFD, len, flags, ..] => {
            let signature = if flags & 0x01 != 0 { 13 } else { 0 };
            Some(10 + usize::from(*len) + 2 + signature)
        }
        _ => None,
    }
}

/// The link to `address`: a `udpin` socket is bound now (an error if it cannot be); the other
/// kinds open in the background, and again whenever they fail (see [`CrateLink`]).
pub async fn connect(address: &str) -> Result<Link, RunError> {
    let failed = |source| RunError::Mavlink {
        address: address.to_string(),
        source,
    };
    if let Some(local) = address.strip_prefix("udpin:") {
        return Ok(Link::UdpIn(Arc::new(
            UdpIn::bind(address, local).map_err(failed)?,
        )));
    }
    Ok(Link::Crate(CrateLink::start(address)))
}

impl Link {
    /// The next frames and, for `udpin`, the address they came from.
    async fn recv(
        &self,
        buf: &mut [u8],
    ) -> Result<(Vec<MAVLinkMessageRaw>, Option<SocketAddr>), MessageReadError> {
        match self {
            Link::UdpIn(udp) => {
                let (n, from) = udp.recv_from(buf).await?;
                Ok((frames_of(&buf[..n]), Some(from)))
            }
            Link::Crate(link) => {
                let conn = link.connection().await;
                match conn.recv_raw().await {
                    Ok(frame) => Ok((vec![frame], None)),
                    Err(MessageReadError::Io(e)) => {
                        link.check(&conn, &e);
                        Err(MessageReadError::Io(e))
                    }
                    Err(e) => Err(e),
                }
            }
        }
    }

    /// Stop the tasks that read a `udpin` link's peers' own sockets (nothing on the others).
    pub fn close_peers(&self) {
        if let Link::UdpIn(udp) = self {
            udp.close_peers();
        }
    }

    /// Datagrams the kernel dropped before the bridge read them: counted on `udpin` links
    /// (0 on the others, which cannot tell).
    pub fn lost(&self) -> u64 {
        match self {
            Link::UdpIn(udp) => udp.lost(),
            Link::Crate(_) => 0,
        }
    }

    /// Whether a frame sent now goes anywhere (a `udpin` link nobody has spoken to has
    /// nowhere to send).
    fn can_send(&self) -> bool {
        match self {
            Link::UdpIn(udp) => udp.has_peers(),
            Link::Crate(link) => link.open.borrow().is_some(),
        }
    }

    async fn send(&self, frame: &MAVLinkMessageRaw) -> Result<usize, MessageWriteError> {
        match self {
            Link::UdpIn(udp) => Ok(udp.send(raw_bytes(frame)).await?),
            Link::Crate(link) => {
                let Some(conn) = link.open.borrow().clone() else {
                    return Ok(0);
                };
                let sent = conn.send_raw(frame).await;
                if let Err(MessageWriteError::Io(e)) = &sent {
                    link.check(&conn, e);
                }
                sent
            }
        }
    }
}

fn raw_bytes(frame: &MAVLinkMessageRaw) -> &[u8] {
    match frame {
        MAVLinkMessageRaw::V1(f) => f.raw_bytes(),
        MAVLinkMessageRaw::V2(f) => f.raw_bytes(),
    }
}

/// MAVLink 2 signing, shared by the links' readers and writers, where the timestamp
/// reservations it asks for go to be written (by [`keep_reservations`]), and the latest one
/// written (which a writer waiting for a reservation watches).
#[derive(Clone)]
pub struct SharedSigning {
    signing: Arc<Mutex<Signing>>,
    reservations: watch::Sender<u64>,
    stored: watch::Receiver<u64>,
}

impl SharedSigning {
    pub fn lock(&self) -> MutexGuard<'_, Signing> {
        self.signing.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The signing, unless a reader or writer holds it now (across no wait: on the loop's one
    /// thread, it never does).
    pub fn try_lock(&self) -> Option<MutexGuard<'_, Signing>> {
        match self.signing.try_lock() {
            Ok(guard) => Some(guard),
            Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }
}

/// Signing for `links` links as the mapping asks (`None`: off). The timestamp file of a mapping
/// given without a file goes in the flight record's folder, or the temporary folder.
pub fn open_signing(
    cfg: &Config,
    links: usize,
    record_dir: Option<&std::path::Path>,
) -> Result<Option<SharedSigning>, RunError> {
    let Some(setup) = &cfg.mavlink.signing else {
        return Ok(None);
    };
    let path = setup.timestamp_file.clone().unwrap_or_else(|| {
        record_dir
            .map(std::path::Path::to_path_buf)
            .unwrap_or_else(std::env::temp_dir)
            .join("lj9da-bridge.signing-timestamp")
    });
    let file = TimestampFile::new(&path);
    let signing = Arc::new(Mutex::new(Signing::open(
        setup.key.clone(),
        links,
        &file,
        signing::now(),
    )?));
    tracing::info!(timestamp_file = %path.display(), "MAVLink 2 signing on: every message signed, unsigned ones dropped");
    let (reservations, pending) = watch::channel(0);
    let (stored_tx, stored) = watch::channel(0);
    tokio::spawn(keep_reservations(file, signing.clone(), pending, stored_tx));
    Ok(Some(SharedSigning {
        signing,
        reservations,
        stored,
    }))
}

/// Write each new signing timestamp reservation, off the send path (a write waits for the
/// disk), and tell the signing and the waiting writers once it is in the file; the latest one
/// wins if they come faster than the disk. A failed write is tried again every
/// [`RESERVATION_RETRY`]: meanwhile nothing is signed beyond the reservation in the file.
/// Ends with the bridge.
async fn keep_reservations(
    file: TimestampFile,
    signing: Arc<Mutex<Signing>>,
    mut pending: watch::Receiver<u64>,
    stored: watch::Sender<u64>,
) {
    let mut failing = false;
    while pending.changed().await.is_ok() {
        loop {
            let reservation = *pending.borrow_and_update();
            let f = file.clone();
            match tokio::task::spawn_blocking(move || f.store(reservation)).await {
                Ok(Ok(())) => {
                    if std::mem::take(&mut failing) {
                        tracing::info!("signing timestamp reservation written again");
                    }
                    signing
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .reservation_stored(reservation);
                    stored.send_replace(reservation);
                    break;
                }
                Ok(Err(e)) => {
                    if !std::mem::replace(&mut failing, true) {
                        tracing::warn!(
                            "{e}; retrying every second, and nothing is signed past the last reservation written"
                        );
                    }
                    tokio::time::sleep(RESERVATION_RETRY).await;
                }
                Err(_) => return,
            }
        }
    }
}

/// The autopilot's system and component as the loop knows them, for the readers (see
/// [`Admission`]): 0 until it is known.
#[derive(Clone, Default)]
pub struct KnownAutopilot(Arc<AtomicU32>);

impl KnownAutopilot {
    pub fn set(&self, autopilot: Option<(u8, u8)>) {
        let packed = autopilot.map_or(0, |(s, c)| 0x1_0000 | u32::from(s) << 8 | u32::from(c));
        self.0.store(packed, Ordering::Relaxed);
    }

    pub fn get(&self) -> Option<(u8, u8)> {
        let packed = self.0.load(Ordering::Relaxed);
        (packed != 0).then_some(((packed >> 8) as u8, packed as u8))
    }
}

/// What the reader makes of one frame from `link`: every parsed message without signing;
/// with it, only correctly signed fresh ones (the others are counted and, now and then,
/// logged with the link's `address`). `Some(None)`: accepted, but not a message of the dialect.
#[allow(clippy::option_option)]
pub(crate) fn judge(
    frame: &MAVLinkMessageRaw,
    link_id: LinkId,
    address: &str,
    signing: Option<&SharedSigning>,
) -> Option<Option<(MavHeader, MavMessage)>> {
    let Some(signing) = signing else {
        let header = MavHeader {
            system_id: frame.system_id(),
            component_id: frame.component_id(),
            sequence: frame.sequence(),
        };
        let message = MavMessage::parse(frame.version(), frame.message_id(), frame.payload());
        return Some(message.ok().map(|m| (header, m)));
    };
    let incoming = signing
        .lock()
        .receive(link_id, frame, signing::now(), Instant::now());
    match incoming {
        Incoming::Message(header, message) => Some(Some((header, message))),
        Incoming::Unknown => Some(None),
        Incoming::Radio => None,
        Incoming::Dropped { warning, .. } => {
            if let Some(w) = warning {
                tracing::warn!(%address, "{w}");
            }
            None
        }
    }
}

/// What a link's readers share: where accepted messages go, and how they are judged.
struct Reader {
    link: Link,
    link_id: LinkId,
    address: String,
    signing: Option<SharedSigning>,
    autopilot: KnownAutopilot,
    admission: Arc<Mutex<Admission>>,
    /// Wakes the admission's keeper (see [`keep_admission`]): a message was held or dropped.
    keeper: Notify,
    to_core: mpsc::Sender<(LinkId, MavHeader, MavMessage)>,
}

impl Reader {
    /// Take the frames of one datagram (or one frame of a stream) from `from`: each accepted
    /// and admitted message to the core. On a `udpin` link, a datagram with an accepted frame
    /// makes its sender a peer; a new peer's own socket is read by a task of its own from
    /// then on. `false`: the core is gone.
    async fn take(
        self: &Arc<Self>,
        frames: &[MAVLinkMessageRaw],
        from: Option<SocketAddr>,
    ) -> bool {
        for frame in frames {
            let Some(accepted) = judge(frame, self.link_id, &self.address, self.signing.as_ref())
            else {
                continue;
            };
            if let (Link::UdpIn(udp), Some(from)) = (&self.link, from)
                && let Some(socket) = udp.heard(from)
            {
                self.read_own(udp, from, socket);
            }
            let Some((header, msg)) = accepted else {
                continue;
            };
            let verdict = lock(&self.admission).judge(
                &header,
                &msg,
                Sender::of(from),
                self.autopilot.get(),
                Instant::now(),
            );
            if matches!(verdict, Verdict::Held | Verdict::OverBudget) {
                self.keeper.notify_one();
            }
            if verdict == Verdict::Pass
                && self
                    .to_core
                    .send((self.link_id, header, msg))
                    .await
                    .is_err()
            {
                return false;
            }
        }
        true
    }

    /// Read `peer`'s own socket from now on. What waits in the listening socket's queue is
    /// taken first (at most [`HANDOVER`] datagrams), so that the peer's messages reach the
    /// core in the order they were sent.
    fn read_own(self: &Arc<Self>, udp: &Arc<UdpIn>, peer: SocketAddr, socket: Arc<udp::Socket>) {
        let reader = self.clone();
        let udp_in = udp.clone();
        let task = tokio::spawn(async move {
            let mut buf = vec![0u8; 65_536];
            for _ in 0..HANDOVER {
                match udp_in.try_recv_from(&mut buf) {
                    Ok(Some((n, from))) => {
                        if !reader.take(&frames_of(&buf[..n]), Some(from)).await {
                            return;
                        }
                    }
                    Ok(None) => break,
                    Err(e) => {
                        tracing::debug!(link = reader.link_id, "MAVLink receive: {e}");
                        break;
                    }
                }
            }
            loop {
                match udp_in.recv_own(peer, &socket, &mut buf).await {
                    Ok((n, from)) => {
                        if !reader.take(&frames_of(&buf[..n]), Some(from)).await {
                            return;
                        }
                    }
                    Err(e) => {
                        tracing::debug!(link = reader.link_id, %peer, "MAVLink receive: {e}");
                        tokio::time::sleep(RECEIVE_RETRY).await;
                    }
                }
            }
        });
        udp.reading(peer, task.abort_handle());
    }
}

/// At most this many datagrams of the listening socket are taken before a new peer's own
/// socket is read.
const HANDOVER: usize = 1024;

/// A link's reader: its tasks, and its admission (for what it dropped, said at exit).
pub struct SpawnedReader {
    pub tasks: [JoinHandle<()>; 2],
    pub admission: Arc<Mutex<Admission>>,
}

/// A task that reads `link` and hands each message, with the link's id, to `to_core` (see
/// [`Reader::take`]), and one that hands on the PARAM_SETs its admission held and says what it
/// dropped ([`keep_admission`]); the reader ends when the core is gone. A `udpin` link sends,
/// from then on, to every address a datagram with an accepted frame came from recently.
/// `autopilot_component`: the mapping's.
#[allow(clippy::too_many_arguments)]
pub fn spawn_reader(
    link: Link,
    link_id: LinkId,
    address: String,
    signing: Option<SharedSigning>,
    autopilot: KnownAutopilot,
    autopilot_component: u8,
    to_core: mpsc::Sender<(LinkId, MavHeader, MavMessage)>,
) -> SpawnedReader {
    let admission = Arc::new(Mutex::new(Admission::new(
        link_id,
        autopilot_component,
        Instant::now(),
    )));
    let reader = Arc::new(Reader {
        link,
        link_id,
        address,
        signing,
        autopilot,
        admission: admission.clone(),
        keeper: Notify::new(),
        to_core,
    });
    let keeper = tokio::spawn(keep_admission(reader.clone()));
    let task = tokio::spawn(async move {
        let mut buf = vec![0u8; 65_536];
        loop {
            let (frames, from) = match reader.link.recv(&mut buf).await {
                Ok(received) => received,
                Err(e) => {
                    tracing::debug!(link = link_id, "MAVLink receive: {e}");
                    tokio::time::sleep(RECEIVE_RETRY).await;
                    continue;
                }
            };
            if !reader.take(&frames, from).await {
                return;
            }
        }
    });
    SpawnedReader {
        tasks: [task, keeper],
        admission,
    }
}

/// Hand on the PARAM_SETs `reader`'s admission held as their senders' budgets refill, and say
/// what it dropped and coalesced when due; asleep while nothing is held or to be said. Ends
/// when the core is gone.
async fn keep_admission(reader: Arc<Reader>) {
    loop {
        let next = lock(&reader.admission).next_due(Instant::now());
        match next {
            None => reader.keeper.notified().await,
            Some(at) => {
                tokio::select! {
                    () = tokio::time::sleep_until(at.into()) => {}
                    () = reader.keeper.notified() => {}
                }
            }
        }
        let now = Instant::now();
        let (released, news) = {
            let mut admission = lock(&reader.admission);
            (admission.release(now), admission.news(now))
        };
        if let Some(news) = news {
            tracing::warn!(address = %reader.address, "{news}");
        }
        for (header, msg) in released {
            if reader
                .to_core
                .send((reader.link_id, header, msg))
                .await
                .is_err()
            {
                return;
            }
        }
    }
}

/// The frame of `queued` with sequence number `sequence`, signed when signing is on; waits,
/// when a signed peer's clock has pushed the timestamps past the reservation in the file,
/// until a reservation above them is written.
async fn frame_of(
    link_id: LinkId,
    signing: Option<&SharedSigning>,
    queued: &Queued,
    sequence: u8,
) -> MAVLinkMessageRaw {
    let header = MavHeader {
        sequence,
        ..queued.header
    };
    let Some(signing) = signing else {
        let mut frame = MAVLinkV2MessageRaw::new();
        frame.serialize_message(header, &queued.message);
        return MAVLinkMessageRaw::V2(frame);
    };
    let mut stored = signing.stored.clone();
    loop {
        let signed = signing
            .lock()
            .sign(link_id, header, &queued.message, signing::now());
        match signed {
            Signed::Frame(frame, reserve) => {
                if let Some(r) = reserve {
                    signing.reservations.send_replace(r);
                }
                return frame;
            }
            Signed::Wait { needed, reserve } => {
                if let Some(r) = reserve {
                    signing.reservations.send_replace(r);
                }
                // Ends when the reservation is written; the bridge's stop ends the task.
                let _ = stored.wait_for(|r| *r > needed).await;
            }
        }
    }
}

/// One link's writer: the bridge queues into its [`Outbox`] without waiting; a task of its own
/// numbers what is queued, signs it when signing is on, and sends it as fast as the link takes
/// it. The bridge's own frames are numbered per link as they leave (a message dropped from the
/// outbox leaves no gap); a relayed message keeps its sender's number.
pub struct LinkWriter {
    outbox: Arc<Mutex<Outbox>>,
    ready: Arc<Notify>,
    task: JoinHandle<()>,
}

impl LinkWriter {
    pub fn spawn(link: Link, link_id: LinkId, signing: Option<SharedSigning>) -> Self {
        let outbox = Arc::new(Mutex::new(Outbox::default()));
        let ready = Arc::new(Notify::new());
        let task = {
            let (outbox, ready) = (outbox.clone(), ready.clone());
            tokio::spawn(async move {
                let mut sequence: u8 = 0;
                loop {
                    let next = lock(&outbox).pop();
                    let Some(queued) = next else {
                        ready.notified().await;
                        continue;
                    };
                    if !link.can_send() {
                        continue;
                    }
                    let number = if queued.relayed {
                        queued.header.sequence
                    } else {
                        let n = sequence;
                        sequence = sequence.wrapping_add(1);
                        n
                    };
                    let frame = frame_of(link_id, signing.as_ref(), &queued, number).await;
                    if let Err(e) = link.send(&frame).await {
                        tracing::debug!(link = link_id, "MAVLink send: {e}");
                    }
                }
            })
        };
        LinkWriter {
            outbox,
            ready,
            task,
        }
    }

    /// Queue `queued` for sending; never waits.
    pub fn queue(&self, queued: Queued) {
        lock(&self.outbox).push(queued);
        self.ready.notify_one();
    }

    /// Messages dropped because the link did not keep up.
    pub fn dropped(&self) -> u64 {
        lock(&self.outbox).dropped()
    }

    /// Messages still waiting.
    pub fn waiting(&self) -> usize {
        lock(&self.outbox).len()
    }
}

impl Drop for LinkWriter {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn lock<T>(outbox: &Mutex<T>) -> MutexGuard<'_, T> {
    outbox.lock().unwrap_or_else(PoisonError::into_inner)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A datagram is whole: junk, or the start of a frame cut short, before or between frames
    /// loses none of them.
    #[test]
    fn a_start_byte_whose_frame_runs_past_the_datagram_loses_no_frame_after_it() {
        let sequences =
            |bytes: &[u8]| -> Vec<u8> { frames_of(bytes).iter().map(|f| f.sequence()).collect() };
        let two = [heartbeat(1), heartbeat(2)].concat();
        assert_eq!(sequences(&two), [1, 2]);
        // A MAVLink 1 start byte announcing 64 bytes, then two frames (fewer than 64 bytes
        // follow the header it would have).
        assert_eq!(sequences(&[&[0xFE, 0x40][..], &two].concat()), [1, 2]);
        // A MAVLink 2 header cut short.
        assert_eq!(
            sequences(&[&[0xFD, 0x20, 0x00][..], &heartbeat(3)].concat()),
            [3]
        );
        // A frame cut short between two whole ones.
        let cut = &heartbeat(4)[..9];
        assert_eq!(
            sequences(&[heartbeat(5), cut.to_vec(), heartbeat(6)].concat()),
            [5, 6]
        );
        // A frame with a bad checksum is skipped, the next one kept.
        let mut bad = heartbeat(7);
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        assert_eq!(sequences(&[bad, heartbeat(8)].concat()), [8]);
        // Junk only.
        assert_eq!(sequences(&[0xFD; 300]), Vec::<u8>::new());
    }

    /// A heartbeat frame numbered `sequence`, as the autopilot sends it.
    fn heartbeat(sequence: u8) -> Vec<u8> {
        use ::mavlink::dialects::common::HEARTBEAT_DATA;
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence,
        };
        let mut bytes = Vec::new();
        ::mavlink::write_v2_msg(
            &mut bytes,
            header,
            &MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()),
        )
        .unwrap();
        bytes
    }

    /// A TCP port nobody listens on.
    fn unused_port() -> u16 {
        std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    }

    /// `peer`, connected to `link`, sends a heartbeat numbered `sequence` and closes the
    /// connection: the frame arrives, and the link's next read fails (the link is down until
    /// it is open again).
    async fn one_heartbeat_then_gone(link: &Link, mut peer: tokio::net::TcpStream, sequence: u8) {
        use tokio::io::AsyncWriteExt;
        let wait = Duration::from_secs(10);
        let mut buf = vec![0u8; 1024];
        peer.write_all(&heartbeat(sequence)).await.unwrap();
        let (frames, _) = tokio::time::timeout(wait, link.recv(&mut buf))
            .await
            .expect("the frame arrives")
            .unwrap();
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].sequence(), sequence);
        assert!(link.can_send());
        drop(peer);
        let ended = tokio::time::timeout(wait, link.recv(&mut buf))
            .await
            .unwrap();
        assert!(ended.is_err(), "{:?}", ended.map(|(f, _)| f.len()));
    }

    /// A `tcpout` link whose peer is not there yet opens when it comes, and opens again after
    /// the peer closed the connection (an autopilot's reboot), with frames flowing each time.
    #[tokio::test]
    async fn a_tcp_link_opens_when_its_peer_comes_and_again_after_it_left() {
        let wait = Duration::from_secs(10);
        let port = unused_port();
        let link = connect(&format!("tcpout:127.0.0.1:{port}")).await.unwrap();
        // Once an attempt to connect has failed, the link has nowhere to send.
        let Link::Crate(crate_link) = &link else {
            panic!("a tcpout link is the mavlink crate's")
        };
        let started = tokio::time::Instant::now();
        while crate_link
            .failed_opens
            .load(std::sync::atomic::Ordering::Relaxed)
            == 0
        {
            assert!(
                started.elapsed() < wait,
                "no attempt to connect in {wait:?}"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert!(!link.can_send(), "nobody listens yet");
        let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
            .await
            .unwrap();
        for sequence in [7, 8] {
            let (peer, _) = tokio::time::timeout(wait, listener.accept())
                .await
                .expect("the link connects within a few retries")
                .unwrap();
            one_heartbeat_then_gone(&link, peer, sequence).await;
        }
    }

    /// A `tcpin` link does not hold the bridge's start until a client connects: it is there at
    /// once, with nowhere to send. A client's frames arrive; when the client leaves, the link
    /// listens again and takes the next one (a ground station that reconnects).
    #[tokio::test]
    async fn a_tcp_listening_link_takes_a_client_and_the_next_after_it_left() {
        let wait = Duration::from_secs(10);
        let port = unused_port();
        let link = tokio::time::timeout(wait, connect(&format!("tcpin:127.0.0.1:{port}")))
            .await
            .expect("the link is made without waiting for a client")
            .unwrap();
        // Once it listens (the port is taken), with no client, it has nowhere to send.
        let started = tokio::time::Instant::now();
        while std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            assert!(started.elapsed() < wait, "not listening after {wait:?}");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert!(!link.can_send(), "no client yet");
        for sequence in [3, 4] {
            // The link binds its port again after the last client left: it may not be
            // listening the moment the client tries.
            let started = tokio::time::Instant::now();
            let client = loop {
                match tokio::net::TcpStream::connect(("127.0.0.1", port)).await {
                    Ok(client) => break client,
                    Err(e) if started.elapsed() < wait => {
                        tracing::debug!("not listening yet: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                    Err(e) => panic!("the link listens again within {wait:?}: {e}"),
                }
            };
            one_heartbeat_then_gone(&link, client, sequence).await;
        }
    }
}
