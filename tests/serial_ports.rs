//! `lj9da-bridge ports` against a fake `/sys` and `/dev` laid out as the kernel and udev lay
//! them out: an FTDI adapter, a CP2102, a CDC-ACM device, a Raspberry Pi UART behind the
//! newer kernels' `serial-base` devices, an 8250 UART, and the 8250 lines with no UART behind
//! them that must not be listed.

mod tempdir;

use lj9da_bridge::serial::ports::{Opener, PortInfo, UsbInfo, list, list_in, render, render_json};
use std::fs;
use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::process::Command;
use tempdir::TempDir;

struct Tree {
    dir: TempDir,
}

impl Tree {
    fn sys(&self) -> PathBuf {
        self.dir.path().join("sys")
    }
    fn dev(&self) -> PathBuf {
        self.dir.path().join("dev")
    }
}

fn write(path: &Path, text: &str) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    fs::write(path, text).unwrap();
}

fn link(target: &str, at: &Path) {
    fs::create_dir_all(at.parent().unwrap()).unwrap();
    symlink(target, at).unwrap();
}

/// `/sys/devices/<path>` relative to `from` (a directory under `/sys`), as `../../..` links.
fn up_to_sys(from: &Path, sys: &Path) -> String {
    let depth = from.strip_prefix(sys).unwrap().components().count();
    vec![".."; depth].join("/")
}

/// A USB device at `usb` (under `/sys/devices`) with its strings.
fn usb_device(sys: &Path, usb: &str, ids: (&str, &str), strings: [Option<&str>; 3]) {
    let dir = sys.join("devices").join(usb);
    write(&dir.join("idVendor"), &format!("{}\n", ids.0));
    write(&dir.join("idProduct"), &format!("{}\n", ids.1));
    for (file, value) in ["manufacturer", "product", "serial"].iter().zip(strings) {
        if let Some(v) = value {
            write(&dir.join(file), &format!("{v}\n"));
        }
    }
}

/// The class device `/sys/class/tty/<name>` for a tty whose device is `device` (a path under
/// `/sys/devices`), with `driver` and `subsystem` links on the device where given.
fn tty(sys: &Path, name: &str, device: &str, driver: Option<(&str, &str)>, subsystem: &str) {
    let device_dir = sys.join("devices").join(device);
    fs::create_dir_all(&device_dir).unwrap();
    let up = up_to_sys(&device_dir, sys);
    if let Some((bus, drv)) = driver {
        link(
            &format!("{up}/bus/{bus}/drivers/{drv}"),
            &device_dir.join("driver"),
        );
    }
    link(
        &format!("{up}/bus/{subsystem}"),
        &device_dir.join("subsystem"),
    );
    let class_dev = device_dir.join("tty").join(name);
    fs::create_dir_all(&class_dev).unwrap();
    link(
        &format!(
            "../../../{}",
            device_dir.file_name().unwrap().to_string_lossy()
        ),
        &class_dev.join("device"),
    );
    let rel = class_dev.strip_prefix(sys).unwrap();
    link(
        &format!("../../{}", rel.display()),
        &sys.join("class/tty").join(name),
    );
}

