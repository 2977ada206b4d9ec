//! The Pythons the tests run third-party programs in, each a virtual environment under the
//! target directory made with `pip install` of pinned packages by whichever test asks first
//! (all pinned: the tests read what those programs decode, and a new release of a package
//! they need must not change a run):
//! - [`python`]: pymavlink, [`PYMAVLINK`] and what it needs ([`PYMAVLINK_NEEDS`]), as a
//!   third-party autopilot or ground station; `$LJ9DA_PYTHON` if set;
//! - [`data_python`]: the field's flight-data readers, [`DATA_PACKAGES`]: pyulog (PX4's ULog
//!   reader), DuckDB and pyarrow;
//! - [`dronecan_python`]: the `dronecan` package ([`DRONECAN`]), DroneCAN's reference Python
//!   implementation, as a third-party node;
//! - [`spark_python`]: PySpark, for the fleet bench only.
//!
//! Tests of one binary run on threads and the binaries of a workspace may run side by side, so
//! an environment is made under an exclusive `flock` on a file beside it, and is used only once
//! a marker written after a successful install exists. A half-made environment (a run killed
//! during `pip install`) has no marker and is made again from scratch.

use std::fs::{self, File};
use std::path::PathBuf;
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

/// The flight-data readers of [`data_python`], with what they need, at the versions pip chose
/// for them. A new pin makes a new environment.
pub const DATA_PACKAGES: [&str; 4] = [
    "pyulog==1.3.0",
    "numpy==2.4.6",
    "duckdb==2.0.1",
    "pyarrow==26.0.1",
];

/// The DroneCAN implementation the tests install (pure Python, nothing else needed).
pub const DRONECAN: &str = "dronecan==1.0.27";

/// Spark for the fleet bench, with what it needs: Java comes from Debian
/// (`openjdk-17-jre-headless`).
pub const SPARK_PACKAGES: [&str; 2] = ["pyspark==4.3.0", "py4j==0.10.9.9"];

/// The Python with pymavlink: `$LJ9DA_PYTHON` if set, else its environment, made on first use.
#[allow(dead_code)] // each test binary uses one Python or the other
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("LJ9DA_PYTHON") {
        return PathBuf::from(p);
    }
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    MADE.get_or_init(|| {
        let packages = [&[PYMAVLINK][..], &PYMAVLINK_NEEDS[..]].concat();
        make_venv("pymavlink-venv", &packages, "import pymavlink.mavutil")
    })
    .clone()
}

/// The Python with pyulog, DuckDB and pyarrow ([`DATA_PACKAGES`]), made on first use.
#[allow(dead_code)] // each test binary uses one Python or the other
pub fn data_python() -> PathBuf {
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    MADE.get_or_init(|| {
        make_venv(
            "data-venv",
            &DATA_PACKAGES,
            "import pyulog, duckdb, pyarrow.parquet",
        )
    })
    .clone()
}

/// The Python with `dronecan` ([`DRONECAN`]), made on first use.
#[allow(dead_code)]
pub fn dronecan_python() -> PathBuf {
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    MADE.get_or_init(|| make_venv("dronecan-venv", &[DRONECAN], "import dronecan"))
        .clone()
}

/// The Python with PySpark ([`SPARK_PACKAGES`]), made on first use: the fleet bench's, not
/// the tests' (a 450 MB download).
#[allow(dead_code)]
pub fn spark_python() -> PathBuf {
    static MADE: OnceLock<PathBuf> = OnceLock::new();
    MADE.get_or_init(|| make_venv("spark-venv", &SPARK_PACKAGES, "import pyspark.sql"))
        .clone()
}

/// The environment `name` under the target's tmp directory with `packages` installed, checked
/// by running `check`; its Python.
fn make_venv(name: &str, packages: &[&str], check: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let venv = dir.join(name);
    let python = venv.join("bin/python");
    let pins = packages.join(",");
    let marker = venv.join(format!("lj9da-ready-{pins}"));
    fs::create_dir_all(&dir).expect("create the target's tmp directory");
    let lock = File::create(dir.join(format!("{name}.lock"))).expect("create the venv lock file");
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
        .args(["install", "--quiet", "--disable-pip-version-check"])
        .args(packages)
        .status();
    assert!(
        pip.is_ok_and(|s| s.success()),
        "`pip install {}` into {} failed (it needs PyPI)",
        packages.join(" "),
        venv.display()
    );
    let works = Command::new(&python).args(["-c", check]).status();
    assert!(
        works.is_ok_and(|s| s.success()),
        "{} were installed into {} but `{check}` fails",
        packages.join(" "),
        venv.display()
    );
    fs::write(&marker, format!("{pins} installed\n")).expect("write the venv's ready marker");
    python
}
