//! The bodies of the fuzz targets (`fuzz/fuzz_targets/*.rs`), kept in the library so that the
//! regression test (`tests/fuzz_regressions.rs`) replays every saved input through exactly the
//! same code as the fuzzer. Each function must return normally for any input; a panic is a
//! finding.

use crate::config::Config;
use crate::mavlink::BridgeCore;
use crate::mavlink::signing::{
    self, DropCounts, DropReason, Incoming, NEW_STREAM_WINDOW, Signed, Signing, SigningKey,
    TICKS_PER_SECOND, WARN_EVERY,
};
use crate::protocol::{Decoder, Expect, PositionLimits};
use crate::runtime::links::{SharedSigning, frames_of, judge, open_signing};
use mavlink::dialects::common::MavMessage;
use mavlink::{
    AsyncMavlinkReader, MAVLinkMessageRaw, MAVLinkV1MessageRaw, MAVLinkV2MessageRaw, MavHeader,
    MavlinkVersion, Message,
};
use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

/// The protocol decoder fed `data` in chunks whose sizes come from the input itself, with and
/// without an ACK expected; everything must drain once the wait is given up.
pub fn protocol_decoder(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(first % 32) + 1;
    let mut d = Decoder::new();
    if first & 0x80 != 0 {
        d.expect(Expect::Ack);
    }
    for piece in rest.chunks(chunk) {
        d.push(piece);
        while d.poll().is_some() {}
    }
    d.abandon_partial();
    while d.poll().is_some() {}
    assert_eq!(
        d.buffered(),
        0,
        "the decoder must drain after abandon_partial"
    );
}

const FUZZ_MAPPING: &str = r#"
[mavlink]
connection = "udpin:127.0.0.1:14560"
[[bus]]
name = "a"
port = "/dev/null"
[[servo]]
name = "s1"
bus = "a"
id = 1
channel = 1
actuator = 1
[[servo]]
name = "s2"
bus = "a"
id = 2
channel = 17
reverse = true
failsafe = -3.5
"#;

/// MAVLink messages decoded from `data` and handed to the bridge's core, with the clock
/// advancing. Each message is `[selector, system id, component id, length, payload…]`: the
/// selector picks one of the messages the bridge acts on (or any id), and the payload goes
/// through the same `Message::parse` as a CRC-valid frame's payload, so the fuzzer reaches the
/// core without having to forge checksums. Every goal the core produces must lie inside the
/// servo's travel.
pub fn mavlink_input(data: &[u8]) {
    const IDS: [u32; 6] = [0, 36, 375, 76, 77, 253];
    let cfg = Config::parse(FUZZ_MAPPING, "fuzz").expect("fuzz mapping is valid");
    let travel: Vec<_> = cfg.servos.iter().map(|s| s.travel).collect();
    let t0 = Instant::now();
    let mut core = BridgeCore::new(cfg, t0);
    let mut now = t0;
    let mut rest = data;
    while let [selector, system, component, len, tail @ ..] = rest {
        let len = usize::from(*len).min(tail.len());
        let (payload, next) = tail.split_at(len);
        rest = next;
        let id = IDS[usize::from(selector % 6)];
        let version = if selector & 0x80 != 0 {
            MavlinkVersion::V1
        } else {
            MavlinkVersion::V2
        };
        let Ok(msg) = MavMessage::parse(version, id, payload) else {
            continue;
        };
        let header = MavHeader {
            system_id: u32::from(*system),
            component_id: *component,
            sequence: 0,
        };
        now += Duration::from_millis(u64::from(selector >> 3));
        drive(
            &mut core,
            &travel,
            usize::from(selector & 1),
            &header,
            &msg,
            now,
        );
    }
}

