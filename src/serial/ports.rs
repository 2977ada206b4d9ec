//! `lj9da-bridge ports`: the serial ports of this computer and what each one is, so that the
//! right one goes into a mapping file without reading `dmesg`.
//!
//! Everything comes from sysfs and `/dev` (both roots are parameters, so the tests build a fake
//! tree): a port is a `tty` of a serial kind (`ttyUSB*`, `ttyACM*`, `ttyAMA*`, `ttySC*`,
//! `ttyTHS*`, `ttyS*`) whose `/sys/class/tty/<name>/device` exists (a real device behind it,
//! not a virtual console or a pseudo-terminal). An 8250-style `ttyS*` is also skipped when its
//! `type` reads 0 (`PORT_UNKNOWN`): the driver reserves such lines (`ttyS1` … `ttyS31` on a
//! PC) but found no UART there. For each port: its stable names (`/dev/serial/by-id/…`,
//! `/dev/serial/by-path/…`, and aliases such as the Raspberry Pi's `/dev/serial0`), its
//! driver, the USB device it belongs to (vendor and product IDs, manufacturer, product, serial
//! number), an FTDI-style latency timer (read with [`crate::serial::latency::check_latency_with`],
//! never changed here), whether this user may open it (`access(2)`: nothing is opened, so no
//! adapter sees its modem lines move), and which processes have it open (`/proc/<pid>/fd`, as
//! far as this user may look: all of them for root).

use crate::serial::latency::{LatencyCheck, ReportOnly, check_latency_with};
use serde::Serialize;
use std::fs;
use std::path::{Path, PathBuf};

/// The tty names listed, by prefix (each followed by a number).
pub const KINDS: [&str; 6] = ["ttyUSB", "ttyACM", "ttyAMA", "ttySC", "ttyTHS", "ttyS"];

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct PortInfo {
    /// `/dev/ttyUSB0`.
    pub device: PathBuf,
    /// Names under `/dev/serial/by-id/` that point at it (USB adapters: they keep their name
    /// whatever the order they were plugged in).
    pub by_id: Vec<PathBuf>,
    /// Names under `/dev/serial/by-path/` (the USB socket or bus it is on).
    pub by_path: Vec<PathBuf>,
    /// Other names in `/dev` that point at it (`/dev/serial0` on a Raspberry Pi).
    pub aliases: Vec<PathBuf>,
    /// The kernel driver (`ftdi_sio`, `cp210x`, `cdc_acm`, `uart-pl011`, `serial`, …).
    pub driver: Option<String>,
    /// The USB device, for a USB adapter.
    pub usb: Option<UsbInfo>,
    /// The latency timer in ms, for an adapter that has one (FTDI).
    pub latency_timer_ms: Option<u32>,
    /// Whether this user may read and write the device (`false`: add the user to the group
    /// that owns it, usually `dialout`).
    pub accessible: bool,
    /// Processes that have it open, among those this user may look into (all, for root).
    pub open_by: Vec<Opener>,
}

/// A process that has a port open.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Opener {
    pub pid: u32,
    /// Its command name (`/proc/<pid>/comm`).
    pub command: String,
}

/// What a USB device says it is.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct UsbInfo {
    /// `0403`.
    pub vendor_id: String,
    /// `6001`.
    pub product_id: String,
    pub manufacturer: Option<String>,
    pub product: Option<String>,
    pub serial: Option<String>,
}

/// The serial ports under `sysfs` (`/sys`) and `dev` (`/dev`), in name order, without looking
/// for processes that have them open.
pub fn list(sysfs: &Path, dev: &Path) -> Vec<PortInfo> {
    list_ports(sysfs, dev, None)
}

/// [`list`], with the processes under `proc` (`/proc`) that have each port open.
pub fn list_in(sysfs: &Path, dev: &Path, proc: &Path) -> Vec<PortInfo> {
    list_ports(sysfs, dev, Some(proc))
}

fn list_ports(sysfs: &Path, dev: &Path, proc: Option<&Path>) -> Vec<PortInfo> {
    let class = sysfs.join("class/tty");
    let mut names: Vec<String> = fs::read_dir(&class)
        .map(|entries| {
            entries
                .filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|name| is_serial_name(name))
                .collect()
        })
        .unwrap_or_default();
    names.sort_by_key(|a| natural_key(a));
    let links = Links::read(dev);
    let open_files = proc.map(open_files).unwrap_or_default();
    names
        .into_iter()
        .filter(|name| has_hardware(&class.join(name), name))
        .map(|name| {
            let mut port = describe(sysfs, dev, &class.join(&name), &name, &links);
            if let Ok(device) = fs::canonicalize(&port.device) {
                port.open_by = open_files
                    .iter()
                    .filter(|(file, _)| *file == device)
                    .map(|(_, opener)| opener.clone())
                    .collect();
                port.open_by.dedup();
            }
            port
        })
        .collect()
}

