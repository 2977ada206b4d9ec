//! The simulated bus, sans I/O: the servos, the half-duplex line between them and the host, and the faults.
//!
//! The caller (the runtime thread, or a test with virtual time) feeds it what the host wrote, stamped with
//! the instant `read()` returned and the host's bit rate; advances it to `now`; and takes the bytes that
//! are due toward the host. It never reads a clock.
//!
//! Wire model:
//! - Receive: a host byte occupies the line for one byte time at the host's rate, starting when it was read
//!   or when the previous host byte ended, whichever is later. A packet is complete (and acted on) when its
//!   last byte has fully arrived.
//! - Bit rates: each servo listens at its own rate (register 6, changed at once by a write). A packet sent
//!   at another rate is noise to that servo: it ignores it. A reply sent at a rate other than the host's
//!   reaches the host as noise (random bytes spanning the reply's wire time).
//! - Transmit: a reply starts after the packet's completion + Return Delay Time + processing latency; each
//!   byte is handed to the host when its stop bit ends.
//! - Half duplex: a host byte on the line while a reply is on it is a collision: the overlapping reply bytes
//!   are garbled and the host's packet is not understood. Two replies at once (duplicate IDs) collide too:
//!   the later one is lost and the earlier one garbled where they overlap.
//! - Echo fault: the adapter hands every host byte back to the host when it ends.
//! - Inter-byte timeout: after [`RX_GAP_RESET`] of silence a partial packet is abandoned (its first byte
//!   counts as garbage and the rest is scanned again), so a host that died mid-packet does not swallow the
//!   next host's first packets.

use std::collections::{HashSet, VecDeque};
use std::time::{Duration, Instant};

use super::wire::{TxByte, TxSource, byte_time};
use crate::config::SimConfig;
use crate::events::{BusEvent, BusStats, DamageEvent, PacketEvent, ReplyEvent};
use crate::fault::{Fault, FaultKind, ReplyFaults, XorShift64};
use crate::protocol::frame_decoder::{Decoded, FrameDecoder};
use crate::protocol::host_packet::HostPacket;
use crate::servo::memory_map::{self, LJ9DA41_MODEL_NUMBER};
use crate::servo::{Servo, ServoConfig, ServoSnapshot};

/// Events kept for the caller at most; older ones are dropped first.
const MAX_PENDING_EVENTS: usize = 100_000;
/// A garbage run is reported once it reaches this many bytes (or when something else is decoded).
const MAX_GARBAGE_RUN: usize = 256;
/// Processing latencies above this are clamped (a servo that slow would be broken anyway).
const MAX_PROCESSING_LATENCY: Duration = Duration::from_secs(1);
/// Bytes that follow each other closer than this belong to one run (one reply on the line).
const RUN_GAP: Duration = Duration::from_micros(5);

/// Silence after which a servo gives up on a partial packet (inter-byte timeout).
pub const RX_GAP_RESET: Duration = Duration::from_millis(20);

/// Wire facts about one received host byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct RxMeta {
    read_at: Instant,
    start: Instant,
    end: Instant,
    baud: Option<u32>,
    collided: bool,
}

/// The simulated bus; see the module documentation.
#[derive(Debug)]
pub struct BusModel {
    servos: Vec<Servo>,
    configured_ids: Vec<u8>,
    default_baud: u32,
    latency: Duration,
    decoder: FrameDecoder<RxMeta>,
    rx_queue: VecDeque<(u8, RxMeta)>,
    rx_line_free_at: Instant,
    last_decoded_end: Instant,
    host_baud: Option<u32>,
    tx_queue: VecDeque<TxByte>,
    /// When the last byte handed to the host was complete (see [`BusModel::next_wake`]).
    last_handed: Option<Instant>,
    next_reply_seq: u64,
    collided_replies: HashSet<u64>,
    echo: bool,
    bus_reply_faults: ReplyFaults,
    servo_reply_faults: Vec<ReplyFaults>,
    /// Replies each servo has started, for [`Fault::LateReplies`].
    replies_started: Vec<u64>,
    rng: XorShift64,
    events: VecDeque<BusEvent>,
    garbage: Vec<u8>,
    garbage_at: Option<Instant>,
    stats: BusStats,
    now: Instant,
}

