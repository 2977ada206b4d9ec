//! The bench's table: one row per scenario, and the lines that check its targets.

use super::{Row, WARM_UP, WINDOW};
use std::time::Duration;

fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let rank = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted.get(rank.min(sorted.len() - 1)).copied()
}

fn fmt_us(v: Option<f64>) -> String {
    match v {
        Some(us) if us >= 10_000.0 => format!("{:.1}ms", us / 1000.0),
        Some(us) => format!("{us:.0}"),
        None => "–".into(),
    }
}

/// A latency for a sentence: "85 µs", "12.3 ms".
fn fmt_latency(v: Option<f64>) -> String {
    match v {
        Some(us) if us.abs() >= 1000.0 => format!("{:.2} ms", us / 1000.0),
        Some(us) => format!("{us:.0} µs"),
        None => "–".into(),
    }
}

pub(super) fn print_table(
    rows: &[Row],
    load_before: &str,
    load_after: &str,
    wake_cost: Option<Duration>,
) {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!();
    println!("Bus master vs simulated LJ9DA41 bus over a pty ({cores} cores, {cpu})");
    println!(
        "window {:.1} s after {:.1} s warm-up; turnaround allowance 2 ms; latency in µs; load average {} → {}",
        WINDOW.as_secs_f64(),
        WARM_UP.as_secs_f64(),
        load_before,
        load_after
    );
    println!(
        "a thread's 1 ms sleep and wake-up costs it {} µs of CPU here (the floor of a read's CPU/tx)",
        wake_cost.map_or("?".into(), |d| format!("{:.1}", d.as_secs_f64() * 1e6))
    );
    println!();
    let header = [
        "frames/s", "polls/s", "pos/s", "telem Hz", "wire %", "limit %", "→goal", "gap", "p50",
        "p99", "max", "idle p50", "busy exc", "busy exc", "on wire", "t/o", "coll", "sim", "bus",
        "stolen", "CPU/tx", "wake", "CPU",
    ];
    let header2 = [
        "", "", "", "/servo", "", "", "idle %", "p50", "", "", "", "", "p99", "max", "/set", "",
        "", "late", "late", "", "µs", "/tx", "%",
    ];
    let widths = [
        8, 7, 6, 9, 6, 7, 6, 5, 7, 7, 7, 8, 8, 8, 11, 4, 4, 4, 4, 6, 6, 5, 5,
    ];
    let line = |label: &str, cells: &[String]| {
        let mut out = format!("{label:<27}");
        for (cell, w) in cells.iter().zip(widths) {
            out.push_str(&format!(" {cell:>w$}"));
        }
        println!("{out}");
    };
    line("bit/s N goals", &header.map(String::from));
    line("", &header2.map(String::from));
    for r in rows {
        let sorted = |v: &[f64]| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            v
        };
        let all = sorted(&r.latencies_us);
        let idle = sorted(&r.idle_us);
        let busy = sorted(&r.busy_excess_us);
        line(
            &r.label,
            &[
                format!("{:.1}", r.frames_s),
                format!("{:.1}", r.polls_s),
                format!("{:.1}", r.position_s),
                format!("{:.1}", r.telemetry_hz_min),
                format!("{:.1}%", r.wire_fraction * 100.0),
                format!("{:.1}%", r.utilisation * 100.0),
                format!("{:.1}%", r.before_goals_fraction * 100.0),
                fmt_us(percentile(&sorted(&r.gaps_us), 50.0)),
                fmt_us(percentile(&all, 50.0)),
                fmt_us(percentile(&all, 99.0)),
                fmt_us(all.last().copied()),
                fmt_us(percentile(&idle, 50.0)),
                fmt_us(percentile(&busy, 99.0)),
                fmt_us(busy.last().copied()),
                format!("{}/{}", r.goals_on_wire, r.goals_set),
                r.timeouts.to_string(),
                r.collisions.to_string(),
                r.sim_late.to_string(),
                r.late_wakeups.to_string(),
                r.stolen_ms.map_or("?".into(), |ms| ms.to_string()),
                format!("{:.1}", r.cpu_per_tx_us),
                format!("{:.2}", r.wakeups_per_tx),
                format!("{:.2}", r.cpu_percent),
            ],
        );
    }
    println!();
    println!(
        "telem Hz/servo: replies with position and current (registers 42–49 or 42–59) of the slowest servo. wire %: wire time of"
    );
    println!(
        "all bytes / elapsed. limit %: share of the section-8 wire-time limit used (bytes on the line"
    );
    println!(
        "plus the servos' own reply turnaround; the rest is line left idle). →goal idle %: idle line"
    );
    println!(
        "time that ended with a goal frame (50 Hz: kept free for an expected goal). gap p50: idle gap"
    );
    println!(
        "after a reply's last byte (the bus thread and the simulator waking). idle p50: latency of goals"
    );
    println!(
        "set with no reply awaited. busy exc: latency − time left of the reply in flight, for goals set"
    );
    println!(
        "while one was awaited (goals behind a reply that timed out are left out). on wire/set: goals"
    );
    println!(
        "seen in a long packet / goals set (the rest were superseded by newer ones before a frame"
    );
    println!(
        "left). t/o: reply timeouts. coll: collisions on the line (simulator's count). sim late: times the"
    );
    println!(
        "simulator's thread handed bytes over > 200 µs after their wire instant (a reply's time left"
    );
    println!("then runs to its actual hand-over).");
    println!("bus late: the bus thread woke > 0.5 ms after");
    println!(
        "the instant it slept until (the machine did not run it in time). stolen: CPU time the"
    );
    println!("hypervisor ran something else in the window (/proc/stat steal, 10 ms ticks).");
    println!(
        "CPU/tx: the bus thread's CPU time (getrusage RUSAGE_THREAD, read by the thread when it"
    );
    println!(
        "publishes its status) per transaction (request and reply, or long packet); wake/tx: its"
    );
    println!(
        "voluntary context switches (sleeps ended by a timer, a byte or a goal) per transaction; CPU: of one core."
    );
    println!();
    println!(
        "Targets (anchor: ArduPilot Volz at 115 200 bit/s, 4 servos: ~128 commands/s, ~10 Hz telemetry):"
    );
    for r in rows {
        if r.label.trim_start().starts_with("115200 4 50 Hz") && !r.label.contains("idle") {
            println!(
                "  115 200, 4 servos, 50 Hz: every goal on the wire: {} ({}/{}); position and current ≥ 60 Hz: {} ({:.1}); temperature and voltage ≥ 10 Hz: {} ({:.1}); limit ≥ 90 %: {} ({:.1} %)",
                ok(r.goals_on_wire == r.goals_set),
                r.goals_on_wire,
                r.goals_set,
                ok(r.telemetry_hz_min >= 60.0),
                r.telemetry_hz_min,
                ok(r.full_hz_min >= 10.0),
                r.full_hz_min,
                ok(r.utilisation >= 0.90),
                r.utilisation * 100.0
            );
        }
    }
    let idle_rows = || rows.iter().filter(|r| r.label.contains("idle"));
    let mut idle_all: Vec<f64> = idle_rows()
        .flat_map(|r| r.idle_us.iter().copied())
        .collect();
    idle_all.sort_by(f64::total_cmp);
    let mut calls: Vec<f64> = idle_rows()
        .flat_map(|r| r.idle_call_us.iter().copied())
        .collect();
    calls.sort_by(f64::total_cmp);
    let idle_p50 = percentile(&idle_all, 50.0);
    println!(
        "  idle-bus latency p50 ≤ 100 µs: {} ({} over {} goals of the idle-bus rows;",
        ok(idle_p50.is_some_and(|v| v <= 100.0)),
        fmt_latency(idle_p50),
        idle_all.len()
    );
    println!(
        "    of it, set_goals until its write returned: p50 {}, p99 {}; the rest is the simulator thread waking)",
        fmt_latency(percentile(&calls, 50.0)),
        fmt_latency(percentile(&calls, 99.0)),
    );
    let mut excess: Vec<f64> = rows
        .iter()
        .flat_map(|r| r.busy_excess_us.iter().copied())
        .collect();
    excess.sort_by(f64::total_cmp);
    let over = excess.iter().filter(|&&v| v > 500.0).count();
    println!(
        "  busy-bus latency ≤ time left of the poll in flight + 0.5 ms: {} (p99 excess {}, worst {}; {} of {} goals over)",
        ok(over == 0),
        fmt_latency(percentile(&excess, 99.0)),
        fmt_latency(excess.last().copied()),
        over,
        excess.len()
    );
    let by_bus: u64 = rows.iter().map(|r| r.over_bus_late).sum();
    let by_sim: u64 = rows.iter().map(|r| r.over_sim_late).sum();
    println!(
        "    of them {by_bus} while the bus thread was woken > 0.5 ms late, {by_sim} while the simulator handed bytes over late, {} with neither",
        (over as u64).saturating_sub(by_bus + by_sim)
    );
    println!(
        "    (in the whole run: {} late wake-ups of the bus thread, {} late hand-overs of the simulator)",
        rows.iter().map(|r| r.late_wakeups).sum::<u64>(),
        rows.iter().map(|r| r.sim_late).sum::<u64>(),
    );
    let worst_util = rows
        .iter()
        .filter(|r| !r.label.contains("idle"))
        .map(|r| r.utilisation)
        .fold(f64::INFINITY, f64::min);
    println!(
        "  limit ≥ 90 % whenever there is work (every row but the idle-bus ones): {} (lowest {:.1} %)",
        ok(worst_util >= 0.90),
        worst_util * 100.0
    );
}

fn ok(b: bool) -> &'static str {
    if b { "yes" } else { "NO" }
}
