//! The autopilot's ticks as a real autopilot sends them: outputs that hold still for seconds,
//! steps after a hold, a port that falls silent, both silent and back, a rate that changes, a
//! burst of late messages. Every output message is a tick, changed or not; a step must find
//! the bus free, and the rhythm must come back within ten periods of any disturbance.

use super::*;

/// 50 Hz.
const PERIOD: Duration = Duration::from_millis(20);
/// Port 1's message after port 0's, as ArduPilot sends them back to back.
const PORT1_AFTER: Duration = Duration::from_micros(65);

/// One output message: when, on which port, and whether it changes its servos' goals.
#[derive(Debug, Clone, Copy)]
struct Msg {
    at: Instant,
    port: usize,
    step: bool,
}

/// What became of a message that changed goals.
#[derive(Debug, Clone, Copy)]
#[allow(dead_code)] // `port` is for the failure messages.
struct Step {
    at: Instant,
    port: usize,
    /// From the message to the first frame handed out at or after it.
    wait: Duration,
    /// The request on the wire when it came, if any.
    behind: Option<TxKind>,
}

/// Servos of port 0 and port 1.
const PORTS: [&[u8]; 2] = [&[1, 2, 3], &[4]];

/// Drive the rig with `messages` (sorted by time): each one a tick; a step gives its port's
/// servos new goals. Returns every step.
fn drive(rig: &mut Rig, messages: &[Msg]) -> Vec<Step> {
    let mut value = [0i16; 2];
    let mut pending = Vec::new();
    for m in messages {
        rig.run(m.at.saturating_duration_since(rig.t));
        let behind = rig
            .m
            .reply_pending()
            .then(|| rig.log.last().map(|s| s.tx.kind))
            .flatten();
        let goals: Vec<_> = if m.step {
            value[m.port] = (value[m.port] + 37) % 2000;
            PORTS[m.port]
                .iter()
                .map(|&n| (n, Goal::Position(MmCenti(value[m.port] + i16::from(n)))))
                .collect()
        } else {
            Vec::new()
        };
        rig.message(&goals);
        if m.step {
            pending.push((rig.t, m.port, rig.log.len(), behind));
        }
    }
    rig.run(PERIOD);
    pending
        .into_iter()
        .map(|(at, port, from, behind)| Step {
            at,
            port,
            wait: rig
                .sent_since(from)
                .iter()
                .find(|s| s.tx.kind == TxKind::Command)
                .map(|s| s.at - at)
                .expect("a frame after every step"),
            behind,
        })
        .collect()
}

/// Ticks every `period` from `from` for `count` ticks, on `ports`, with `jitter_us` of spread
/// (deterministic) and a step on port 0 (and on port 1 with it) at every tick for which `step`
/// says so.
fn ticks(
    from: Instant,
    count: usize,
    period: Duration,
    ports: &[usize],
    jitter_us: i64,
    step: impl Fn(usize) -> bool,
) -> Vec<Msg> {
    let mut out = Vec::new();
    for k in 0..count {
        let base = from + period * k as u32;
        let off = if jitter_us > 0 {
            uniform(k, 3, jitter_us)
        } else {
            0
        };
        let at = if off >= 0 {
            base + us(off as u64)
        } else {
            base - us(off.unsigned_abs())
        };
        for &port in ports {
            let at = at + PORT1_AFTER * port as u32;
            out.push(Msg {
                at,
                port,
                step: step(k),
            });
        }
    }
    out
}

/// The end of the latest message of `messages`, plus one period.
fn after(messages: &[Msg]) -> Instant {
    messages.last().map_or(Instant::now(), |m| m.at) + PERIOD
}

/// Every step found the bus free (nothing in flight) and its frame left within `within`.
fn assert_free(steps: &[Step], within: Duration, what: &str) {
    assert!(!steps.is_empty(), "{what}: no step");
    let bad: Vec<_> = steps
        .iter()
        .filter(|s| s.behind.is_some() || s.wait > within)
        .collect();
    assert!(
        bad.is_empty(),
        "{what}: {} of {}: {bad:?}",
        bad.len(),
        steps.len()
    );
}

/// The steps that came at least ten periods of the autopilot after `since`.
fn settled(steps: &[Step], since: Instant, period: Duration) -> Vec<Step> {
    steps
        .iter()
        .filter(|s| s.at >= since + period * 10)
        .copied()
        .collect()
}

