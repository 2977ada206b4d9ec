//! What the bench prints of a run: its two lines per peer, and the table that sets the bridge
//! and another peer side by side.

use super::{Case, Outcome, Peer, Pings};

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

/// A latency in whole µs, `-` where there was none.
fn us(v: f64) -> String {
    if v.is_nan() {
        "-".to_string()
    } else {
        format!("{v:.0}")
    }
}

/// What [`compare`] sets side by side, per peer.
pub(super) struct Figures {
    p0_p50: f64,
    p1_p50: f64,
    all_p50: f64,
    all_p99: f64,
    on_wire_percent: f64,
    cpu_percent: Option<f64>,
}

/// Print a run's two lines (the bridge's as they always were; the naive peer's with its name
/// after the case, and `n/a` where it has no such figure: it sends the ground station nothing,
/// and has one thread) and return its figures for [`compare`].
pub(super) fn report(case: &Case, peer: &Peer, mut o: Outcome) -> Figures {
    let bridge = matches!(peer, Peer::Bridge);
    let na = || "n/a".to_string();
    for l in &mut o.latencies_us {
        l.sort_by(f64::total_cmp);
    }
    o.settled_us.sort_by(f64::total_cmp);
    let mut all: Vec<f64> = o.latencies_us.concat();
    all.sort_by(f64::total_cmp);
    let [p0, p1] = &o.latencies_us;
    let settled = if o.settled_us.is_empty() {
        "-".to_string()
    } else {
        format!(
            "{}/{}",
            us(percentile(&o.settled_us, 0.5)),
            us(percentile(&o.settled_us, 0.9))
        )
    };
    let label = if bridge {
        format!("{} {}", case.name(), case.scenario.name())
    } else {
        format!("{} {} {}", case.name(), case.scenario.name(), peer.name())
    };
    let on_wire_percent = o.on_wire as f64 * 100.0 / o.sent.max(1) as f64;
    println!(
        "{:<16} {:>4} {:>5} {:>6.1}% {:>5} {:>4} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>7} {:>6.1}% {:>7.1} {:>6.1} {:>6} {:>6} {:>6} {:>16} {:>9} {:>11} {:>6}",
        label,
        case.hogs,
        o.sent,
        on_wire_percent,
        o.superseded,
        o.lost,
        us(percentile(p0, 0.5)),
        us(percentile(p0, 0.9)),
        us(percentile(p0, 0.99)),
        us(p0.last().copied().unwrap_or(f64::NAN)),
        us(percentile(p1, 0.5)),
        us(percentile(&all, 0.99)),
        settled,
        o.behind as f64 * 100.0 / o.sent.max(1) as f64,
        o.polls_hz,
        o.servo1_ok_hz,
        if bridge {
            format!("{:.1}", o.telemetry_hz)
        } else {
            na()
        },
        o.cpu_percent
            .map_or("n/m".to_string(), |c| format!("{c:.2}")),
        o.peak_rss_kib
            .map_or("n/m".to_string(), |r| format!("{:.1}", r as f64 / 1024.0)),
        match o.threads {
            _ if !bridge => na(),
            Some(t) => format!("{:.2}/{:.2}/{:.2}", t[0].0, t[1].0, t[2].0),
            None => "n/m".to_string(),
        },
        match o.threads {
            _ if !bridge => na(),
            Some(t) => format!("{:.0}/{:.0}", t[0].1, t[1].1),
            None => "n/m".to_string(),
        },
        if o.collisions_sim_starved > 0 {
            format!("{} ({} sim)", o.collisions, o.collisions_sim_starved)
        } else {
            o.collisions.to_string()
        },
        if bridge {
            o.alarms.len().to_string()
        } else {
            na()
        },
    );
    for l in &mut o.unstalled_us {
        l.sort_by(f64::total_cmp);
    }
    let mut all_unstalled: Vec<f64> = o.unstalled_us.concat();
    all_unstalled.sort_by(f64::total_cmp);
    o.port1_lag_us.sort_by(f64::total_cmp);
    println!(
        "    machine stalls {} (max {} µs, steal {} ms/s); idle spells {}; beside no stall: p0 p99 {}, all p99 {} µs{}",
        o.stalls,
        us(o.stall_max_us),
        o.steal_ms_per_s
            .map_or("n/m".to_string(), |s| format!("{s:.1}")),
        o.idle_spells.map_or(
            "n/a (reads bunched after each tick)".to_string(),
            |(n, u)| { format!("{n} ({u} beside no stall)") }
        ),
        us(percentile(&o.unstalled_us[0], 0.99)),
        us(percentile(&all_unstalled, 0.99)),
        if o.both_port_ticks > 0 {
            format!(
                "; one packet in {:.1}% of {} two-port ticks ({} more sent >0.5 ms apart), port 1 behind port 0 p50/p99 {}/{} µs",
                o.one_packet_ticks as f64 * 100.0 / o.both_port_ticks as f64,
                o.both_port_ticks,
                o.split_sends,
                us(percentile(&o.port1_lag_us, 0.5)),
                us(percentile(&o.port1_lag_us, 0.99)),
            )
        } else {
            String::new()
        },
    );
    if let Some(w) = &o.watchdog {
        watchdog_line(w);
    }
    for a in &o.alarms {
        println!("    alarm heard: {a}");
    }
    Figures {
        p0_p50: percentile(p0, 0.5),
        p1_p50: percentile(p1, 0.5),
        all_p50: percentile(&all, 0.5),
        all_p99: percentile(&all, 0.99),
        on_wire_percent,
        cpu_percent: o.cpu_percent,
    }
}