/// `msg` from `link` into `core` at `now`, then its timeout and its outputs: every goal must
/// lie inside the servo's travel.
fn drive(
    core: &mut BridgeCore,
    travel: &[PositionLimits],
    link: usize,
    header: &MavHeader,
    msg: &MavMessage,
    now: Instant,
) {
    core.handle_message(link, header, msg, now);
    core.handle_timeout(now, &[]);
    while let Some((servo, goal)) = core.poll_command() {
        if let crate::bus::Goal::Position(p) = goal {
            assert!(
                travel[servo].contains(p),
                "goal {p} outside the travel of servo {servo}"
            );
        }
    }
    while core.poll_message().is_some() {}
}

/// A mapping file: any text must give a config or an error, never a panic.
pub fn mapping_file(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(cfg) = Config::parse(&text, "fuzz.toml") {
        let _ = cfg.resolved_table();
        for s in &cfg.servos {
            for us in [0, 900, 1000, 1520, 2000, 2120, 65535] {
                if let Some(p) = s.map_pwm(us) {
                    assert!(s.travel.contains(p));
                }
            }
        }
    }
}

/// The signing key of the receive-path targets, and of the signed frames among their seeds.
pub const FUZZ_KEY: [u8; 32] = [0x5e; 32];

/// A signing timestamp in 2090 (10 µs units since 2015): frames signed with it (the seeds' signed
/// frames among them) stay fresh whenever the inputs are replayed, where a frame signed at its
/// capture would be more than a minute old by the next run.
pub const FAR_FUTURE: u64 = 75 * 365 * 86_400 * TICKS_PER_SECOND;

/// MAVLINK_IFLAG_SIGNED.
const IFLAG_SIGNED: u8 = 0x01;

/// The fuzz mapping with two links (the autopilot's and a ground station's) and signing on.
fn fuzz_mapping_signed() -> Config {
    let text = FUZZ_MAPPING.replace(
        "[mavlink]\n",
        "[mavlink]\ngcs = \"udpout:127.0.0.1:14561\"\n\
         signing_key = \"5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e5e\"\n",
    );
    Config::parse(&text, "fuzz").expect("fuzz mapping is valid")
}

fn raw_bytes(frame: &MAVLinkMessageRaw) -> &[u8] {
    match frame {
        MAVLinkMessageRaw::V1(f) => f.raw_bytes(),
        MAVLinkMessageRaw::V2(f) => f.raw_bytes(),
    }
}

/// Whether `a` and `b` are the same message: the same id and encoding (a float field may be
/// NaN, which `==` holds unequal to itself).
fn same_messages(a: Option<&MavMessage>, b: Option<&MavMessage>) -> bool {
    let encoded = |m: &MavMessage| {
        let mut payload = [0u8; 255];
        let n = m.ser(MavlinkVersion::V2, &mut payload);
        (m.message_id(), payload[..n].to_vec())
    };
    a.map(encoded) == b.map(encoded)
}

/// Whether `frame` is MAVLink 2, flagged signed, and its signature is `key`'s.
fn signature_verifies(frame: &MAVLinkMessageRaw, key: &[u8; 32]) -> bool {
    let MAVLinkMessageRaw::V2(f) = frame else {
        return false;
    };
    if f.incompatibility_flags() & IFLAG_SIGNED == 0 {
        return false;
    }
    let mut signature = [0u8; 6];
    f.calculate_signature(key, &mut signature);
    signature == f.signature_value()
}

/// `frame` signed with `key` as a peer would sign it: flagged signed, its checksum made again
/// (it covers the flags), then link id, timestamp and signature.
fn sign_raw(
    frame: &MAVLinkV2MessageRaw,
    key: &[u8; 32],
    link_id: u8,
    timestamp: u64,
) -> MAVLinkV2MessageRaw {
    let mut f = *frame;
    *f.incompatibility_flags_mut() |= IFLAG_SIGNED;
    let crc_at = 1 + f.header().len() + usize::from(f.payload_length());
    let crc = mavlink::calculate_crc(
        &f.as_slice()[1..crc_at],
        MavMessage::extra_crc(f.message_id()),
    );
    f.as_mut_slice()[crc_at..crc_at + 2].copy_from_slice(&crc.to_le_bytes());
    *f.signature_link_id_mut() = link_id;
    f.signature_timestamp_bytes_mut()
        .copy_from_slice(&timestamp.to_le_bytes()[..6]);
    let mut signature = [0u8; 6];
    f.calculate_signature(key, &mut signature);
    f.signature_value_mut().copy_from_slice(&signature);
    f
}

