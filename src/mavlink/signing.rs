//! MAVLink 2 message signing (<https://mavlink.io/en/guide/message_signing.html>) for every link
//! of the bridge: which incoming messages may reach [`super::BridgeCore`], how outgoing ones are
//! signed, and why the signing timestamp never goes backwards, not even across a restart.
//!
//! The signature itself (SHA-256 over key, frame and timestamp, first 6 bytes) is the `mavlink`
//! crate's ([`MAVLinkV2MessageRaw::calculate_signature`]). The crate's connection-level signing
//! is not used: it drops bad messages without saying so, and its timestamp cannot be seeded
//! from a persisted value. Here instead:
//!
//! - **Receiving** ([`Signing::receive`]): a MAVLink 1 or unsigned MAVLink 2 frame, a frame
//!   whose signature does not match the key, and a frame whose timestamp is not newer than the
//!   last one of its stream (link id, system, component) — or, for a stream not seen before,
//!   more than one minute older than the local timestamp — is dropped and counted per link and
//!   reason ([`DropCounts`]); a warning text is returned for the first drop of a link and then
//!   at most every [`WARN_EVERY`]. The signature is checked before the timestamp, so "bad
//!   signature" means a wrong key (or a corrupted frame) and "old timestamp" a replay.
//! - **Sending** ([`Signing::sign`]): every frame is signed with the link's id (the link's
//!   index) and a timestamp strictly greater than the previous one of any link; the bridge
//!   numbers each link's frames itself.
//! - **Timestamps** ([`Timestamps`]): the local timestamp is at least the wall clock (10 µs
//!   units since 2015-01-01 UTC) and at least every accepted incoming timestamp. The timestamps
//!   sent are moreover never below a *reservation* kept in a small file ([`TimestampFile`]):
//!   at start the first timestamp sent is max(reservation, now) and a new reservation
//!   [`RESERVE_AHEAD`] beyond it is written (temporary file, fsync, rename) before anything is
//!   sent ([`Signing::open`]); whenever a timestamp comes within [`RESERVE_MARGIN`] of the
//!   reservation, [`Signing::sign`] asks for the next, which the caller writes off the send path
//!   (the disk may be slow) while those [`RESERVE_MARGIN`] of timestamps last. A crash leaves the
//!   old file or the new one, and a restart — even with the clock set back — starts above every
//!   timestamp the previous run could have sent.
//!
//! The local timestamp that judges new incoming streams is max(now, reservation −
//! [`RESERVE_AHEAD`], accepted timestamps), not the reservation itself: right after a restart
//! the bridge may send up to [`RESERVE_AHEAD`] ahead of the clock, and judging the autopilot's
//! first messages by that would refuse an autopilot whose clock is a little behind.

use mavlink::dialects::common::MavMessage;
use mavlink::{MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, Message};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};
use thiserror::Error;

pub use crate::config::signing_key::{KeyError, SigningKey};

/// The signing epoch, 2015-01-01 00:00:00 UTC, in seconds since the Unix epoch.
pub const EPOCH_UNIX_S: u64 = 1_420_070_400;
/// Signing timestamps count 10 µs.
pub const TICKS_PER_SECOND: u64 = 100_000;
/// A new incoming stream may start at most this far behind the local timestamp (one minute).
pub const NEW_STREAM_WINDOW: u64 = 60 * TICKS_PER_SECOND;
/// How far beyond the latest timestamp sent a reservation is written (30 s).
pub const RESERVE_AHEAD: u64 = 30 * TICKS_PER_SECOND;
/// A new reservation is written when a timestamp comes this close to the current one (10 s):
/// while the bridge sends, the file is rewritten about every 20 s.
pub const RESERVE_MARGIN: u64 = 10 * TICKS_PER_SECOND;
/// Drops are logged at the first and then at most this often per link.
pub const WARN_EVERY: Duration = Duration::from_secs(10);

/// MAVLINK_IFLAG_SIGNED.
const IFLAG_SIGNED: u8 = 0x01;
/// RADIO_STATUS and RADIO, which a telemetry radio sends unsigned.
const RADIO_STATUS_ID: u32 = 109;
const RADIO_ID: u32 = 166;

fn is_signed(raw: &MAVLinkMessageRaw) -> bool {
    matches!(raw, MAVLinkMessageRaw::V2(f) if f.incompatibility_flags() & IFLAG_SIGNED != 0)
}

fn is_radio_status(raw: &MAVLinkMessageRaw) -> bool {
    matches!(raw.message_id(), RADIO_STATUS_ID | RADIO_ID)
}

