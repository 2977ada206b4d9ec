//! Dynamic node id allocation, the client's side (`uavcan.protocol.dynamic_node_id.Allocation`,
//! rules A–E of its DSDL), sans-IO: a node without an id asks an allocator on the bus (ArduPilot
//! runs one on each DroneCAN driver) for one, naming itself by its 16-byte unique id in
//! anonymous single-frame requests of at most six bytes of it each.
//!
//! - A: the request timer starts with a random period in [`REQUEST_PERIOD`].
//! - B: when it expires it restarts, and a first-stage request goes out: the preferred id (0:
//!   any), `first_part_of_unique_id`, the unique id's first six bytes.
//! - C: any Allocation message (a request of another node's too) restarts the timer.
//! - D: an allocator's answer whose unique id is a prefix of ours, shorter than 16 bytes: after
//!   a random delay in [`FOLLOWUP_DELAY`] (cut short by any other Allocation message), the next
//!   request carries the next six bytes from where the answer's ended.
//! - E: an allocator's answer with our whole unique id and a node id: that is the node's id.
//!
//! An answer that is not ours puts the client back to the first stage (its next request, when
//! the timer expires, is a first-stage one).

use super::bits::{BitReader, BitWriter};
use super::messages::DataType;
use std::ops::RangeInclusive;
use std::time::{Duration, Instant};

/// `uavcan.protocol.dynamic_node_id.Allocation`.
pub const ALLOCATION: DataType = DataType {
    name: "uavcan.protocol.dynamic_node_id.Allocation",
    id: 1,
    signature: 0x0B2A_8126_20A1_1D40,
};

/// The request timer's random period (ms): the DSDL's MIN_REQUEST_PERIOD_MS–MAX_REQUEST_PERIOD_MS.
pub const REQUEST_PERIOD: RangeInclusive<u64> = 600..=1000;
/// The follow-up's random delay (ms): MIN_FOLLOWUP_DELAY_MS–MAX_FOLLOWUP_DELAY_MS.
pub const FOLLOWUP_DELAY: RangeInclusive<u64> = 0..=400;
/// The most bytes of unique id in one request (one frame: a byte of id and flag, six, the tail).
pub const UNIQUE_ID_PER_REQUEST: usize = 6;

/// One Allocation message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Allocation {
    /// In a request, the preferred id (0: any); in an answer, the id allocated.
    pub node_id: u8,
    /// In a request: the first stage.
    pub first_part_of_unique_id: bool,
    /// At most 16 bytes (six in a request).
    pub unique_id: Vec<u8>,
}

pub fn encode(a: &Allocation) -> Vec<u8> {
    let mut w = BitWriter::new();
    w.put(u64::from(a.node_id & 0x7F), 7);
    w.put(u64::from(a.first_part_of_unique_id), 1);
    // The array is the last field: tail-optimised, no length before it.
    for b in &a.unique_id {
        w.put(u64::from(*b), 8);
    }
    w.finish()
}

/// `None` for an empty payload or a unique id over 16 bytes.
pub fn decode(payload: &[u8]) -> Option<Allocation> {
    let (first, rest) = payload.split_first()?;
    let mut r = BitReader::new(std::slice::from_ref(first));
    let node_id = r.get(7) as u8;
    let first_part_of_unique_id = r.get(1) == 1;
    (rest.len() <= 16).then(|| Allocation {
        node_id,
        first_part_of_unique_id,
        unique_id: rest.to_vec(),
    })
}

/// The client: see the module docs.
#[derive(Debug)]
pub struct Allocatee {
    unique_id: [u8; 16],
    preferred: u8,
    /// How many bytes of the unique id the allocator has confirmed (0: first stage next).
    confirmed: usize,
    /// When the next request goes out, and whether it is a follow-up (stage 2 or 3).
    next_request: Instant,
    followup: bool,
    allocated: Option<u8>,
    rng: u64,
}

impl Allocatee {
    /// A client started at `now` (rule A). `seed` makes its random periods; two nodes with the
    /// same unique id must not share it (the unique id is mixed in).
    pub fn new(unique_id: [u8; 16], preferred: u8, seed: u64, now: Instant) -> Self {
        let mut rng = seed ^ u64::from_le_bytes(unique_id[..8].try_into().expect("8 bytes"));
        if rng == 0 {
            rng = 0x9E37_79B9_7F4A_7C15;
        }
        let mut a = Allocatee {
            unique_id,
            preferred: preferred & 0x7F,
            confirmed: 0,
            next_request: now,
            followup: false,
            allocated: None,
            rng,
        };
        a.restart_timer(now);
        a
    }