impl BusModel {
    /// A bus with the configured servos, powered and ready at `now`. The configuration is not validated
    /// here (see [`SimConfig::validate`]); an unsupported baud falls back to 115 200 bit/s.
    pub fn new(config: &SimConfig, now: Instant) -> Self {
        let baud_code = memory_map::code_from_baud(config.baud).unwrap_or(0x07);
        let default_baud = memory_map::baud_from_code(baud_code).unwrap_or(115_200);
        let servos: Vec<Servo> = config
            .ids
            .iter()
            .map(|&id| {
                let servo_config = ServoConfig {
                    id,
                    baud_code,
                    return_delay_ms: config.return_delay_ms,
                    voltage_v: f64::from(config.voltage_v),
                    ambient_c: f64::from(config.ambient_c),
                };
                Servo::new(servo_config, now)
            })
            .collect();
        let mut model = BusModel {
            servo_reply_faults: vec![ReplyFaults::default(); servos.len()],
            replies_started: vec![0; servos.len()],
            servos,
            configured_ids: config.ids.clone(),
            default_baud,
            latency: config.processing_latency.min(MAX_PROCESSING_LATENCY),
            decoder: FrameDecoder::new(),
            rx_queue: VecDeque::new(),
            rx_line_free_at: now,
            last_decoded_end: now,
            host_baud: Some(default_baud),
            tx_queue: VecDeque::new(),
            last_handed: None,
            next_reply_seq: 0,
            collided_replies: HashSet::new(),
            echo: false,
            bus_reply_faults: ReplyFaults::default(),
            rng: XorShift64::new(config.seed),
            events: VecDeque::new(),
            garbage: Vec::new(),
            garbage_at: None,
            stats: BusStats::default(),
            now,
        };
        for (id, fault) in &config.faults {
            model.inject(now, *id, *fault);
        }
        model
    }

    /// The bit rate the servos start with.
    pub fn default_baud(&self) -> u32 {
        self.default_baud
    }

    /// The host's bit rate as last observed.
    pub fn host_baud(&self) -> Option<u32> {
        self.host_baud
    }

    /// Record the host's bit rate (called whenever it is observed, not only with data).
    pub fn observe_host_baud(&mut self, baud: Option<u32>) {
        self.host_baud = baud;
    }

    // ----- the line -----

    /// Bytes the host wrote, as returned by one `read()` at `read_at`, sent at `host_baud`.
    pub fn receive(&mut self, read_at: Instant, bytes: &[u8], host_baud: Option<u32>) {
        self.host_baud = host_baud;
        let byte_time = byte_time(host_baud.unwrap_or(self.default_baud));
        for &byte in bytes {
            let start = read_at.max(self.rx_line_free_at);
            let end = start + byte_time;
            self.rx_line_free_at = end;
            let collided = self.collide_with_replies(start, end);
            self.rx_queue.push_back((
                byte,
                RxMeta {
                    read_at,
                    start,
                    end,
                    baud: host_baud,
                    collided,
                },
            ));
            if self.echo {
                self.insert_tx(TxByte {
                    start,
                    at: end,
                    byte,
                    source: TxSource::Echo,
                });
                self.stats.echo_bytes += 1;
            }
        }
        self.stats.bytes_rx += bytes.len() as u64;
    }

    /// Garble reply bytes on the line during `[start, end)`; true if there were any.
    fn collide_with_replies(&mut self, start: Instant, end: Instant) -> bool {
        let mut hit = false;
        for index in 0..self.tx_queue.len() {
            let tx = self.tx_queue[index];
            let TxSource::Reply { id, seq, .. } = tx.source else {
                continue;
            };
            if tx.start < end && start < tx.at {
                self.tx_queue[index].byte ^= self.rng.nonzero_byte();
                hit = true;
                if self.collided_replies.insert(seq) {
                    self.stats.collisions += 1;
                    self.push_event(BusEvent::Collision {
                        at: start.max(tx.start),
                        id,
                    });
                }
            }
        }
        hit
    }

