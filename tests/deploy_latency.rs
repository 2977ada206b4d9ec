//! The start-up check of USB RS485 adapters' latency timer, against a fake sysfs tree.

mod tempdir;

use lj9da_bridge::deploy::{
    LatencyCheck, LatencyFixer, LoweredBy, ReportOnly, check_latency, check_latency_in,
    check_latency_with,
};
use std::io;
use std::path::{Path, PathBuf};
use tempdir::TempDir;

/// A fake `/sys` and `/dev`: `ttyUSB0` is an FTDI adapter with `latency` in its
/// `latency_timer`, reached through a `/dev/serial/by-id` symlink.
struct Fake {
    dir: TempDir,
}

impl Fake {
    fn new(latency: &str) -> Self {
        let dir = TempDir::new("sysfs");
        let device = dir.path().join("sys/bus/usb-serial/devices/ttyUSB0");
        std::fs::create_dir_all(&device).unwrap();
        std::fs::write(device.join("latency_timer"), latency).unwrap();
        let dev = dir.path().join("dev");
        std::fs::create_dir_all(dev.join("serial/by-id")).unwrap();
        std::fs::write(dev.join("ttyUSB0"), b"").unwrap();
        std::os::unix::fs::symlink(
            "../../ttyUSB0",
            dev.join("serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0"),
        )
        .unwrap();
        Fake { dir }
    }
    fn sysfs(&self) -> PathBuf {
        self.dir.path().join("sys")
    }
    fn by_id(&self) -> PathBuf {
        self.dir
            .path()
            .join("dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0")
    }
    fn latency_file(&self) -> PathBuf {
        self.sysfs()
            .join("bus/usb-serial/devices/ttyUSB0/latency_timer")
    }
    fn latency(&self) -> String {
        std::fs::read_to_string(self.latency_file()).unwrap()
    }
}

#[test]
fn a_16_ms_timer_is_lowered_to_1_ms_when_sysfs_is_writable() {
    let fake = Fake::new("16\n");
    let check = check_latency_in(&fake.sysfs(), &fake.by_id());
    assert_eq!(
        check,
        LatencyCheck::Lowered {
            tty: "ttyUSB0".into(),
            from: 16,
            by: LoweredBy::Sysfs
        }
    );
    assert_eq!(fake.latency().trim(), "1");
    assert!(!check.needs_attention());
    assert!(check.to_string().contains("lj9da-bridge deploy udev"));
    // Checked again, it is fine.
    assert_eq!(
        check_latency_in(&fake.sysfs(), &fake.by_id()),
        LatencyCheck::Ok {
            tty: "ttyUSB0".into(),
            ms: 1
        }
    );
}

#[test]
fn a_timer_that_cannot_be_lowered_warns_with_the_exact_fix() {
    let fake = Fake::new("16\n");
    let check = check_latency_with(&fake.sysfs(), &fake.by_id(), &ReportOnly);
    let LatencyCheck::High {
        tty,
        ms,
        fix,
        tried,
    } = &check
    else {
        panic!("expected High, got {check:?}");
    };
    assert_eq!((tty.as_str(), *ms), ("ttyUSB0", 16));
    // The whole advice, spelled out here rather than rebuilt with `latency_fix` (which would
    // compare the function with itself): the tty, the rule's path and the turnaround of a
    // 16 ms timer (16 + 4 ms) are all in it.
    assert_eq!(
        fix,
        "replies reach the bridge up to 16 ms late, which ruins half-duplex turnaround. Fix it now:\n  \
         echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer\n\
         and for good, with the udev rule:\n  \
         lj9da-bridge deploy udev | sudo tee /etc/udev/rules.d/99-lj9da-bridge.rules\n  \
         sudo udevadm control --reload-rules && sudo udevadm trigger --action=add --subsystem-match=usb-serial\n\
         (or live with it: turnaround_ms = 20 in this bus's [[bus]] table, at the cost of a slower bus)"
    );
    assert!(
        fix.contains("\n  echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer\n")
    );
    assert!(
        fix.contains("lj9da-bridge deploy udev | sudo tee /etc/udev/rules.d/99-lj9da-bridge.rules")
    );
    assert!(fix.contains(
        "sudo udevadm control --reload-rules && sudo udevadm trigger --action=add --subsystem-match=usb-serial"
    ));
    assert!(fix.contains("turnaround_ms = 20"));
    assert_eq!(tried.len(), 2, "{tried:?}");
    assert!(check.needs_attention());
    assert!(
        check
            .to_string()
            .starts_with("ttyUSB0: latency timer 16 ms: replies reach")
    );
    assert_eq!(fake.latency(), "16\n", "nothing was changed");
}

