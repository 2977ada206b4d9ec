//! A `udpin` link: the bridge's own UDP socket, listening.
//!
//! The `mavlink` crate's replies to whoever sent the last datagram, a dropped one included:
//! with signing on, a stranger's unsigned datagram would steer where the bridge's signed
//! messages go, and with two systems on the port each gets part of them. Here the bridge's
//! messages go to every peer heard recently ([`Peers`]), and a peer is heard only by a datagram
//! that held a frame the bridge accepted (with signing on, a correctly signed fresh one).
//!
//! Each peer also gets a socket of its own, connected to it, on the same local port
//! (`SO_REUSEPORT`): the kernel puts a datagram into the socket connected to its sender
//! before the listening one, so each peer's datagrams wait in a queue of their own. A stranger
//! flooding the port fills the listening socket's queue (or its own, once it is a peer), and
//! the kernel drops its datagrams there, never the autopilot's.

use crate::mavlink::peers::{MAX_PEERS, PEER_TIMEOUT, PeerChange, Peers};
use nix::sys::socket::{
    AddressFamily, ControlMessageOwned, MsgFlags, SockFlag, SockType, SockaddrStorage, bind,
    connect, recvmsg, setsockopt, socket, sockopt,
};
use std::io::IoSliceMut;
use std::net::{SocketAddr, ToSocketAddrs};
use std::os::fd::{AsRawFd, OwnedFd};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Instant;
use tokio::io::Interest;
use tokio::task::AbortHandle;

/// One socket of the link, and the datagrams the kernel dropped on it.
pub struct Socket {
    socket: tokio::net::UdpSocket,
    /// Datagrams the kernel dropped because the socket's receive buffer was full (the bridge
    /// did not read in time), as `SO_RXQ_OVFL` counts them: the kernel tells the count with the
    /// next datagram it queues after a drop. `None` where it cannot count.
    lost: Option<AtomicU64>,
}

impl Socket {
    /// A UDP socket bound to `local` with `SO_REUSEPORT` (so that the link's sockets share the
    /// port), connected to `peer` if given, non-blocking, on the current tokio runtime.
    fn open(local: SocketAddr, peer: Option<SocketAddr>) -> std::io::Result<Socket> {
        let family = match local {
            SocketAddr::V4(_) => AddressFamily::Inet,
            SocketAddr::V6(_) => AddressFamily::Inet6,
        };
        let fd: OwnedFd = socket(
            family,
            SockType::Datagram,
            SockFlag::SOCK_NONBLOCK | SockFlag::SOCK_CLOEXEC,
            None,
        )?;
        setsockopt(&fd, sockopt::ReusePort, &true)?;
        bind(fd.as_raw_fd(), &SockaddrStorage::from(local))?;
        if let Some(peer) = peer {
            connect(fd.as_raw_fd(), &SockaddrStorage::from(peer))?;
        }
        let lost = match setsockopt(&fd, sockopt::RxqOvfl, &1) {
            Ok(()) => Some(AtomicU64::new(0)),
            Err(e) => {
                tracing::debug!(%local, "datagrams dropped on receipt are not counted: {e}");
                None
            }
        };
        let socket = tokio::net::UdpSocket::from_std(std::net::UdpSocket::from(fd))?;
        Ok(Socket { socket, lost })
    }

    /// The next datagram into `buf`: its length and sender, and whether the kernel's count of
    /// drops on this socket grew (the new total).
    async fn recv_from(&self, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr, Option<u64>)> {
        let fd = self.socket.as_raw_fd();
        let (n, from, lost) = self
            .socket
            .async_io(Interest::READABLE, || receive(fd, buf))
            .await?;
        Ok((n, from, self.count(lost)))
    }