    fn insert_tx(&mut self, tx: TxByte) {
        let index = self.tx_queue.partition_point(|queued| queued.at <= tx.at);
        self.tx_queue.insert(index, tx);
    }

    /// Process everything due up to `now`: packets whose last byte has arrived, motion, heat.
    pub fn advance(&mut self, now: Instant) {
        while let Some(&(byte, meta)) = self.rx_queue.front() {
            if meta.end > now {
                break;
            }
            self.rx_queue.pop_front();
            self.update_servos(meta.end);
            let mut decoded = Vec::new();
            if self.decoder.pending() > 0 && meta.start > self.last_decoded_end + RX_GAP_RESET {
                self.decoder.abandon(&mut decoded);
            }
            self.last_decoded_end = meta.end;
            self.decoder.push(byte, meta, &mut decoded);
            for result in decoded {
                self.handle_decoded(result);
            }
        }
        if self.rx_queue.is_empty() && self.decoder.pending() == 0 {
            self.flush_garbage();
        }
        self.update_servos(now);
        self.now = self.now.max(now);
    }

    /// Bytes due toward the host at `now`, in wire order.
    pub fn poll_transmit(&mut self, now: Instant) -> Vec<TxByte> {
        let mut due = Vec::new();
        while let Some(tx) = self.tx_queue.front() {
            if tx.at > now {
                break;
            }
            if let Some(tx) = self.tx_queue.pop_front() {
                due.push(tx);
            }
        }
        if self.tx_queue.is_empty() {
            self.collided_replies.clear();
        }
        if let Some(last) = due.last() {
            self.last_handed = Some(last.at);
        }
        self.stats.bytes_tx += due.len() as u64;
        due
    }

    /// When a real-time runtime must next wake: as [`BusModel::next_deadline`], except that host
    /// bytes that arrived back to back are processed together at the end of the last, and that
    /// once the first byte of a run of back-to-back bytes (a reply) has been handed over, the
    /// rest of the run is due together at its end. The host waits for a reply's last byte; the
    /// first is handed at its own instant, so the reply still spreads over its wire time, and
    /// the bytes between cost no wake-up each (at 115 200 bit/s a 26-byte reply would
    /// otherwise wake the runtime 26 times).
    pub fn next_wake(&self) -> Option<Instant> {
        // Host bytes are stamped when read and processed at their own instants, so those read
        // together are processed together once the last of them is complete.
        let rx = self.rx_run_end();
        let tx = self.tx_queue.front().map(|front| {
            if self.continues_handed_run(front) {
                self.run_end()
            } else {
                front.at
            }
        });
        match (rx, tx) {
            (Some(rx), Some(tx)) => Some(rx.min(tx)),
            (rx, tx) => rx.or(tx),
        }
    }

    /// When [`BusModel::next_wake`] is the end of a reply (the host is waiting for it, so the
    /// runtime should not be late with it), that instant.
    pub fn reply_end_due(&self) -> Option<Instant> {
        let front = self.tx_queue.front()?;
        let end = if self.continues_handed_run(front) || self.tx_queue.len() == 1 {
            self.run_end()
        } else {
            return None;
        };
        (self.next_wake() == Some(end)).then_some(end)
    }

    /// The instant the run of back-to-back host bytes at the front of the queue is complete.
    fn rx_run_end(&self) -> Option<Instant> {
        let mut end = self.rx_queue.front()?.1.end;
        for (_, meta) in self.rx_queue.iter().skip(1) {
            if meta.start.saturating_duration_since(end) > RUN_GAP {
                break;
            }
            end = meta.end;
        }
        Some(end)
    }