/// A driver that takes the writes but keeps its timer (or a fixer that only has the flag).
struct Stubborn {
    flag_works_on: Option<PathBuf>,
}

impl LatencyFixer for Stubborn {
    fn write_latency(&self, _file: &Path, _ms: u32) -> io::Result<()> {
        Ok(())
    }
    fn set_low_latency(&self, _port: &Path) -> io::Result<()> {
        match &self.flag_works_on {
            Some(file) => std::fs::write(file, "1\n"),
            None => Err(io::Error::from_raw_os_error(25)), // ENOTTY
        }
    }
}

#[test]
fn a_write_that_does_not_take_is_not_reported_as_lowered() {
    let fake = Fake::new("16\n");
    let check = check_latency_with(
        &fake.sysfs(),
        &fake.by_id(),
        &Stubborn {
            flag_works_on: None,
        },
    );
    match check {
        LatencyCheck::High { tried, .. } => {
            assert!(tried[0].contains("still reads 16 ms"), "{tried:?}");
        }
        other => panic!("expected High, got {other:?}"),
    }
}

#[test]
fn the_low_latency_flag_is_tried_when_sysfs_is_not_writable() {
    let fake = Fake::new("16\n");
    let check = check_latency_with(
        &fake.sysfs(),
        &fake.by_id(),
        &Stubborn {
            flag_works_on: Some(fake.latency_file()),
        },
    );
    assert_eq!(
        check,
        LatencyCheck::Lowered {
            tty: "ttyUSB0".into(),
            from: 16,
            by: LoweredBy::LowLatencyFlag
        }
    );
}

#[test]
fn the_class_tty_path_is_found_too() {
    let dir = TempDir::new("classtty");
    let sys = dir.path().join("sys");
    std::fs::create_dir_all(sys.join("class/tty/ttyUSB3/device")).unwrap();
    std::fs::write(sys.join("class/tty/ttyUSB3/device/latency_timer"), "2").unwrap();
    let check = check_latency_with(&sys, Path::new("/dev/ttyUSB3"), &ReportOnly);
    assert!(
        matches!(&check, LatencyCheck::High { tty, ms: 2, .. } if tty == "ttyUSB3"),
        "{check:?}"
    );
}

#[test]
fn adapters_without_a_latency_timer_and_other_ports_are_left_alone() {
    let dir = TempDir::new("cp210x");
    let sys = dir.path().join("sys");
    let device = sys.join("bus/usb-serial/devices/ttyUSB1");
    std::fs::create_dir_all(&device).unwrap();
    std::fs::create_dir_all(sys.join("bus/usb-serial/drivers/cp210x")).unwrap();
    std::os::unix::fs::symlink("../../drivers/cp210x", device.join("driver")).unwrap();
    assert_eq!(
        check_latency_in(&sys, Path::new("/dev/ttyUSB1")),
        LatencyCheck::NoLatencyTimer {
            tty: "ttyUSB1".into(),
            driver: Some("cp210x".into())
        }
    );
    for port in ["/dev/ttyS0", "/dev/ttyACM0", "/dev/ttyAMA0"] {
        assert_eq!(
            check_latency_in(&sys, Path::new(port)),
            LatencyCheck::NotUsbSerial { port: port.into() }
        );
    }
}

#[test]
fn a_pseudo_terminal_is_not_a_usb_serial_adapter() {
    let sim = lj9da_sim::SimBus::spawn_pty(lj9da_sim::SimConfig::default()).unwrap();
    let pty = sim.path();
    assert!(pty.starts_with("/dev/pts"), "{}", pty.display());
    let fake = Fake::new("16\n");
    assert_eq!(
        check_latency_in(&fake.sysfs(), &pty),
        LatencyCheck::NotUsbSerial { port: pty.clone() }
    );
    // And with the real /sys of this machine.
    let real = check_latency(&pty);
    assert!(
        matches!(real, LatencyCheck::NotUsbSerial { .. }),
        "{real:?}"
    );
    sim.shutdown();
}

#[test]
fn an_unreadable_timer_is_reported() {
    let fake = Fake::new("sixteen");
    let check = check_latency_in(&fake.sysfs(), &fake.by_id());
    assert!(
        matches!(&check, LatencyCheck::Unreadable { reason, .. } if reason.contains("\"sixteen\" is not a number")),
        "{check:?}"
    );
    assert!(check.needs_attention());
}
