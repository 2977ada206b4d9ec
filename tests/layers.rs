//! The library's layers (docs/architecture.md): each top-level module of `src/` uses only the
//! modules below it. Read from the source: every `crate::<module>` path outside comments.

use std::path::Path;

/// Bottom first. A module may use those before it, never those after it.
const LAYERS: [&str; 12] = [
    "protocol",
    "serial",
    "bus",
    "config",
    "mavlink",
    "record",
    "deploy",
    "runtime",
    "ui",
    "commission",
    "simulation",
    "fuzz_targets",
];

/// The Rust files of top-level module `name` (a folder or a file).
fn files_of(name: &str) -> Vec<std::path::PathBuf> {
    let dir = Path::new("src").join(name);
    if dir.is_dir() {
        let mut out = Vec::new();
        let mut stack = vec![dir];
        while let Some(d) = stack.pop() {
            for entry in std::fs::read_dir(&d).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    stack.push(path);
                } else if path.extension().is_some_and(|e| e == "rs") {
                    out.push(path);
                }
            }
        }
        out
    } else {
        let file = Path::new("src").join(format!("{name}.rs"));
        assert!(file.is_file(), "no module {name} in src/");
        vec![file]
    }
}

/// The top-level modules named by `crate::<module>` paths in `source`, comments left out.
fn uses(source: &str) -> Vec<String> {
    let mut found = Vec::new();
    for line in source.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(at) = rest.find("crate::") {
            let after = &rest[at + "crate::".len()..];
            let name: String = after
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            // `lj9da_crate::` and the like are not this crate.
            let before = rest[..at].chars().last();
            if !before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') && !name.is_empty() {
                found.push(name);
            }
            rest = after;
        }
    }
    found
}

#[test]
fn every_module_uses_only_the_layers_below_it() {
    let mut wrong = Vec::new();
    for (level, module) in LAYERS.iter().enumerate() {
        for file in files_of(module) {
            let source = std::fs::read_to_string(&file).unwrap();
            for used in uses(&source) {
                match LAYERS.iter().position(|l| *l == used) {
                    Some(l) if l > level => {
                        wrong.push(format!("{}: {module} uses {used}", file.display()))
                    }
                    Some(_) => {}
                    None => wrong.push(format!(
                        "{}: {used} is in no layer: add it to LAYERS and docs/architecture.md",
                        file.display()
                    )),
                }
            }
        }
    }
    wrong.sort();
    wrong.dedup();
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn every_top_level_module_has_a_layer() {
    let lib = std::fs::read_to_string("src/lib.rs").unwrap();
    for line in lib.lines() {
        if let Some(name) = line.trim().strip_prefix("pub mod ") {
            let name = name.trim_end_matches(';');
            assert!(LAYERS.contains(&name), "src/lib.rs: {name} is in no layer");
        }
    }
}

#[test]
fn a_use_from_above_is_found() {
    let source = "use crate::runtime::BridgeView; // crate::simulation in a comment\n\
                  /// [`crate::deploy`] in a doc\nlet x = lj9da_crate::x; crate::bus::Goal";
    assert_eq!(uses(source), ["runtime", "bus"]);
}