    /// `tx` starts where the last byte handed over ended: the same reply, already begun.
    fn continues_handed_run(&self, tx: &TxByte) -> bool {
        self.last_handed
            .is_some_and(|at| tx.start.saturating_duration_since(at) <= RUN_GAP)
    }

    /// The instant the run of back-to-back bytes at the front of the queue is complete.
    fn run_end(&self) -> Instant {
        let mut end = self.tx_queue.front().map_or_else(Instant::now, |tx| tx.at);
        for tx in self.tx_queue.iter().skip(1) {
            if tx.start.saturating_duration_since(end) > RUN_GAP {
                break;
            }
            end = tx.at;
        }
        end
    }

    /// The next instant something is due (a host byte completes, a byte goes to the host).
    pub fn next_deadline(&self) -> Option<Instant> {
        let rx = self.rx_queue.front().map(|(_, meta)| meta.end);
        let tx = self.tx_queue.front().map(|tx| tx.at);
        match (rx, tx) {
            (Some(rx), Some(tx)) => Some(rx.min(tx)),
            (rx, tx) => rx.or(tx),
        }
    }

    /// When the next deadline hands the host the last byte queued toward it (the end of a reply),
    /// that instant: the host is waiting for it, so the runtime should not be late with it.
    pub fn transmission_ends_at(&self) -> Option<Instant> {
        match (self.tx_queue.front(), self.tx_queue.len()) {
            (Some(tx), 1) if self.next_deadline() == Some(tx.at) => Some(tx.at),
            _ => None,
        }
    }

    /// The runtime handed the host bytes whose last one was due at `due` only at `at`.
    pub fn record_late_handover(&mut self, due: Instant, at: Instant, bytes: usize) {
        self.stats.handed_late += 1;
        self.push_event(BusEvent::HandedLate { due, at, bytes });
    }

    /// The link to the host went away (device disappeared): bytes in flight are lost.
    pub fn reset_link(&mut self) {
        self.rx_queue.clear();
        self.decoder.reset();
        self.tx_queue.clear();
        self.last_handed = None;
        self.collided_replies.clear();
        self.garbage.clear();
        self.garbage_at = None;
    }

    fn update_servos(&mut self, t: Instant) {
        for servo in &mut self.servos {
            servo.update(t);
        }
    }

    fn push_event(&mut self, event: BusEvent) {
        if self.events.len() >= MAX_PENDING_EVENTS {
            self.events.pop_front();
        }
        self.events.push_back(event);
    }

    fn flush_garbage(&mut self) {
        if let Some(at) = self.garbage_at.take() {
            let bytes = std::mem::take(&mut self.garbage);
            self.push_event(BusEvent::Garbage { at, bytes });
        }
    }

    fn handle_decoded(&mut self, result: Decoded<RxMeta>) {
        match result {
            Decoded::Garbage { byte, meta } => {
                self.garbage.push(byte);
                self.garbage_at.get_or_insert(meta.read_at);
                self.stats.garbage_bytes += 1;
                if self.garbage.len() >= MAX_GARBAGE_RUN {
                    self.flush_garbage();
                }
            }
            Decoded::BadSum { bytes } => {
                self.flush_garbage();
                self.stats.bad_sums += 1;
                let at = bytes.first().map_or(self.now, |(_, meta)| meta.read_at);
                self.push_event(BusEvent::BadSum {
                    at,
                    bytes: bytes.iter().map(|(byte, _)| *byte).collect(),
                });
            }
            Decoded::Packet { packet, bytes } => {
                self.flush_garbage();
                self.handle_packet(packet, &bytes);
            }
        }
    }