/// An unsigned MAVLink 2 frame of message `id` with `payload` as it is (any bytes, up to 255),
/// with a valid checksum: what a peer's faulty or newer encoder may send.
fn raw_v2(header: MavHeader, id: u32, payload: &[u8]) -> MAVLinkV2MessageRaw {
    let payload = &payload[..payload.len().min(255)];
    let mut bytes = [0u8; mavlink::consts::MAX_FRAME_SIZE];
    bytes[0] = 0xFD;
    bytes[1] = payload.len() as u8;
    bytes[4] = header.sequence;
    bytes[5] = header.system_id as u8;
    bytes[6] = header.component_id;
    bytes[7..10].copy_from_slice(&id.to_le_bytes()[..3]);
    bytes[10..10 + payload.len()].copy_from_slice(payload);
    let crc_at = 10 + payload.len();
    let crc = mavlink::calculate_crc(&bytes[1..crc_at], MavMessage::extra_crc(id));
    bytes[crc_at..crc_at + 2].copy_from_slice(&crc.to_le_bytes());
    MAVLinkV2MessageRaw::from_bytes_unparsed(bytes)
}

/// The signing of the receive-path targets as a running bridge has it (`open_signing`, from
/// a mapping with [`FUZZ_KEY`]), opened once per thread and started afresh (no stream heard,
/// nothing dropped) for each input.
fn fuzz_signing() -> SharedSigning {
    thread_local! {
        static SIGNING: SharedSigning = {
            let cfg = fuzz_mapping_signed();
            // The timestamp file is written once, at the opening: a folder of this thread's own.
            let dir = std::env::temp_dir().join(format!(
                "lj9da-fuzz-signing-{}-{:?}",
                std::process::id(),
                std::thread::current().id()
            ));
            let runtime = tokio::runtime::Builder::new_current_thread()
                .build()
                .expect("a runtime to open signing in");
            let entered = runtime.enter();
            let signing = open_signing(&cfg, 2, Some(&dir))
                .expect("signing opens")
                .expect("the mapping signs");
            drop(entered);
            let _ = std::fs::remove_dir_all(&dir);
            signing
        };
    }
    let shared = SIGNING.with(Clone::clone);
    *shared.lock() = Signing::new(SigningKey::from_bytes(FUZZ_KEY), 2, None, signing::now()).0;
    shared
}