/// The signing timestamp of a wall-clock time: 10 µs units since 2015-01-01 UTC (0 before it).
pub fn timestamp_at(time: SystemTime) -> u64 {
    let since = time
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap_or_default()
        .saturating_sub(Duration::from_secs(EPOCH_UNIX_S));
    (since.as_micros() / 10) as u64
}

/// The signing timestamp of now.
pub fn now() -> u64 {
    timestamp_at(SystemTime::now())
}

/// Why an incoming message was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// MAVLink 1, or MAVLink 2 without a signature.
    Unsigned,
    /// The signature does not match the key.
    BadSignature,
    /// Correctly signed, but not newer than its stream's last message, or a new stream more than
    /// a minute behind the local timestamp: a replay.
    OldTimestamp,
}

/// The messages one link dropped, per reason, since the start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DropCounts {
    pub unsigned: u64,
    pub bad_signature: u64,
    pub old_timestamp: u64,
}

impl DropCounts {
    pub fn total(&self) -> u64 {
        self.unsigned + self.bad_signature + self.old_timestamp
    }

    fn add(&mut self, reason: DropReason) {
        let n = match reason {
            DropReason::Unsigned => &mut self.unsigned,
            DropReason::BadSignature => &mut self.bad_signature,
            DropReason::OldTimestamp => &mut self.old_timestamp,
        };
        *n += 1;
    }
}

/// The local timestamp, the timestamps sent and their reservation (see the module doc).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Timestamps {
    /// Judges new incoming streams: max(now, accepted timestamps, start floor).
    local: u64,
    /// The least timestamp the next message sent may carry.
    next: u64,
    /// The latest reservation asked for (persisted, or on its way to the file).
    reserved: u64,
    /// The latest reservation known to be in the file: no timestamp at or above it is sent.
    persisted: u64,
}

/// What [`Timestamps::stamp`] allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamp {
    /// Send with `timestamp`; persist `reserve`, if any, off the send path.
    Ready {
        timestamp: u64,
        reserve: Option<u64>,
    },
    /// The timestamp due, `needed`, is not below the persisted reservation (a signed peer
    /// with a clock ahead pushed it there): nothing may be sent with it until a reservation
    /// above it is in the file. Persist `reserve`, if any, and ask again once it is.
    Wait { needed: u64, reserve: Option<u64> },
}

impl Timestamps {
    /// Start from the reservation the previous run left (`None`: first run) at wall-clock
    /// timestamp `now`; returns the reservation to persist before anything is sent (it
    /// counts as persisted).
    pub fn start(stored: Option<u64>, now: u64) -> (Self, u64) {
        let stored = stored.unwrap_or(0);
        let next = now.max(stored);
        let reserved = next + RESERVE_AHEAD;
        let t = Timestamps {
            local: now.max(stored.saturating_sub(RESERVE_AHEAD)),
            next,
            reserved,
            persisted: reserved,
        };
        (t, reserved)
    }

    /// The local timestamp at wall-clock timestamp `now`.
    pub fn local(&mut self, now: u64) -> u64 {
        self.local = self.local.max(now);
        self.local
    }

    /// A correctly signed, fresh message carried `timestamp`.
    pub fn accepted(&mut self, timestamp: u64) {
        self.local = self.local.max(timestamp);
        self.next = self.next.max(timestamp);
    }

    /// The timestamp for the next message sent, if the file's reservation is above it, and
    /// the reservation to persist when one is due.
    pub fn stamp(&mut self, now: u64) -> Stamp {
        let timestamp = self.local(now).max(self.next);
        let reserve = (timestamp + RESERVE_MARGIN >= self.reserved).then(|| {
            self.reserved = timestamp + RESERVE_AHEAD;
            self.reserved
        });
        if timestamp >= self.persisted {
            return Stamp::Wait {
                needed: timestamp,
                reserve,
            };
        }
        self.next = timestamp + 1;
        Stamp::Ready { timestamp, reserve }
    }

    /// `reservation` is in the file.
    pub fn persisted(&mut self, reservation: u64) {
        self.persisted = self.persisted.max(reservation);
    }
}

/// Why the timestamp file could not be used.
#[derive(Debug, Error)]
pub enum TimestampFileError {
    #[error(
        "cannot read the signing timestamp file {path}: {source} (set [mavlink] signing_timestamp_file to a place the bridge can read and write)"
    )]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "the signing timestamp file {path} does not hold a timestamp ({text:?}); delete it only if the clock is right"
    )]
    Garbled { path: PathBuf, text: String },
    #[error(
        "cannot write the signing timestamp file {path}: {source} (set [mavlink] signing_timestamp_file to a writable place)"
    )]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// The file that keeps the reservation: one decimal number (10 µs units since 2015-01-01 UTC)
