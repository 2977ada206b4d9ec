//! A link whose peer stops reading holds neither the other link nor a goal. The ground station
//! is a TCP peer (as MAVProxy or a telemetry radio's bridge can be) that connects, reads
//! parameters faster than it could take the answers, and reads nothing for 10 s or more (until
//! the bridge drops some for it); meanwhile the test, as the autopilot, changes its outputs
//! every 250 ms on the other link, and each change must reach the simulated servo. What the ground-station link could not take is dropped, oldest
//! telemetry first, and counted in the view; once the peer reads again it hears the bridge.

mod common;

use common::mapping::Mapping;
use common::peer::{Autopilot, outputs};
use common::{Chain, ChainOptions};
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use std::io::Read;
use std::net::TcpListener;
use std::os::fd::AsRawFd;
use std::time::{Duration, Instant};

/// Two servos; the outputs asked for at 50 Hz, telemetry at 50 Hz.
fn mapping() -> Mapping {
    Mapping::new()
        .with("[mavlink]", "output_rate_hz = 50")
        .with("[telemetry]", "rate_hz = 50")
        .servo("aileron", 1, 1)
        .servo("elevator", 2, 2)
}

/// A listening socket whose connections have a small receive buffer and a radio link's
/// segment size, so that a peer that does not read fills up within a second. (Over loopback's
/// 64 KiB segments the sender's own buffer would start at megabytes.)
fn small_buffer_listener() -> TcpListener {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    for (option, value, name) in [
        (libc::SO_RCVBUF, 4096, "SO_RCVBUF"),
        (libc::TCP_MAXSEG, 536, "TCP_MAXSEG"),
    ] {
        let level = if option == libc::TCP_MAXSEG {
            libc::IPPROTO_TCP
        } else {
            libc::SOL_SOCKET
        };
        let value: libc::c_int = value;
        // SAFETY: a valid socket and a c_int option value of the size given.
        let r = unsafe {
            libc::setsockopt(
                listener.as_raw_fd(),
                level,
                option,
                (&value as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            )
        };
        assert_eq!(r, 0, "{name}");
    }
    listener
}

/// A read of parameter `index`, answered at once with its PARAM_VALUE on the link it came in
/// on (the bridge's system ID is the autopilot's; component 0 asks every component).
fn param_read(index: i16) -> MavMessage {
    MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
        target_system: 1,
        target_component: 0,
        param_index: index,
        ..Default::default()
    })
}

/// Parameter reads the ground station sends per autopilot tick: 10,000 a second.
const READS_PER_TICK: usize = 200;
/// The systems they claim to come from, in turn. The bridge's loop takes at most 100 messages
/// a second from the link (`mavlink::admission`: one budget per sender, whatever ids it
/// claims), so the station gets about 100 answers a second beside its telemetry: the stall
/// lasts until the link's outbox drops, at least [`STALL`] and at most [`STALL_AT_MOST`].
const SYSTEMS: usize = 40;
/// The peer reads nothing for at least this long, each change of the outputs checked.
const STALL: Duration = Duration::from_secs(10);
/// And at most this long, until the bridge has had to drop something for it.
const STALL_AT_MOST: Duration = Duration::from_secs(60);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ground_station_that_stops_reading_holds_no_goal() {
    let listener = small_buffer_listener();
    let port = listener.local_addr().unwrap().port();
    let chain = Chain::start_opts(
        mapping(),
        ChainOptions {
            gcs_address: Some(format!("tcpout:127.0.0.1:{port}")),
            ..ChainOptions::default()
        },
    )
    .await;
    let (mut station, _) = tokio::task::spawn_blocking(move || listener.accept())
        .await
        .unwrap()
        .expect("the bridge connects to the ground station");
    let ap = Autopilot::connect(chain.autopilot_port).await;
    ap.heartbeat().await;
    let sim = chain.sims[0].handle();

    // Outputs at 50 Hz for the stall's length, the value of channel 1 changing every 250 ms
    // between +10 and −10 mm; the ground station asks for parameters and reads nothing.
    let start = Instant::now();
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    let mut changes = 0u32;
    let mut awaited: Option<(f32, Instant)> = None;
    let mut latencies = Vec::new();
    let mut k = 0u32;
    let stalled_drops = |chain: &Chain| chain.view.borrow().send_drops.get(1).copied();
    while start.elapsed() < STALL
        || (stalled_drops(&chain) == Some(0) && start.elapsed() < STALL_AT_MOST)
    {
        tick.tick().await;
        let step = k / 12;
        let (us, mm) = if step.is_multiple_of(2) {
            (1760, 10.0)
        } else {
            (1280, -10.0)
        };
        if k.is_multiple_of(12) {
            changes += 1;
            if let Some((mm, since)) = awaited.take() {
                panic!(
                    "the goal {mm} mm sent {:?} ago never reached the servo (change {changes})",
                    since.elapsed()
                );
            }
            awaited = Some((mm, Instant::now()));
        }
        ap.send(&outputs(&[us, 1520])).await;
        if k.is_multiple_of(50) {
            ap.heartbeat().await;
        }
        let mut frames = Vec::new();
        for n in 0..READS_PER_TICK {
            let header = MavHeader {
                system_id: 200 + (n % SYSTEMS) as u32,
                component_id: 190,
                sequence: n as u8,
            };
            mavlink::write_v2_msg(&mut frames, header, &param_read((n % 30) as i16)).unwrap();
        }
        // The bridge reads what it is sent, though its peer does not read what it sends.
        std::io::Write::write_all(&mut station, &frames).unwrap();
        if let Some((mm, since)) = awaited
            && sim
                .snapshot(1)
                .is_some_and(|s| (s.goal_mm - mm).abs() < 0.05)
        {
            latencies.push(since.elapsed());
            awaited = None;
        }
        k += 1;
    }
    latencies.sort();
    println!(
        "{changes} changes, {} reached the servo; slowest {:?}",
        latencies.len(),
        latencies.last()
    );
    assert!(
        latencies.len() + 1 >= changes as usize,
        "{} of {changes} changes reached the servo",
        latencies.len()
    );
    let drops = chain.view.borrow().send_drops.clone();

    assert_eq!(drops.len(), 2, "{drops:?}");
    assert_eq!(drops[0], 0, "the autopilot's link dropped nothing");
    assert!(
        drops[1] > 0,
        "the stalled link's drops are counted: {drops:?}"
    );

    // The peer reads again: the bridge's messages come through.
    station.set_nonblocking(false).unwrap();
    station
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut buf = vec![0u8; 1 << 20];
    let mut heard = 0;
    let deadline = Instant::now() + Duration::from_secs(10);
    while heard < 64 * 1024 && Instant::now() < deadline {
        match station.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => heard += n,
        }
    }
    assert!(heard > 0, "nothing heard once the peer read again");
    chain.stop().await;
}
