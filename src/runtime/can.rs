//! The DroneCAN node's frames on a CAN interface: SocketCAN (`can0`, the aircraft's bus) or
//! ArduPilot SITL's multicast UDP (`mcast:N`, the simulated bus), behind one frame channel.
//!
//! One task owns the interface: it opens it (and, when that fails or the interface goes away,
//! says why once and tries again every [`REOPEN_EVERY`]: the bridge keeps its MAVLink links and
//! buses meanwhile), passes the frames received to the loop with the time they came, and sends
//! the frames the loop gives it. Frames the loop cannot take at once are dropped and counted,
//! never queued without bound; so are frames to send while the interface is closed.

use crate::config::CanInterface;
use crate::dronecan::frame::CanFrame;
use crate::dronecan::mcast;
use std::io;
use std::net::{Ipv4Addr, SocketAddrV4};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::io::unix::AsyncFd;
use tokio::net::UdpSocket;
use tokio::sync::mpsc;

/// How often a closed interface is tried again.
pub const REOPEN_EVERY: Duration = Duration::from_secs(1);

/// Frames waiting for the loop, or for the interface.
const QUEUE: usize = 256;

/// The loop's ends of the interface's task.
#[derive(Debug)]
pub struct CanLink {
    pub received: mpsc::Receiver<(CanFrame, Instant)>,
    pub to_send: mpsc::Sender<CanFrame>,
    /// Frames dropped: received while the loop's queue was full, or to send while the
    /// interface was closed or its queue full.
    pub dropped: Arc<AtomicU64>,
}

/// Start the task that owns `interface`.
pub fn spawn(interface: CanInterface) -> (CanLink, tokio::task::JoinHandle<()>) {
    let (rx_tx, received) = mpsc::channel(QUEUE);
    let (to_send, tx_rx) = mpsc::channel(QUEUE);
    let dropped = Arc::new(AtomicU64::new(0));
    let task = tokio::spawn(serve(interface, rx_tx, tx_rx, dropped.clone()));
    (
        CanLink {
            received,
            to_send,
            dropped,
        },
        task,
    )
}