    fn handle_packet(&mut self, packet: HostPacket, bytes: &[(u8, RxMeta)]) {
        let (Some((_, first)), Some((_, last))) = (bytes.first(), bytes.last()) else {
            return;
        };
        self.stats.packets_rx += 1;
        let completed_at = last.end;
        let baud = if bytes.iter().all(|(_, meta)| meta.baud == first.baud) {
            first.baud
        } else {
            None
        };
        let collided = bytes.iter().any(|(_, meta)| meta.collided);
        let mut acted = Vec::new();
        let mut effects = Vec::new();
        let mut replies = Vec::new();
        if !collided {
            for (slot, servo) in self.servos.iter_mut().enumerate() {
                if !servo.is_powered() {
                    continue;
                }
                if baud.is_none() || servo.baud() != baud {
                    if servo.is_addressed(&packet) {
                        self.stats.baud_mismatches += 1;
                    }
                    continue;
                }
                let id_before = servo.id();
                let reception = servo.receive(completed_at, &packet);
                if reception.acted {
                    acted.push(id_before);
                }
                for kind in reception.damage {
                    self.stats.damage_events += 1;
                    effects.push(BusEvent::Damage(DamageEvent {
                        at: completed_at,
                        id: servo.id(),
                        kind,
                    }));
                }
                if let Some(reason) = reception.ignored {
                    self.stats.ignored += 1;
                    effects.push(BusEvent::Ignored {
                        at: completed_at,
                        id: id_before,
                        reason,
                    });
                }
                if let Some(reply) = reception.reply {
                    let late = match self.servo_reply_faults.get(slot).and_then(|f| f.late) {
                        Some((delay, every)) => {
                            let started = &mut self.replies_started[slot];
                            *started += 1;
                            if started.is_multiple_of(u64::from(every.max(1))) {
                                delay
                            } else {
                                Duration::ZERO
                            }
                        }
                        None => Duration::ZERO,
                    };
                    replies.push((
                        slot,
                        reply,
                        completed_at + servo.return_delay() + self.latency + late,
                    ));
                }
            }
        }
        self.push_event(BusEvent::Packet(PacketEvent {
            first_byte_at: first.read_at,
            completed_at,
            host_baud: baud,
            bytes: bytes.iter().map(|(byte, _)| *byte).collect(),
            packet,
            acted,
            collided,
        }));
        for event in effects {
            self.push_event(event);
        }
        for (slot, reply, start) in replies {
            self.schedule_reply(slot, reply, start);
        }
    }

    fn reply_faults(&self, slot: usize) -> ReplyFaults {
        let own = self
            .servo_reply_faults
            .get(slot)
            .copied()
            .unwrap_or_default();
        ReplyFaults {
            corrupt_probability: own
                .corrupt_probability
                .or(self.bus_reply_faults.corrupt_probability),
            drop_probability: own
                .drop_probability
                .or(self.bus_reply_faults.drop_probability),
            late: own.late,
        }
    }

