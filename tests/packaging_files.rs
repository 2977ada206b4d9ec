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
        config.mavlink.system_id,
        Some(1),
        "the service as installed is back on the autopilot's outputs within 1 s of a kill only \
         with the autopilot's system id"
    );
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
        "packaging/ardupilot/lj9da.lua",
        "cat packaging/conffile-head.toml mappings/ardupilot-plane.toml packaging/conffile-tail.toml",
    ] {
        assert!(script.contains(file), "build-debs does not use {file}");
    }
}

/// The unit and the package point only at what exists: the unit's documentation is the man page
/// the package ships, and no file of the package names a web address of the project's own
/// (there is none to name; a homepage is given at build time with `DEB_HOMEPAGE`).
#[test]
fn the_unit_and_the_package_name_no_address_that_does_not_exist() {
    let unit = read("packaging/lj9da-bridge.service");
    let docs: Vec<&str> = unit
        .lines()
        .filter_map(|l| l.strip_prefix("Documentation="))
        .flat_map(str::split_whitespace)
        .collect();
    assert!(!docs.is_empty(), "the unit names its documentation");
    let script = read("packaging/build-debs");
    for doc in docs {
        let page = doc
            .strip_prefix("man:")
            .unwrap_or_else(|| panic!("{doc}: the unit's documentation is a man page"));
        let (name, section) = page.trim_end_matches(')').split_once('(').unwrap();
        let source = format!("packaging/{name}.{section}");
        assert!(repo(&source).exists(), "{doc}: no {source}");
        assert!(
            script.contains(&format!("<{source}")),
            "build-debs does not ship {source}"
        );
    }
    for file in [
        "packaging/lj9da-bridge.service",
        "packaging/build-debs",
        "packaging/debian/copyright",
        "Cargo.toml",
    ] {
        let text = read(file);
        for (at, _) in text.match_indices("://") {
            let url = &text[text[..at].rfind(char::is_whitespace).map_or(0, |i| i + 1)..]
                .split_whitespace()
                .next()
                .unwrap();
            assert!(
                url.contains("debian.org"),
                "{file} names the address {url}, which nothing keeps"
            );
        }
    }
}

/// The package's Maintainer is whoever builds it, given at build time; a value that is not
/// "Name <address>" stops the build before anything is compiled.
#[test]
fn build_debs_refuses_a_maintainer_that_is_not_name_and_address() {
    let out = std::process::Command::new("bash")
        .arg(repo("packaging/build-debs"))
        .arg("amd64")
        .env("DEB_MAINTAINER", "nobody")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("maintainer 'nobody' is not 'Name <address>': set DEB_MAINTAINER"),
        "{err}"
    );
}
