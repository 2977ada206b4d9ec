//! What one MAVLink link has still to send, bounded, so that a link whose peer does not keep up
//! (a telemetry radio, a serial link to a busy autopilot, a TCP peer that stalls) holds neither
//! another link nor the bridge's loop, and costs bounded memory.
//!
//! When the outbox is full, the oldest *telemetry* message is dropped for the new one: a newer
//! value of the same kind follows within a second, so the peer loses only time resolution.
//! Answers (PARAM_VALUE, COMMAND_ACK, the bridge's description), STATUSTEXTs and the bridge's
//! requests to the autopilot are kept over telemetry; only an outbox full of them drops the
//! oldest of them. Every drop is counted.
//!
//! Plain data: the link's writer task takes messages out and sends them (see the runtime).

use mavlink::MavHeader;
use mavlink::dialects::common::MavMessage;
use std::collections::VecDeque;

/// Messages an outbox holds at most: about 9 kB, 1.5 s of a 57 600-baud telemetry radio and
/// 0.1 s of a 921 600-baud serial link. A longer backlog is stale telemetry that only delays
/// what follows it; a parameter list is paced by the parameter server, not queued here whole.
pub const CAPACITY: usize = 256;

/// A message waiting in an outbox.
#[derive(Debug, Clone, PartialEq)]
pub struct Queued {
    pub header: MavHeader,
    pub message: MavMessage,
    /// Another component's message relayed (the autopilot's HEARTBEAT): it keeps the sequence
    /// number of `header`. The bridge's own messages are numbered by the link as they leave,
    /// so that what is dropped here leaves no gap.
    pub relayed: bool,
}

/// One link's messages waiting to be sent, oldest first.
#[derive(Debug)]
pub struct Outbox {
    queue: VecDeque<Queued>,
    capacity: usize,
    dropped: u64,
}

/// Whether a message is telemetry that a newer one replaces (see the module docs).
pub fn is_telemetry(message: &MavMessage) -> bool {
    matches!(
        message,
        MavMessage::HEARTBEAT(_)
            | MavMessage::NAMED_VALUE_FLOAT(_)
            | MavMessage::NAMED_VALUE_INT(_)
            | MavMessage::ESC_INFO(_)
            | MavMessage::ESC_STATUS(_)
    )
}

impl Default for Outbox {
    fn default() -> Self {
        Outbox::with_capacity(CAPACITY)
    }
}

impl Outbox {
    /// An outbox for at most `capacity` messages (at least one).
    pub fn with_capacity(capacity: usize) -> Self {
        Outbox {
            queue: VecDeque::new(),
            capacity: capacity.max(1),
            dropped: 0,
        }
    }

    /// Queue `message`; when full, drop the oldest telemetry first, else the oldest message.
    pub fn push(&mut self, queued: Queued) {
        if self.queue.len() >= self.capacity {
            let oldest_telemetry = self.queue.iter().position(|q| is_telemetry(&q.message));
            self.queue.remove(oldest_telemetry.unwrap_or(0));
            self.dropped += 1;
        }
        self.queue.push_back(queued);
    }

    /// The oldest message waiting.
    pub fn pop(&mut self) -> Option<Queued> {
        self.queue.pop_front()
    }

    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Messages dropped so far because the outbox was full.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{COMMAND_ACK_DATA, NAMED_VALUE_FLOAT_DATA, PARAM_VALUE_DATA};

    fn value(n: u32) -> MavMessage {
        MavMessage::NAMED_VALUE_FLOAT(NAMED_VALUE_FLOAT_DATA {
            time_boot_ms: n,
            ..Default::default()
        })
    }

    fn answer(n: u16) -> MavMessage {
        MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_index: n,
            ..Default::default()
        })
    }

    fn own(message: MavMessage) -> Queued {
        Queued {
            header: MavHeader::default(),
            message,
            relayed: false,
        }
    }

    fn contents(o: &mut Outbox) -> Vec<MavMessage> {
        std::iter::from_fn(|| o.pop().map(|q| q.message)).collect()
    }

    #[test]
    fn a_full_outbox_drops_the_oldest_telemetry_and_keeps_answers() {
        let mut o = Outbox::with_capacity(4);
        o.push(own(value(1)));
        o.push(own(answer(1)));
        o.push(own(value(2)));
        o.push(own(answer(2)));
        o.push(own(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA::default())));
        o.push(own(value(3)));
        assert_eq!(o.dropped(), 2);
        assert_eq!(o.len(), 4);
        assert_eq!(
            contents(&mut o),
            vec![
                answer(1),
                answer(2),
                MavMessage::COMMAND_ACK(COMMAND_ACK_DATA::default()),
                value(3)
            ]
        );
    }

    #[test]
    fn an_outbox_full_of_answers_drops_the_oldest_answer() {
        let mut o = Outbox::with_capacity(3);
        for n in 0..5 {
            o.push(own(answer(n)));
        }
        assert_eq!(o.dropped(), 2);
        assert_eq!(contents(&mut o), vec![answer(2), answer(3), answer(4)]);
        assert!(o.is_empty());
    }

    #[test]
    fn nothing_is_dropped_below_the_capacity_and_order_is_kept() {
        let mut o = Outbox::default();
        for n in 0..CAPACITY as u32 {
            o.push(own(value(n)));
        }
        assert_eq!(o.dropped(), 0);
        let got = contents(&mut o);
        assert_eq!(got.len(), CAPACITY);
        assert_eq!(got[0], value(0));
        assert_eq!(got[CAPACITY - 1], value(CAPACITY as u32 - 1));
    }
}