/// and a newline.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimestampFile {
    path: PathBuf,
}

impl TimestampFile {
    pub fn new(path: impl Into<PathBuf>) -> Self {
        TimestampFile { path: path.into() }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The stored reservation; `None` when there is no file yet.
    pub fn load(&self) -> Result<Option<u64>, TimestampFileError> {
        match std::fs::read_to_string(&self.path) {
            Ok(text) => {
                text.trim()
                    .parse::<u64>()
                    .map(Some)
                    .map_err(|_| TimestampFileError::Garbled {
                        path: self.path.clone(),
                        text: text.chars().take(40).collect(),
                    })
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(TimestampFileError::Read {
                path: self.path.clone(),
                source,
            }),
        }
    }

    /// Replace the stored reservation: a temporary file beside it, fsync, rename over, fsync
    /// of the folder. A power cut leaves the old number or the new one.
    pub fn store(&self, reservation: u64) -> Result<(), TimestampFileError> {
        self.store_renaming(reservation, |from, to| std::fs::rename(from, to))
    }

    /// [`TimestampFile::store`] with the rename given: a test makes it fail, as a power cut
    /// between writing and renaming would.
    fn store_renaming(
        &self,
        reservation: u64,
        rename: impl FnOnce(&Path, &Path) -> std::io::Result<()>,
    ) -> Result<(), TimestampFileError> {
        let write = || -> std::io::Result<()> {
            let dir = match self.path.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => PathBuf::from("."),
            };
            std::fs::create_dir_all(&dir)?;
            let mut tmp_name = self.path.file_name().unwrap_or_default().to_os_string();
            tmp_name.push(".tmp");
            let tmp = dir.join(tmp_name);
            let mut f = std::fs::File::create(&tmp)?;
            writeln!(f, "{reservation}")?;
            f.sync_all()?;
            drop(f);
            rename(&tmp, &self.path)?;
            // The rename itself is durable once the folder is.
            if let Ok(d) = std::fs::File::open(&dir) {
                let _ = d.sync_all();
            }
            Ok(())
        };
        write().map_err(|source| TimestampFileError::Write {
            path: self.path.clone(),
            source,
        })
    }
}

/// What [`Signing::receive`] made of a frame.
#[derive(Debug, Clone)]
// Returned once per frame and taken apart at once: boxing would allocate for every message.
#[allow(clippy::large_enum_variant)]
pub enum Incoming {
    /// Correctly signed and fresh: for [`super::BridgeCore`].
    Message(MavHeader, MavMessage),
    /// Correctly signed and fresh, but not a message of the dialect.
    Unknown,
    /// An unsigned RADIO_STATUS or RADIO: what a telemetry radio says of itself, unsigned
    /// because a radio has no key. ArduPilot accepts them unsigned on every link and forwards
    /// them nowhere; the bridge has no use for them: dropped, but neither counted nor warned
    /// about, so that a radio on a link does not look like an attack.
    Radio,
    /// Dropped; `warning` is the log line due now, if any.
    Dropped {
        reason: DropReason,
        warning: Option<String>,
    },
}

impl Incoming {
    /// A message for the core.
    pub fn is_message(&self) -> bool {
        matches!(self, Incoming::Message(..))
    }
}

/// One link's drops.
#[derive(Debug, Default)]
struct LinkState {
    drops: DropCounts,
    warned_at: Option<Instant>,
}

/// Signing for all the bridge's links (index = the link's index = its signature link id).
#[derive(Debug)]
pub struct Signing {
    key: SigningKey,
    timestamps: Timestamps,
    /// The last accepted timestamp per stream: (their link id, system, component), whichever
    /// of the bridge's links it arrived on, as the spec and the C library key them. Keyed per
    /// link of the bridge as well, a frame captured on one link would be a new stream on the
    /// other, and accepted there within [`NEW_STREAM_WINDOW`].
    streams: HashMap<(u8, u32, u8), u64>,
    links: Vec<LinkState>,
}

impl Signing {
    /// Signing for `links` links with `key`, from the reservation the previous run left
    /// (`stored`, `None`: none) at wall-clock timestamp `now`; returns the reservation to
    /// persist before anything is sent.
    pub fn new(key: SigningKey, links: usize, stored: Option<u64>, now: u64) -> (Self, u64) {
        let (timestamps, reservation) = Timestamps::start(stored, now);
        let signing = Signing {
            key,
            timestamps,
            streams: HashMap::new(),
            links: (0..links).map(|_| LinkState::default()).collect(),
        };
        (signing, reservation)
    }