    fn schedule_reply(&mut self, slot: usize, mut bytes: Vec<u8>, start: Instant) {
        let Some(servo) = self.servos.get(slot) else {
            return;
        };
        let id = servo.id();
        let servo_baud = servo.baud();
        let faults = self.reply_faults(slot);
        if self.rng.chance(faults.drop_probability.unwrap_or(0.0)) {
            self.stats.replies_dropped += 1;
            self.push_event(BusEvent::ReplyDropped { at: start, id });
            return;
        }
        let corrupted =
            !bytes.is_empty() && self.rng.chance(faults.corrupt_probability.unwrap_or(0.0));
        if corrupted {
            let index = self.rng.below(bytes.len());
            bytes[index] ^= self.rng.nonzero_byte();
            self.stats.replies_corrupted += 1;
        }
        let host_baud = self.host_baud;
        let reply_baud = servo_baud.or(host_baud).unwrap_or(self.default_baud);
        let duration = byte_time(reply_baud) * u32::try_from(bytes.len()).unwrap_or(u32::MAX);
        let baud_mismatch = servo_baud.is_none() || servo_baud != host_baud;
        if baud_mismatch {
            // The host's UART frames the reply's bits at its own rate: noise, as many bytes as fit.
            let noise_len = match (servo_baud, host_baud) {
                (Some(servo), Some(host)) => {
                    ((bytes.len() as f64 * f64::from(host) / f64::from(servo)).round() as usize)
                        .clamp(1, 4096)
                }
                _ => bytes.len(),
            };
            bytes = (0..noise_len).map(|_| self.rng.next_u64() as u8).collect();
        }
        let count = u32::try_from(bytes.len()).unwrap_or(u32::MAX).max(1);
        let step = duration / count;
        let end = start + step * count;
        // Two talkers at once: a reply already scheduled overlaps this one.
        let overlapping_reply = self.tx_queue.iter().any(|tx| {
            matches!(tx.source, TxSource::Reply { .. }) && tx.start < end && start < tx.at
        });
        if overlapping_reply {
            // The later talker's reply is lost in the earlier one, which is garbled where they overlap.
            self.collide_with_replies(start, end);
            return;
        }
        let seq = self.next_reply_seq;
        self.next_reply_seq += 1;
        let mut scheduled: Vec<TxByte> = bytes
            .iter()
            .enumerate()
            .map(|(index, &byte)| {
                let index = u32::try_from(index).unwrap_or(u32::MAX);
                TxByte {
                    start: start + step * index,
                    at: start + step * (index + 1),
                    byte,
                    source: TxSource::Reply { slot, id, seq },
                }
            })
            .collect();
        // The host already talking while this reply will be on the line.
        let mut collision_at = None;
        for (_, meta) in self.rx_queue.iter_mut() {
            for tx in scheduled.iter_mut() {
                if tx.start < meta.end && meta.start < tx.at {
                    meta.collided = true;
                    tx.byte ^= self.rng.nonzero_byte();
                    collision_at.get_or_insert(tx.start.max(meta.start));
                }
            }
        }
        if let Some(at) = collision_at {
            self.collided_replies.insert(seq);
            self.stats.collisions += 1;
            self.push_event(BusEvent::Collision { at, id });
        }
        self.stats.replies_tx += 1;
        self.push_event(BusEvent::Reply(ReplyEvent {
            id,
            first_byte_at: scheduled.first().map_or(start, |tx| tx.at),
            last_byte_at: scheduled.last().map_or(start, |tx| tx.at),
            bytes: scheduled.iter().map(|tx| tx.byte).collect(),
            corrupted,
            baud_mismatch,
        }));
        for tx in scheduled {
            self.insert_tx(tx);
        }
    }

    // ----- events and counters -----

    /// Take the events recorded so far.
    pub fn drain_events(&mut self) -> Vec<BusEvent> {
        self.events.drain(..).collect()
    }

    pub fn stats(&self) -> BusStats {
        self.stats
    }

    // ----- servos -----

    /// Number of servos on the bus.
    pub fn servo_count(&self) -> usize {
        self.servos.len()
    }

    /// The slot of the servo answering to `id` now; if none does, the servo configured with `id`.
    pub fn slot_of(&self, id: u8) -> Option<usize> {
        self.servos
            .iter()
            .position(|servo| servo.id() == id)
            .or_else(|| {
                self.configured_ids
                    .iter()
                    .position(|&configured| configured == id)
            })
    }

    fn slots(&self, id: Option<u8>) -> Vec<usize> {
        match id {
            Some(id) => self.slot_of(id).into_iter().collect(),
            None => (0..self.servos.len()).collect(),
        }
    }

    /// State of the servo answering to `id` (see [`BusModel::slot_of`]) at `now`.
    pub fn snapshot(&mut self, now: Instant, id: u8) -> Option<ServoSnapshot> {
        let slot = self.slot_of(id)?;
        Some(self.servos[slot].snapshot(slot, now))
    }

    /// State of every servo at `now`, in configuration order.
    pub fn snapshots(&mut self, now: Instant) -> Vec<ServoSnapshot> {
        self.servos
            .iter_mut()
            .enumerate()
            .map(|(slot, servo)| servo.snapshot(slot, now))
            .collect()
    }

