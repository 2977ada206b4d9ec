//! The MAVLink links of a running bridge: opening them, their readers (verifying signatures
//! when signing is on) and their writers.
//!
//! Each link sends from an [`Outbox`] of its own, emptied by a task of its own: the bridge's
//! loop only queues, so a link whose peer does not read holds neither the other link nor a
//! goal, and loses its oldest telemetry first (counted, see [`LinkWriter::dropped`]).

use crate::config::Config;
use crate::mavlink::LinkId;
use crate::mavlink::outbox::{Outbox, Queued};
use crate::mavlink::signing::{self, Incoming, Signed, Signing, TimestampFile};
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::error::{MessageReadError, MessageWriteError};
use ::mavlink::{
    AsyncMavConnection, MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkReader, Message,
};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tokio::net::UdpSocket;
use tokio::sync::{Notify, mpsc, watch};
use tokio::task::JoinHandle;

use super::RunError;

/// How long a reader waits after a receive error before it reads again.
const RECEIVE_RETRY: Duration = Duration::from_millis(20);
/// How long after a failed write of a timestamp reservation it is tried again.
const RESERVATION_RETRY: Duration = Duration::from_secs(1);

/// One MAVLink link, carrying raw frames: the bridge numbers, signs and checks them itself.
#[derive(Clone)]
pub enum Link {
    /// `udpin`: the bridge's own socket (see [`UdpIn`]).
    UdpIn(Arc<UdpIn>),
    /// Every other kind of address: the `mavlink` crate's connection.
    Crate(Arc<::mavlink::AsyncConnection<MavMessage>>),
}

/// A `udpin` link. The `mavlink` crate's replies to whoever sent the last datagram, a dropped
/// one included: with signing on, a stranger's unsigned datagram would steer where the
/// bridge's signed messages go. Here the reply address changes only with a datagram that held
/// a frame the bridge accepted (with signing on, a correctly signed fresh one).
pub struct UdpIn {
    socket: UdpSocket,
    peer: Mutex<Option<SocketAddr>>,
}

impl UdpIn {
    /// Where replies go now (`None`: nobody has spoken yet).
    pub fn peer(&self) -> Option<SocketAddr> {
        *self.peer.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn set_peer(&self, from: SocketAddr) {
        *self.peer.lock().unwrap_or_else(PoisonError::into_inner) = Some(from);
    }
}

/// The frames of one UDP datagram, in order; what is not a frame is skipped.
pub fn frames_of(datagram: &[u8]) -> Vec<MAVLinkMessageRaw> {
    let mut reader = MavlinkReader::new(datagram);
    std::iter::from_fn(|| reader.read_any_raw_message::<MavMessage>().ok()).collect()
}

pub async fn connect(address: &str) -> Result<Link, RunError> {
    let failed = |source| RunError::Mavlink {
        address: address.to_string(),
        source,
    };
    if let Some(local) = address.strip_prefix("udpin:") {
        let socket = UdpSocket::bind(local).await.map_err(failed)?;
        return Ok(Link::UdpIn(Arc::new(UdpIn {
            socket,
            peer: Mutex::new(None),
        })));
    }
    let mut conn = ::mavlink::connect_async::<MavMessage>(address)
        .await
        .map_err(failed)?;
    conn.set_allow_recv_any_version(true);
    Ok(Link::Crate(Arc::new(conn)))
}

impl Link {
    /// The next frames and, for `udpin`, the address they came from.
    async fn recv(
        &self,
        buf: &mut [u8],
    ) -> Result<(Vec<MAVLinkMessageRaw>, Option<SocketAddr>), MessageReadError> {
        match self {
            Link::UdpIn(udp) => {
                let (n, from) = udp.socket.recv_from(buf).await?;
                Ok((frames_of(&buf[..n]), Some(from)))
            }
            Link::Crate(conn) => Ok((vec![conn.recv_raw().await?], None)),
        }
    }

    /// Whether a frame sent now goes anywhere (a `udpin` link nobody has spoken to has
    /// nowhere to send).
    fn can_send(&self) -> bool {
        match self {
            Link::UdpIn(udp) => udp.peer().is_some(),
            Link::Crate(_) => true,
        }
    }

    async fn send(&self, frame: &MAVLinkMessageRaw) -> Result<usize, MessageWriteError> {
        match self {
            Link::UdpIn(udp) => match udp.peer() {
                Some(peer) => Ok(udp.socket.send_to(raw_bytes(frame), peer).await?),
                None => Ok(0),
            },
            Link::Crate(conn) => conn.send_raw(frame).await,
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

/// What the reader makes of one frame from `link`: every parsed message without signing;
/// with it, only correctly signed fresh ones (the others are counted and, now and then,
/// logged with the link's `address`). `Some(None)`: accepted, but not a message of the dialect.
#[allow(clippy::option_option)]
fn judge(
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

/// A task that reads `link` and hands each message, with the link's id, to `to_core`; it ends
/// when the core is gone. A `udpin` link replies, from then on, to where the latest datagram
/// with an accepted frame came from.
pub fn spawn_reader(
    link: Link,
    link_id: LinkId,
    address: String,
    signing: Option<SharedSigning>,
    to_core: mpsc::Sender<(LinkId, MavHeader, MavMessage)>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut buf = vec![0u8; 65_536];
        loop {
            let (frames, from) = match link.recv(&mut buf).await {
                Ok(received) => received,
                Err(e) => {
                    tracing::debug!(link = link_id, "MAVLink receive: {e}");
                    tokio::time::sleep(RECEIVE_RETRY).await;
                    continue;
                }
            };
            for frame in &frames {
                let Some(accepted) = judge(frame, link_id, &address, signing.as_ref()) else {
                    continue;
                };
                if let (Link::UdpIn(udp), Some(from)) = (&link, from) {
                    udp.set_peer(from);
                }
                if let Some((header, msg)) = accepted
                    && to_core.send((link_id, header, msg)).await.is_err()
                {
                    return;
                }
            }
        }
    })
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

fn lock(outbox: &Mutex<Outbox>) -> MutexGuard<'_, Outbox> {
    outbox.lock().unwrap_or_else(PoisonError::into_inner)
}