    /// A datagram already queued (`None`: none now), as [`Socket::recv_from`].
    fn try_recv_from(
        &self,
        buf: &mut [u8],
    ) -> std::io::Result<Option<(usize, SocketAddr, Option<u64>)>> {
        let fd = self.socket.as_raw_fd();
        match self.socket.try_io(Interest::READABLE, || receive(fd, buf)) {
            Ok((n, from, lost)) => Ok(Some((n, from, self.count(lost)))),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// The kernel's count of drops (of the socket's life, in 32 bits): the new total if it grew.
    fn count(&self, lost: Option<u32>) -> Option<u64> {
        let (counter, total) = (self.lost.as_ref()?, u64::from(lost?));
        (counter.fetch_max(total, Ordering::Relaxed) < total).then_some(total)
    }

    fn lost(&self) -> u64 {
        self.lost.as_ref().map_or(0, |l| l.load(Ordering::Relaxed))
    }
}

/// One `recvmsg`: the bytes, the sender, and the kernel's count of drops if it came with it.
fn receive(fd: i32, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr, Option<u32>)> {
    let mut iov = [IoSliceMut::new(buf)];
    let mut space = nix::cmsg_space!(u32);
    let msg = recvmsg::<SockaddrStorage>(fd, &mut iov, Some(&mut space), MsgFlags::MSG_DONTWAIT)
        .map_err(std::io::Error::from)?;
    let lost = msg.cmsgs().ok().and_then(|mut cmsgs| {
        cmsgs.find_map(|c| match c {
            ControlMessageOwned::RxqOvfl(n) => Some(n),
            _ => None,
        })
    });
    let from = msg
        .address
        .as_ref()
        .and_then(socket_addr)
        .ok_or_else(|| std::io::Error::other("a datagram without a sender address"))?;
    Ok((msg.bytes, from, lost))
}

/// A socket address of the IP families (a UDP socket's sender is one).
fn socket_addr(address: &SockaddrStorage) -> Option<SocketAddr> {
    if let Some(v4) = address.as_sockaddr_in() {
        return Some(SocketAddr::V4((*v4).into()));
    }
    address
        .as_sockaddr_in6()
        .map(|v6| SocketAddr::V6((*v6).into()))
}

/// A peer's own socket and the task that reads it.
struct Own {
    peer: SocketAddr,
    socket: Arc<Socket>,
    task: Option<AbortHandle>,
}

/// A `udpin` link (see the module's documentation).
pub struct UdpIn {
    /// The listening socket: every datagram of a sender without a socket of its own.
    listening: Socket,
    local: SocketAddr,
    peers: Mutex<Peers>,
    own: Mutex<Vec<Own>>,
    /// Drops on the sockets of peers that left.
    lost_before: AtomicU64,
    /// Whether drops were said (the first time is a warning).
    lost_said: std::sync::atomic::AtomicBool,
    /// The link's address (`udpin:…`), for the log.
    address: String,
}

impl UdpIn {
    /// Bind `local` (of the link `address`). Refused when another socket already listens on
    /// that port: with `SO_REUSEPORT` the kernel would share the datagrams between the two.
    pub fn bind(address: &str, local: &str) -> std::io::Result<Self> {
        let local = local.to_socket_addrs()?.next().ok_or_else(|| {
            std::io::Error::new(std::io::ErrorKind::InvalidInput, "no address to bind")
        })?;
        let listening = Socket::open(local, None)?;
        let local = listening.socket.local_addr()?;
        // The socket's inode, as the kernel's table lists it (`stat` through the fd's link).
        let own = std::fs::metadata(format!("/proc/self/fd/{}", listening.socket.as_raw_fd()))
            .map(|m| std::os::unix::fs::MetadataExt::ino(&m));
        let others = others_listening(local, own.ok());
        if !others.is_empty() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                format!(
                    "another program listens on UDP port {} ({})",
                    local.port(),
                    describe(&others)
                ),
            ));
        }
        Ok(UdpIn {
            listening,
            local,
            peers: Mutex::new(Peers::default()),
            own: Mutex::new(Vec::new()),
            lost_before: AtomicU64::new(0),
            lost_said: std::sync::atomic::AtomicBool::new(false),
            address: address.to_string(),
        })
    }

    /// Datagrams the kernel dropped before the bridge read them, on all the link's sockets.
    pub fn lost(&self) -> u64 {
        let own: u64 = self.own().iter().map(|o| o.socket.lost()).sum();
        self.listening.lost() + own + self.lost_before.load(Ordering::Relaxed)
    }

    /// The next datagram on the listening socket: its length and sender.
    pub async fn recv_from(&self, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr)> {
        let (n, from, grew) = self.listening.recv_from(buf).await?;
        self.tell_lost(grew, None);
        Ok((n, from))
    }

    /// A datagram already queued on the listening socket (`None`: none now).
    pub fn try_recv_from(&self, buf: &mut [u8]) -> std::io::Result<Option<(usize, SocketAddr)>> {
        let received = self.listening.try_recv_from(buf)?;
        Ok(received.map(|(n, from, grew)| {
            self.tell_lost(grew, None);
            (n, from)
        }))
    }

    /// The next datagram on `peer`'s own socket.
    pub async fn recv_own(
        &self,
        peer: SocketAddr,
        socket: &Socket,
        buf: &mut [u8],
    ) -> std::io::Result<(usize, SocketAddr)> {
        let (n, from, grew) = socket.recv_from(buf).await?;
        self.tell_lost(grew, Some(peer));
        Ok((n, from))
    }

    /// Log the growth of a socket's drops (the first time on the link as a warning).
    fn tell_lost(&self, grew: Option<u64>, peer: Option<SocketAddr>) {
        let Some(total) = grew else {
            return;
        };
        let from = match peer {
            Some(peer) => format!("{peer}'s socket"),
            None => "the listening socket".into(),
        };
        let message = format!(
            "datagrams lost before the bridge read them: {from}'s receive buffer was full (the \
             bridge was held up, or the sender floods the port; the count is in sitl's view)"
        );
        if !self.lost_said.swap(true, Ordering::Relaxed) {
            tracing::warn!(address = %self.address, total, "{message}");
        } else {
            tracing::debug!(address = %self.address, total, "{message}");
        }
    }

    fn peers(&self) -> MutexGuard<'_, Peers> {
        self.peers.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn own(&self) -> MutexGuard<'_, Vec<Own>> {
        self.own.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// `from` sent a frame the bridge accepted. Returns the socket of its own when it is new
    /// (it just joined): the caller starts a task that reads it and hands its handle to
    /// [`UdpIn::reading`].
    pub fn heard(&self, from: SocketAddr) -> Option<Arc<Socket>> {
        let changes = self.peers().heard(from, Instant::now());
        self.tell(&changes);
        if !changes.contains(&PeerChange::Joined(from)) || self.own().iter().any(|o| o.peer == from)
        {
            return None;
        }
        match Socket::open(self.local, Some(from)) {
            Ok(socket) => {
                let socket = Arc::new(socket);
                self.own().push(Own {
                    peer: from,
                    socket: socket.clone(),
                    task: None,
                });
                Some(socket)
            }
            Err(e) => {
                tracing::warn!(address = %self.address, "no socket of its own for {from} (its datagrams share the listening socket's queue): {e}");
                None
            }
        }
    }

    /// The task that reads `peer`'s own socket, ended when the peer leaves.
    pub fn reading(&self, peer: SocketAddr, task: AbortHandle) {
        match self.own().iter_mut().find(|o| o.peer == peer) {
            Some(own) => own.task = Some(task),
            None => task.abort(),
        }
    }

    /// Whether anyone is to be sent to now.
    pub fn has_peers(&self) -> bool {
        self.peers().any(Instant::now())
    }

    /// Where a message sent now goes (peers silent for too long are dropped first).
    fn addresses(&self) -> Vec<SocketAddr> {
        let now = Instant::now();
        let mut peers = self.peers();
        let left = peers.expire(now);
        let addresses = peers.addresses(now).collect();
        drop(peers);
        self.tell(&left);
        addresses
    }

    /// Send `bytes` to every peer heard recently. One peer's error (an ICMP unreachable from a
    /// gone ground station) holds up none of the others.
    pub async fn send(&self, bytes: &[u8]) -> std::io::Result<usize> {
        let (mut sent, mut failed) = (0, None);
        for peer in self.addresses() {
            match self.listening.socket.send_to(bytes, peer).await {
                Ok(n) => sent += n,
                Err(e) => failed = Some(e),
            }
        }
        match failed {
            Some(e) if sent == 0 => Err(e),
            _ => Ok(sent),
        }
    }

    /// Log what changed in who the link answers, and close the own socket of a peer that left.
    fn tell(&self, changes: &[PeerChange]) {
        for change in changes {
            match change {
                PeerChange::Joined(peer) => tracing::info!(
                    address = %self.address,
                    "{peer} heard: the bridge's messages on this link go to it too"
                ),
                PeerChange::Left(peer) => tracing::info!(
                    address = %self.address,
                    "{peer} silent for {} s: the bridge's messages no longer go to it",
                    PEER_TIMEOUT.as_secs()
                ),
                PeerChange::Replaced(peer) => tracing::warn!(
                    address = %self.address,
                    "{peer} dropped to make room for a new peer: the link answers at most \
                     {MAX_PEERS}"
                ),
            }
            if let PeerChange::Left(peer) | PeerChange::Replaced(peer) = change {
                let mut own = self.own();
                if let Some(i) = own.iter().position(|o| o.peer == *peer) {
                    let gone = own.swap_remove(i);
                    self.lost_before
                        .fetch_add(gone.socket.lost(), Ordering::Relaxed);
                    if let Some(task) = gone.task {
                        task.abort();
                    }
                }
            }
        }
    }
}