/// Every file that a process under `proc` has open (`/proc/<pid>/fd/*`), with the process;
/// processes this user may not look into are skipped, and so is this one.
fn open_files(proc: &Path) -> Vec<(PathBuf, Opener)> {
    let me = std::process::id();
    let Ok(entries) = fs::read_dir(proc) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for entry in entries.filter_map(Result::ok) {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == me {
            continue;
        }
        let Ok(fds) = fs::read_dir(entry.path().join("fd")) else {
            continue;
        };
        let command = read_trimmed(&entry.path().join("comm")).unwrap_or_default();
        for fd in fds.filter_map(Result::ok) {
            if let Ok(target) = fs::read_link(fd.path())
                && target.is_absolute()
            {
                out.push((
                    target,
                    Opener {
                        pid,
                        command: command.clone(),
                    },
                ));
            }
        }
    }
    out.sort_by_key(|(_, o)| o.pid);
    out
}

/// `ttyUSB0`, `ttyS12`, … but not `ttySC` alone, `tty0` or `ttyprintk`.
fn is_serial_name(name: &str) -> bool {
    KINDS.iter().any(|kind| {
        name.strip_prefix(kind)
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    })
}

/// `ttyUSB10` after `ttyUSB9`.
fn natural_key(name: &str) -> (String, u64) {
    let digits = name.trim_start_matches(|c: char| !c.is_ascii_digit());
    let prefix = &name[..name.len() - digits.len()];
    (prefix.to_string(), digits.parse().unwrap_or(0))
}

/// A device behind the tty; for an 8250 `ttyS*`, a UART found there (`type` not 0).
fn has_hardware(tty: &Path, name: &str) -> bool {
    if !tty.join("device").exists() {
        return false;
    }
    let is_8250 = name
        .strip_prefix("ttyS")
        .is_some_and(|n| n.bytes().all(|b| b.is_ascii_digit()));
    !(is_8250 && read_trimmed(&tty.join("type")).is_some_and(|t| t == "0"))
}