    /// [`Signing::new`] from the reservation in `file`, the first one of this run written
    /// there before returning.
    pub fn open(
        key: SigningKey,
        links: usize,
        file: &TimestampFile,
        now: u64,
    ) -> Result<Self, TimestampFileError> {
        let (signing, reservation) = Self::new(key, links, file.load()?, now);
        file.store(reservation)?;
        Ok(signing)
    }

    /// Each link's drops so far.
    pub fn drops(&self) -> Vec<DropCounts> {
        self.links.iter().map(|l| l.drops).collect()
    }

    /// Check a frame that arrived on `link` at wall-clock timestamp `now` (monotonic `at`, for
    /// the warnings' rate).
    pub fn receive(
        &mut self,
        link: usize,
        raw: &MAVLinkMessageRaw,
        now: u64,
        at: Instant,
    ) -> Incoming {
        if is_radio_status(raw) && !is_signed(raw) {
            return Incoming::Radio;
        }
        match self.verify(raw, now) {
            Ok(()) => match MavMessage::parse(raw.version(), raw.message_id(), raw.payload()) {
                Ok(message) => Incoming::Message(
                    MavHeader {
                        system_id: raw.system_id(),
                        component_id: raw.component_id(),
                        sequence: raw.sequence(),
                    },
                    message,
                ),
                Err(_) => Incoming::Unknown,
            },
            Err(reason) => {
                let warning = self.drop(link, reason, at);
                Incoming::Dropped { reason, warning }
            }
        }
    }

    fn verify(&mut self, raw: &MAVLinkMessageRaw, now: u64) -> Result<(), DropReason> {
        let MAVLinkMessageRaw::V2(frame) = raw else {
            return Err(DropReason::Unsigned);
        };
        if !is_signed(raw) {
            return Err(DropReason::Unsigned);
        }
        let mut signature = [0u8; 6];
        frame.calculate_signature(self.key.bytes(), &mut signature);
        if signature != frame.signature_value() {
            return Err(DropReason::BadSignature);
        }
        let timestamp = frame.signature_timestamp();
        let stream = (
            frame.signature_link_id(),
            frame.system_id(),
            frame.component_id(),
        );
        let local = self.timestamps.local(now);
        let fresh = match self.streams.get(&stream) {
            Some(last) => timestamp > *last,
            None => timestamp + NEW_STREAM_WINDOW >= local,
        };
        if !fresh {
            return Err(DropReason::OldTimestamp);
        }
        self.streams.insert(stream, timestamp);
        self.timestamps.accepted(timestamp);
        Ok(())
    }

    /// Count a drop; the warning due now, if any.
    fn drop(&mut self, link: usize, reason: DropReason, at: Instant) -> Option<String> {
        let state = self.links.get_mut(link)?;
        state.drops.add(reason);
        if state
            .warned_at
            .is_some_and(|t| at.saturating_duration_since(t) < WARN_EVERY)
        {
            return None;
        }
        state.warned_at = Some(at);
        let d = state.drops;
        Some(format!(
            "MAVLink link {link}: signing is on and messages are being dropped ({} unsigned, {} with a bad signature, {} with an old timestamp since the start); check that the sender signs with this mapping's key",
            d.unsigned, d.bad_signature, d.old_timestamp
        ))
    }

    /// The reservation `reservation` is in the file (see [`TimestampFile::store`]).
    pub fn reservation_stored(&mut self, reservation: u64) {
        self.timestamps.persisted(reservation);
    }