/// A UDP datagram as a link's reader takes it: `[options, datagram…]`. The datagram's frames
/// (`frames_of`) are judged as the reader judges them, on link `options & 1`, without signing
/// and with it ([`FUZZ_KEY`]); with `options & 2`, each MAVLink 2 frame is first signed with
/// the key (signature link id `options >> 4`), at timestamps that increase from now
/// (`options & 4`) or from [`FAR_FUTURE`], so that fuzzed contents pass the check too, or
/// (`options & 8`) with another key. Every accepted message goes into the bridge's core.
///
/// Asserted: without signing every frame is accepted, as the message its payload parses to;
/// with signing, an accepted frame is MAVLink 2, flagged signed, its signature the key's, and
/// its timestamp above every one accepted before in its stream (link id, system, component),
/// and it is the same message as without signing; a frame the target signed fresh with the
/// key is accepted, one it signed with another key dropped; and each frame `frames_of` gives has a valid checksum and lies in the datagram,
/// in order, without overlapping the one before.
pub fn link_datagram(data: &[u8]) {
    let Some((&options, datagram)) = data.split_first() else {
        return;
    };
    let link = usize::from(options & 1);
    let resign = options & 2 != 0;
    let signer = if options & 8 != 0 {
        [0xa1; 32]
    } else {
        FUZZ_KEY
    };
    let signature_link = options >> 4;
    let mut stamp = if options & 4 != 0 {
        signing::now()
    } else {
        FAR_FUTURE
    };
    let cfg = fuzz_mapping_signed();
    let travel: Vec<_> = cfg.servos.iter().map(|s| s.travel).collect();
    let t0 = Instant::now();
    let mut core = BridgeCore::new(cfg, t0);
    let shared = fuzz_signing();
    let mut last_accepted: HashMap<(u8, u32, u8), u64> = HashMap::new();
    let mut rest = datagram;
    for (i, frame) in frames_of(datagram).into_iter().enumerate() {
        let now = t0 + Duration::from_millis(i as u64);
        let bytes = raw_bytes(&frame);
        let at = rest
            .windows(bytes.len())
            .position(|w| w == bytes)
            .expect("a frame is bytes of its datagram, after the frame before");
        rest = &rest[at + bytes.len()..];
        let valid = match &frame {
            MAVLinkMessageRaw::V1(f) => f.has_valid_crc::<MavMessage>(),
            MAVLinkMessageRaw::V2(f) => f.has_valid_crc::<MavMessage>(),
        };
        assert!(valid, "frames_of gave a frame with a bad checksum");

        let frame = match (&frame, resign) {
            (MAVLinkMessageRaw::V2(f), true) => {
                stamp += 1;
                MAVLinkMessageRaw::V2(sign_raw(f, &signer, signature_link, stamp))
            }
            _ => frame,
        };
        let plain =
            judge(&frame, link, "fuzz", None).expect("without signing every frame is accepted");
        let parsed = MavMessage::parse(frame.version(), frame.message_id(), frame.payload()).ok();
        assert!(
            same_messages(plain.as_ref().map(|(_, m)| m), parsed.as_ref()),
            "without signing, the message is the frame's payload"
        );
        if let Some((header, msg)) = &plain {
            assert_eq!(
                (header.system_id, header.component_id, header.sequence),
                (frame.system_id(), frame.component_id(), frame.sequence())
            );
            drive(&mut core, &travel, link, header, msg, now);
        }

        let signed = judge(&frame, link, "fuzz", Some(&shared));
        let fresh_signed_here =
            resign && signer == FUZZ_KEY && matches!(frame, MAVLinkMessageRaw::V2(_));
        let Some(accepted) = signed else {
            assert!(
                !fresh_signed_here,
                "a frame signed with the key at a fresh timestamp was dropped"
            );
            continue;
        };
        let MAVLinkMessageRaw::V2(f) = &frame else {
            panic!("a MAVLink 1 frame accepted with signing on");
        };
        assert!(
            f.incompatibility_flags() & IFLAG_SIGNED != 0,
            "an unsigned frame accepted with signing on"
        );
        assert!(
            signature_verifies(&frame, &FUZZ_KEY),
            "a frame whose signature is not the key's accepted"
        );
        let stream = (f.signature_link_id(), f.system_id(), f.component_id());
        let timestamp = f.signature_timestamp();
        if let Some(last) = last_accepted.insert(stream, timestamp) {
            assert!(
                timestamp > last,
                "stream {stream:?}: timestamp {timestamp} accepted after {last}"
            );
        }
        assert!(
            accepted.as_ref().map(|(h, _)| h) == plain.as_ref().map(|(h, _)| h)
                && same_messages(
                    accepted.as_ref().map(|(_, m)| m),
                    plain.as_ref().map(|(_, m)| m)
                ),
            "signing changed the message"
        );
        if let Some((header, msg)) = &accepted {
            drive(&mut core, &travel, link, header, msg, now);
        }
    }
}

/// Reads `data` over `input` in order, as a fuzz target's record: missing bytes read as 0.
struct Input<'a>(&'a [u8]);

impl<'a> Input<'a> {
    fn u8(&mut self) -> u8 {
        self.take(1).first().copied().unwrap_or(0)
    }

    fn i16(&mut self) -> i16 {
        i16::from_le_bytes([self.u8(), self.u8()])
    }

    fn take(&mut self, n: usize) -> &'a [u8] {
        let (head, tail) = self.0.split_at(n.min(self.0.len()));
        self.0 = tail;
        head
    }
}

