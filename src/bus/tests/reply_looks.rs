//! When the bus thread looks for a reply ([`BusMaster::reply_look_at`]): a reply is awaited
//! from its earliest end and counted down byte by byte; run as the bus thread runs them, the
//! looks learn how late the servos answer (about a byte before the reply's end), are not
//! thrown off by one very late reply, and learn from a look the port held until the kernel
//! passed the reply on.

use super::*;

#[test]
fn a_reply_is_awaited_from_its_earliest_end_and_counted_down_byte_by_byte() {
    let (mut rig, tx) = Rig::at_a_full_poll();
    // A telemetry poll: 8 bytes out, 26 back.
    let request_end = rig.t + rig.wire(tx.bytes.len());
    let complete_at = rig.m.reply_complete_at().expect("a reply is awaited");
    let deadline = rig.m.poll_timeout().expect("the reply's deadline");
    // No earlier than the request and the whole reply on the wire; the deadline adds only the
    // turnaround allowance.
    assert!(complete_at >= request_end + rig.wire(26), "{complete_at:?}");
    assert_eq!(deadline - complete_at, rig.m.config().turnaround);
    assert_eq!(rig.m.bytes_awaited(), Some(26));

    let reply = rig.servo(1).handle(&tx.bytes).expect("the servo answers");
    // An echo of the request is not part of the reply.
    rig.m.handle_input(&tx.bytes, request_end);
    assert_eq!(rig.m.bytes_awaited(), Some(26));
    rig.m.handle_input(&reply[..20], complete_at);
    assert_eq!(rig.m.bytes_awaited(), Some(6));
    rig.m.handle_input(&reply[20..25], complete_at);
    assert_eq!(rig.m.bytes_awaited(), Some(1));
    rig.m.handle_input(&reply[25..], complete_at);
    assert_eq!(rig.m.bytes_awaited(), None);
    assert_eq!(rig.m.reply_complete_at(), None);
    assert_eq!(rig.m.counters().timeouts, 0);
}

impl Rig {
    /// Write what is due; when a request went out, take its reply (when it is whole on the
    /// wire, and its bytes) and move to the bus master's look at it. Otherwise move to the next
    /// deadline and return `None`.
    fn request_and_look(&mut self) -> Option<(Instant, Vec<u8>)> {
        self.transmit();
        if !self.m.reply_pending() {
            self.t = self.m.poll_timeout().expect("a request is due").max(self.t);
            self.m.handle_timeout(self.t);
            return None;
        }
        let reply = self.reply.take().expect("the servo answers");
        self.t = self
            .t
            .max(self.m.reply_look_at().expect("a reply is awaited"));
        Some(reply)
    }
}

/// Run `requests` requests like the bus thread does: look when [`BusMaster::reply_look_at`]
/// says, and when part of the reply is missing, wait until it is all in (the tty's read
/// threshold) and read it then. The n-th reply is late by `lateness(n)` besides the return
/// delay. Returns, per answered request, the bytes missing at the first look and how long the
/// reply had been whole when it was read.
fn run_like_the_bus_thread(
    rig: &mut Rig,
    requests: usize,
    mut lateness: impl FnMut(usize) -> Duration,
) -> Vec<(usize, Duration)> {
    let byte = rig.wire(1);
    let mut out = Vec::new();
    let mut sent = 0;
    while sent < requests {
        rig.latency = lateness(sent);
        let Some((at, bytes)) = rig.request_and_look() else {
            continue;
        };
        sent += 1;
        let missing = at
            .saturating_duration_since(rig.t)
            .as_nanos()
            .div_ceil(byte.as_nanos());
        let missing = (missing as usize).min(bytes.len());
        rig.m.handle_input(&bytes[..bytes.len() - missing], rig.t);
        rig.m.handle_timeout(rig.t);
        let read_at = if missing > 0 {
            assert_eq!(rig.m.bytes_awaited(), Some(missing));
            rig.t = at;
            rig.m.handle_input(&bytes[bytes.len() - missing..], at);
            at
        } else {
            rig.t
        };
        assert!(!rig.m.reply_pending());
        out.push((missing, read_at.duration_since(at)));
        rig.drain_events();
    }
    out
}