async fn serve(
    interface: CanInterface,
    received: mpsc::Sender<(CanFrame, Instant)>,
    mut to_send: mpsc::Receiver<CanFrame>,
    dropped: Arc<AtomicU64>,
) {
    let mut said: Option<String> = None;
    loop {
        let port = match Port::open(&interface) {
            Ok(port) => port,
            Err(e) => {
                let why = opening_error(&interface, &e);
                if said.as_deref() != Some(why.as_str()) {
                    tracing::error!(
                        "{why}; trying again every {REOPEN_EVERY:?}, the bridge runs on meanwhile"
                    );
                    said = Some(why);
                }
                let until = tokio::time::Instant::now() + REOPEN_EVERY;
                while let Ok(Some(_)) = tokio::time::timeout_at(until, to_send.recv()).await {
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
                continue;
            }
        };
        if said.take().is_some() {
            tracing::info!("DroneCAN interface {interface} open");
        } else {
            tracing::info!("DroneCAN node on {interface}");
        }
        let e = run(&port, &received, &mut to_send, &dropped).await;
        match e {
            None => return,
            Some(e) => {
                let why = format!("DroneCAN interface {interface} lost: {e}");
                tracing::error!("{why}; trying again every {REOPEN_EVERY:?}");
                said = Some(why);
            }
        }
    }
}

/// Carry frames until the interface fails (its error) or the loop is gone (`None`).
async fn run(
    port: &Port,
    received: &mpsc::Sender<(CanFrame, Instant)>,
    to_send: &mut mpsc::Receiver<CanFrame>,
    dropped: &AtomicU64,
) -> Option<io::Error> {
    let mut send_error: Option<String> = None;
    let mut bus: Option<BusNews> = None;
    loop {
        tokio::select! {
            frame = port.recv() => match frame {
                Ok(Received::Bus(news)) => {
                    // Said when the bus's state changes, not per error frame.
                    if bus != Some(news) {
                        if news.is_trouble() {
                            tracing::warn!("DroneCAN: {news}");
                        } else {
                            tracing::info!("DroneCAN: {news}");
                        }
                        bus = Some(news);
                    }
                }
                Ok(Received::Frame(frame)) => {
                    if bus.is_some_and(BusNews::is_trouble) {
                        tracing::info!("DroneCAN: frames come in again");
                        bus = None;
                    }
                    if received.try_send((frame, Instant::now())).is_err() {
                        if received.is_closed() {
                            return None;
                        }
                        dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
                Ok(Received::Other) => {}
                Err(e) => return Some(e),
            },
            frame = to_send.recv() => {
                let frame = frame?;
                if let Err(e) = port.send(&frame).await {
                    dropped.fetch_add(1, Ordering::Relaxed);
                    if gone(&e) {
                        return Some(e);
                    }
                    // ENOBUFS: the adapter's queue is full, mostly because no other node
                    // acknowledges (the bus is unplugged or unterminated). Said once a spell.
                    let why = e.to_string();
                    if send_error.as_deref() != Some(why.as_str()) {
                        tracing::warn!("DroneCAN: a frame could not be sent ({why}); is another node on the bus, and the bus terminated?");
                        send_error = Some(why);
                    }
                } else {
                    send_error = None;
                }
            }
        }
    }
}

/// The interface is gone or down: close it and open it again.
fn gone(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::ENODEV | libc::ENETDOWN | libc::ENXIO | libc::EBADF)
    )
}

fn opening_error(interface: &CanInterface, e: &io::Error) -> String {
    match interface {
        CanInterface::SocketCan(name) if e.raw_os_error() == Some(libc::ENODEV) => format!(
            "DroneCAN: no network interface {name} (`ip link show {name}`; a CAN adapter's \
             driver loaded? brought up with its bit rate, see docs/dronecan.md)"
        ),
        CanInterface::SocketCan(name) if e.raw_os_error() == Some(libc::EAFNOSUPPORT) => {
            format!(
                "DroneCAN: this kernel has no SocketCAN (module can_raw), so {name} cannot be \
                 opened, or the service's RestrictAddressFamilies lacks AF_CAN"
            )
        }
        _ => format!("DroneCAN: cannot open {interface}: {e}"),
    }
}

/// An open interface.
enum Port {
    SocketCan(AsyncFd<OwnedFd>),
    Multicast {
        inbound: UdpSocket,
        outbound: UdpSocket,
        group: SocketAddrV4,
    },
}

impl Port {
    fn open(interface: &CanInterface) -> io::Result<Port> {
        match interface {
            CanInterface::SocketCan(name) => {
                let fd = socketcan(name)?;
                // SAFETY: an OwnedFd keeps its descriptor open and the same until it is
                // dropped with the AsyncFd.
                let fd = unsafe { AsyncFd::register(fd) }.map_err(io::Error::from)?;
                Ok(Port::SocketCan(fd))
            }
            CanInterface::Multicast(n) => {
                let o = mcast::GROUP.octets();
                let group = SocketAddrV4::new(Ipv4Addr::new(o[0], o[1], o[2], *n), mcast::PORT);
                let inbound = multicast_inbound(group)?;
                let outbound = std::net::UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0))?;
                outbound.set_nonblocking(true)?;
                Ok(Port::Multicast {
                    inbound: UdpSocket::from_std(inbound)?,
                    outbound: UdpSocket::from_std(outbound)?,
                    group,
                })
            }
        }
    }

    /// The next frame, or what an error frame says of the bus; `Ok(Received::Other)` for
    /// something that is neither (a standard id, CAN FD, a stranger's datagram).
    async fn recv(&self) -> io::Result<Received> {
        match self {
            Port::SocketCan(fd) => loop {
                let mut guard = fd.readable().await?;
                let mut raw: libc::can_frame = unsafe { std::mem::zeroed() };
                let n = guard.try_io(|fd| {
                    // SAFETY: `raw` is a can_frame of its own size, written by the kernel.
                    let n = unsafe {
                        libc::read(
                            fd.as_raw_fd(),
                            (&raw mut raw).cast(),
                            std::mem::size_of::<libc::can_frame>(),
                        )
                    };
                    if n < 0 {
                        Err(io::Error::last_os_error())
                    } else {
                        Ok(n as usize)
                    }
                });
                let Ok(n) = n else { continue };
                let n = n?;
                if n < std::mem::size_of::<libc::can_frame>() {
                    return Ok(Received::Other);
                }
                if let Some(news) = bus_news(&raw) {
                    return Ok(Received::Bus(news));
                }
                return Ok(from_socketcan(&raw).map_or(Received::Other, Received::Frame));
            },
            Port::Multicast { inbound, .. } => {
                let mut buf = [0u8; 128];
                let n = inbound.recv(&mut buf).await?;
                Ok(mcast::decode(&buf[..n]).map_or(Received::Other, Received::Frame))
            }
        }
    }

    async fn send(&self, frame: &CanFrame) -> io::Result<()> {
        match self {
            Port::SocketCan(fd) => loop {
                let raw = to_socketcan(frame);
                let mut guard = fd.writable().await?;
                let sent = guard.try_io(|fd| {
                    // SAFETY: `raw` is a whole can_frame.
                    let n = unsafe {
                        libc::write(
                            fd.as_raw_fd(),
                            (&raw const raw).cast(),
                            std::mem::size_of::<libc::can_frame>(),
                        )
                    };
                    if n < 0 {
                        Err(io::Error::last_os_error())
                    } else {
                        Ok(())
                    }
                });
                if let Ok(result) = sent {
                    return result;
                }
            },
            Port::Multicast {
                outbound, group, ..
            } => outbound
                .send_to(&mcast::encode(frame), *group)
                .await
                .map(drop),
        }
    }
}