/// The messages the signed-stream target sends: those the bridge acts on, a telemetry radio's,
/// and a few more of what autopilots send.
const STREAM_IDS: [u32; 10] = [0, 36, 375, 76, 77, 253, 22, 23, 109, 75];

/// What [`Signing::receive`] must make of a frame, by the rules of `crate::mavlink::signing`.
#[derive(Debug, PartialEq)]
enum Verdict {
    Radio,
    Dropped(DropReason),
    Accepted,
}

/// The signing rules as the module documents them, kept beside the [`Signing`] under test.
struct Model {
    /// max(wall clock at every receipt, accepted timestamps): judges new streams.
    local: u64,
    /// The last accepted timestamp of each stream (their link id, system, component).
    streams: HashMap<(u8, u32, u8), u64>,
    drops: [DropCounts; 2],
    warned_at: [Option<Instant>; 2],
    /// Every frame accepted, as bytes.
    accepted: HashSet<Vec<u8>>,
}

impl Model {
    fn verdict(&mut self, raw: &MAVLinkMessageRaw, now: u64) -> Verdict {
        let signed = matches!(raw, MAVLinkMessageRaw::V2(f) if f.incompatibility_flags() & IFLAG_SIGNED != 0);
        // RADIO_STATUS and RADIO, unsigned: a telemetry radio's own, neither counted nor taken.
        if !signed && matches!(raw.message_id(), 109 | 166) {
            return Verdict::Radio;
        }
        let MAVLinkMessageRaw::V2(f) = raw else {
            return Verdict::Dropped(DropReason::Unsigned);
        };
        if !signed {
            return Verdict::Dropped(DropReason::Unsigned);
        }
        // The signature first: a bad one is a wrong key, whatever the timestamp.
        if !signature_verifies(raw, &FUZZ_KEY) {
            return Verdict::Dropped(DropReason::BadSignature);
        }
        self.local = self.local.max(now);
        let timestamp = f.signature_timestamp();
        let stream = (f.signature_link_id(), f.system_id(), f.component_id());
        let fresh = match self.streams.get(&stream) {
            // Newer than the stream's last.
            Some(&last) => timestamp > last,
            // A new stream: at most a minute behind the local timestamp.
            None => timestamp + NEW_STREAM_WINDOW >= self.local,
        };
        if !fresh {
            return Verdict::Dropped(DropReason::OldTimestamp);
        }
        self.streams.insert(stream, timestamp);
        self.local = self.local.max(timestamp);
        Verdict::Accepted
    }
}