    /// `message` with `header` (ids and sequence number as given: the caller numbers each
    /// link's frames), signed for `link` at wall-clock timestamp `now`; or, when the timestamp
    /// due is not yet covered by the file's reservation, nothing until it is (see
    /// [`Stamp::Wait`]). Either way the reservation to persist, when one is due: the caller
    /// writes it away from the send path ([`TimestampFile::store`] may wait for the disk),
    /// reports it with [`Signing::reservation_stored`], and normally has [`RESERVE_MARGIN`]
    /// of timestamps to do it in before anything waits.
    pub fn sign(
        &mut self,
        link: usize,
        header: MavHeader,
        message: &MavMessage,
        now: u64,
    ) -> Signed {
        let (timestamp, reserve) = match self.timestamps.stamp(now) {
            Stamp::Ready { timestamp, reserve } => (timestamp, reserve),
            Stamp::Wait { needed, reserve } => return Signed::Wait { needed, reserve },
        };
        let mut frame = MAVLinkV2MessageRaw::new();
        frame.serialize_message_for_signing(header, message);
        *frame.signature_link_id_mut() = u8::try_from(link).unwrap_or(u8::MAX);
        frame
            .signature_timestamp_bytes_mut()
            .copy_from_slice(&timestamp.to_le_bytes()[..6]);
        let mut signature = [0u8; 6];
        frame.calculate_signature(self.key.bytes(), &mut signature);
        frame.signature_value_mut().copy_from_slice(&signature);
        Signed::Frame(MAVLinkMessageRaw::V2(frame), reserve)
    }
}

/// What [`Signing::sign`] made of a message.
// Returned once per frame and taken apart at once: boxing would allocate for every message.
#[allow(clippy::large_enum_variant)]
pub enum Signed {
    /// The signed frame, and the reservation to persist, if one is due.
    Frame(MAVLinkMessageRaw, Option<u64>),
    /// Not signed: first a reservation above `needed` must be in the file; `reserve` is the
    /// one to write, unless it has been asked for already.
    Wait { needed: u64, reserve: Option<u64> },
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{HEARTBEAT_DATA, SERVO_OUTPUT_RAW_DATA};

    const KEY: SigningKey = SigningKey::from_bytes([7; 32]);

    fn header() -> MavHeader {
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        }
    }

