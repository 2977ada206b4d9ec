//! Which peers the bridge obeys and answers, over real UDP sockets with real MAVLink frames
//! (the `mavlink` crate's framing, signed as the bridge signs), simulated servos behind it:
//!
//! - A signed frame of the autopilot's outputs, captured on its link and replayed on the
//!   ground-station link, is dropped there as an old timestamp, counted, and moves nothing.
//! - With signing on, unsigned (or replayed) datagrams from a second socket do not change where
//!   a `udpin` link replies: the signed peer keeps hearing the bridge, the stranger hears nothing.
//! - The bridge's own frames are numbered per link without gaps; the autopilot's HEARTBEAT
//!   relayed to the ground station keeps the autopilot's sequence numbers.
//! - A second system streaming to the autopilot's `udpin` port takes none of the autopilot's
//!   share: the bridge sends each message to both.
//! - A burst of 1 000 PARAM_SETs rewrites the mapping file a bounded number of times, and the
//!   latest value is the one kept.

mod common;

use common::mapping::Mapping;
use common::peer::{heartbeat, outputs};
use common::{Chain, ChainOptions, free_udp_port};
use lj9da_bridge::mavlink::signing::{Signed, Signing, SigningKey};
use lj9da_bridge::runtime::{BridgeView, MAPPING_WRITE_SPACING};
use mavlink::dialects::common::{
    MavMessage, MavParamType, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA,
};
use mavlink::{MAVLinkMessageRaw, MAVLinkV2MessageRaw, MavHeader, MavlinkReader, Message};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::UdpSocket;

const KEY: [u8; 32] = [0x5e; 32];
const AP: (u8, u8) = (1, 1);
const BRIDGE: (u8, u8) = (1, 140);

/// A mapping with one servo on channel 1, signed with [`KEY`] when `signed`.
fn mapping(signed: bool, name: &str) -> String {
    let signing = if signed {
        let ts = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!(
            "peers-{name}-{}.signing-timestamp",
            std::process::id()
        ));
        let _ = std::fs::remove_file(&ts);
        let hex: String = KEY.iter().map(|b| format!("{b:02x}")).collect();
        format!(
            "signing_key = \"{hex}\"\nsigning_timestamp_file = \"{}\"",
            ts.display()
        )
    } else {
        String::new()
    };
    Mapping::new()
        .with(
            "[mavlink]",
            "system_id = 1\noutput_rate_hz = 20\nfailsafe_timeout_ms = 5000",
        )
        .with("[mavlink]", &signing)
        .with("[telemetry]", "rate_hz = 10")
        .servo("aileron", 1, 1)
        .to_string()
}

/// A MAVLink peer on a UDP socket of its own: it sends frames (signed with [`KEY`] or not)
/// and keeps every message it hears.
struct Peer {
    socket: Arc<UdpSocket>,
    signing: Option<Signing>,
    ids: (u8, u8),
    sequence: u8,
    heard: Arc<Mutex<Vec<(MavHeader, MavMessage, bool)>>>,
    task: tokio::task::JoinHandle<()>,
}

fn now_stamp() -> u64 {
    lj9da_bridge::mavlink::signing::now()
}

