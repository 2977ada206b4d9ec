//! `sitl` on a terminal shows a live view that redraws in place: run under a pseudo-terminal,
//! it takes the alternate screen, rewrites cells there by moving the cursor (no line feeds,
//! so no growing scroll-back), quits on `q`, and gives the terminal back.

mod common;
mod tempdir;

use common::sitl::sitl_records;
use nix::pty::{Winsize, openpty};
use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tempdir::TempDir;

const ENTER_ALTERNATE_SCREEN: &str = "\x1b[?1049h";
const LEAVE_ALTERNATE_SCREEN: &str = "\x1b[?1049l";
/// What ends every frame drawn: the cursor hidden again.
const FRAME_END: &str = "\x1b[?25l";

/// Cursor moves to a row and column (`ESC [ row ; col H`) in `s`, with where each ends.
fn cursor_moves(s: &str) -> Vec<usize> {
    let b = s.as_bytes();
    let mut ends = Vec::new();
    let mut i = 0;
    while let Some(at) = s[i..].find("\x1b[").map(|p| p + i) {
        let mut j = at + 2;
        while j < b.len() && (b[j].is_ascii_digit() || b[j] == b';') {
            j += 1;
        }
        if j < b.len() && b[j] == b'H' && s[at + 2..j].contains(';') {
            ends.push(j + 1);
        }
        i = at + 2;
    }
    ends
}

#[test]
fn sitl_on_a_terminal_redraws_its_view_in_place_and_quits_on_q() {
    let size = Winsize {
        ws_row: 32,
        ws_col: 160,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    let pty = openpty(Some(&size), None).expect("a pseudo-terminal");
    let dir = TempDir::new("live-view");
    let mut child = {
        let slave = pty.slave;
        Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args(["sitl", "--seconds", "3600"])
            .current_dir(dir.path())
            .stdin(Stdio::from(slave.try_clone().unwrap()))
            .stdout(Stdio::from(slave.try_clone().unwrap()))
            .stderr(Stdio::from(slave))
            .spawn()
            .expect("lj9da-bridge sitl starts")
    };
    // Read the terminal's output until the program has closed it.
    let mut keyboard = std::fs::File::from(pty.master.try_clone().unwrap());
    let mut master = std::fs::File::from(pty.master);
    let (tx, rx) = std::sync::mpsc::channel::<Vec<u8>>();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        loop {
            match master.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    if tx.send(buf[..n].to_vec()).is_err() {
                        break;
                    }
                }
            }
        }
    });
    // Safety nets for a run that hangs or never draws a frame (the plain table, say: it would
    // run its hour), not bounds on how long a run takes: a frame comes every 200 ms. The run
    // is long, so that only `q` ends it within the test; `q` must end it within QUIT_WITHIN.
    const QUIT_WITHIN: Duration = Duration::from_secs(10);
    let started = Instant::now();
    let give_up = started + Duration::from_secs(300);
    let no_frame_by = started + Duration::from_secs(60);
    let mut out = Vec::new();
    let mut quit_at = None;
    loop {
        let wait =
            Duration::from_millis(500).min(give_up.saturating_duration_since(Instant::now()));
        match rx.recv_timeout(wait) {
            Ok(chunk) => out.extend_from_slice(&chunk),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) if Instant::now() < give_up => {}
            Err(_) => break,
        }
        // Once a few frames have been drawn (each ends by hiding the cursor), press `q`.
        let frames = String::from_utf8_lossy(&out).matches(FRAME_END).count();
        if quit_at.is_none() && frames >= 5 {
            keyboard.write_all(b"q").unwrap();
            quit_at = Some(Instant::now());
        }
        if let Some(at) = quit_at
            && at.elapsed() > QUIT_WITHIN
        {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "q did not quit in {QUIT_WITHIN:?}; the terminal got:\n{}",
                String::from_utf8_lossy(&out)
            );
        }
        if quit_at.is_none() && Instant::now() >= no_frame_by {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "{frames} live-view frames in 60 s; the terminal got:\n{}",
                String::from_utf8_lossy(&out)
            );
        }
    }
    let status = child.wait().unwrap();
    quit_at.expect("five frames drawn");
    let out = String::from_utf8_lossy(&out).into_owned();
    assert!(status.success(), "{status:?}\n{out}");

    let enter = out
        .find(ENTER_ALTERNATE_SCREEN)
        .expect("the view takes the alternate screen");
    let leave = out
        .rfind(LEAVE_ALTERNATE_SCREEN)
        .expect("and gives it back at the end");
    assert!(enter < leave);
    let live = &out[enter..leave];
    assert!(
        !live.contains('\n'),
        "no line feed while the view is up: nothing scrolls"
    );
    // Words are written one by one (the cursor skips the blanks between them).
    for shown in ["aileron_left", "rudder", "servos", "buses", "quit"] {
        assert!(live.contains(shown), "{shown} not shown:\n{live:?}");
    }
    // The first full frame ends with the help line; later frames rewrite what changed
    // (positions, currents, the bus's rates) in place, by moving the cursor.
    let first_frame_end = live.find("quit").unwrap();
    let redraws = cursor_moves(live)
        .into_iter()
        .filter(|&end| end > first_frame_end)
        .count();
    assert!(redraws > 0, "the screen was never redrawn:\n{live:?}");
    // The final table is printed after the terminal is given back.
    assert!(out[leave..].contains("aileron_left"));
}

/// `sitl --config` with a mapping that names no record folder records into the current
/// folder's `records/`, not beside the mapping (which, for the examples, is the repository).
#[test]
fn sitl_with_a_mapping_records_into_the_current_folder_not_beside_the_mapping() {
    let dir = TempDir::new("sitl-records");
    let mappings = dir.path().join("mappings");
    let work = dir.path().join("work");
    std::fs::create_dir_all(&mappings).unwrap();
    std::fs::create_dir_all(&work).unwrap();
    let mapping = mappings.join("px4-vtol.toml");
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/mappings/px4-vtol.toml"),
        &mapping,
    )
    .unwrap();
    let records = sitl_records(&work, "2", &["--config", mapping.to_str().unwrap()]);
    assert!(!records.is_empty(), "no record file in work/records");
    assert!(
        !mappings.join("records").exists(),
        "sitl wrote records beside the mapping file"
    );
}

/// `--seconds` that is no duration (negative, not a number, beyond what a clock holds, zero) is
/// refused by name with the reason, as any bad argument: exit 2, nothing started.
#[test]
fn sitl_refuses_seconds_that_are_no_duration() {
    for bad in ["-1", "nan", "inf", "1e20", "0", "ten"] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
            .args(["sitl", "--plain", &format!("--seconds={bad}")])
            .output()
            .expect("the binary runs");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "--seconds={bad}: {stderr}");
        assert!(
            stderr.contains("--seconds") && stderr.contains("seconds, e.g. 20")
                || stderr.contains("is not a number of seconds"),
            "--seconds={bad}: {stderr}"
        );
    }
}