    /// Inject a fault into one servo or (with `None`) every servo / the whole bus. Returns false if `id`
    /// is not on the bus.
    pub fn inject(&mut self, now: Instant, id: Option<u8>, fault: Fault) -> bool {
        if let Fault::Echo = fault {
            self.echo = true;
            return true;
        }
        let slots = self.slots(id);
        if slots.is_empty() {
            return false;
        }
        match fault {
            Fault::CorruptReplies { probability } => match id {
                None => self.bus_reply_faults.corrupt_probability = Some(probability),
                Some(_) => slots.iter().for_each(|&slot| {
                    self.servo_reply_faults[slot].corrupt_probability = Some(probability)
                }),
            },
            Fault::DropReplies { probability } => match id {
                None => self.bus_reply_faults.drop_probability = Some(probability),
                Some(_) => slots.iter().for_each(|&slot| {
                    self.servo_reply_faults[slot].drop_probability = Some(probability)
                }),
            },
            Fault::LateReplies { delay_us, every } => slots.iter().for_each(|&slot| {
                self.servo_reply_faults[slot].late =
                    Some((Duration::from_micros(u64::from(delay_us)), every));
            }),
            Fault::Echo => {}
            Fault::Stall => slots
                .iter()
                .for_each(|&slot| self.servos[slot].set_stalled(now, true)),
            Fault::ExternalLoad { newtons } => slots
                .iter()
                .for_each(|&slot| self.servos[slot].set_load_n(now, f64::from(newtons))),
            Fault::Overheat => slots
                .iter()
                .for_each(|&slot| self.servos[slot].set_overheating(now, true)),
            Fault::WrongModel(model) => slots
                .iter()
                .for_each(|&slot| self.servos[slot].set_model_number(now, model)),
            Fault::Unplugged => slots.iter().for_each(|&slot| self.power_off(now, slot)),
        }
        true
    }

    /// Remove a fault from one servo or (with `None`) from every servo and the bus. Clearing `Unplugged`
    /// plugs the servo back in.
    pub fn clear(&mut self, now: Instant, id: Option<u8>, kind: FaultKind) -> bool {
        if kind == FaultKind::Echo {
            self.echo = false;
            return true;
        }
        let slots = self.slots(id);
        if slots.is_empty() {
            return false;
        }
        for &slot in &slots {
            match kind {
                FaultKind::CorruptReplies => {
                    self.servo_reply_faults[slot].corrupt_probability = None
                }
                FaultKind::DropReplies => self.servo_reply_faults[slot].drop_probability = None,
                FaultKind::LateReplies => self.servo_reply_faults[slot].late = None,
                FaultKind::Echo => {}
                FaultKind::Stall => self.servos[slot].set_stalled(now, false),
                FaultKind::ExternalLoad => self.servos[slot].set_load_n(now, 0.0),
                FaultKind::Overheat => self.servos[slot].set_overheating(now, false),
                FaultKind::WrongModel => {
                    self.servos[slot].set_model_number(now, LJ9DA41_MODEL_NUMBER)
                }
                FaultKind::Unplugged => self.servos[slot].power_on(now),
            }
        }
        if id.is_none() {
            match kind {
                FaultKind::CorruptReplies => self.bus_reply_faults.corrupt_probability = None,
                FaultKind::DropReplies => self.bus_reply_faults.drop_probability = None,
                _ => {}
            }
        }
        true
    }

    /// Remove every fault (and plug every servo back in).
    pub fn clear_all(&mut self, now: Instant) {
        for kind in [
            FaultKind::CorruptReplies,
            FaultKind::DropReplies,
            FaultKind::LateReplies,
            FaultKind::Echo,
            FaultKind::Stall,
            FaultKind::ExternalLoad,
            FaultKind::Overheat,
            FaultKind::WrongModel,
            FaultKind::Unplugged,
        ] {
            self.clear(now, None, kind);
        }
    }

