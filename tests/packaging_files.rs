//! The files of the Debian packages (packaging/build-debs): the systemd unit and udev rule are
//! exactly what `lj9da-bridge deploy` prints for a program in /usr/bin, and the mapping file
//! installed in /etc/lj9da-bridge is valid and records into the service's state folder.

use lj9da_bridge::config::Config;
use lj9da_bridge::deploy::{DEFAULT_CONFIG, STATE_DIR, systemd_unit, udev_rule};
use std::path::{Path, PathBuf};

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn read(path: &str) -> String {
    std::fs::read_to_string(repo(path)).unwrap_or_else(|e| panic!("{path}: {e}"))
}

#[test]
fn the_packaged_unit_is_what_deploy_systemd_prints_for_usr_bin() {
    let unit = systemd_unit(
        Path::new("/usr/bin/lj9da-bridge"),
        Path::new(DEFAULT_CONFIG),
    );
    assert_eq!(
        read("packaging/lj9da-bridge.service"),
        unit,
        "regenerate it: lj9da-bridge deploy systemd --binary /usr/bin/lj9da-bridge \
         > packaging/lj9da-bridge.service"
    );
    assert!(unit.contains(
        "\nExecStart=/usr/bin/lj9da-bridge run --config /etc/lj9da-bridge/bridge.toml\n"
    ));
}

#[test]
fn the_packaged_udev_rule_is_what_deploy_udev_prints() {
    assert_eq!(
        read("packaging/99-lj9da-bridge.rules"),
        udev_rule(),
        "regenerate it: lj9da-bridge deploy udev > packaging/99-lj9da-bridge.rules"
    );
}

#[test]
fn the_packaged_mapping_file_is_valid_and_records_into_the_state_folder() {
    // As packaging/build-debs puts it together.
    let text = [
        "packaging/conffile-head.toml",
        "mappings/ardupilot-plane.toml",
        "packaging/conffile-tail.toml",
    ]
    .map(read)
    .concat();
    let path = Path::new(DEFAULT_CONFIG);
    let config =
        Config::parse_at(&text, DEFAULT_CONFIG, Some(path)).unwrap_or_else(|e| panic!("{e}"));
    assert!(config.record.enabled);
    assert_eq!(
        config.record.dir_for(Some(path)),
        Path::new(STATE_DIR).join("records")
    );
    // The same servos as the example it is made from.
    let example = Config::load(&repo("mappings/ardupilot-plane.toml")).unwrap();
    let names = |c: &Config| c.servos.iter().map(|s| s.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(&config), names(&example));
    assert_eq!(
        example.record.dir, None,
        "the example now has a [record] table, which the package's would repeat"
    );
}

#[test]
fn the_package_script_ships_the_files_these_tests_check() {
    let script = read("packaging/build-debs");
    for file in [
        "packaging/lj9da-bridge.service",
        "packaging/99-lj9da-bridge.rules",
        "cat packaging/conffile-head.toml mappings/ardupilot-plane.toml packaging/conffile-tail.toml",
    ] {
        assert!(script.contains(file), "build-debs does not use {file}");
    }
}
