//! The Python with pymavlink (from PyPI) that the tests run as a third-party autopilot or
//! ground station: `$LJ9DA_PYTHON` if set, else a virtual environment under the target directory,
//! made with `pip install` of [`PYMAVLINK`] and the packages it needs, [`PYMAVLINK_NEEDS`]
//! (all pinned: the tests read what its parser decodes, and a new release of a package it
//! needs must not change a run) by whichever test asks first.
//!
//! Tests of one binary run on threads and the binaries of a workspace may run side by side, so
//! the environment is made under an exclusive `flock` on a file beside it, and is used only once
//! a marker written after a successful install exists. A half-made environment (a run killed
//! during `pip install`) has no marker and is made again from scratch.

use std::fs::{self, File};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use nix::fcntl::{Flock, FlockArg};

/// The pymavlink the tests install. A new pin makes a new environment (the ready marker
/// names it).
pub const PYMAVLINK: &str = "pymavlink==2.4.50";

/// What pymavlink 2.4.50 needs (its `Requires`), at the versions pip chose for it: pinned too,
/// so that pip installs the same packages whenever the environment is made. A new pin here
/// also makes a new environment.
pub const PYMAVLINK_NEEDS: [&str; 2] = ["fastcrc==0.5.0", "lxml==6.1.3"];

pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("LJ9DA_PYTHON") {
        return PathBuf::from(p);
    }
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    MADE.get_or_init(|| make_venv(&PathBuf::from(env!("CARGO_TARGET_TMPDIR"))))
        .clone()
}

fn make_venv(dir: &Path) -> PathBuf {
    let venv = dir.join("pymavlink-venv");
    let python = venv.join("bin/python");
    let pins = format!("{PYMAVLINK},{}", PYMAVLINK_NEEDS.join(","));
    let marker = venv.join(format!("lj9da-ready-{pins}"));
    fs::create_dir_all(dir).expect("create the target's tmp directory");
    let lock = File::create(dir.join("pymavlink-venv.lock")).expect("create the venv lock file");
    // Held until the end of this function: a second process waits here and then finds the marker.
    let _lock = Flock::lock(lock, FlockArg::LockExclusive)
        .map_err(|(_, e)| e)
        .expect("lock the venv lock file");
    if marker.exists() {
        return python;
    }
    if venv.exists() {
        fs::remove_dir_all(&venv).expect("remove a half-made virtual environment");
    }
    let made = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&venv)
        .status();
    assert!(
        made.is_ok_and(|s| s.success()),
        "`python3 -m venv {}` failed: install Python 3 with venv (python3-venv on Debian/Ubuntu)",
        venv.display()
    );
    let pip = Command::new(venv.join("bin/pip"))
        .args([
            "install",
            "--quiet",
            "--disable-pip-version-check",
            PYMAVLINK,
        ])
        .args(PYMAVLINK_NEEDS)
        .status();
    assert!(
        pip.is_ok_and(|s| s.success()),
        "`pip install {PYMAVLINK} {}` into {} failed (it needs PyPI)",
        PYMAVLINK_NEEDS.join(" "),
        venv.display()
    );
    let works = Command::new(&python)
        .args(["-c", "import pymavlink.mavutil"])
        .status();
    assert!(
        works.is_ok_and(|s| s.success()),
        "pymavlink was installed into {} but does not import",
        venv.display()
    );
    fs::write(&marker, format!("{pins} installed\n")).expect("write the venv's ready marker");
    python
}
