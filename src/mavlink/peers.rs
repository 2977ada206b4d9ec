//! Who a listening UDP link (`udpin`) answers: every system heard on it recently, as MAVLink
//! routers do, not only the last sender. With a ground station's or a joystick's stream
//! forwarded to the same port as the autopilot's, answering only the last sender would give
//! the other system part of what the autopilot must hear. Sans-IO: handed addresses and times.
//!
//! A peer joins with a datagram that held a frame the bridge accepted (with signing on, a
//! correctly signed fresh one: a stranger's unsigned datagram adds no one), and leaves after
//! [`PEER_TIMEOUT`] without one. At most [`MAX_PEERS`] are kept: a new one then takes the place
//! of the one heard least recently, so that a sender that changes its port at every datagram
//! cannot make the bridge send to ever more addresses.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// A peer not heard from for this long is sent nothing more, until it speaks again. An
/// autopilot and a ground station send a HEARTBEAT every second: five of them missed.
pub const PEER_TIMEOUT: Duration = Duration::from_secs(5);

/// The most peers one link sends to.
pub const MAX_PEERS: usize = 8;

/// A change in who a link answers, for the log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PeerChange {
    /// A peer heard for the first time (or again, after it had left).
    Joined(SocketAddr),
    /// A peer silent for [`PEER_TIMEOUT`].
    Left(SocketAddr),
    /// A peer dropped to make room for a new one ([`MAX_PEERS`]).
    Replaced(SocketAddr),
}

/// The peers of one link, each with when it was last heard.
#[derive(Debug, Default)]
pub struct Peers {
    heard: Vec<(SocketAddr, Instant)>,
}

impl Peers {
    /// `from` sent an accepted frame at `now`. Returns the changes it made: a new peer joined,
    /// and perhaps the least recently heard one replaced.
    pub fn heard(&mut self, from: SocketAddr, now: Instant) -> Vec<PeerChange> {
        let mut changes = self.expire(now);
        if let Some(peer) = self.heard.iter_mut().find(|(a, _)| *a == from) {
            peer.1 = now;
            return changes;
        }
        if self.heard.len() == MAX_PEERS
            && let Some(oldest) = (0..self.heard.len()).min_by_key(|&i| self.heard[i].1)
        {
            changes.push(PeerChange::Replaced(self.heard.swap_remove(oldest).0));
        }
        self.heard.push((from, now));
        changes.push(PeerChange::Joined(from));
        changes
    }

    /// Drop the peers silent for [`PEER_TIMEOUT`] at `now`; returns them.
    pub fn expire(&mut self, now: Instant) -> Vec<PeerChange> {
        let mut left = Vec::new();
        self.heard.retain(|&(address, at)| {
            let alive = now.saturating_duration_since(at) < PEER_TIMEOUT;
            if !alive {
                left.push(PeerChange::Left(address));
            }
            alive
        });
        left
    }

    /// Where a message sent at `now` goes: every peer heard within [`PEER_TIMEOUT`], in the
    /// order they joined. Call [`Peers::expire`] first to drop the others.
    pub fn addresses(&self, now: Instant) -> impl Iterator<Item = SocketAddr> + '_ {
        self.heard
            .iter()
            .filter(move |(_, at)| now.saturating_duration_since(*at) < PEER_TIMEOUT)
            .map(|(address, _)| *address)
    }

    /// Whether anyone is to be sent to at `now`.
    pub fn any(&self, now: Instant) -> bool {
        self.addresses(now).next().is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    #[test]
    fn every_peer_heard_recently_is_sent_to_and_a_silent_one_leaves() {
        let t0 = Instant::now();
        let mut peers = Peers::default();
        assert!(!peers.any(t0), "nobody before anyone spoke");
        assert_eq!(peers.heard(addr(1), t0), [PeerChange::Joined(addr(1))]);
        assert_eq!(peers.heard(addr(2), t0), [PeerChange::Joined(addr(2))]);
        // Heard again: no change, and the order stays the order of joining.
        assert_eq!(peers.heard(addr(1), t0 + Duration::from_secs(3)), []);
        let at = t0 + Duration::from_secs(4);
        assert_eq!(peers.addresses(at).collect::<Vec<_>>(), [addr(1), addr(2)]);
        // Peer 2 has been silent for PEER_TIMEOUT; peer 1 not.
        let at = t0 + PEER_TIMEOUT;
        assert_eq!(peers.addresses(at).collect::<Vec<_>>(), [addr(1)]);
        assert_eq!(peers.expire(at), [PeerChange::Left(addr(2))]);
        assert_eq!(peers.expire(at), []);
        // It comes back: it joins again.
        assert_eq!(peers.heard(addr(2), at), [PeerChange::Joined(addr(2))]);
        let later = t0 + Duration::from_secs(3) + PEER_TIMEOUT;
        assert_eq!(peers.addresses(later).collect::<Vec<_>>(), [addr(2)]);
    }

    #[test]
    fn a_new_peer_beyond_the_most_takes_the_place_of_the_one_heard_least_recently() {
        let t0 = Instant::now();
        let mut peers = Peers::default();
        for port in 0..MAX_PEERS as u16 {
            peers.heard(
                addr(100 + port),
                t0 + Duration::from_millis(u64::from(port)),
            );
        }
        // The first one speaks again: the second is now the least recently heard.
        peers.heard(addr(100), t0 + Duration::from_millis(50));
        let at = t0 + Duration::from_millis(60);
        assert_eq!(
            peers.heard(addr(9), at),
            [PeerChange::Replaced(addr(101)), PeerChange::Joined(addr(9))]
        );
        let now: Vec<_> = peers.addresses(at).collect();
        assert_eq!(now.len(), MAX_PEERS);
        assert!(now.contains(&addr(100)) && now.contains(&addr(9)));
        assert!(!now.contains(&addr(101)));
    }
}