/// Servos 1 to `servos` had their position and current read at a rate in `hz` (50 Hz asked)
/// from `from` until `until`.
fn assert_read_at(
    rig: &Rig,
    servos: u8,
    hz: std::ops::RangeInclusive<f64>,
    from: Instant,
    until: Instant,
    what: &str,
) {
    for n in 1..=servos {
        let reads = rig
            .log
            .iter()
            .filter(|s| s.at >= from && s.at < until)
            .filter(|s| matches!(s.tx.kind, TxKind::Poll(i) | TxKind::MotionPoll(i) if i == id(n)))
            .count();
        let rate = reads as f64 / (until - from).as_secs_f64();
        assert!(
            hz.contains(&rate),
            "{what}: servo {n} read at {rate:.1} Hz, 50 asked"
        );
    }
}

/// A step waits at most for port 1's message of its tick (and the slack after it: 250 µs).
const STEP_WAIT: Duration = Duration::from_micros(400);

/// A bus of four servos online, and one second of a sweep on both ports.
fn warmed_up() -> (Rig, Vec<Msg>) {
    warmed_up_on(config(&[1, 2, 3, 4]))
}

/// [`warmed_up`] on the bus `cfg`.
fn warmed_up_on(cfg: BusConfig) -> (Rig, Vec<Msg>) {
    let rig = Rig::online_with_force_on(cfg);
    let sweep = ticks(rig.t + ms(5), 50, PERIOD, &[0, 1], 0, |_| true);
    (rig, sweep)
}

#[test]
fn after_ten_seconds_of_unchanged_outputs_a_step_finds_the_bus_free() {
    for jitter in [0, 1000] {
        let (mut rig, mut messages) = warmed_up();
        // 10 s of holding, then a step every 0.8 s (40 ticks) for 8 s.
        let hold = ticks(after(&messages), 500, PERIOD, &[0, 1], jitter, |_| false);
        let steps_from = after(&hold);
        let stepping = ticks(steps_from, 400, PERIOD, &[0, 1], jitter, |k| k % 40 == 20);
        messages.extend(hold);
        messages.extend(stepping);
        let steps = drive(&mut rig, &messages);
        let after_hold: Vec<_> = steps.into_iter().filter(|s| s.at >= steps_from).collect();
        assert_eq!(after_hold.len(), 20, "ten steps on each port");
        assert_free(&after_hold, STEP_WAIT, &format!("±{jitter} µs"));
    }
}

#[test]
fn polls_go_on_while_the_outputs_hold() {
    let (mut rig, mut messages) = warmed_up();
    messages.extend(ticks(after(&messages), 250, PERIOD, &[0, 1], 0, |_| false));
    let c0 = *rig.m.counters();
    let t0 = rig.t;
    drive(&mut rig, &messages);
    let c = rig.m.counters();
    let seconds = (rig.t - t0).as_secs_f64();
    let motion_hz = ((c.polls + c.motion_polls) - (c0.polls + c0.motion_polls)) as f64 / seconds;
    assert!(
        motion_hz / 4.0 >= 60.0,
        "{:.1} Hz per servo",
        motion_hz / 4.0
    );
}

#[test]
fn one_port_silent_for_seconds_while_the_other_goes_on() {
    let (mut rig, mut messages) = warmed_up();
    // Port 1 falls silent for 3 s, steps on port 0 every 0.3 s; then it comes back.
    let silent = ticks(after(&messages), 150, PERIOD, &[0], 0, |k| k % 15 == 7);
    let silent_from = after(&messages);
    let back_from = after(&silent);
    let back = ticks(back_from, 150, PERIOD, &[0, 1], 0, |k| k % 15 == 7);
    messages.extend(silent);
    messages.extend(back);
    let steps = drive(&mut rig, &messages);
    let during: Vec<_> = settled(&steps, silent_from, PERIOD)
        .into_iter()
        .filter(|s| s.at < back_from)
        .collect();
    assert_free(&during, STEP_WAIT, "port 1 silent");
    assert_free(
        &settled(&steps, back_from, PERIOD),
        STEP_WAIT,
        "port 1 back",
    );
}