impl UdpIn {
    /// Stop reading the peers' own sockets, and close them: their tasks hold the link, so
    /// that dropping it does not end them. Said by the bridge as it stops.
    pub fn close_peers(&self) {
        for own in self.own().drain(..) {
            if let Some(task) = own.task {
                task.abort();
            }
        }
    }
}

impl Drop for UdpIn {
    fn drop(&mut self) {
        self.close_peers();
    }
}

/// A socket the kernel lists as bound and not connected: where it listens, and its inode.
#[derive(Debug, PartialEq)]
struct Listener {
    local: SocketAddr,
    inode: u64,
}

/// The other sockets listening on `local`'s port that would share its datagrams: bound, not
/// connected, to the same address or to a wildcard one (either side's), as `/proc/net/udp`
/// and `udp6` list them, `own` (the link's own socket) left out. None where they cannot be
/// read: then only the kernel's own refusal at `bind` stands.
fn others_listening(local: SocketAddr, own: Option<u64>) -> Vec<Listener> {
    ["/proc/net/udp", "/proc/net/udp6"]
        .iter()
        .filter_map(|path| std::fs::read_to_string(path).ok())
        .flat_map(|table| {
            table
                .lines()
                .skip(1)
                .filter_map(listener_of)
                .collect::<Vec<_>>()
        })
        .filter(|l| Some(l.inode) != own && overlaps(l.local, local))
        .collect()
}