#[test]
fn the_first_look_at_a_reply_learns_to_come_about_a_byte_before_its_end() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let byte = rig.wire(1);
    // Replies 200–380 µs later than the return delay says (the servo's processing, the
    // adapter), in an order with no pattern.
    let lateness = |n: usize| us(200 + (n as u64 * 7919 % 10) * 20);
    run_like_the_bus_thread(&mut rig, 200, lateness);
    let looks = run_like_the_bus_thread(&mut rig, 1000, |n| lateness(n + 200));
    let learned = rig.m.reply_lateness();
    assert!(
        learned >= us(200) && learned <= us(380) + byte,
        "learned {learned:?}"
    );
    // The bus is left idle after a reply (found whole at a look that came late) for less
    // than a byte time on average ...
    let idle: Duration = looks.iter().map(|(_, idle)| *idle).sum();
    assert!(
        idle / looks.len() as u32 <= byte,
        "mean idle {:?}",
        idle / looks.len() as u32
    );
    // ... and a look that comes early finds only the last few bytes missing (each one a
    // wake-up of the thread waiting for them, in the kernel).
    let missing: usize = looks.iter().map(|(m, _)| m).sum();
    assert!(
        missing <= looks.len() * 3,
        "{missing} bytes missing at {} first looks",
        looks.len()
    );
}

#[test]
fn without_a_learned_lateness_a_late_servo_costs_a_wait_for_many_bytes() {
    // The baseline of the test above: at the start nothing is learned, and the first looks of
    // replies 380 µs late come when more than four bytes are still on their way.
    let mut rig = Rig::online_with_force(&[1]);
    rig.settle();
    assert_eq!(rig.m.reply_lateness(), Duration::ZERO);
    let first = run_like_the_bus_thread(&mut rig, 1, |_| us(380));
    assert!(first[0].0 >= 4, "{first:?}");
    let later = run_like_the_bus_thread(&mut rig, 100, |_| us(380));
    assert!(
        later[60..].iter().all(|(m, _)| *m <= 2),
        "{:?}",
        &later[60..]
    );
}

#[test]
fn one_very_late_reply_does_not_delay_the_looks_at_the_next_ones() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    let byte = rig.wire(1);
    run_like_the_bus_thread(&mut rig, 100, |_| us(300));
    let learned = rig.m.reply_lateness();
    // One reply 1.5 ms late (the servo or the adapter stalled), then the usual again.
    let looks = run_like_the_bus_thread(&mut rig, 20, |n| if n == 0 { us(1800) } else { us(300) });
    assert!(rig.m.reply_lateness() <= learned + byte / 4);
    assert!(
        looks[1..].iter().all(|(_, idle)| *idle <= byte),
        "{looks:?}"
    );
}

/// Run `requests` requests through a port that passes each reply on `passed_on` after it is
/// whole on the wire (a tty's bytes go through the kernel's worker). A look before the reply is
/// whole finds part of it and waits for the rest; a look after that, before the port has it,
/// is held by the read until the bytes are in and then finds the reply whole, and the bus
/// master is told that the port held less than the reply at the look only if `tell`. Returns
/// how many looks came before the port had the reply.
fn looks_before_the_port_has_the_reply(
    rig: &mut Rig,
    requests: usize,
    passed_on: Duration,
    tell: bool,
) -> usize {
    let mut early = 0;
    let mut sent = 0;
    while sent < requests {
        let Some((at, bytes)) = rig.request_and_look() else {
            continue;
        };
        sent += 1;
        let in_port = at + passed_on;
        if rig.t < in_port {
            early += 1;
            if rig.t < at {
                // Part of it is in: the driver waits for the rest.
                rig.m.handle_timeout(rig.t);
            } else if tell {
                // As the driver does: the port's count is asked for at the first look only.
                let missing = rig.m.bytes_awaited_at_first_look();
                assert_eq!(missing, Some(bytes.len()), "the first look at this reply");
                rig.m.note_reply_incomplete();
                assert_eq!(rig.m.bytes_awaited_at_first_look(), None, "looked at");
            }
            rig.t = in_port;
        }
        rig.m.handle_input(&bytes, rig.t);
        assert!(!rig.m.reply_pending());
        rig.drain_events();
    }
    early
}

#[test]
fn a_look_held_until_the_kernel_passes_the_reply_on_teaches_a_later_look() {
    let passed_on = us(150);
    let early = |tell: bool| {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        looks_before_the_port_has_the_reply(&mut rig, 200, passed_on, tell);
        looks_before_the_port_has_the_reply(&mut rig, 400, passed_on, tell)
    };
    // Untold, the looks learn to come when the reply is whole on the wire, and nearly every
    // one is then held by the read (a second wake-up of the bus thread, in the kernel).
    let untold = early(false);
    assert!(untold >= 300, "{untold} of 400 looks came early");
    // Told, three looks in four come once the port has the reply.
    let told = early(true);
    assert!(told <= 140, "{told} of 400 looks came early");
}