fn read_trimmed(file: &Path) -> Option<String> {
    fs::read_to_string(file)
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

/// The last component of the link `link` points to.
fn link_name(link: &Path) -> Option<String> {
    fs::read_link(link)
        .ok()
        .and_then(|t| t.file_name().map(|n| n.to_string_lossy().into_owned()))
}

/// The symlinks of `/dev/serial/by-id`, `/dev/serial/by-path` and `/dev` itself, resolved.
struct Links {
    by_id: Vec<(PathBuf, PathBuf)>,
    by_path: Vec<(PathBuf, PathBuf)>,
    aliases: Vec<(PathBuf, PathBuf)>,
}

impl Links {
    fn read(dev: &Path) -> Links {
        let resolved = |dir: &Path, only_serial: bool| -> Vec<(PathBuf, PathBuf)> {
            let mut out: Vec<(PathBuf, PathBuf)> = fs::read_dir(dir)
                .map(|entries| {
                    entries
                        .filter_map(Result::ok)
                        .filter(|e| e.file_type().is_ok_and(|t| t.is_symlink()))
                        .filter(|e| {
                            !only_serial || e.file_name().to_string_lossy().starts_with("serial")
                        })
                        .filter_map(|e| {
                            let target = fs::canonicalize(e.path()).ok()?;
                            Some((e.path(), target))
                        })
                        .collect()
                })
                .unwrap_or_default();
            out.sort();
            out
        };
        Links {
            by_id: resolved(&dev.join("serial/by-id"), false),
            by_path: resolved(&dev.join("serial/by-path"), false),
            aliases: resolved(dev, true),
        }
    }

    fn pointing_at(links: &[(PathBuf, PathBuf)], device: &Path) -> Vec<PathBuf> {
        let Ok(device) = fs::canonicalize(device) else {
            return Vec::new();
        };
        links
            .iter()
            .filter(|(_, target)| *target == device)
            .map(|(link, _)| link.clone())
            .collect()
    }
}

fn describe(sysfs: &Path, dev: &Path, tty: &Path, name: &str, links: &Links) -> PortInfo {
    let device = dev.join(name);
    let device_dir = fs::canonicalize(tty.join("device")).ok();
    let latency_timer_ms = match check_latency_with(sysfs, &device, &ReportOnly) {
        LatencyCheck::Ok { ms, .. } | LatencyCheck::High { ms, .. } => Some(ms),
        LatencyCheck::Lowered { from, .. } => Some(from),
        _ => None,
    };
    PortInfo {
        by_id: Links::pointing_at(&links.by_id, &device),
        by_path: Links::pointing_at(&links.by_path, &device),
        aliases: Links::pointing_at(&links.aliases, &device),
        driver: device_dir.as_deref().and_then(driver_of),
        usb: device_dir.as_deref().and_then(usb_of),
        latency_timer_ms,
        accessible: nix::unistd::access(
            &device,
            nix::unistd::AccessFlags::R_OK | nix::unistd::AccessFlags::W_OK,
        )
        .is_ok(),
        open_by: Vec::new(),
        device,
    }
}

/// The driver of the device or of the first ancestor outside `serial-base` (which newer
/// kernels put between a UART's driver and its tty, with drivers named `port` and `ctrl`).
fn driver_of(device_dir: &Path) -> Option<String> {
    device_dir.ancestors().take(4).find_map(|dir| {
        if link_name(&dir.join("subsystem")).as_deref() == Some("serial-base") {
            return None;
        }
        link_name(&dir.join("driver"))
    })
}

/// The USB device above the tty's device: the first ancestor with an `idVendor`.
fn usb_of(device_dir: &Path) -> Option<UsbInfo> {
    let usb = device_dir
        .ancestors()
        .take(4)
        .find(|dir| dir.join("idVendor").is_file())?;
    Some(UsbInfo {
        vendor_id: read_trimmed(&usb.join("idVendor"))?,
        product_id: read_trimmed(&usb.join("idProduct")).unwrap_or_default(),
        manufacturer: read_trimmed(&usb.join("manufacturer")),
        product: read_trimmed(&usb.join("product")),
        serial: read_trimmed(&usb.join("serial")),
    })
}

/// The ports as text: one block per port, its best name for a mapping file first.
pub fn render(ports: &[PortInfo]) -> String {
    if ports.is_empty() {
        return format!(
            "no serial ports found (looked for {} with a device behind them). A USB adapter \
             shows up here once plugged in; a Raspberry Pi's UART once enabled \
             (enable_uart=1 or a dtoverlay in config.txt).\n",
            KINDS.map(|k| format!("{k}*")).join(", ")
        );
    }
    let mut out = String::new();
    for p in ports {
        let mut what = Vec::new();
        if let Some(usb) = &p.usb {
            let names: Vec<&str> = [&usb.manufacturer, &usb.product]
                .into_iter()
                .filter_map(|s| s.as_deref())
                .collect();
            let mut usb_text = format!("USB {}:{}", usb.vendor_id, usb.product_id);
            if !names.is_empty() {
                usb_text = format!("{} ({usb_text}", names.join(" "));
                if let Some(serial) = &usb.serial {
                    usb_text.push_str(&format!(", serial {serial}"));
                }
                usb_text.push(')');
            }
            what.push(usb_text);
        } else {
            what.push("built-in or on-board UART".to_string());
        }
        if let Some(driver) = &p.driver {
            what.push(format!("driver {driver}"));
        }
        out.push_str(&format!("{}  {}\n", p.device.display(), what.join(", ")));
        for (label, names) in [
            ("by-id", &p.by_id),
            ("by-path", &p.by_path),
            ("alias", &p.aliases),
        ] {
            for name in names {
                out.push_str(&format!("  {label:<8} {}\n", name.display()));
            }
        }
        if p.usb.is_some() && p.by_id.is_empty() {
            out.push_str("  by-id    none (udev did not name it)\n");
        }
        if let Some(ms) = p.latency_timer_ms {
            let verdict = if ms <= 1 {
                "good".to_string()
            } else {
                "high: the bridge lowers it at start if it may; for good: lj9da-bridge deploy udev"
                    .to_string()
            };
            out.push_str(&format!("  latency  {ms} ms ({verdict})\n"));
        }
        if !p.accessible {
            out.push_str(
                "  access   this user may not open it (add the user to its group, usually \
                 `dialout`, or run as its owner)\n",
            );
        }
        for o in &p.open_by {
            out.push_str(&format!(
                "  in use   by {} (pid {}): stop it before using the port\n",
                o.command, o.pid
            ));
        }
        out.push_str(&format!(
            "  mapping  port = \"{}\"\n",
            p.best_name().display()
        ));
    }
    out
}

impl PortInfo {
    /// The name to put in a mapping file: the by-id name of a USB adapter (it does not change
    /// when adapters are plugged in another order), else an alias, else the device.
    pub fn best_name(&self) -> &Path {
        self.by_id
            .first()
            .or(self.aliases.first())
            .unwrap_or(&self.device)
    }
}

/// The ports as JSON (an array of objects with the fields of [`PortInfo`]).
pub fn render_json(ports: &[PortInfo]) -> String {
    serde_json::to_string_pretty(ports).unwrap_or_else(|_| "[]".to_string()) + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serial_names_are_a_kind_and_a_number() {
        for name in [
            "ttyUSB0", "ttyACM12", "ttyAMA0", "ttyS4", "ttySC1", "ttyTHS2",
        ] {
            assert!(is_serial_name(name), "{name}");
        }
        for name in ["tty0", "ttyS", "ttySC", "ttyprintk", "ptmx", "ttyUSBx"] {
            assert!(!is_serial_name(name), "{name}");
        }
        let mut names = vec!["ttyUSB10", "ttyUSB9", "ttyACM0"];
        names.sort_by_key(|a| natural_key(a));
        assert_eq!(names, ["ttyACM0", "ttyUSB9", "ttyUSB10"]);
    }
}
