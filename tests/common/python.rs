//! The Python with pymavlink (from PyPI) that the tests run as a third-party autopilot or
//! ground station: `$LJ9DA_PYTHON` if set (`.ci/run` sets it), else a virtual environment made
//! once under the target directory with `pip install pymavlink`.

use std::path::PathBuf;
use std::process::Command;

pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("LJ9DA_PYTHON") {
        return PathBuf::from(p);
    }
    let venv = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("pymavlink-venv");
    let python = venv.join("bin/python");
    let ready = python.exists()
        && Command::new(&python)
            .args(["-c", "import pymavlink"])
            .status()
            .is_ok_and(|s| s.success());
    if !ready {
        let made = Command::new("python3")
            .args(["-m", "venv"])
            .arg(&venv)
            .status();
        assert!(
            made.is_ok_and(|s| s.success()),
            "python3 -m venv failed: install Python 3 with venv"
        );
        let pip = Command::new(venv.join("bin/pip"))
            .args(["install", "--quiet", "pymavlink"])
            .status();
        assert!(
            pip.is_ok_and(|s| s.success()),
            "pip install pymavlink failed (needs PyPI)"
        );
    }
    python
}