    /// The id allocated, once it is.
    pub fn allocated(&self) -> Option<u8> {
        self.allocated
    }

    fn random_ms(&mut self, range: &RangeInclusive<u64>) -> Duration {
        // xorshift64: plenty for spreading requests apart.
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        let span = range.end() - range.start() + 1;
        Duration::from_millis(range.start() + self.rng % span)
    }

    fn restart_timer(&mut self, now: Instant) {
        self.next_request = now + self.random_ms(&REQUEST_PERIOD);
        self.followup = false;
    }

    /// An Allocation message heard at `now` from `source` (0: anonymous, another client's
    /// request). Returns the id once it is allocated (rule E).
    pub fn handle(&mut self, source: u8, message: &Allocation, now: Instant) -> Option<u8> {
        if self.allocated.is_some() {
            return self.allocated;
        }
        if source == 0 {
            // Another client's request: our follow-up, if one was due, waits (rule D.1). Our
            // own, heard back (the multicast bus loops a node's datagrams back to it), is
            // none of that.
            let n = message.unique_id.len();
            let ours = (0..16)
                .step_by(UNIQUE_ID_PER_REQUEST)
                .any(|at| n > 0 && self.unique_id.get(at..at + n) == Some(&message.unique_id[..]));
            if !ours {
                self.restart_timer(now);
            }
            return None;
        }
        // Rule C, whatever else follows.
        self.restart_timer(now);
        let n = message.unique_id.len();
        if n == 0 || self.unique_id[..n.min(16)] != message.unique_id[..] {
            // An answer to someone else: start again from the first stage.
            self.confirmed = 0;
            return None;
        }
        if n == 16 {
            if message.node_id != 0 {
                self.allocated = Some(message.node_id);
            }
            return self.allocated;
        }
        // Rule D: the next stage after a random follow-up delay.
        self.confirmed = n;
        self.next_request = now + self.random_ms(&FOLLOWUP_DELAY);
        self.followup = true;
        None
    }

    /// The request due at `now`, if any (rules B and D.2).
    pub fn poll(&mut self, now: Instant) -> Option<Allocation> {
        if self.allocated.is_some() || now < self.next_request {
            return None;
        }
        let from = if self.followup { self.confirmed } else { 0 };
        self.confirmed = from;
        let request = Allocation {
            node_id: self.preferred,
            first_part_of_unique_id: from == 0,
            unique_id: self.unique_id[from..(from + UNIQUE_ID_PER_REQUEST).min(16)].to_vec(),
        };
        self.restart_timer(now);
        Some(request)
    }