/// A raw CAN socket bound to interface `name`, non-blocking, with the error frames that tell of
/// bus-off, the controller's error state, a restart and missing acknowledgements.
fn socketcan(name: &str) -> io::Result<OwnedFd> {
    let index = nix::net::if_::if_nametoindex(name).map_err(io::Error::from)?;
    // SAFETY: a plain socket(2) call; the descriptor is owned at once.
    let fd = unsafe {
        libc::socket(
            libc::PF_CAN,
            libc::SOCK_RAW | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
            libc::CAN_RAW,
        )
    };
    if fd < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: `fd` was just returned by socket(2) and is owned by nothing else.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    let mut addr: libc::sockaddr_can = unsafe { std::mem::zeroed() };
    addr.can_family = libc::AF_CAN as libc::sa_family_t;
    addr.can_ifindex = index as libc::c_int;
    // SAFETY: `addr` is a sockaddr_can of its own size.
    let r = unsafe {
        libc::bind(
            fd.as_raw_fd(),
            (&raw const addr).cast(),
            std::mem::size_of::<libc::sockaddr_can>() as libc::socklen_t,
        )
    };
    if r < 0 {
        return Err(io::Error::last_os_error());
    }
    let errors: libc::can_err_mask_t =
        libc::CAN_ERR_BUSOFF | libc::CAN_ERR_CRTL | libc::CAN_ERR_RESTARTED | libc::CAN_ERR_ACK;
    // SAFETY: the option's value is a can_err_mask_t of its own size.
    let r = unsafe {
        libc::setsockopt(
            fd.as_raw_fd(),
            libc::SOL_CAN_RAW,
            libc::CAN_RAW_ERR_FILTER,
            (&raw const errors).cast(),
            std::mem::size_of::<libc::can_err_mask_t>() as libc::socklen_t,
        )
    };
    if r < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(fd)
}

/// What the interface gave.
enum Received {
    Frame(CanFrame),
    Bus(BusNews),
    Other,
}

/// What the adapter's error frames say of the bus (those of CAN_RAW_ERR_FILTER's mask above).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BusNews {
    BusOff,
    Restarted,
    Passive,
    Warning,
    Active,
    NoAck,
}

impl BusNews {
    fn is_trouble(self) -> bool {
        !matches!(self, BusNews::Restarted | BusNews::Active)
    }
}

impl std::fmt::Display for BusNews {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            BusNews::BusOff => {
                "the CAN adapter went bus-off (too many errors: a wrong bit rate, a short or open \
                 wire, a babbling node); it sends and hears nothing until restarted \
                 (systemd-networkd's RestartSec=, or `ip link set can0 type can restart-ms 100`)"
            }
            BusNews::Restarted => "the CAN adapter restarted after bus-off",
            BusNews::Passive => {
                "the CAN adapter is error-passive: many errors on the bus (check the bit rate, \
                 the termination, the wiring)"
            }
            BusNews::Warning => "the CAN adapter counts errors on the bus (error warning)",
            BusNews::Active => "the CAN adapter is error-active again",
            BusNews::NoAck => {
                "no node acknowledges the bridge's frames: is the autopilot on and on this bus, \
                 and the bus terminated?"
            }
        })
    }
}

/// The news of an error frame (`None` for any other frame), the worst it carries.
fn bus_news(raw: &libc::can_frame) -> Option<BusNews> {
    let id = raw.can_id;
    if id & libc::CAN_ERR_FLAG == 0 {
        return None;
    }
    let controller = i32::from(raw.data[1]);
    Some(if id & libc::CAN_ERR_BUSOFF != 0 {
        BusNews::BusOff
    } else if id & libc::CAN_ERR_RESTARTED != 0 {
        BusNews::Restarted
    } else if id & libc::CAN_ERR_CRTL != 0
        && controller & (libc::CAN_ERR_CRTL_RX_PASSIVE | libc::CAN_ERR_CRTL_TX_PASSIVE) != 0
    {
        BusNews::Passive
    } else if id & libc::CAN_ERR_CRTL != 0
        && controller & (libc::CAN_ERR_CRTL_RX_WARNING | libc::CAN_ERR_CRTL_TX_WARNING) != 0
    {
        BusNews::Warning
    } else if id & libc::CAN_ERR_CRTL != 0 && controller & libc::CAN_ERR_CRTL_ACTIVE != 0 {
        BusNews::Active
    } else if id & libc::CAN_ERR_ACK != 0 {
        BusNews::NoAck
    } else {
        return None;
    })
}