fn fake() -> Tree {
    let tree = Tree {
        dir: TempDir::new("ports"),
    };
    let (sys, dev) = (tree.sys(), tree.dev());
    // FTDI FT232R on ttyUSB0: usb-serial device under the interface, latency timer 16 ms.
    let ftdi = "pci0000:00/0000:00:14.0/usb1/1-1";
    usb_device(
        &sys,
        ftdi,
        ("0403", "6001"),
        [Some("FTDI"), Some("FT232R USB UART"), Some("A50285BI")],
    );
    tty(
        &sys,
        "ttyUSB0",
        &format!("{ftdi}/1-1:1.0/ttyUSB0"),
        Some(("usb-serial", "ftdi_sio")),
        "usb-serial",
    );
    write(
        &sys.join("devices")
            .join(ftdi)
            .join("1-1:1.0/ttyUSB0/latency_timer"),
        "16\n",
    );
    link(
        &format!("../../../devices/{ftdi}/1-1:1.0/ttyUSB0"),
        &sys.join("bus/usb-serial/devices/ttyUSB0"),
    );
    // CP2102 on ttyUSB1: no latency timer, no serial string.
    let cp = "pci0000:00/0000:00:14.0/usb1/1-2";
    usb_device(
        &sys,
        cp,
        ("10c4", "ea60"),
        [
            Some("Silicon Labs"),
            Some("CP2102 USB to UART Bridge Controller"),
            None,
        ],
    );
    tty(
        &sys,
        "ttyUSB1",
        &format!("{cp}/1-2:1.0/ttyUSB1"),
        Some(("usb-serial", "cp210x")),
        "usb-serial",
    );
    link(
        &format!("../../../devices/{cp}/1-2:1.0/ttyUSB1"),
        &sys.join("bus/usb-serial/devices/ttyUSB1"),
    );
    // CDC-ACM on ttyACM0: the tty's device is the USB interface itself.
    let acm = "pci0000:00/0000:00:14.0/usb1/1-3";
    usb_device(
        &sys,
        acm,
        ("2e8a", "000a"),
        [Some("Raspberry Pi"), Some("Pico"), Some("E66038B7")],
    );
    tty(
        &sys,
        "ttyACM0",
        &format!("{acm}/1-3:1.0"),
        Some(("usb", "cdc_acm")),
        "usb",
    );
    // Raspberry Pi PL011 on ttyAMA0, behind serial-base port and ctrl devices.
    let soc = "platform/soc/fe201000.serial";
    fs::create_dir_all(sys.join("devices").join(soc)).unwrap();
    link(
        "../../../../bus/amba/drivers/uart-pl011",
        &sys.join("devices").join(soc).join("driver"),
    );
    link(
        "../../../../bus/amba",
        &sys.join("devices").join(soc).join("subsystem"),
    );
    let ctrl = format!("{soc}/fe201000.serial:0");
    fs::create_dir_all(sys.join("devices").join(&ctrl)).unwrap();
    link(
        "../../../../../bus/serial-base/drivers/ctrl",
        &sys.join("devices").join(&ctrl).join("driver"),
    );
    link(
        "../../../../../bus/serial-base",
        &sys.join("devices").join(&ctrl).join("subsystem"),
    );
    tty(
        &sys,
        "ttyAMA0",
        &format!("{ctrl}/fe201000.serial:0.0"),
        Some(("serial-base", "port")),
        "serial-base",
    );
    // 8250: ttyS0 has a UART (type 4, 16550A); ttyS1 is a line with none (type 0); ttyS2 has
    // no device at all.
    for (name, kind) in [("ttyS0", "4"), ("ttyS1", "0")] {
        let pnp = format!("pnp0/00:0{}", &name[4..]);
        fs::create_dir_all(sys.join("devices").join(&pnp)).unwrap();
        link(
            "../../../bus/pnp/drivers/serial",
            &sys.join("devices").join(&pnp).join("driver"),
        );
        tty(
            &sys,
            name,
            &format!("{pnp}/{name}-port"),
            None,
            "serial-base",
        );
        write(&sys.join("class/tty").join(name).join("type"), kind);
    }
    fs::create_dir_all(sys.join("class/tty/ttyS2")).unwrap();
    // A virtual console and a pseudo-terminal master: not serial ports.
    fs::create_dir_all(sys.join("class/tty/tty0")).unwrap();
    fs::create_dir_all(sys.join("class/tty/ptmx")).unwrap();

    for name in [
        "ttyUSB0", "ttyUSB1", "ttyACM0", "ttyAMA0", "ttyS0", "ttyS1", "ttyS2", "tty0",
    ] {
        write(&dev.join(name), "");
    }
    link(
        "../../ttyUSB0",
        &dev.join("serial/by-id/usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0"),
    );
    link(
        "../../ttyUSB0",
        &dev.join("serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0"),
    );
    link(
        "../../ttyUSB1",
        &dev.join(
            "serial/by-id/usb-Silicon_Labs_CP2102_USB_to_UART_Bridge_Controller_0001-if00-port0",
        ),
    );
    link(
        "../../ttyACM0",
        &dev.join("serial/by-id/usb-Raspberry_Pi_Pico_E66038B7-if00"),
    );
    link("ttyAMA0", &dev.join("serial0"));
    tree
}

fn find<'a>(ports: &'a [PortInfo], name: &str) -> &'a PortInfo {
    ports
        .iter()
        .find(|p| p.device.file_name().unwrap() == name)
        .unwrap_or_else(|| panic!("{name} not listed: {ports:#?}"))
}

#[test]
fn every_real_serial_port_is_listed_and_nothing_else() {
    let tree = fake();
    let ports = list(&tree.sys(), &tree.dev());
    let names: Vec<String> = ports
        .iter()
        .map(|p| p.device.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["ttyACM0", "ttyAMA0", "ttyS0", "ttyUSB0", "ttyUSB1"]);
}