/// The listening socket of one line of `/proc/net/udp` or `udp6` (`None`: a connected one, or
/// a line that does not parse). Addresses there are hex, in the kernel's byte order: each
/// 32-bit word as the machine stores it.
fn listener_of(line: &str) -> Option<Listener> {
    let fields: Vec<&str> = line.split_whitespace().collect();
    let (local, remote, inode) = (fields.get(1)?, fields.get(2)?, fields.get(9)?);
    if !remote.ends_with(":0000") {
        return None;
    }
    let (address, port) = local.split_once(':')?;
    let port = u16::from_str_radix(port, 16).ok()?;
    let word = |i: usize| -> Option<[u8; 4]> {
        Some(
            u32::from_str_radix(address.get(8 * i..8 * i + 8)?, 16)
                .ok()?
                .to_ne_bytes(),
        )
    };
    let ip: std::net::IpAddr = match address.len() {
        8 => std::net::Ipv4Addr::from(word(0)?).into(),
        32 => {
            let mut bytes = [0u8; 16];
            for i in 0..4 {
                bytes[4 * i..4 * i + 4].copy_from_slice(&word(i)?);
            }
            std::net::Ipv6Addr::from(bytes).into()
        }
        _ => return None,
    };
    Some(Listener {
        local: SocketAddr::new(ip, port),
        inode: inode.parse().ok()?,
    })
}

/// Whether datagrams to `ours` could go to a socket bound to `theirs`: the same port, and the
/// same address or a wildcard on either side (a v6 wildcard takes IPv4 too, unless it is
/// v6-only, which the table does not say).
fn overlaps(theirs: SocketAddr, ours: SocketAddr) -> bool {
    let (t, o) = (theirs.ip().to_canonical(), ours.ip().to_canonical());
    theirs.port() == ours.port() && (t == o || t.is_unspecified() || o.is_unspecified())
}