/// A DroneCAN frame from a SocketCAN one: extended, data, not an error or remote frame.
fn from_socketcan(raw: &libc::can_frame) -> Option<CanFrame> {
    let id = raw.can_id;
    if id & libc::CAN_EFF_FLAG == 0 || id & (libc::CAN_ERR_FLAG | libc::CAN_RTR_FLAG) != 0 {
        return None;
    }
    let len = usize::from(raw.can_dlc).min(8);
    CanFrame::new(id & libc::CAN_EFF_MASK, &raw.data[..len])
}

fn to_socketcan(frame: &CanFrame) -> libc::can_frame {
    // SAFETY: can_frame is plain data; all zero is a valid empty frame.
    let mut raw: libc::can_frame = unsafe { std::mem::zeroed() };
    raw.can_id = frame.id() | libc::CAN_EFF_FLAG;
    raw.can_dlc = frame.data().len() as u8;
    raw.data[..frame.data().len()].copy_from_slice(frame.data());
    raw
}

/// A socket that hears `group` (SO_REUSEADDR, as ArduPilot's SITL binds it, so both can).
fn multicast_inbound(group: SocketAddrV4) -> io::Result<std::net::UdpSocket> {
    use nix::sys::socket::{
        AddressFamily, IpMembershipRequest, SockFlag, SockType, SockaddrIn, bind, setsockopt,
        socket, sockopt,
    };
    let fd = socket(
        AddressFamily::Inet,
        SockType::Datagram,
        SockFlag::SOCK_NONBLOCK | SockFlag::SOCK_CLOEXEC,
        None,
    )?;
    setsockopt(&fd, sockopt::ReuseAddr, &true)?;
    bind(fd.as_raw_fd(), &SockaddrIn::from(group))?;
    setsockopt(
        &fd,
        sockopt::IpAddMembership,
        &IpMembershipRequest::new(*group.ip(), None),
    )?;
    Ok(std::net::UdpSocket::from(fd))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_socketcan_frame_is_taken_only_extended_and_with_data() {
        let f = CanFrame::new(0x0803_F20A, &[1, 2, 3, 0xC0]).unwrap();
        let raw = to_socketcan(&f);
        assert_eq!(raw.can_id, 0x0803_F20A | libc::CAN_EFF_FLAG);
        assert_eq!(from_socketcan(&raw), Some(f));
        let mut standard = raw;
        standard.can_id = 0x123;
        assert_eq!(from_socketcan(&standard), None);
        let mut error = raw;
        error.can_id |= libc::CAN_ERR_FLAG;
        assert_eq!(from_socketcan(&error), None);
    }

    #[test]
    fn an_error_frame_says_what_became_of_the_bus() {
        let frame = |id: u32, controller: i32| {
            // SAFETY: can_frame is plain data.
            let mut raw: libc::can_frame = unsafe { std::mem::zeroed() };
            raw.can_id = libc::CAN_ERR_FLAG | id;
            raw.can_dlc = 8;
            raw.data[1] = controller as u8;
            raw
        };
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_BUSOFF, 0)),
            Some(BusNews::BusOff)
        );
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_CRTL, libc::CAN_ERR_CRTL_TX_PASSIVE)),
            Some(BusNews::Passive)
        );
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_CRTL, libc::CAN_ERR_CRTL_RX_WARNING)),
            Some(BusNews::Warning)
        );
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_CRTL, libc::CAN_ERR_CRTL_ACTIVE)),
            Some(BusNews::Active)
        );
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_RESTARTED, 0)),
            Some(BusNews::Restarted)
        );
        assert_eq!(bus_news(&frame(libc::CAN_ERR_ACK, 0)), Some(BusNews::NoAck));
        // Bus-off outweighs what else the same frame says.
        assert_eq!(
            bus_news(&frame(libc::CAN_ERR_BUSOFF | libc::CAN_ERR_ACK, 0)),
            Some(BusNews::BusOff)
        );
        let data = to_socketcan(&CanFrame::new(0x0803_F20A, &[0xC0]).unwrap());
        assert_eq!(bus_news(&data), None);
        assert!(BusNews::BusOff.to_string().contains("bus-off"));
        assert!(!BusNews::Active.is_trouble() && BusNews::NoAck.is_trouble());
    }

    #[tokio::test]
    async fn a_missing_interface_is_named_with_what_to_check() {
        let e = Port::open(&CanInterface::SocketCan("lj9nocan0".into()))
            .err()
            .unwrap();
        let why = opening_error(&CanInterface::SocketCan("lj9nocan0".into()), &e);
        assert!(why.contains("no network interface lj9nocan0"), "{why}");
    }
}