impl Peer {
    async fn new(ids: (u8, u8), signed: bool) -> Peer {
        let socket = Arc::new(UdpSocket::bind("127.0.0.1:0").await.unwrap());
        let heard = Arc::new(Mutex::new(Vec::new()));
        let (s, h) = (socket.clone(), heard.clone());
        let task = tokio::spawn(async move {
            let mut buf = vec![0u8; 65_536];
            while let Ok((n, _)) = s.recv_from(&mut buf).await {
                let mut reader = MavlinkReader::new(&buf[..n]);
                while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
                    let signed = matches!(&raw, MAVLinkMessageRaw::V2(f) if f.incompatibility_flags() & 1 != 0);
                    let header = MavHeader {
                        system_id: raw.system_id(),
                        component_id: raw.component_id(),
                        sequence: raw.sequence(),
                    };
                    if let Ok(m) = MavMessage::parse(raw.version(), raw.message_id(), raw.payload())
                    {
                        h.lock().unwrap().push((header, m, signed));
                    }
                }
            }
        });
        let signing =
            signed.then(|| Signing::new(SigningKey::from_bytes(KEY), 1, None, now_stamp()).0);
        Peer {
            socket,
            signing,
            ids,
            sequence: 0,
            heard,
            task,
        }
    }

    /// The next frame of `message` from this peer, as bytes on the wire.
    fn frame(&mut self, message: &MavMessage) -> Vec<u8> {
        let sequence = self.sequence;
        self.frame_numbered(message, sequence)
    }

    fn frame_numbered(&mut self, message: &MavMessage, sequence: u8) -> Vec<u8> {
        self.sequence = sequence.wrapping_add(1);
        let header = MavHeader {
            system_id: u32::from(self.ids.0),
            component_id: self.ids.1,
            sequence,
        };
        match &mut self.signing {
            Some(signing) => match signing.sign(0, header, message, now_stamp()) {
                Signed::Frame(MAVLinkMessageRaw::V2(f), reserve) => {
                    if let Some(r) = reserve {
                        signing.reservation_stored(r);
                    }
                    f.raw_bytes().to_vec()
                }
                _ => panic!("the test peer signs at once"),
            },
            None => {
                let mut f = MAVLinkV2MessageRaw::new();
                f.serialize_message(header, message);
                f.raw_bytes().to_vec()
            }
        }
    }

    async fn send_bytes(&self, port: u16, bytes: &[u8]) {
        self.socket
            .send_to(bytes, ("127.0.0.1", port))
            .await
            .unwrap();
    }

    async fn send(&mut self, port: u16, message: &MavMessage) {
        let bytes = self.frame(message);
        self.send_bytes(port, &bytes).await;
    }

    /// Send a HEARTBEAT and neutral outputs every 50 ms, as an autopilot keeps sending them,
    /// until the bridge has found this autopilot. (The bridge starts in a task of its own and
    /// may bind its port only after a first datagram was sent: one datagram alone may be lost.)
    async fn announce(&mut self, port: u16, chain: &Chain) {
        let deadline = Instant::now() + Duration::from_secs(20);
        while chain.view.borrow().autopilot != Some(self.ids) {
            assert!(
                Instant::now() < deadline,
                "the bridge never found the autopilot"
            );
            self.send(port, &heartbeat()).await;
            self.send(port, &outputs(&[1520])).await;
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    fn heard(&self) -> Vec<(MavHeader, MavMessage, bool)> {
        self.heard.lock().unwrap().clone()
    }

    /// The bridge's messages heard so far.
    fn heard_from_bridge(&self) -> Vec<(MavHeader, MavMessage, bool)> {
        self.heard()
            .into_iter()
            .filter(|(h, _, _)| (h.system_id, h.component_id) == (1, BRIDGE.1))
            .collect()
    }

    async fn wait_for(&self, what: &str, pred: impl Fn(&[(MavHeader, MavMessage, bool)]) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(20);
        while !pred(&self.heard()) {
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// The servo's goal, in mm, as the bus has it.
fn goal(chain: &Chain) -> Option<f64> {
    chain.view.borrow().servos.first().and_then(|s| s.goal_mm)
}

async fn wait_goal(chain: &Chain, mm: f64) {
    chain
        .wait_view(
            &format!("a goal of {mm} mm"),
            Duration::from_secs(20),
            |v| {
                v.servos
                    .first()
                    .and_then(|s| s.goal_mm)
                    .is_some_and(|g| (g - mm).abs() < 0.05)
            },
        )
        .await;
}

/// 1900 µs with the default PWM range (920/1520/2120 µs ↔ −25/0/+25 mm).
const MM_1900: f64 = 25.0 * (1900.0 - 1520.0) / 600.0;

/// Sequence numbers, each one more than the last (mod 256): the count of gaps.
fn gaps(sequences: &[u8]) -> usize {
    sequences
        .windows(2)
        .filter(|w| w[1] != w[0].wrapping_add(1))
        .count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_signed_frame_replayed_on_the_ground_station_link_is_dropped_and_moves_nothing() {
    let gcs_port = free_udp_port();
    let opts = ChainOptions {
        gcs_address: Some(format!("udpin:127.0.0.1:{gcs_port}")),
        ..ChainOptions::default()
    };
    let chain = Chain::start_opts(&mapping(true, "replay"), opts).await;
    let port = chain.autopilot_port;
    let mut ap = Peer::new(AP, true).await;
    ap.announce(port, &chain).await;
    wait_goal(&chain, 0.0).await;
    // A frame of the autopilot's on its link, captured there.
    let captured = ap.frame(&outputs(&[1900]));
    ap.send_bytes(port, &captured).await;
    wait_goal(&chain, MM_1900).await;
    ap.send(port, &outputs(&[1520])).await;
    wait_goal(&chain, 0.0).await;
    // Played again on the ground-station link, within the minute a new stream is given.
    let attacker = Peer::new((9, 9), false).await;
    attacker.send_bytes(gcs_port, &captured).await;
    chain
        .wait_view("the replay counted", Duration::from_secs(10), |v| {
            v.signing_drops.get(1).is_some_and(|d| d.old_timestamp == 1)
        })
        .await;
    // A barrier, not a pause: a signed ground station's request on the same link, answered
    // only once the bridge has handled everything that link passed on before it (one reader,
    // one queue, in order). Had the replay been passed on, it would have moved the servo first.
    let mut gcs = Peer::new((255, 190), true).await;
    let read = MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
        param_index: -1,
        target_system: 1,
        target_component: BRIDGE.1,
        param_id: "S1_PWM_MIN".into(),
    });
    gcs.send(gcs_port, &read).await;
    gcs.wait_for("the answer to the ground station's request", |h| {
        h.iter()
            .any(|(_, m, _)| matches!(m, MavMessage::PARAM_VALUE(_)))
    })
    .await;
    assert_eq!(goal(&chain).map(|g| (g * 100.0).round()), Some(0.0));
    assert_eq!(chain.view.borrow().signing_drops[0].total(), 0);
    chain.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unsigned_datagrams_from_a_stranger_do_not_take_the_signed_peers_replies() {
    let chain = Chain::start_opts(&mapping(true, "redirect"), ChainOptions::default()).await;
    let port = chain.autopilot_port;
    let mut ap = Peer::new(AP, true).await;
    let first_heartbeat = ap.frame(&heartbeat());
    ap.send_bytes(port, &first_heartbeat).await;
    ap.announce(port, &chain).await;
    ap.wait_for("the bridge's HEARTBEAT", |h| {
        h.iter()
            .any(|(hd, m, _)| hd.component_id == BRIDGE.1 && matches!(m, MavMessage::HEARTBEAT(_)))
    })
    .await;
    // From now on the autopilot says nothing, and a stranger keeps talking: unsigned frames,
    // and the autopilot's own signed frame replayed from the stranger's address.
    let before = ap.heard_from_bridge().len();
    let mut stranger = Peer::new((1, 1), false).await;
    let until = Instant::now() + Duration::from_millis(2500);
    let mut sent = 0;
    while Instant::now() < until {
        stranger.send(port, &heartbeat()).await;
        stranger.send(port, &outputs(&[1900])).await;
        stranger.send_bytes(port, &first_heartbeat).await;
        sent += 2;
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let heard = ap.heard_from_bridge();
    let heartbeats_after = heard[before..]
        .iter()
        .filter(|(_, m, _)| matches!(m, MavMessage::HEARTBEAT(_)))
        .count();
    assert!(
        heartbeats_after >= 2,
        "the signed peer heard {heartbeats_after} HEARTBEATs in 2.5 s of a stranger's datagrams"
    );
    assert!(heard.iter().all(|(_, _, signed)| *signed));
    assert!(
        stranger.heard().is_empty(),
        "the stranger heard {:?}",
        stranger.heard().first()
    );
    // The last datagrams may still be on their way through the loop and into the view
    // (refreshed every 50 ms): wait for them, rather than read the view at once.
    let counted = |v: &lj9da_bridge::runtime::BridgeView| {
        v.signing_drops
            .first()
            .is_some_and(|d| d.unsigned >= sent as u64 - 2)
    };
    if !counted(&chain.view.borrow()) {
        chain
            .wait_view(
                "the stranger's unsigned frames counted",
                Duration::from_secs(10),
                counted,
            )
            .await;
    }
    let drops = chain.view.borrow().signing_drops[0];
    assert!(drops.unsigned >= sent as u64 - 2, "{drops:?}, {sent} sent");
    assert!(drops.old_timestamp >= 1, "{drops:?}");
    assert_eq!(goal(&chain).map(|g| (g * 100.0).round()), Some(0.0));
    // The bridge's frames to the autopilot are numbered without a gap.
    let sequences: Vec<u8> = heard.iter().map(|(h, _, _)| h.sequence).collect();
    assert_eq!(gaps(&sequences), 0, "{sequences:?}");
    chain.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn own_frames_count_without_gaps_and_the_relayed_heartbeat_keeps_its_numbers() {
    let chain = Chain::start_opts(&mapping(false, "sequence"), ChainOptions::default()).await;
    let port = chain.autopilot_port;
    let mut ap = Peer::new(AP, false).await;
    let sent: Vec<u8> = (0..15).map(|i| 200u8.wrapping_add(i * 7)).collect();
    for &sequence in &sent {
        let hb = ap.frame_numbered(&heartbeat(), sequence);
        ap.send_bytes(port, &hb).await;
        ap.send(port, &outputs(&[1520])).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Enough of both to judge: how soon the bridge has ten frames of its own to send depends
    // on how soon its servos come online.
    let from = |h: &MavHeader, component: u8| (h.system_id, h.component_id) == (1, component);
    chain
        .gcs
        .wait_for(
            "3 relayed HEARTBEATs and 10 frames of the bridge's own",
            Duration::from_secs(10),
            |h| {
                h.iter().filter(|(_, hd, _)| from(hd, AP.1)).count() >= 3
                    && h.iter().filter(|(_, hd, _)| from(hd, BRIDGE.1)).count() >= 10
            },
        )
        .await;
    let heard = chain.gcs.all();
    let relayed: Vec<u8> = heard
        .iter()
        .filter(|(_, h, _)| from(h, AP.1))
        .map(|(_, h, _)| h.sequence)
        .collect();
    assert!(
        relayed.iter().all(|s| sent.contains(s)),
        "relayed {relayed:?}, the autopilot sent {sent:?}"
    );
    let own: Vec<u8> = heard
        .iter()
        .filter(|(_, h, _)| from(h, BRIDGE.1))
        .map(|(_, h, _)| h.sequence)
        .collect();
    assert_eq!(gaps(&own), 0, "the bridge's own frames: {own:?}");
    // On the autopilot's link too.
    ap.wait_for("2 frames of the bridge's", |h| {
        h.iter().filter(|(hd, _, _)| from(hd, BRIDGE.1)).count() >= 2
    })
    .await;
    let to_ap: Vec<u8> = ap
        .heard_from_bridge()
        .iter()
        .map(|(h, _, _)| h.sequence)
        .collect();
    assert_eq!(gaps(&to_ap), 0, "to the autopilot: {to_ap:?}");
    chain.stop().await;
}

/// A ground station (or a joystick's MANUAL_CONTROL forwarded by a router) streaming at 25 Hz
/// to the autopilot's `udpin` port takes nothing of what the autopilot hears: the bridge sends
/// each of its messages to both. Judged by the link's own numbering: the autopilot hears every
/// frame the link numbered while the other system streamed (a gap is a frame that went only to
/// the other), and the other hears the bridge too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_system_on_the_autopilots_port_takes_none_of_its_messages() {
    let chain = Chain::start_opts(&mapping(false, "two-peers"), ChainOptions::default()).await;
    let port = chain.autopilot_port;
    let mut ap = Peer::new(AP, false).await;
    ap.announce(port, &chain).await;
    ap.wait_for("the bridge's HEARTBEAT", |h| {
        h.iter()
            .any(|(hd, m, _)| hd.component_id == BRIDGE.1 && matches!(m, MavMessage::HEARTBEAT(_)))
    })
    .await;
    let mut gcs = Peer::new((255, 190), false).await;
    let joystick = MavMessage::MANUAL_CONTROL(mavlink::dialects::common::MANUAL_CONTROL_DATA {
        target: 1,
        ..Default::default()
    });
    let before = ap.heard_from_bridge().len();
    // 3 s: the autopilot's outputs at 20 Hz, the ground station's stream at 25 Hz, interleaved
    // as they come from two systems.
    let start = Instant::now();
    let (mut next_ap, mut next_gcs) = (start, start);
    while start.elapsed() < Duration::from_secs(3) {
        let now = Instant::now();
        if now >= next_ap {
            ap.send(port, &outputs(&[1520])).await;
            next_ap += Duration::from_millis(50);
        }
        if now >= next_gcs {
            gcs.send(port, &joystick).await;
            next_gcs += Duration::from_millis(40);
        }
        tokio::time::sleep_until(next_ap.min(next_gcs).into()).await;
    }
    // What the link numbered last in those 3 s has reached both.
    let last = gcs
        .heard_from_bridge()
        .last()
        .map(|(h, _, _)| h.sequence)
        .expect("the ground station heard the bridge");
    ap.wait_for("the last frame the ground station heard", |h| {
        h.iter()
            .any(|(hd, _, _)| hd.component_id == BRIDGE.1 && hd.sequence == last)
    })
    .await;
    let to_ap: Vec<u8> = ap.heard_from_bridge()[before..]
        .iter()
        .map(|(h, _, _)| h.sequence)
        .collect();
    let to_gcs = gcs.heard_from_bridge();
    println!(
        "in 3 s: the autopilot heard {} of the bridge's frames, the ground station {}",
        to_ap.len(),
        to_gcs.len()
    );
    assert!(to_ap.len() >= 5, "{to_ap:?}");
    assert_eq!(gaps(&to_ap), 0, "frames the autopilot missed: {to_ap:?}");
    assert!(
        to_gcs
            .iter()
            .any(|(_, m, _)| matches!(m, MavMessage::HEARTBEAT(_))),
        "the ground station heard no HEARTBEAT of the bridge's"
    );
    assert!(sockets_on(port) >= 2, "a socket of its own for each peer");
    chain.stop().await;
    // The runtime outlives the bridge here, as in `sitl`: the peers' sockets close with it.
    assert_eq!(
        sockets_on(port),
        0,
        "sockets left on the port after the stop"
    );
}

/// The UDP sockets bound to local `port`, as /proc/net/udp and udp6 list them.
fn sockets_on(port: u16) -> usize {
    let local = format!(":{port:04X} ");
    ["/proc/net/udp", "/proc/net/udp6"]
        .iter()
        .filter_map(|f| std::fs::read_to_string(f).ok())
        .flat_map(|t| t.lines().skip(1).map(str::to_string).collect::<Vec<_>>())
        .filter(|l| {
            l.split_whitespace()
                .nth(1)
                .is_some_and(|a| format!("{a} ").ends_with(&local))
        })
        .count()
}

/// A chain whose parameters are saved into a mapping file of its own (`name` in its path),
/// with the autopilot announced; that file, and the autopilot (kept for the test's length).
async fn chain_with_mapping_file(name: &str) -> (Chain, PathBuf, Peer) {
    let text = mapping(false, name);
    let file = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("peers-{name}-{}.toml", std::process::id()));
    std::fs::write(&file, &text).unwrap();
    let opts = ChainOptions {
        mapping_file: Some(file.clone()),
        ..ChainOptions::default()
    };
    let chain = Chain::start_opts(&text, opts).await;
    let mut ap = Peer::new(AP, false).await;
    ap.announce(chain.autopilot_port, &chain).await;
    (chain, file, ap)
}

/// The burst of 1 000 PARAM_SETs: [`WINDOWS`] windows of [`WINDOW_SETS`] sets, one window every
/// [`WINDOW_EVERY`].
const WINDOWS: u16 = 10;
const WINDOW_SETS: u16 = 100;
const WINDOW_EVERY: Duration = Duration::from_millis(100);

/// A view of the bridge made after this call: it holds whatever the bridge had done by then.
async fn view_from_now(chain: &Chain) -> BridgeView {
    let mut view = chain.view.clone();
    view.mark_unchanged();
    // The view is made again at least every 200 ms, whatever comes in.
    tokio::time::timeout(Duration::from_secs(10), view.changed())
        .await
        .expect("a new view within 10 s")
        .expect("the bridge runs");
    view.borrow().clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_a_thousand_param_sets_writes_the_file_a_bounded_number_of_times() {
    let (chain, file, _ap) = chain_with_mapping_file("burst").await;
    let port = chain.autopilot_port;
    let set = |name: &str, value: f32| {
        MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: BRIDGE.1,
            param_id: name.into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    };
    // Two parameters, a value never sent before in each set (a set of the value the file will
    // hold anyway is no change): the trim 1 000–1 499 µs, the maximum 1 600–2 099 µs, always
    // above the trim, which stays above the minimum (920 µs).
    let trim = |i: u16| 1000.0 + f32::from(i);
    let max = |i: u16| 1600.0 + f32::from(i);
    let read = MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
        param_index: -1,
        target_system: 1,
        target_component: BRIDGE.1,
        param_id: "S1_PWM_MIN".into(),
    });
    let reads_answered = |gcs: &Peer| {
        gcs.heard
            .lock()
            .unwrap()
            .iter()
            .filter(|(_, m, _)| {
                matches!(m, MavMessage::PARAM_VALUE(v) if v.param_id.to_str().is_ok_and(|id| id == "S1_PWM_MIN"))
            })
            .count()
    };
    // Sent so that the kernel drops none of it: each window is 101 datagrams (its sets, then
    // a read), half of what the bridge's socket buffer holds at the default 208 KiB, and the
    // next window goes only once the bridge has answered the read that closed the one before
    // (it reads a link in order: the answer says it took the whole window in). The windows
    // are paced, one every 100 ms: the burst is planned to last 900 ms from the first window
    // to the last. Each window comes from a ground station of its own: the bridge's loop takes
    // at most 100 messages a second from a system other than the autopilot, in bursts of 200
    // (`mavlink::admission`), and a window is 101.
    let start = tokio::time::Instant::now();
    let mut gcs = Peer::new((200, 190), false).await;
    for window in 0..WINDOWS {
        if window > 0 {
            gcs = Peer::new((200 + window as u8, 190), false).await;
        }
        tokio::time::sleep_until(start + WINDOW_EVERY * u32::from(window)).await;
        for k in 0..WINDOW_SETS / 2 {
            let i = window * (WINDOW_SETS / 2) + k;
            gcs.send(port, &set("S1_PWM_TRIM", trim(i))).await;
            gcs.send(port, &set("S1_PWM_MAX", max(i))).await;
        }
        gcs.send(port, &read).await;
        let closed = usize::from(window) + 1;
        let deadline = Instant::now() + Duration::from_secs(20);
        while reads_answered(&gcs) < 1 {
            assert!(
                Instant::now() < deadline,
                "no answer to the read closing window {closed} (receive drops: {:?})",
                chain.view.borrow().receive_drops
            );
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    }
    // Nothing was lost: the kernel counts what it drops and tells it with the next datagram
    // it queues, here the read that closed the window.
    let lost = view_from_now(&chain).await.receive_drops;
    assert_eq!(
        lost.first(),
        Some(&0),
        "datagrams of the burst dropped by the kernel (per link)"
    );
    // The latest values are the ones kept: the answer to a set goes out once the file holds it.
    let last = WINDOWS * (WINDOW_SETS / 2) - 1;
    let (trim, max) = (trim(last), max(last));
    for (name, value) in [("S1_PWM_TRIM", trim), ("S1_PWM_MAX", max)] {
        gcs.wait_for(&format!("PARAM_VALUE of {name} = {value}"), |h| {
            h.iter().any(|(_, m, _)| {
                matches!(m, MavMessage::PARAM_VALUE(v) if v.param_value == value
                    && v.param_id.to_str().unwrap_or("") == name)
            })
        })
        .await;
    }
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(
        text.contains(&format!("pwm_trim_us = {trim}"))
            && text.contains(&format!("pwm_max_us = {max}")),
        "the file does not hold the last values {trim} and {max}: {text}"
    );
    // Both last values are written: no set waits any more, the count of writes is final.
    //
    // The writer takes one change at a time, the next once the last is written, and starts a
    // write at least MAPPING_WRITE_SPACING after the one before. So while the bridge takes the
    // burst in (for a time D), it is handed at most 1 + ⌈D / spacing⌉ changes, and after it at
    // most one per parameter still waiting (2). D is the planned 900 ms and a margin of
    // 200 ms: on a loaded machine the last window may reach the bridge late (the sender's
    // timer and the bridge's task each wait for a core).
    let planned = WINDOW_EVERY * u32::from(WINDOWS - 1);
    let margin = Duration::from_millis(200);
    let spacings = (planned + margin)
        .as_millis()
        .div_ceil(MAPPING_WRITE_SPACING.as_millis()) as u64;
    let bound = 1 + spacings + 2;
    let writes = view_from_now(&chain).await.mapping_writes;
    assert!(
        (2..=bound).contains(&writes),
        "{writes} writes of the mapping file for 1 000 sets on two parameters in {:?} \
         (at most {bound})",
        start.elapsed()
    );
    eprintln!("{writes} writes for 1 000 sets (at most {bound})");
    chain.stop().await;
    let _ = std::fs::remove_file(file);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sets_that_come_while_a_change_is_written_leave_the_latest_value_in_the_file() {
    let (chain, file, _ap) = chain_with_mapping_file("latest").await;
    let port = chain.autopilot_port;
    let set = |value: f32| {
        MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: BRIDGE.1,
            param_id: "S1_PWM_TRIM".into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    };
    // Four sets of one parameter back to back, each sent once (four datagrams: nothing for
    // the kernel to drop): the first is written at once, the others come while that write
    // and its spacing last, and only the last of them may follow it into the file.
    let mut gcs = Peer::new((255, 190), false).await;
    for trim in [1501.0, 1502.0, 1503.0, 1504.0] {
        gcs.send(port, &set(trim)).await;
    }
    gcs.wait_for("PARAM_VALUE of the last set", |h| {
        h.iter().any(|(_, m, _)| {
            matches!(m, MavMessage::PARAM_VALUE(v) if v.param_value == 1504.0
                && v.param_id.to_str().unwrap_or("") == "S1_PWM_TRIM")
        })
    })
    .await;
    let deadline = Instant::now() + Duration::from_secs(10);
    while chain.view.borrow().mapping_writes == 0 {
        assert!(Instant::now() < deadline, "the file was never written");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // The answer comes once the file holds the value: the file now holds 1504.
    let written = std::fs::read_to_string(&file).unwrap();
    assert!(written.contains("pwm_trim_us = 1504"), "{written}");
    let writes = chain.view.borrow().mapping_writes;
    assert!((1..=2).contains(&writes), "{writes} writes for four sets");
    chain.stop().await;
    let _ = std::fs::remove_file(file);
}