#[test]
fn a_usb_adapter_is_named_by_its_device_its_strings_and_its_stable_names() {
    let tree = fake();
    let ports = list(&tree.sys(), &tree.dev());
    let ftdi = find(&ports, "ttyUSB0");
    assert_eq!(ftdi.device, tree.dev().join("ttyUSB0"));
    assert_eq!(
        ftdi.usb,
        Some(UsbInfo {
            vendor_id: "0403".into(),
            product_id: "6001".into(),
            manufacturer: Some("FTDI".into()),
            product: Some("FT232R USB UART".into()),
            serial: Some("A50285BI".into()),
        })
    );
    assert_eq!(ftdi.driver.as_deref(), Some("ftdi_sio"));
    assert_eq!(ftdi.latency_timer_ms, Some(16));
    assert_eq!(
        ftdi.by_id,
        [tree
            .dev()
            .join("serial/by-id/usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0")]
    );
    assert_eq!(
        ftdi.by_path,
        [tree
            .dev()
            .join("serial/by-path/pci-0000:00:14.0-usb-0:1:1.0-port0")]
    );
    assert_eq!(ftdi.best_name(), ftdi.by_id[0]);
    // The latency timer was only read.
    assert_eq!(
        fs::read_to_string(
            tree.sys()
                .join("devices/pci0000:00/0000:00:14.0/usb1/1-1/1-1:1.0/ttyUSB0/latency_timer")
        )
        .unwrap(),
        "16\n"
    );

    let cp = find(&ports, "ttyUSB1");
    assert_eq!(cp.driver.as_deref(), Some("cp210x"));
    assert_eq!(cp.latency_timer_ms, None);
    let usb = cp.usb.as_ref().unwrap();
    assert_eq!(
        (usb.vendor_id.as_str(), usb.product_id.as_str()),
        ("10c4", "ea60")
    );
    assert_eq!(usb.serial, None);

    let acm = find(&ports, "ttyACM0");
    assert_eq!(acm.driver.as_deref(), Some("cdc_acm"));
    assert_eq!(acm.usb.as_ref().unwrap().product.as_deref(), Some("Pico"));
    assert_eq!(acm.by_id.len(), 1);
}

#[test]
fn a_uart_is_named_by_its_drivers_and_its_alias() {
    let tree = fake();
    let ports = list(&tree.sys(), &tree.dev());
    let pl011 = find(&ports, "ttyAMA0");
    assert_eq!(pl011.usb, None);
    // Past serial-base's `port` and `ctrl` to the UART's own driver.
    assert_eq!(pl011.driver.as_deref(), Some("uart-pl011"));
    assert_eq!(pl011.aliases, [tree.dev().join("serial0")]);
    assert_eq!(pl011.best_name(), tree.dev().join("serial0"));
    assert!(pl011.by_id.is_empty());
    assert_eq!(find(&ports, "ttyS0").driver.as_deref(), Some("serial"));
}

#[test]
fn the_text_and_json_say_what_each_port_is() {
    let tree = fake();
    let ports = list(&tree.sys(), &tree.dev());
    let text = render(&ports);
    for part in [
        "ttyUSB0  FTDI FT232R USB UART (USB 0403:6001, serial A50285BI), driver ftdi_sio",
        "by-id    ",
        "usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0",
        "latency  16 ms (high",
        "ttyAMA0  built-in or on-board UART, driver uart-pl011",
        "alias    ",
        "mapping  port = \"",
    ] {
        assert!(text.contains(part), "{part:?} not in\n{text}");
    }
    let json: serde_json::Value = serde_json::from_str(&render_json(&ports)).unwrap();
    assert_eq!(json.as_array().unwrap().len(), 5);
    let ftdi = &json.as_array().unwrap()[3];
    assert_eq!(ftdi["usb"]["vendor_id"], "0403");
    assert_eq!(ftdi["latency_timer_ms"], 16);
    assert!(render(&[]).contains("no serial ports found"));
}

#[test]
fn the_binary_lists_the_same_ports() {
    let tree = fake();
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["ports", "--json", "--sysfs-root"])
        .arg(tree.sys())
        .arg("--dev-root")
        .arg(tree.dev())
        .output()
        .expect("the binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let devices: Vec<&str> = json
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["device"].as_str().unwrap())
        .collect();
    assert_eq!(devices.len(), 5, "{devices:?}");
    assert!(devices[0].ends_with("/dev/ttyACM0"), "{devices:?}");
}

#[test]
fn a_port_some_process_has_open_says_which() {
    let tree = fake();
    let proc = tree.dir.path().join("proc");
    let usb0 = fs::canonicalize(tree.dev().join("ttyUSB0")).unwrap();
    // pid 4242, the bridge run as a service, has the FTDI port open twice; pid 77 has an
    // unrelated file; `self` and other non-pid entries are not processes.
    write(&proc.join("4242/comm"), "lj9da-bridge\n");
    link(usb0.to_str().unwrap(), &proc.join("4242/fd/5"));
    link(usb0.to_str().unwrap(), &proc.join("4242/fd/6"));
    write(&proc.join("77/comm"), "bash\n");
    link("/dev/null", &proc.join("77/fd/0"));
    link("socket:[1234]", &proc.join("77/fd/1"));
    fs::create_dir_all(proc.join("self/fd")).unwrap();
    let ports = list_in(&tree.sys(), &tree.dev(), &proc);
    assert_eq!(
        find(&ports, "ttyUSB0").open_by,
        [Opener {
            pid: 4242,
            command: "lj9da-bridge".into()
        }]
    );
    assert!(find(&ports, "ttyUSB1").open_by.is_empty());
    let text = render(&ports);
    assert!(
        text.contains("in use   by lj9da-bridge (pid 4242): stop it before using the port"),
        "{text}"
    );
}