/// Who holds `others`: each socket's address and the processes that have it open (their pid
/// and name, from `/proc/<pid>/fd`), or that this user may not see them.
fn describe(others: &[Listener]) -> String {
    let mut holders: Vec<Vec<String>> = vec![Vec::new(); others.len()];
    if let Ok(procs) = std::fs::read_dir("/proc") {
        for pid in procs.filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok()) {
            let Ok(fds) = std::fs::read_dir(format!("/proc/{pid}/fd")) else {
                continue;
            };
            for fd in fds.filter_map(Result::ok) {
                let Ok(target) = std::fs::read_link(fd.path()) else {
                    continue;
                };
                let target = target.to_string_lossy();
                for (socket, names) in others.iter().zip(&mut holders) {
                    if target == format!("socket:[{}]", socket.inode) {
                        let comm = std::fs::read_to_string(format!("/proc/{pid}/comm"))
                            .unwrap_or_default();
                        let holder = format!("pid {pid} {}", comm.trim());
                        if !names.contains(&holder) {
                            names.push(holder);
                        }
                    }
                }
            }
        }
    }
    others
        .iter()
        .zip(holders)
        .map(|(socket, names)| match names.is_empty() {
            true => format!("{}, by a process this user cannot see", socket.local),
            false => format!("{}, by {}", socket.local, names.join(", ")),
        })
        .collect::<Vec<_>>()
        .join("; ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// A link on a free port of loopback.
    fn link() -> UdpIn {
        UdpIn::bind("udpin:127.0.0.1:0", "127.0.0.1:0").unwrap()
    }

    fn port_of(udp: &UdpIn) -> SocketAddr {
        udp.listening.socket.local_addr().unwrap()
    }

    /// A link that is not read while datagrams pour in counts the ones the kernel had no room
    /// for: with those it did read, they make up every datagram sent.
    #[tokio::test]
    async fn datagrams_dropped_unread_are_counted() {
        let udp = link();
        assert!(
            udp.listening.lost.is_some(),
            "the kernel counts drops on this socket"
        );
        // A small receive buffer, whatever the machine's default (each datagram takes ~1 KiB).
        setsockopt(&udp.listening.socket, sockopt::RcvBuf, &4096).unwrap();
        let to = port_of(&udp);
        let sender = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let sent = 1_000u64;
        for i in 0..sent {
            sender.send_to(&i.to_le_bytes(), to).unwrap();
        }
        let mut buf = [0u8; 64];
        let mut received = 0u64;
        while let Ok(Ok((n, from))) =
            tokio::time::timeout(Duration::from_millis(200), udp.recv_from(&mut buf)).await
        {
            assert_eq!(n, 8);
            assert_eq!(from, sender.local_addr().unwrap());
            received += 1;
        }
        // The kernel tells the count with the next datagram queued after the drops (as the
        // autopilot's next one is).
        sender.send_to(&sent.to_le_bytes(), to).unwrap();
        let (n, _) = udp.recv_from(&mut buf).await.unwrap();
        assert_eq!(buf[..n], sent.to_le_bytes());
        let sent = sent + 1;
        received += 1;
        let lost = udp.lost();
        assert!(lost > 0 && received > 0, "{received} received, {lost} lost");
        assert_eq!(received + lost, sent, "{received} received, {lost} lost");
    }

    /// Once heard, a peer's datagrams wait in a queue of their own: a stranger who fills the
    /// listening socket's queue (the kernel dropping its datagrams) takes none of them.
    #[tokio::test]
    async fn a_peers_datagrams_have_a_queue_of_their_own_that_a_flood_does_not_fill() {
        let udp = link();
        setsockopt(&udp.listening.socket, sockopt::RcvBuf, &4096).unwrap();
        let to = port_of(&udp);
        let peer = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let peer_at = peer.local_addr().unwrap();
        peer.send_to(b"hello", to).unwrap();
        let mut buf = [0u8; 64];
        let (_, from) = udp.recv_from(&mut buf).await.unwrap();
        assert_eq!(from, peer_at);
        let own = udp
            .heard(from)
            .expect("a new peer gets a socket of its own");
        assert!(udp.heard(from).is_none(), "one socket per peer");
        // The flood, from another socket, and the peer's datagrams amid it.
        let stranger = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        for i in 0..2_000u32 {
            stranger.send_to(&[0u8; 32], to).unwrap();
            if i % 100 == 0 {
                peer.send_to(&i.to_le_bytes(), to).unwrap();
            }
        }
        let mut heard = Vec::new();
        while let Ok(Ok((n, from))) = tokio::time::timeout(
            Duration::from_millis(200),
            udp.recv_own(peer_at, &own, &mut buf),
        )
        .await
        {
            assert_eq!(from, peer_at);
            heard.push(u32::from_le_bytes(buf[..n].try_into().unwrap()));
        }
        assert_eq!(heard, (0..2_000).step_by(100).collect::<Vec<_>>());
        assert_eq!(own.lost(), 0);
        // The stranger's datagrams: on the listening socket, most of them dropped there (the
        // kernel tells the count with the next datagram queued after the drops).
        while let Ok(Ok((_, from))) =
            tokio::time::timeout(Duration::from_millis(100), udp.recv_from(&mut buf)).await
        {
            assert_eq!(from, stranger.local_addr().unwrap());
        }
        stranger.send_to(&[0u8; 32], to).unwrap();
        udp.recv_from(&mut buf).await.unwrap();
        // (Not counted under qemu-user, which refuses SO_RXQ_OVFL.)
        if udp.listening.lost.is_some() {
            assert!(udp.lost() > 0, "the flood overflowed the listening socket");
        }
    }

    #[tokio::test]
    async fn a_second_link_on_the_same_port_is_refused() {
        let udp = link();
        let local = port_of(&udp).to_string();
        let second = UdpIn::bind("udpin:again", &local);
        let Err(e) = second else {
            panic!("two links on {local}");
        };
        assert_eq!(e.kind(), std::io::ErrorKind::AddrInUse, "{e}");
        let told = e.to_string();
        assert!(told.contains("another program listens"), "{told}");
        // Who holds the port: this process, by its pid.
        let pid = format!("pid {} ", std::process::id());
        assert!(told.contains(&local) && told.contains(&pid), "{told}");
    }

    /// A socket on the same port of another address takes none of the link's datagrams: the
    /// link opens beside it. One on the wildcard address would share them: refused, and named.
    #[tokio::test]
    async fn only_a_socket_that_would_share_the_datagrams_refuses_the_link() {
        let beside = std::net::UdpSocket::bind("127.0.0.2:0").unwrap();
        let port = beside.local_addr().unwrap().port();
        let link = UdpIn::bind("udpin:beside", &format!("127.0.0.1:{port}"));
        assert!(link.is_ok(), "{:?}", link.err());
        drop(link);
        // With `SO_REUSEPORT` on both, the kernel would let the link bind: the check refuses.
        let wildcard = Socket::open("0.0.0.0:0".parse().unwrap(), None).unwrap();
        let port = wildcard.socket.local_addr().unwrap().port();
        let Err(e) = UdpIn::bind("udpin:under", &format!("127.0.0.1:{port}")) else {
            panic!("a link beside a wildcard socket on port {port}");
        };
        assert!(e.to_string().contains(&format!("0.0.0.0:{port}")), "{e}");
    }

    /// The table's lines as the kernel writes them: a listening socket read back with its
    /// address, a connected one left out.
    #[test]
    fn the_kernels_table_is_read_in_its_byte_order() {
        let hex = |a: [u8; 4]| format!("{:08X}", u32::from_ne_bytes(a));
        let listening = format!(
            "  12: {}:3925 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 4242 2 0000000000000000 0",
            hex([127, 0, 0, 1])
        );
        assert_eq!(
            listener_of(&listening),
            Some(Listener {
                local: "127.0.0.1:14629".parse().unwrap(),
                inode: 4242
            })
        );
        let connected = listening.replace("00000000:0000", &format!("{}:3A98", hex([10, 0, 0, 2])));
        assert_eq!(listener_of(&connected), None);
        let v6 = format!(
            "  3: {}{}{}{}:3925 00000000000000000000000000000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 77 2 0000000000000000 0",
            hex([0, 0, 0, 0]),
            hex([0, 0, 0, 0]),
            hex([0, 0, 0, 0]),
            hex([0, 0, 0, 1])
        );
        assert_eq!(
            listener_of(&v6).unwrap().local,
            "[::1]:14629".parse().unwrap()
        );
        assert_eq!(listener_of("garbage"), None);
    }
}