    fn outputs() -> MavMessage {
        MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA {
            servo1_raw: 1600,
            ..Default::default()
        })
    }

    /// A start in 2026.
    const T0: u64 = 11 * 365 * 86_400 * TICKS_PER_SECOND;

    impl Signing {
        /// Sign as a link writer does when its reservations are written at once.
        fn sign_now(
            &mut self,
            link: usize,
            header: MavHeader,
            message: &MavMessage,
            now: u64,
        ) -> (MAVLinkMessageRaw, Option<u64>) {
            match self.sign(link, header, message, now) {
                Signed::Frame(raw, reserve) => {
                    if let Some(r) = reserve {
                        self.reservation_stored(r);
                    }
                    (raw, reserve)
                }
                Signed::Wait { needed, .. } => panic!("waits for a reservation above {needed}"),
            }
        }
    }

    fn signing(key: SigningKey) -> Signing {
        Signing::new(key, 2, None, T0).0
    }

    fn receive(
        s: &mut Signing,
        raw: &MAVLinkMessageRaw,
        now: u64,
    ) -> Result<MavMessage, DropReason> {
        match s.receive(0, raw, now, Instant::now()) {
            Incoming::Message(_, m) => Ok(m),
            Incoming::Unknown => panic!("unknown"),
            Incoming::Radio => panic!("radio"),
            Incoming::Dropped { reason, .. } => Err(reason),
        }
    }

    fn unique_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("lj9da-signing-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_signed_message_verifies_and_parses() {
        let mut sender = signing(KEY);
        let mut receiver = signing(KEY);
        let (raw, _) = sender.sign_now(1, header(), &outputs(), T0);
        let MAVLinkMessageRaw::V2(frame) = &raw else {
            panic!("MAVLink 2")
        };
        assert_eq!(frame.incompatibility_flags() & IFLAG_SIGNED, IFLAG_SIGNED);
        assert_eq!(frame.signature_link_id(), 1);
        match receiver.receive(0, &raw, T0, Instant::now()) {
            Incoming::Message(h, m) => {
                assert_eq!((h.system_id, h.component_id), (1, 1));
                assert_eq!(m, outputs());
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(receiver.drops()[0], DropCounts::default());
    }

    #[test]
    fn a_message_signed_with_another_key_is_dropped_as_bad_signature() {
        let mut sender = signing(SigningKey::from_bytes([8; 32]));
        let mut receiver = signing(KEY);
        let (raw, _) = sender.sign_now(0, header(), &outputs(), T0);
        assert_eq!(
            receive(&mut receiver, &raw, T0),
            Err(DropReason::BadSignature)
        );
        // A corrupted signature as well.
        let (mut raw, _) = signing(KEY).sign_now(0, header(), &outputs(), T0);
        if let MAVLinkMessageRaw::V2(f) = &mut raw {
            f.signature_value_mut()[0] ^= 1;
        }
        assert_eq!(
            receive(&mut receiver, &raw, T0),
            Err(DropReason::BadSignature)
        );
        assert_eq!(receiver.drops()[0].bad_signature, 2);
    }

    #[test]
    fn unsigned_messages_of_either_version_are_dropped() {
        let mut receiver = signing(KEY);
        let mut v2 = MAVLinkV2MessageRaw::new();
        v2.serialize_message(header(), &outputs());
        assert_eq!(
            receive(&mut receiver, &MAVLinkMessageRaw::V2(v2), T0),
            Err(DropReason::Unsigned)
        );
        let mut v1 = mavlink::MAVLinkV1MessageRaw::new();
        v1.serialize_message(header(), &outputs());
        assert_eq!(
            receive(&mut receiver, &MAVLinkMessageRaw::V1(v1), T0),
            Err(DropReason::Unsigned)
        );
        assert_eq!(receiver.drops()[0].unsigned, 2);
    }

    #[test]
    fn a_replayed_message_is_dropped_as_old() {
        let mut sender = signing(KEY);
        let mut receiver = signing(KEY);
        let (first, _) = sender.sign_now(0, header(), &outputs(), T0);
        let (second, _) = sender.sign_now(0, header(), &outputs(), T0);
        assert!(receive(&mut receiver, &first, T0).is_ok());
        assert!(receive(&mut receiver, &second, T0).is_ok());
        assert_eq!(
            receive(&mut receiver, &second, T0),
            Err(DropReason::OldTimestamp)
        );
        assert_eq!(
            receive(&mut receiver, &first, T0),
            Err(DropReason::OldTimestamp)
        );
        // Another component's stream is its own.
        let (other, _) = sender.sign_now(
            0,
            MavHeader {
                component_id: 2,
                ..header()
            },
            &outputs(),
            T0,
        );
        assert!(receive(&mut receiver, &other, T0).is_ok());
    }

    #[test]
    fn a_frame_captured_on_one_link_and_replayed_on_the_other_is_dropped_as_old() {
        // The autopilot's outputs, heard on link 0, played again on link 1 within the minute
        // a new stream is given: the same stream (link id, system, component), not a new one.
        let mut autopilot = signing(KEY);
        let mut bridge = signing(KEY);
        let (captured, _) = autopilot.sign_now(0, header(), &outputs(), T0);
        assert!(
            bridge
                .receive(0, &captured, T0, Instant::now())
                .is_message()
        );
        match bridge.receive(1, &captured, T0 + 100, Instant::now()) {
            Incoming::Dropped {
                reason: DropReason::OldTimestamp,
                ..
            } => {}
            other => panic!("{other:?}"),
        }
        assert_eq!(bridge.drops()[1].old_timestamp, 1);
        assert_eq!(bridge.drops()[0], DropCounts::default());
        // Replayed on link 1 first and then arriving on link 0: the first to come is taken.
        let (next, _) = autopilot.sign_now(0, header(), &outputs(), T0);
        assert!(bridge.receive(1, &next, T0, Instant::now()).is_message());
        assert!(!bridge.receive(0, &next, T0, Instant::now()).is_message());
    }

    #[test]
    fn an_unsigned_radio_status_is_dropped_without_being_counted() {
        let mut receiver = signing(KEY);
        let mut v2 = MAVLinkV2MessageRaw::new();
        let radio = MavMessage::RADIO_STATUS(mavlink::dialects::common::RADIO_STATUS_DATA {
            rssi: 200,
            ..Default::default()
        });
        v2.serialize_message(header(), &radio);
        let raw = MAVLinkMessageRaw::V2(v2);
        assert!(matches!(
            receiver.receive(1, &raw, T0, Instant::now()),
            Incoming::Radio
        ));
        assert_eq!(receiver.drops()[1], DropCounts::default());
        // Signed, it is a message like any other.
        let (signed, _) = signing(KEY).sign_now(0, header(), &radio, T0);
        assert!(
            receiver
                .receive(1, &signed, T0, Instant::now())
                .is_message()
        );
    }

    #[test]
    fn a_fast_clock_peer_cannot_make_a_restart_reuse_a_timestamp() {
        let dir = unique_dir("fast-peer");
        let file = TimestampFile::new(dir.join("t"));
        let mut bridge = Signing::open(KEY, 2, &file, T0).unwrap();
        let (first, _) = bridge.sign_now(0, header(), &outputs(), T0);
        // A signed peer whose clock is ten minutes ahead: accepted, and what the bridge sends
        // next must be above its timestamp, beyond the reservation in the file.
        let ahead = T0 + 600 * TICKS_PER_SECOND;
        let (peer, _) =
            Signing::new(KEY, 1, None, ahead)
                .0
                .sign_now(0, header(), &outputs(), ahead);
        assert!(bridge.receive(1, &peer, T0, Instant::now()).is_message());
        let reserve = match bridge.sign(0, header(), &outputs(), T0) {
            Signed::Wait { needed, reserve } => {
                assert!(needed >= ahead);
                reserve.expect("a reservation above the peer's timestamp is asked for")
            }
            Signed::Frame(..) => panic!("signed beyond the reservation in the file"),
        };
        // Killed here, before the reservation is written: nothing was sent past the file's
        // reservation, and a bridge started again (its clock where it was) signs above
        // everything sent before.
        let mut restarted = Signing::open(KEY, 2, &file, T0).unwrap();
        let (after_kill, _) = restarted.sign_now(0, header(), &outputs(), T0);
        assert!(stamp_of(&after_kill) > stamp_of(&first));
        drop(restarted);
        // Or the reservation is written, the frame sent, and the bridge killed right after.
        file.store(reserve).unwrap();
        bridge.reservation_stored(reserve);
        let (sent, _) = bridge.sign_now(0, header(), &outputs(), T0);
        assert!(stamp_of(&sent) >= ahead && stamp_of(&sent) > stamp_of(&first));
        drop(bridge);
        // Restarted with the clock where it was: every timestamp is above the one sent.
        let mut again = Signing::open(KEY, 2, &file, T0).unwrap();
        let (after, _) = again.sign_now(0, header(), &outputs(), T0);
        assert!(stamp_of(&after) > stamp_of(&sent));
        // A receiver that heard the first run accepts the second.
        let mut receiver = signing(KEY);
        assert!(receiver.receive(0, &sent, T0, Instant::now()).is_message());
        assert!(receiver.receive(0, &after, T0, Instant::now()).is_message());
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn a_new_stream_more_than_a_minute_behind_is_dropped() {
        let sent_at = |t: u64| {
            Signing::new(KEY, 1, None, t)
                .0
                .sign_now(0, header(), &outputs(), t)
                .0
        };
        let minute = NEW_STREAM_WINDOW;
        let mut receiver = signing(KEY);
        let old = sent_at(T0 - minute - 1);
        assert_eq!(
            receive(&mut receiver, &old, T0),
            Err(DropReason::OldTimestamp)
        );
        assert!(receive(&mut receiver, &sent_at(T0 - minute + 100), T0).is_ok());
    }

    #[test]
    fn sent_timestamps_strictly_increase_across_links_even_at_one_instant() {
        let mut s = signing(KEY);
        let mut last = 0;
        for i in 0..1000 {
            let (raw, _) = s.sign_now(i % 2, header(), &outputs(), T0);
            let MAVLinkMessageRaw::V2(f) = raw else {
                panic!()
            };
            assert!(f.signature_timestamp() > last);
            last = f.signature_timestamp();
        }
        // A clock that goes back changes nothing.
        let (raw, _) = s.sign_now(0, header(), &outputs(), T0 - 1_000_000);
        let MAVLinkMessageRaw::V2(f) = raw else {
            panic!()
        };
        assert!(f.signature_timestamp() > last);
    }

    #[test]
    fn frames_carry_the_callers_sequence_number() {
        // The link writers number frames: the bridge's own per link, a relayed message keeps
        // its sender's.
        let mut s = signing(KEY);
        for sequence in [0, 7, 255] {
            let (raw, _) = s.sign_now(
                1,
                MavHeader {
                    sequence,
                    ..header()
                },
                &outputs(),
                T0,
            );
            assert_eq!(raw.sequence(), sequence);
        }
    }

    fn stamp_of(raw: &MAVLinkMessageRaw) -> u64 {
        match raw {
            MAVLinkMessageRaw::V2(f) => f.signature_timestamp(),
            MAVLinkMessageRaw::V1(_) => panic!(),
        }
    }

    #[test]
    fn a_restart_with_the_clock_set_back_still_sends_later_timestamps() {
        let dir = unique_dir("restart");
        let file = TimestampFile::new(dir.join("plane.toml.signing-timestamp"));
        // As the bridge runs: each reservation due is written (there, on another task).
        let send = |s: &mut Signing, now: u64| {
            let (raw, reserve) = s.sign_now(0, header(), &outputs(), now);
            if let Some(r) = reserve {
                file.store(r).unwrap();
            }
            stamp_of(&raw)
        };
        let mut first = Signing::open(KEY, 1, &file, T0).unwrap();
        let mut last = 0;
        // A minute and a half of sending at 100 Hz: several reservations.
        for i in 0..9000 {
            last = send(&mut first, T0 + i * 1000);
        }
        let stored = file.load().unwrap().unwrap();
        assert!(
            stored >= last + RESERVE_MARGIN,
            "the reservation covers what was sent"
        );
        // Killed (no goodbye), restarted with the clock an hour back.
        drop(first);
        let back = T0 - 3600 * TICKS_PER_SECOND;
        let mut second = Signing::open(KEY, 1, &file, back).unwrap();
        let (raw, _) = second.sign_now(0, header(), &outputs(), back);
        assert!(stamp_of(&raw) > last);
        // A receiver that saw the first run accepts the second run's messages.
        let mut receiver = signing(KEY);
        let (raw1, _) = Signing::new(KEY, 1, None, T0)
            .0
            .sign_now(0, header(), &outputs(), T0);
        assert!(receive(&mut receiver, &raw1, T0).is_ok());
        assert!(receive(&mut receiver, &raw, T0).is_ok());
        // A third start (the clock still back) is above the second's timestamps too.
        let second_last = send(&mut second, back);
        drop(second);
        let mut third = Signing::open(KEY, 1, &file, back).unwrap();
        assert!(send(&mut third, back) > second_last);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn signing_does_not_open_where_its_timestamps_cannot_be_kept() {
        // A folder that cannot exist: a path under a regular file.
        let dir = unique_dir("unwritable");
        std::fs::write(dir.join("file"), "").unwrap();
        let file = TimestampFile::new(dir.join("file/ts"));
        let e = Signing::open(KEY, 1, &file, T0).expect_err("no place for the file");
        assert!(
            matches!(
                e,
                TimestampFileError::Read { .. } | TimestampFileError::Write { .. }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("signing_timestamp_file"), "{e}");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn a_crash_between_writing_and_renaming_leaves_the_previous_reservation() {
        let dir = unique_dir("torn");
        let file = TimestampFile::new(dir.join("t"));
        file.store(123_456).unwrap();
        // The power goes once the new number is written and synced, before the rename.
        let e = file
            .store_renaming(200_000, |_, _| {
                Err(std::io::Error::other("power cut before the rename"))
            })
            .expect_err("the rename failed");
        assert!(matches!(e, TimestampFileError::Write { .. }), "{e}");
        assert_eq!(
            std::fs::read_to_string(dir.join("t.tmp")).unwrap(),
            "200000\n"
        );
        // The temporary file is not read: the previous reservation stands.
        assert_eq!(file.load().unwrap(), Some(123_456));
        // The next store writes over the leftover temporary file.
        file.store(200_000).unwrap();
        assert_eq!(file.load().unwrap(), Some(200_000));
        std::fs::write(dir.join("t"), "garbage").unwrap();
        assert!(matches!(
            file.load(),
            Err(TimestampFileError::Garbled { .. })
        ));
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn the_local_timestamp_after_a_restart_does_not_refuse_a_peer_at_the_right_time() {
        // The previous run reserved up to now + 30 s; a peer whose clock is 50 s behind ours
        // still starts a stream.
        let (mut t, _) = Timestamps::start(Some(T0 + RESERVE_AHEAD), T0);
        assert!(T0 - 50 * TICKS_PER_SECOND + NEW_STREAM_WINDOW >= t.local(T0));
        // What is sent is above the reservation.
        assert!(
            matches!(t.stamp(T0), Stamp::Ready { timestamp, .. } if timestamp >= T0 + RESERVE_AHEAD)
        );
    }

    #[test]
    fn drops_warn_at_the_first_then_at_most_every_ten_seconds() {
        let mut s = signing(KEY);
        let mut v2 = MAVLinkV2MessageRaw::new();
        v2.serialize_message(header(), &MavMessage::HEARTBEAT(HEARTBEAT_DATA::default()));
        let raw = MAVLinkMessageRaw::V2(v2);
        let t0 = Instant::now();
        let warn = |s: &mut Signing, after: u64| match s.receive(
            1,
            &raw,
            T0,
            t0 + Duration::from_millis(after),
        ) {
            Incoming::Dropped { warning, .. } => warning,
            other => panic!("{other:?}"),
        };
        assert!(warn(&mut s, 0).unwrap().contains("1 unsigned"));
        assert_eq!(warn(&mut s, 5_000), None);
        assert_eq!(warn(&mut s, 9_999), None);
        let w = warn(&mut s, 10_000).unwrap();
        assert!(w.contains("link 1") && w.contains("4 unsigned"), "{w}");
        assert_eq!(s.drops()[1].unsigned, 4);
        assert_eq!(s.drops()[0], DropCounts::default());
    }

    #[test]
    fn timestamps_count_10_us_since_2015() {
        let t = SystemTime::UNIX_EPOCH + Duration::from_secs(EPOCH_UNIX_S + 2);
        assert_eq!(timestamp_at(t), 200_000);
        assert_eq!(timestamp_at(SystemTime::UNIX_EPOCH), 0);
    }
}