/// The frames a receiver with [`FUZZ_KEY`] is sent, in order, on links 0, 1 and 2 (one more
/// than it has), with its clocks moved by the input: each record is `[op, …]`, `op % 8`:
///
/// - 0, 1: a message of `STREAM_IDS` signed by a peer (`Signing::sign`, as the tests' peers
///   sign) with the input's link id, ids, sequence number and timestamp (now ± 327 s, in
///   10 ms), with the key or (`op & 8`) another;
/// - 2: any payload of any of those ids signed with the key (`sign_raw`), as a peer whose
///   encoder is newer or faulty would;
/// - 3: a frame sent before, again (a replay);
/// - 4: a frame sent before with one byte changed (the signature's or any other: those that
///   still frame are judged);
/// - 5: bytes as they are (what frames in them is judged);
/// - 6: the wall clock moves (± 327 s, in 10 ms; backwards too) and the monotonic one forward;
/// - 7: an unsigned message, MAVLink 1 (ids up to 255) or 2 (a RADIO_STATUS among them).
///
/// Every frame is sent as bytes through `frames_of`. Asserted, against the rules of
/// `crate::mavlink::signing` kept in a model: each verdict (radio, dropped and why, or
/// accepted); a frame accepted once is never accepted again; the timestamps accepted in a
/// stream (link id, system, component) strictly increase; a new stream is accepted only within
/// a minute of the local timestamp; the drop counts of each link; and a warning at a link's
/// first drop, then at most every ten seconds.
pub fn signed_stream(data: &[u8]) {
    let mut input = Input(data);
    let key = SigningKey::from_bytes(FUZZ_KEY);
    let other_key = SigningKey::from_bytes([0xa1; 32]);
    // A start in 2026, and the wall clock from there.
    let start = 11 * 365 * 86_400 * TICKS_PER_SECOND;
    let mut now = start;
    let mut at = Instant::now();
    let (mut receiver, _) = Signing::new(key.clone(), 2, None, now);
    let mut model = Model {
        local: now,
        streams: HashMap::new(),
        drops: [DropCounts::default(); 2],
        warned_at: [None; 2],
        accepted: HashSet::new(),
    };
    let mut sent: Vec<Vec<u8>> = Vec::new();
    while !input.0.is_empty() {
        let op = input.u8();
        let link = usize::from(op >> 4) % 3;
        let bytes: Vec<u8> = match op % 8 {
            0 | 1 => {
                let (link_id, system, component, sequence) =
                    (input.u8(), input.u8(), input.u8(), input.u8());
                let id = STREAM_IDS[usize::from(input.u8()) % STREAM_IDS.len()];
                let stamp = now.saturating_add_signed(i64::from(input.i16()) * 1000);
                let len = usize::from(input.u8());
                let payload = input.take(len);
                let Ok(message) = MavMessage::parse(MavlinkVersion::V2, id, payload) else {
                    continue;
                };
                let header = MavHeader {
                    system_id: u32::from(system),
                    component_id: component,
                    sequence,
                };
                let signer = if op & 8 != 0 { &other_key } else { &key };
                let mut peer = Signing::new(signer.clone(), 1, None, stamp).0;
                match peer.sign(usize::from(link_id), header, &message, stamp) {
                    Signed::Frame(MAVLinkMessageRaw::V2(f), _) => {
                        assert_eq!(f.signature_timestamp(), stamp);
                        f.raw_bytes().to_vec()
                    }
                    Signed::Frame(MAVLinkMessageRaw::V1(_), _) => {
                        panic!("a signed frame is MAVLink 2")
                    }
                    Signed::Wait { needed, .. } => {
                        panic!("a peer started at {stamp} waits to sign at {needed}")
                    }
                }
            }
            2 => {
                let (link_id, system, component, sequence) =
                    (input.u8(), input.u8(), input.u8(), input.u8());
                let id = STREAM_IDS[usize::from(input.u8()) % STREAM_IDS.len()];
                let stamp = now.saturating_add_signed(i64::from(input.i16()) * 1000);
                let len = usize::from(input.u8());
                let header = MavHeader {
                    system_id: u32::from(system),
                    component_id: component,
                    sequence,
                };
                let frame = raw_v2(header, id, input.take(len));
                sign_raw(&frame, &FUZZ_KEY, link_id, stamp)
                    .raw_bytes()
                    .to_vec()
            }
            3 => {
                let index = usize::from(input.u8());
                let Some(frame) = sent.get(index % sent.len().max(1)) else {
                    continue;
                };
                frame.clone()
            }
            4 => {
                let (index, position, flip) = (input.u8(), input.u8(), input.u8() | 1);
                let Some(frame) = sent.get(usize::from(index) % sent.len().max(1)) else {
                    continue;
                };
                if frame.is_empty() {
                    continue;
                }
                let mut frame = frame.clone();
                // Counted from the end: the signature's 13 bytes are the least positions.
                let from_end = usize::from(position) % frame.len();
                let i = frame.len() - 1 - from_end;
                frame[i] ^= flip;
                frame
            }
            5 => {
                let len = usize::from(input.u8());
                input.take(len).to_vec()
            }
            6 => {
                now = now.saturating_add_signed(i64::from(input.i16()) * 1000);
                at += Duration::from_millis(100 * u64::from(input.u8()));
                continue;
            }
            _ => {
                let (system, component, sequence) = (input.u8(), input.u8(), input.u8());
                let selector = input.u8();
                let id = STREAM_IDS[usize::from(selector) % STREAM_IDS.len()];
                let len = usize::from(input.u8());
                // MAVLink 1 carries message ids up to 255 only.
                let version = if selector & 0x80 != 0 && id <= 255 {
                    MavlinkVersion::V1
                } else {
                    MavlinkVersion::V2
                };
                let Ok(message) = MavMessage::parse(version, id, input.take(len)) else {
                    continue;
                };
                let header = MavHeader {
                    system_id: u32::from(system),
                    component_id: component,
                    sequence,
                };
                match version {
                    MavlinkVersion::V1 => {
                        let mut f = MAVLinkV1MessageRaw::new();
                        f.serialize_message(header, &message);
                        f.raw_bytes().to_vec()
                    }
                    MavlinkVersion::V2 => {
                        let mut f = MAVLinkV2MessageRaw::new();
                        f.serialize_message(header, &message);
                        f.raw_bytes().to_vec()
                    }
                }
            }
        };
        let frames = frames_of(&bytes);
        if matches!(op % 8, 0..=2) {
            assert_eq!(frames.len(), 1, "a signed frame frames as one");
        }
        for frame in &frames {
            receive(&mut receiver, &mut model, frame, link, now, at);
        }
        if sent.len() < 64 {
            sent.push(bytes);
        }
    }
}