    /// When [`Allocatee::poll`] next has something to send; `None` once allocated.
    pub fn next_wake(&self) -> Option<Instant> {
        self.allocated.is_none().then_some(self.next_request)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const UID: [u8; 16] = [
        0x10, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x1B, 0x1C, 0x1D, 0x1E,
        0x1F,
    ];

    fn answer(node_id: u8, uid: &[u8]) -> Allocation {
        Allocation {
            node_id,
            first_part_of_unique_id: false,
            unique_id: uid.to_vec(),
        }
    }

    #[test]
    fn the_first_byte_is_the_id_then_the_flag() {
        let a = Allocation {
            node_id: 125,
            first_part_of_unique_id: true,
            unique_id: vec![1, 2, 3],
        };
        assert_eq!(encode(&a), [125 << 1 | 1, 1, 2, 3]);
        assert_eq!(decode(&encode(&a)), Some(a));
        assert_eq!(decode(&[]), None);
        assert_eq!(decode(&[0; 18]), None);
    }

    #[test]
    fn three_stages_of_six_six_and_four_bytes_then_the_id() {
        let t0 = Instant::now();
        let mut c = Allocatee::new(UID, 0, 1, t0);
        assert_eq!(c.poll(t0), None, "rule A: a random wait first");
        let first_at = c.next_wake().unwrap();
        let wait = first_at - t0;
        assert!(
            REQUEST_PERIOD.contains(&(wait.as_millis() as u64)),
            "{wait:?}"
        );
        let r1 = c.poll(first_at).unwrap();
        assert_eq!(
            r1,
            Allocation {
                node_id: 0,
                first_part_of_unique_id: true,
                unique_id: UID[..6].to_vec()
            }
        );
        assert_eq!(c.poll(first_at), None, "one request per period");

        let t = first_at + Duration::from_millis(5);
        assert_eq!(c.handle(10, &answer(0, &UID[..6]), t), None);
        let due = c.next_wake().unwrap();
        assert!(
            due - t <= Duration::from_millis(*FOLLOWUP_DELAY.end()),
            "a follow-up, not a period"
        );
        let r2 = c.poll(due).unwrap();
        assert_eq!(
            r2,
            Allocation {
                node_id: 0,
                first_part_of_unique_id: false,
                unique_id: UID[6..12].to_vec()
            }
        );
        assert_eq!(c.handle(10, &answer(0, &UID[..12]), due), None);
        let r3 = c.poll(c.next_wake().unwrap()).unwrap();
        assert_eq!(r3.unique_id, UID[12..]);
        assert!(!r3.first_part_of_unique_id);
        assert_eq!(c.handle(10, &answer(77, &UID), due), Some(77));
        assert_eq!(c.allocated(), Some(77));
        assert_eq!(c.next_wake(), None);
        assert_eq!(
            c.poll(due + Duration::from_secs(5)),
            None,
            "done: no more requests"
        );
    }

    #[test]
    fn an_answer_to_another_node_sends_it_back_to_the_first_stage() {
        let t0 = Instant::now();
        let mut c = Allocatee::new(UID, 42, 7, t0);
        let at = c.next_wake().unwrap();
        c.poll(at).unwrap();
        c.handle(10, &answer(0, &UID[..6]), at);
        let mut other = UID;
        other[7] ^= 0xFF;
        assert_eq!(c.handle(10, &answer(0, &other[..12]), at), None);
        let next = c.next_wake().unwrap();
        assert!(
            next - at >= Duration::from_millis(*REQUEST_PERIOD.start()),
            "rule C: a whole period"
        );
        let r = c.poll(next).unwrap();
        assert!(r.first_part_of_unique_id, "{r:?}");
        assert_eq!(r.node_id, 42, "the preferred id");
        assert_eq!(r.unique_id, UID[..6]);
    }

    #[test]
    fn another_clients_request_holds_a_follow_up_back() {
        let t0 = Instant::now();
        let mut c = Allocatee::new(UID, 0, 3, t0);
        let at = c.next_wake().unwrap();
        c.poll(at).unwrap();
        c.handle(10, &answer(0, &UID[..6]), at);
        let request = Allocation {
            node_id: 0,
            first_part_of_unique_id: true,
            unique_id: vec![9; 6],
        };
        c.handle(0, &request, at + Duration::from_millis(1));
        let next = c.next_wake().unwrap();
        assert!(next - at >= Duration::from_millis(*REQUEST_PERIOD.start()));
        assert!(c.poll(next).unwrap().first_part_of_unique_id);
    }

    #[test]
    fn its_own_request_heard_back_changes_nothing() {
        let t0 = Instant::now();
        let mut c = Allocatee::new(UID, 0, 3, t0);
        let at = c.next_wake().unwrap();
        c.poll(at).unwrap();
        c.handle(10, &answer(0, &UID[..6]), at);
        let due = c.next_wake().unwrap();
        let mine = c.poll(due).unwrap();
        let next = c.next_wake();
        c.handle(0, &mine, due);
        assert_eq!(c.next_wake(), next);
        c.handle(10, &answer(0, &UID[..12]), due);
        let third = c.poll(c.next_wake().unwrap()).unwrap();
        assert_eq!(third.unique_id, UID[12..], "still the third stage");
    }

    #[test]
    fn a_whole_unique_id_with_no_node_id_is_no_allocation() {
        let t0 = Instant::now();
        let mut c = Allocatee::new(UID, 0, 5, t0);
        assert_eq!(c.handle(10, &answer(0, &UID), t0), None);
        assert_eq!(c.allocated(), None);
        assert!(c.next_wake().is_some());
    }

    #[test]
    fn two_clients_draw_different_periods() {
        let t0 = Instant::now();
        let mut other = UID;
        other[0] = 0x99;
        let a = Allocatee::new(UID, 0, 1, t0).next_wake();
        let b = Allocatee::new(other, 0, 1, t0).next_wake();
        assert_ne!(a, b);
    }
}
