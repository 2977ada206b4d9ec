//! The MAVLink links of a running bridge: opening them, their readers (verifying signatures
//! when signing is on) and their writers.
//!
//! Each link sends from an [`Outbox`] of its own, emptied by a task of its own: the bridge's
//! loop only queues, so a link whose peer does not read holds neither the other link nor a
//! goal, and loses its oldest telemetry first (counted, see [`LinkWriter::dropped`]).

use crate::config::Config;
use crate::mavlink::LinkId;
use crate::mavlink::outbox::Outbox;
use crate::mavlink::signing::{self, Incoming, Signing, TimestampFile};
use ::mavlink::dialects::common::MavMessage;
use ::mavlink::{AsyncMavConnection, MavHeader};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tokio::sync::{Notify, mpsc, watch};
use tokio::task::JoinHandle;

use super::RunError;

pub type Link = Arc<::mavlink::AsyncConnection<MavMessage>>;

/// How long a reader waits after a receive error before it reads again.
const RECEIVE_RETRY: Duration = Duration::from_millis(20);

/// MAVLink 2 signing, shared by the links' readers and writers, and where the timestamp
/// reservations it asks for go to be written (by [`keep_reservations`]).
#[derive(Clone)]
pub struct SharedSigning {
    signing: Arc<Mutex<Signing>>,
    reservations: watch::Sender<u64>,
}

impl SharedSigning {
    pub fn lock(&self) -> MutexGuard<'_, Signing> {
        self.signing.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

pub async fn connect(address: &str) -> Result<Link, RunError> {
    let mut conn = ::mavlink::connect_async::<MavMessage>(address)
        .await
        .map_err(|source| RunError::Mavlink {
            address: address.to_string(),
            source,
        })?;
    conn.set_allow_recv_any_version(true);
    Ok(Arc::new(conn))
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
    let signing = Signing::open(setup.key.clone(), links, &file, signing::now())?;
    tracing::info!(timestamp_file = %path.display(), "MAVLink 2 signing on: every message signed, unsigned ones dropped");
    let (reservations, pending) = watch::channel(0);
    tokio::spawn(keep_reservations(file, pending));
    Ok(Some(SharedSigning {
        signing: Arc::new(Mutex::new(signing)),
        reservations,
    }))
}

/// Write each new signing timestamp reservation, off the send path (a write waits for the
/// disk); the latest one wins if they come faster than the disk. Ends with the bridge.
async fn keep_reservations(file: TimestampFile, mut pending: watch::Receiver<u64>) {
    while pending.changed().await.is_ok() {
        let reservation = *pending.borrow_and_update();
        let file = file.clone();
        if let Ok(Err(e)) = tokio::task::spawn_blocking(move || file.store(reservation)).await {
            tracing::warn!("{e}; a restart might reuse signing timestamps");
        }
    }
}

/// The next message for the core from `link`: every message without signing; with it, only
/// correctly signed fresh ones (the others are counted and, now and then, logged with the
/// link's `address`).
async fn receive(
    link: &Link,
    link_id: LinkId,
    address: &str,
    signing: Option<&SharedSigning>,
) -> Result<Option<(MavHeader, MavMessage)>, ::mavlink::error::MessageReadError> {
    let Some(signing) = signing else {
        return link.recv().await.map(Some);
    };
    let raw = link.recv_raw().await?;
    let incoming = signing
        .lock()
        .receive(link_id, &raw, signing::now(), Instant::now());
    Ok(match incoming {
        Incoming::Message(header, message) => Some((header, message)),
        Incoming::Unknown => None,
        Incoming::Dropped { warning, .. } => {
            if let Some(w) = warning {
                tracing::warn!(%address, "{w}");
            }
            None
        }
    })
}

/// A task that reads `link` and hands each message, with the link's id, to `to_core`; it ends
/// when the core is gone.
pub fn spawn_reader(
    link: Link,
    link_id: LinkId,
    address: String,
    signing: Option<SharedSigning>,
    to_core: mpsc::Sender<(LinkId, MavHeader, MavMessage)>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        loop {
            match receive(&link, link_id, &address, signing.as_ref()).await {
                Ok(Some((header, msg))) => {
                    if to_core.send((link_id, header, msg)).await.is_err() {
                        return;
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    tracing::debug!(link = link_id, "MAVLink receive: {e}");
                    tokio::time::sleep(RECEIVE_RETRY).await;
                }
            }
        }
    })
}

/// Send `message` on `link`, signed when signing is on.
async fn send(
    link: &Link,
    link_id: LinkId,
    signing: Option<&SharedSigning>,
    header: &MavHeader,
    message: &MavMessage,
) -> Result<usize, ::mavlink::error::MessageWriteError> {
    let Some(signing) = signing else {
        return link.send(header, message).await;
    };
    let (frame, reservation) = signing
        .lock()
        .sign(link_id, *header, message, signing::now());
    if let Some(r) = reservation {
        signing.reservations.send_replace(r);
    }
    link.send_raw(&frame).await
}

/// One link's writer: the bridge queues into its [`Outbox`] without waiting; a task of its own
/// sends what is queued, as fast as the link takes it.
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
                loop {
                    let next = lock(&outbox).pop();
                    let Some((header, message)) = next else {
                        ready.notified().await;
                        continue;
                    };
                    if let Err(e) = send(&link, link_id, signing.as_ref(), &header, &message).await
                    {
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

    /// Queue `message` for sending; never waits.
    pub fn queue(&self, header: MavHeader, message: MavMessage) {
        lock(&self.outbox).push(header, message);
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