/// `frame` into `receiver` on `link` at wall clock `now` and monotonic `at`, checked against
/// `model`.
fn receive(
    receiver: &mut Signing,
    model: &mut Model,
    frame: &MAVLinkMessageRaw,
    link: usize,
    now: u64,
    at: Instant,
) {
    let expected = model.verdict(frame, now);
    let got = receiver.receive(link, frame, now, at);
    match (&got, &expected) {
        (Incoming::Radio, Verdict::Radio) => {}
        (Incoming::Dropped { reason, warning }, Verdict::Dropped(r)) if reason == r => {
            if let Some(drops) = model.drops.get_mut(link) {
                match reason {
                    DropReason::Unsigned => drops.unsigned += 1,
                    DropReason::BadSignature => drops.bad_signature += 1,
                    DropReason::OldTimestamp => drops.old_timestamp += 1,
                }
                let due = model.warned_at[link]
                    .is_none_or(|t| at.saturating_duration_since(t) >= WARN_EVERY);
                assert_eq!(
                    warning.is_some(),
                    due,
                    "link {link}: a drop's warning at the first, then at most every {WARN_EVERY:?}"
                );
                if due {
                    model.warned_at[link] = Some(at);
                }
            } else {
                assert!(
                    warning.is_none(),
                    "a warning for link {link}, which is none"
                );
            }
        }
        (Incoming::Message(header, message), Verdict::Accepted) => {
            let parsed = MavMessage::parse(frame.version(), frame.message_id(), frame.payload());
            assert!(same_messages(parsed.as_ref().ok(), Some(message)));
            assert_eq!(
                (header.system_id, header.component_id, header.sequence),
                (frame.system_id(), frame.component_id(), frame.sequence())
            );
        }
        (Incoming::Unknown, Verdict::Accepted) => {
            assert!(
                MavMessage::parse(frame.version(), frame.message_id(), frame.payload()).is_err()
            );
        }
        _ => panic!("expected {expected:?}, got {got:?}"),
    }
    if expected == Verdict::Accepted {
        assert!(
            model.accepted.insert(raw_bytes(frame).to_vec()),
            "a frame accepted a second time"
        );
    }
    assert_eq!(
        receiver.drops(),
        model.drops.to_vec(),
        "the drops counted per link"
    );
}

/// A byte stream (TCP, serial) delivered in pieces: each read gives the next `sizes` bytes (or
/// fewer when the reader has less room), and, where `interrupt` says so, is first interrupted.
struct Pieces<'a> {
    data: &'a [u8],
    rng: u32,
    max_piece: usize,
    interrupt: bool,
}

impl Pieces<'_> {
    fn next_random(&mut self) -> u32 {
        // xorshift32: the split points follow from the input's first bytes.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 17;
        self.rng ^= self.rng << 5;
        self.rng
    }
}