    fn power_off(&mut self, now: Instant, slot: usize) {
        let Some(servo) = self.servos.get_mut(slot) else {
            return;
        };
        let id = servo.id();
        let damage = servo.power_off(now);
        for kind in damage {
            self.stats.damage_events += 1;
            self.push_event(BusEvent::Damage(DamageEvent { at: now, id, kind }));
        }
        // The rest of its reply never reaches the line.
        self.tx_queue
            .retain(|tx| !matches!(tx.source, TxSource::Reply { slot: s, .. } if s == slot));
    }

    /// Unplug a servo: silent, ignores everything.
    pub fn unplug(&mut self, now: Instant, id: u8) -> bool {
        self.inject(now, Some(id), Fault::Unplugged)
    }

    /// Plug a servo back in: power-on state from flash.
    pub fn plug(&mut self, now: Instant, id: u8) -> bool {
        self.clear(now, Some(id), FaultKind::Unplugged)
    }

    /// Power a servo off and on again.
    pub fn power_cycle(&mut self, now: Instant, id: u8) -> bool {
        let Some(slot) = self.slot_of(id) else {
            return false;
        };
        self.power_off(now, slot);
        self.servos[slot].power_on(now);
        true
    }

    /// Adapter echo on or off.
    pub fn set_echo(&mut self, on: bool) {
        self.echo = on;
    }

    pub fn set_load_n(&mut self, now: Instant, id: u8, newtons: f32) -> bool {
        self.with_servo(id, |servo| servo.set_load_n(now, f64::from(newtons)))
    }

    /// Wear of servo `id` from `now` on (see [`Wear`](crate::servo::physics::Wear)).
    pub fn set_wear(&mut self, now: Instant, id: u8, wear: crate::servo::physics::Wear) -> bool {
        self.with_servo(id, |servo| servo.set_wear(now, wear))
    }

    pub fn set_stalled(&mut self, now: Instant, id: u8, stalled: bool) -> bool {
        self.with_servo(id, |servo| servo.set_stalled(now, stalled))
    }

    /// Start the overheat fault (clear it with `clear(.., FaultKind::Overheat)`).
    pub fn overheat(&mut self, now: Instant, id: u8) -> bool {
        self.with_servo(id, |servo| servo.set_overheating(now, true))
    }

    pub fn set_model_number(&mut self, now: Instant, id: u8, model_number: u16) -> bool {
        self.with_servo(id, |servo| servo.set_model_number(now, model_number))
    }

    pub fn set_voltage_v(&mut self, now: Instant, id: Option<u8>, voltage_v: f32) -> bool {
        self.with_servos(id, |servo| servo.set_voltage_v(now, f64::from(voltage_v)))
    }

    pub fn set_ambient_c(&mut self, now: Instant, id: Option<u8>, ambient_c: f32) -> bool {
        self.with_servos(id, |servo| servo.set_ambient_c(now, f64::from(ambient_c)))
    }

    pub fn set_temperature_c(&mut self, now: Instant, id: u8, temperature_c: f32) -> bool {
        self.with_servo(id, |servo| {
            servo.set_temperature_c(now, f64::from(temperature_c))
        })
    }

    /// Move a servo's rod by hand to a physical position, mm.
    pub fn move_rod(&mut self, now: Instant, id: u8, position_mm: f32) -> bool {
        self.with_servo(id, |servo| servo.move_rod(now, f64::from(position_mm)))
    }

    fn with_servo(&mut self, id: u8, action: impl FnOnce(&mut Servo)) -> bool {
        match self.slot_of(id) {
            Some(slot) => {
                action(&mut self.servos[slot]);
                true
            }
            None => false,
        }
    }

    fn with_servos(&mut self, id: Option<u8>, mut action: impl FnMut(&mut Servo)) -> bool {
        let slots = self.slots(id);
        for &slot in &slots {
            action(&mut self.servos[slot]);
        }
        !slots.is_empty()
    }

    /// Direct access to a servo (by slot) for tests and tools.
    pub fn servo(&self, slot: usize) -> Option<&Servo> {
        self.servos.get(slot)
    }
}