#[test]
fn both_ports_silent_and_back_with_another_phase() {
    let (mut rig, mut messages) = warmed_up();
    // The stream stops for 2.5 s (failsafe) and comes back 7.3 ms off its old phase.
    let back_from = after(&messages) + ms(2500) + us(7300);
    messages.extend(ticks(back_from, 200, PERIOD, &[0, 1], 0, |k| k % 13 == 5));
    let steps = drive(&mut rig, &messages);
    assert_free(&settled(&steps, back_from, PERIOD), STEP_WAIT, "back");
}

#[test]
fn a_rate_that_drops_to_a_quarter_and_comes_back() {
    // ArduPilot stretches its streams ×4 during a parameter or log transfer.
    let (mut rig, mut messages) = warmed_up();
    let slow = PERIOD * 4;
    let slow_from = after(&messages);
    let slow_ticks = ticks(slow_from, 38, slow, &[0, 1], 0, |k| k % 3 == 2);
    let back_from = slow_ticks.last().unwrap().at + slow;
    messages.extend(slow_ticks);
    messages.extend(ticks(back_from, 200, PERIOD, &[0, 1], 0, |k| k % 13 == 5));
    let steps = drive(&mut rig, &messages);
    let during: Vec<_> = settled(&steps, slow_from, slow)
        .into_iter()
        .filter(|s| s.at < back_from)
        .collect();
    assert_free(&during, STEP_WAIT, "12.5 Hz");
    assert_free(
        &settled(&steps, back_from, PERIOD),
        STEP_WAIT,
        "50 Hz again",
    );
}

#[test]
fn a_rate_lowered_to_40_hz_after_a_denial() {
    let (mut rig, mut messages) = warmed_up();
    let p40 = ms(25);
    let from = after(&messages);
    messages.extend(ticks(from, 200, p40, &[0, 1], 0, |k| k % 13 == 5));
    let steps = drive(&mut rig, &messages);
    assert_free(&settled(&steps, from, p40), STEP_WAIT, "40 Hz");
}

#[test]
fn a_burst_of_late_messages_then_the_usual_ticks() {
    let (mut rig, mut messages) = warmed_up();
    // 150 ms without a message, then seven ticks' messages at once (0.2 ms apart), then the
    // stream on its old phase.
    let gap_from = after(&messages);
    let burst_at = gap_from + ms(150);
    for k in 0..7u32 {
        for port in [0, 1] {
            messages.push(Msg {
                at: burst_at + us(200) * (2 * k + port as u32),
                port,
                step: false,
            });
        }
    }
    let resume = gap_from + PERIOD * 9;
    messages.extend(ticks(resume, 200, PERIOD, &[0, 1], 0, |k| k % 13 == 5));
    let steps = drive(&mut rig, &messages);
    assert_free(
        &settled(&steps, resume, PERIOD),
        STEP_WAIT,
        "after the burst",
    );
}

#[test]
fn a_servo_with_a_fifth_of_its_replies_garbled_keeps_most_of_its_good_replies() {
    // A garbled reply frees the bus when it has ended, as a clean one does: the servo loses
    // the garbled replies, not the time of a reply allowance after each (20 ms, as `sitl`
    // gives its simulated servos).
    let good_replies = |share: f64| {
        let mut cfg = config(&[1, 2, 3, 4]);
        cfg.turnaround = Duration::from_millis(20);
        let (mut rig, mut messages) = warmed_up_on(cfg);
        rig.servo(1).garble_share = share;
        let from = after(&messages);
        messages.extend(ticks(from, 250, PERIOD, &[0, 1], 0, |k| k % 2 == 0));
        let before = rig.m.status().servo(id(1)).unwrap().answered;
        drive(&mut rig, &messages);
        rig.m.status().servo(id(1)).unwrap().answered - before
    };
    let clean = good_replies(0.0);
    let garbled = good_replies(0.2);
    assert!(
        garbled as f64 >= 0.7 * clean as f64,
        "{garbled} good replies with 20 % garbled against {clean} clean"
    );
}