impl tokio::io::AsyncRead for Pieces<'_> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let r = self.next_random();
        if self.interrupt && r.is_multiple_of(7) {
            return std::task::Poll::Ready(Err(std::io::ErrorKind::Interrupted.into()));
        }
        let n = (r as usize % self.max_piece + 1)
            .min(self.data.len())
            .min(buf.remaining());
        let (piece, rest) = self.data.split_at(n);
        buf.put_slice(piece);
        self.data = rest;
        std::task::Poll::Ready(Ok(()))
    }
}

/// The result of `future`, which must not wait (its source is always ready).
fn at_once<F: std::future::Future>(future: F) -> F::Output {
    let mut future = std::pin::pin!(future);
    match future
        .as_mut()
        .poll(&mut std::task::Context::from_waker(std::task::Waker::noop()))
    {
        std::task::Poll::Ready(out) => out,
        std::task::Poll::Pending => panic!("the reader waited on a source that never waits"),
    }
}

/// A byte stream as a TCP or serial link's reader takes it (the `mavlink` crate's
/// `AsyncMavlinkReader`, through `recv_raw`): `[seed (2 bytes), stream…]`; the seed sets where
/// the stream is split (pieces of 1 to 1, 7, 64 or 300 bytes), whether reads are sometimes
/// interrupted, and the reader's buffer (the default one, or the least the crate allows, one
/// frame).
///
/// Asserted: the reader ends only at the stream's end; its frames are, in order, those a
/// reader finds in the whole stream at once (where a frame was split changes nothing);
/// each has a valid checksum and lies in the stream after the one before; and each is accepted
/// by `judge` without signing.
pub fn stream_framing(data: &[u8]) {
    let [a, b, stream @ ..] = data else {
        return;
    };
    let seed = u16::from_le_bytes([*a, *b]);
    let pieces = Pieces {
        data: stream,
        rng: u32::from(seed) | 0x1_0000,
        max_piece: [1, 7, 64, 300][usize::from(seed & 3)],
        interrupt: seed & 4 != 0,
    };
    let mut reader = if seed & 8 != 0 {
        AsyncMavlinkReader::with_capacity(0, pieces)
    } else {
        AsyncMavlinkReader::new(pieces)
    };
    let mut frames = Vec::new();
    let end = loop {
        match at_once(reader.read_any_raw_message::<MavMessage>()) {
            Ok(frame) => frames.push(frame),
            Err(e) => break e,
        }
    };
    match end {
        mavlink::error::MessageReadError::Io(e)
            if e.kind() == std::io::ErrorKind::UnexpectedEof => {}
        other => panic!("the reader ended before the stream did: {other}"),
    }
    // The frames a reader finds in the whole stream at once (`frames_of` reads a datagram,
    // which is whole: it also takes frames after a start byte whose frame runs past the end).
    let whole: Vec<MAVLinkMessageRaw> = {
        let mut reader = mavlink::MavlinkReader::new(stream);
        std::iter::from_fn(|| reader.read_any_raw_message::<MavMessage>().ok()).collect()
    };
    let bytes = |f: &Vec<MAVLinkMessageRaw>| -> Vec<Vec<u8>> {
        f.iter().map(|f| raw_bytes(f).to_vec()).collect()
    };
    assert_eq!(
        bytes(&frames),
        bytes(&whole),
        "the frames of a stream depend on where it was split"
    );
    let mut rest = stream;
    for frame in &frames {
        let b = raw_bytes(frame);
        let at = rest
            .windows(b.len())
            .position(|w| w == b)
            .expect("a frame is bytes of the stream, after the frame before");
        rest = &rest[at + b.len()..];
        let valid = match frame {
            MAVLinkMessageRaw::V1(f) => f.has_valid_crc::<MavMessage>(),
            MAVLinkMessageRaw::V2(f) => f.has_valid_crc::<MavMessage>(),
        };
        assert!(valid, "a frame with a bad checksum");
        assert!(judge(frame, 0, "fuzz", None).is_some());
    }
}