/// The bridge's third line: the watchdog's pings as the bench, in systemd's place, heard them.
fn watchdog_line(w: &Pings) {
    let ms = |v: f64| {
        if v.is_nan() {
            "-".to_string()
        } else {
            format!("{v:.1}")
        }
    };
    let period = w.period;
    println!(
        "    watchdog {} ms (pinged every {} ms): {} pings{}; gaps from READY on: p50 {}, longest {} ms (READY to the first ping {} ms); {} of {} gaps over 1.5 periods ({} ms){}{}",
        w.timeout.as_millis(),
        period.as_millis(),
        w.pings,
        if w.ready { "" } else { ", no READY=1" },
        ms(w.gap_p50_ms),
        ms(w.gap_max_ms),
        ms(w.first_ms),
        w.over_1_5,
        w.gaps,
        (period * 3 / 2).as_millis(),
        if w.stuck.is_empty() {
            String::new()
        } else {
            format!(
                "; the bridge named a stuck bus thread {} times",
                w.stuck.len()
            )
        },
        if w.announced.is_some() {
            ""
        } else {
            "; NOT announced: no \"systemd watchdog: …\" line in the bridge's log"
        },
    );
    if !w.late.is_empty() {
        let listed: Vec<String> = w
            .late
            .iter()
            .take(8)
            .map(|(ms, after, mono)| format!("{ms:.1} ms ending +{after:.1} s (mono {mono:.3})"))
            .collect();
        println!(
            "    late pings (gap over {} ms): {}{}",
            (period + super::watchdog::LATE).as_millis(),
            listed.join(", "),
            if w.late.len() > 8 { ", …" } else { "" }
        );
    }
    for line in &w.stuck {
        println!("    bridge: {line}");
    }
}

/// The time of day, UTC, to line the runs up with what else the machine ran.
pub(super) fn clock_time() -> String {
    let s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("{:02}:{:02}:{:02}", s / 3600 % 24, s / 60 % 60, s % 60)
}

/// Where a case ran with the bridge and another peer: their figures side by side, with the
/// ratio peer/bridge (above 1: the peer's is higher), headed by the case, quiet or beside how
/// many hogs, and `when` the two runs took place.
pub(super) fn compare(case: &Case, runs: &[(&Peer, Figures)], when: &str) {
    let Some((_, bridge)) = runs.iter().find(|(p, _)| matches!(p, Peer::Bridge)) else {
        return;
    };
    // In `steps`, `gap` and `rate` every measured message is a step after the outputs held.
    let p0_label = if case.scenario.step_every().is_some() {
        "step after hold p50 (port 0)"
    } else {
        "port 0 p50"
    };
    for (peer, other) in runs.iter().filter(|(p, _)| !matches!(p, Peer::Bridge)) {
        let name = peer.name();
        println!(
            "    {} {}, {}, {when} UTC:",
            case.name(),
            case.scenario.name(),
            match case.hogs {
                0 => "quiet".to_string(),
                n => format!("beside {n} hogs"),
            }
        );
        println!(
            "    {:<30} {:>9} {:>9} {:>12}",
            "",
            "bridge",
            name,
            format!("{name}/bridge")
        );
        let ratio = |b: f64, o: f64| {
            if b.is_nan() || o.is_nan() || b == 0.0 {
                "-".to_string()
            } else {
                format!("{:.2}", o / b)
            }
        };
        let latency = |label: &str, b: f64, o: f64| {
            println!(
                "    {:<30} {:>9} {:>9} {:>12}",
                format!("{label}, µs"),
                us(b),
                us(o),
                ratio(b, o)
            );
        };
        latency(p0_label, bridge.p0_p50, other.p0_p50);
        latency("port 1's goals p50", bridge.p1_p50, other.p1_p50);
        latency("all goals p50", bridge.all_p50, other.all_p50);
        latency("all goals p99", bridge.all_p99, other.all_p99);
        println!(
            "    {:<30} {:>8.1}% {:>8.1}% {:>12}",
            "goals on the wire",
            bridge.on_wire_percent,
            other.on_wire_percent,
            ratio(bridge.on_wire_percent, other.on_wire_percent)
        );
        let cpu = |c: Option<f64>| c.map_or("n/m".to_string(), |c| format!("{c:.2}"));
        println!(
            "    {:<30} {:>9} {:>9} {:>12}",
            "CPU, whole process, %",
            cpu(bridge.cpu_percent),
            cpu(other.cpu_percent),
            bridge
                .cpu_percent
                .zip(other.cpu_percent)
                .map_or("-".to_string(), |(b, o)| ratio(b, o))
        );
    }
}