#[test]
fn with_a_telemetry_rate_a_tick_s_frame_carries_the_first_read_behind_it_and_reads_keep_the_rate() {
    for jitter in [0, 1000] {
        let mut cfg = config(&[1, 2, 3, 4]);
        cfg.telemetry_min_interval = PERIOD;
        let (mut rig, mut messages) = warmed_up_on(cfg);
        let from = after(&messages) + PERIOD * 10;
        let sweep = ticks(after(&messages), 260, PERIOD, &[0, 1], jitter, |_| true);
        let until = after(&sweep) - PERIOD * 2;
        messages.extend(sweep);
        drive(&mut rig, &messages);
        let window: Vec<&Sent> = rig
            .log
            .iter()
            .filter(|s| s.at >= from && s.at < until)
            .collect();
        // The thread that writes a tick's frame writes a request behind it in the same turn
        // (a read, or now and then a read-back): nothing else need wake to start the period's
        // reads.
        let frames = window
            .iter()
            .filter(|s| s.tx.kind == TxKind::Command)
            .count();
        let carried = window
            .windows(2)
            .filter(|w| {
                w[0].tx.kind == TxKind::Command
                    && w[1].tx.kind != TxKind::Command
                    && w[1].at == w[0].at
            })
            .count();
        assert!(frames >= 240, "±{jitter} µs: {frames} frames");
        assert!(
            carried * 100 >= frames * 95,
            "±{jitter} µs: {carried} of {frames} frames had a request behind them"
        );
        // A read started early behind a tick is the only one of its period: each servo is
        // read at the rate asked.
        assert_read_at(&rig, 4, 48.0..=51.0, from, until, &format!("±{jitter} µs"));
    }
}

#[test]
fn after_slow_replies_the_reads_of_a_period_come_back_together_behind_its_tick() {
    // Replies 6 ms late for one tick push its reads back. The ticks after it must pull them
    // in again: each read started by the tick's frame or by the reply before it, none on its
    // own (which costs the bus thread a wake-up of its own in every period), and each servo
    // still read at the rate asked.
    for jitter in [0, 1000] {
        let mut cfg = config(&[1, 2, 3, 4]);
        cfg.telemetry_min_interval = PERIOD;
        let (mut rig, warm) = warmed_up_on(cfg);
        drive(&mut rig, &warm);
        let slow = ticks(after(&warm), 1, PERIOD, &[0, 1], jitter, |_| true);
        rig.latency = ms(6);
        drive(&mut rig, &slow);
        rig.latency = us(100);
        let sweep = ticks(after(&slow), 200, PERIOD, &[0, 1], jitter, |_| true);
        let (from, until) = (after(&slow) + PERIOD * 10, after(&sweep) - PERIOD * 2);
        drive(&mut rig, &sweep);
        let window: Vec<&Sent> = rig
            .log
            .iter()
            .filter(|s| s.at >= from && s.at < until)
            .collect();
        let frames_at: Vec<Instant> = window
            .iter()
            .filter(|s| s.tx.kind == TxKind::Command)
            .map(|s| s.at)
            .collect();
        let is_read = |s: &&&Sent| matches!(s.tx.kind, TxKind::Poll(_) | TxKind::MotionPoll(_));
        let reads: Vec<Instant> = window.iter().filter(is_read).map(|s| s.at).collect();
        let alone: Vec<Duration> = reads
            .iter()
            .filter(|at| !frames_at.contains(at) && !rig.replied_at.contains(at))
            .map(|at| *at - from)
            .collect();
        assert!(reads.len() >= 700, "±{jitter} µs: {} reads", reads.len());
        assert!(
            alone.is_empty(),
            "±{jitter} µs: {} of {} reads started on their own, at {:?}…",
            alone.len(),
            reads.len(),
            &alone[..alone.len().min(4)]
        );
        assert_read_at(&rig, 4, 48.0..=51.0, from, until, &format!("±{jitter} µs"));
    }
}

#[test]
fn a_burst_of_reads_longer_than_the_early_margin_reads_no_servo_faster_than_asked() {
    // Five to seven servos at 115 200 bit/s take more than half a 20 ms period to read: reads
    // started early behind each reply would come round to the first servo again.
    for n_servos in 5..=7u8 {
        let ids: Vec<u8> = (1..=n_servos).collect();
        let mut cfg = config(&ids);
        cfg.telemetry_min_interval = PERIOD;
        let (mut rig, warm) = warmed_up_on(cfg);
        drive(&mut rig, &warm);
        let sweep = ticks(after(&warm), 200, PERIOD, &[0, 1], 0, |_| true);
        let (from, until) = (after(&warm) + PERIOD * 10, after(&sweep) - PERIOD * 2);
        drive(&mut rig, &sweep);
        let what = format!("{n_servos} servos");
        assert_read_at(&rig, n_servos, 45.0..=51.0, from, until, &what);
    }
}
