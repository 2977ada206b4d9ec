//! The library's layers (docs/architecture.md): each top-level module of `src/` uses only the
//! modules below it.
//!
//! Read from the source as Rust (with `syn`), not as lines of text. A module of this crate is
//! named by a path that starts at a place of the crate: `crate`, a name `crate` was given
//! (`use crate as c;`), `self` or `super` (climbed from the file's own module: `src/bus/driver.rs`
//! is `bus::driver`, `src/bus/mod.rs` is `bus`, and an inline `mod x { … }` adds a level). Such
//! paths are looked for in every `use` (groups, nested groups, renames, globs), in every path of
//! the code (expressions, types, patterns, attributes) and in the tokens of every macro call.
//! Comments, doc comments and strings are not code: a path written there does not count.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};
use syn::visit::Visit;

/// Bottom first. A module may use those before it, never those after it.
const LAYERS: [&str; 14] = [
    "protocol",
    "dronecan",
    "serial",
    "bus",
    "config",
    "mavlink",
    "can_node",
    "record",
    "deploy",
    "runtime",
    "ui",
    "commission",
    "simulation",
    "fuzz_targets",
];

/// The Rust files of top-level module `name` (a folder or a file).
fn files_of(name: &str) -> Vec<PathBuf> {
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
        out.sort();
        out
    } else {
        let file = Path::new("src").join(format!("{name}.rs"));
        assert!(file.is_file(), "no module {name} in src/");
        vec![file]
    }
}

/// The module a file of `src/` is: `src/bus/driver.rs` is `bus::driver`, `src/bus/mod.rs` and
/// `src/bus.rs` are `bus`.
fn module_of(file: &Path) -> String {
    let relative = file.strip_prefix("src").expect("a file of src/");
    let mut parts: Vec<String> = relative
        .iter()
        .map(|part| part.to_string_lossy().into_owned())
        .collect();
    let name = parts.pop().expect("a file name");
    let stem = name.strip_suffix(".rs").expect("a Rust file");
    if stem != "mod" {
        parts.push(stem.to_string());
    }
    parts.join("::")
}

/// The two passes over a file: first the names given to places of the crate (they may be
/// declared after their use, and one may be built on another), then the modules used.
#[derive(PartialEq)]
enum Pass {
    Names,
    Uses,
}

/// Walks one file and resolves its paths against the module each is written in.
struct Resolver {
    pass: Pass,
    /// The module the walk is in: the file's module, then each inline `mod x { … }` around.
    module: Vec<String>,
    /// Names that stand for a place of the crate, per module that declares them:
    /// `use crate as c;` in `bus` makes `(bus, c)` stand for the crate's root, and
    /// `use super::super as up;` in `bus::driver` makes `(bus::driver, up)` stand for it too.
    names: HashMap<(Vec<String>, String), Vec<String>>,
    /// Modules that import everything from the crate's root (`use crate::*;`, or
    /// `use super::*;` one level down): there a plain `runtime::X` is the crate's `runtime`.
    root_globs: HashSet<Vec<String>>,
    /// The top-level modules used.
    found: BTreeSet<String>,
}

impl Resolver {
    /// Where `segments`, written in the current module, lead from the crate's root; `None`
    /// for a path that does not start at a place of this crate (a local name, `std::…`,
    /// another crate).
    fn absolute(&self, segments: &[String]) -> Option<Vec<String>> {
        let (first, rest) = segments.split_first()?;
        let mut at = match first.as_str() {
            "crate" => Vec::new(),
            "self" => self.module.clone(),
            "super" => {
                let mut parent = self.module.clone();
                parent.pop()?;
                parent
            }
            name => match self.names.get(&(self.module.clone(), name.to_string())) {
                Some(place) => place.clone(),
                None if self.root_globs.contains(&self.module) && LAYERS.contains(&name) => {
                    vec![name.to_string()]
                }
                None => return None,
            },
        };
        let mut climbing = true;
        for segment in rest {
            match segment.as_str() {
                "super" if climbing => {
                    at.pop()?;
                }
                "self" if climbing => {}
                other => {
                    climbing = false;
                    at.push(other.to_string());
                }
            }
        }
        Some(self.through_names(at))
    }

    /// `at` with any name it goes through replaced by the place it stands for
    /// (`super::c::runtime` where the parent module has `use crate as c;`).
    fn through_names(&self, mut at: Vec<String>) -> Vec<String> {
        // Each replacement is of a name declared in the file: a few rounds at most, and the
        // bound stops a name that stands for a place through itself.
        for _ in 0..16 {
            let replaced = (0..at.len()).find_map(|k| {
                let key = (at[..k].to_vec(), at[k].clone());
                self.names.get(&key).map(|place| (k, place.clone()))
            });
            let Some((k, place)) = replaced else {
                return at;
            };
            let mut next = place;
            next.extend_from_slice(&at[k + 1..]);
            at = next;
        }
        at
    }

    /// A path written in the code: counted when it leads to a module of the crate.
    fn path(&mut self, segments: &[String]) {
        if self.pass != Pass::Uses {
            return;
        }
        if let Some(at) = self.absolute(segments)
            && let Some(top) = at.first()
        {
            self.found.insert(top.clone());
        }
    }

    /// One `use` tree, under the path `prefix` written before it.
    fn use_tree(&mut self, prefix: &mut Vec<String>, tree: &syn::UseTree) {
        match tree {
            syn::UseTree::Path(p) => {
                prefix.push(p.ident.to_string());
                self.use_tree(prefix, &p.tree);
                prefix.pop();
            }
            syn::UseTree::Name(n) => self.use_name(prefix, &n.ident, None),
            syn::UseTree::Rename(r) => self.use_name(prefix, &r.ident, Some(&r.rename)),
            syn::UseTree::Glob(_) => {
                if let Some(at) = self.absolute(prefix)
                    && at.is_empty()
                    && self.pass == Pass::Names
                {
                    self.root_globs.insert(self.module.clone());
                }
                self.path(prefix);
            }
            syn::UseTree::Group(g) => {
                for item in &g.items {
                    self.use_tree(prefix, item);
                }
            }
        }
    }

    /// `prefix::ident` (or `prefix` itself for `self`), imported as `rename` if given.
    fn use_name(&mut self, prefix: &[String], ident: &syn::Ident, rename: Option<&syn::Ident>) {
        let mut full = prefix.to_vec();
        if ident != "self" || full.is_empty() {
            full.push(ident.to_string());
        }
        if let (Some(rename), Pass::Names) = (rename, &self.pass)
            && let Some(at) = self.absolute(&full)
        {
            self.names
                .insert((self.module.clone(), rename.to_string()), at);
        }
        self.path(&full);
    }

    /// The tokens of a macro call or an attribute: every `a::b::c` run of identifiers.
    fn scan(&mut self, mut cursor: syn::buffer::Cursor) {
        while !cursor.eof() {
            if let Some((ident, next)) = cursor.ident() {
                let mut segments = vec![ident.to_string()];
                let mut at = next;
                // `::` (two `:` punctuations) and an identifier, as long as they come.
                while let Some((first, after_first)) = at.punct()
                    && first.as_char() == ':'
                    && let Some((second, after_second)) = after_first.punct()
                    && second.as_char() == ':'
                    && let Some((segment, after_segment)) = after_second.ident()
                {
                    segments.push(segment.to_string());
                    at = after_segment;
                }
                self.path(&segments);
                cursor = at;
            } else if let Some((inside, _, _, next)) = cursor.any_group() {
                self.scan(inside);
                cursor = next;
            } else if let Some((_, next)) = cursor.token_tree() {
                cursor = next;
            } else {
                break;
            }
        }
    }
}

impl<'ast> Visit<'ast> for Resolver {
    fn visit_item_mod(&mut self, item: &'ast syn::ItemMod) {
        for attr in &item.attrs {
            self.visit_attribute(attr);
        }
        if let Some((_, items)) = &item.content {
            self.module.push(item.ident.to_string());
            for inner in items {
                self.visit_item(inner);
            }
            self.module.pop();
        }
    }

    fn visit_item_use(&mut self, item: &'ast syn::ItemUse) {
        for attr in &item.attrs {
            self.visit_attribute(attr);
        }
        self.visit_visibility(&item.vis);
        // `use ::name::…` is another crate.
        if item.leading_colon.is_none() {
            self.use_tree(&mut Vec::new(), &item.tree);
        }
    }

    fn visit_item_extern_crate(&mut self, item: &'ast syn::ItemExternCrate) {
        // `extern crate self as c;` names the crate's root.
        if item.ident == "self"
            && let Some((_, rename)) = &item.rename
            && self.pass == Pass::Names
        {
            self.names
                .insert((self.module.clone(), rename.to_string()), Vec::new());
        }
    }

    fn visit_path(&mut self, path: &'ast syn::Path) {
        if path.leading_colon.is_none() {
            let segments: Vec<String> = path.segments.iter().map(|s| s.ident.to_string()).collect();
            self.path(&segments);
        }
        syn::visit::visit_path(self, path);
    }

    fn visit_macro(&mut self, mac: &'ast syn::Macro) {
        self.visit_path(&mac.path);
        let tokens = syn::buffer::TokenBuffer::new2(mac.tokens.clone());
        self.scan(tokens.begin());
    }

    fn visit_meta_list(&mut self, list: &'ast syn::MetaList) {
        self.visit_path(&list.path);
        let tokens = syn::buffer::TokenBuffer::new2(list.tokens.clone());
        self.scan(tokens.begin());
    }
}

/// The top-level modules of the crate that `source`, the file of module `module`
/// (`"bus::driver"`), uses; sorted.
fn uses(source: &str, module: &str) -> Vec<String> {
    let file = syn::parse_file(source).unwrap_or_else(|e| panic!("not Rust: {e}"));
    uses_in(&file, module)
}

/// [`uses`] of a file already parsed.
fn uses_in(file: &syn::File, module: &str) -> Vec<String> {
    let mut resolver = Resolver {
        pass: Pass::Names,
        module: module.split("::").map(str::to_string).collect(),
        names: HashMap::new(),
        root_globs: HashSet::new(),
        found: BTreeSet::new(),
    };
    // Until no new name: a name may be built on one declared after it.
    loop {
        let before = (resolver.names.len(), resolver.root_globs.len());
        resolver.visit_file(file);
        if (resolver.names.len(), resolver.root_globs.len()) == before {
            break;
        }
    }
    resolver.pass = Pass::Uses;
    resolver.visit_file(file);
    resolver.found.into_iter().collect()
}

#[test]
fn every_module_uses_only_the_layers_below_it() {
    let mut wrong = Vec::new();
    for (level, module) in LAYERS.iter().enumerate() {
        for file in files_of(module) {
            let source = std::fs::read_to_string(&file).unwrap();
            let parsed = syn::parse_file(&source)
                .unwrap_or_else(|e| panic!("{}: not read as Rust: {e}", file.display()));
            for used in uses_in(&parsed, &module_of(&file)) {
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
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn every_top_level_module_has_a_layer() {
    let lib = syn::parse_file(&std::fs::read_to_string("src/lib.rs").unwrap()).unwrap();
    let modules: Vec<String> = lib
        .items
        .iter()
        .filter_map(|item| match item {
            syn::Item::Mod(m) => Some(m.ident.to_string()),
            _ => None,
        })
        .collect();
    // `#[cfg(feature = "sitl")] pub mod simulation;` is a module like the others.
    assert!(modules.iter().any(|m| m == "simulation"), "{modules:?}");
    for name in &modules {
        assert!(
            LAYERS.contains(&name.as_str()),
            "src/lib.rs: {name} is in no layer"
        );
    }
}

/// The paths in `source` that start at the `parquet` crate (`parquet::…`, `::parquet::…`, in
/// `use` items and in code).
fn parquet_paths(source: &str) -> Vec<String> {
    struct Found(Vec<String>);
    impl<'ast> Visit<'ast> for Found {
        fn visit_item_use(&mut self, item: &'ast syn::ItemUse) {
            let mut roots = vec![&item.tree];
            while let Some(tree) = roots.pop() {
                match tree {
                    syn::UseTree::Path(p) if p.ident == "parquet" => {
                        self.0.push("use parquet::…".to_string());
                    }
                    syn::UseTree::Group(g) => roots.extend(g.items.iter()),
                    _ => {}
                }
            }
            syn::visit::visit_item_use(self, item);
        }
        fn visit_path(&mut self, path: &'ast syn::Path) {
            if path.segments.len() > 1 && path.segments[0].ident == "parquet" {
                let text: Vec<String> = path.segments.iter().map(|s| s.ident.to_string()).collect();
                self.0.push(text.join("::"));
            }
            syn::visit::visit_path(self, path);
        }
    }
    let file = syn::parse_file(source).expect("Rust");
    let mut found = Found(Vec::new());
    found.visit_file(&file);
    found.0
}

/// The Parquet export is the flight record's business alone: the `parquet` crate is used by
/// the `record` module and nowhere else (not on the bus or MAVLink paths).
#[test]
fn only_the_record_module_uses_the_parquet_crate() {
    let mut wrong = Vec::new();
    let mut files: Vec<PathBuf> = LAYERS
        .iter()
        .filter(|l| **l != "record")
        .flat_map(|l| files_of(l))
        .collect();
    files.extend(["src/main.rs", "src/lib.rs"].map(PathBuf::from));
    for file in files {
        for path in parquet_paths(&std::fs::read_to_string(&file).unwrap()) {
            wrong.push(format!("{}: {path}", file.display()));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    // The check finds the crate's paths, and only them.
    assert_eq!(
        parquet_paths("use parquet::file::W; use {parquet::a}; fn f() { ::parquet::x::y(); }")
            .len(),
        3
    );
    assert!(
        parquet_paths(
            "// parquet::x\n/// `parquet::y`\nfn f() { crate::record::parquet::run(); let s = \"parquet::z\"; }"
        )
        .is_empty()
    );
}

#[test]
fn a_module_in_a_use_group_is_found() {
    assert_eq!(uses("use crate::{runtime::X};", "bus"), ["runtime"]);
    assert_eq!(
        uses("use crate::{bus, runtime::{self}};", "config"),
        ["bus", "runtime"]
    );
    assert_eq!(
        uses("use crate::{protocol::{A, b::C as D}, ui::*};", "bus"),
        ["protocol", "ui"]
    );
}

#[test]
fn a_file_is_the_module_its_path_says() {
    assert_eq!(module_of(Path::new("src/bus/driver.rs")), "bus::driver");
    assert_eq!(module_of(Path::new("src/bus/mod.rs")), "bus");
    assert_eq!(module_of(Path::new("src/deploy.rs")), "deploy");
    assert_eq!(
        module_of(Path::new("src/bus/tests/port.rs")),
        "bus::tests::port"
    );
}

#[test]
fn super_climbs_from_the_files_module() {
    assert_eq!(
        uses("use super::super::runtime::X;", "bus::driver"),
        ["runtime"]
    );
    assert_eq!(
        uses("fn f() { super::super::runtime::x(); }", "bus::driver"),
        ["runtime"]
    );
    // One level up from `bus::driver` is still `bus`.
    assert_eq!(uses("use super::master::Y;", "bus::driver"), ["bus"]);
    // An inline module adds a level: two `super`s from it are only `bus`.
    assert_eq!(
        uses(
            "mod tests { use super::super::Z; fn f() { self::g(); } }",
            "bus::driver"
        ),
        ["bus"]
    );
    // `use super::*;` in `bus` brings the root's modules in: `runtime::x` is the crate's.
    assert_eq!(
        uses("use super::*; fn f() { runtime::x(); }", "bus"),
        ["runtime"]
    );
}

#[test]
fn a_name_given_to_the_crate_is_followed() {
    assert_eq!(
        uses("use crate as c; fn f() { c::runtime::x(); }", "bus"),
        ["runtime"]
    );
    // Declared after its use, built on another name, or given by `extern crate self`.
    assert_eq!(
        uses(
            "fn f() -> d::ui::T { todo!() } use c as d; use crate as c;",
            "bus"
        ),
        ["ui"]
    );
    assert_eq!(
        uses("extern crate self as me; use me::{runtime};", "bus"),
        ["runtime"]
    );
    assert_eq!(
        uses(
            "use super::super as up; type T = up::record::R;",
            "bus::driver"
        ),
        ["record"]
    );
}

#[test]
fn paths_in_types_patterns_and_macros_are_found() {
    assert_eq!(
        uses(
            "fn f(x: crate::config::Config) { match x { crate::mavlink::A => {} } }",
            "bus"
        ),
        ["config", "mavlink"]
    );
    assert_eq!(
        uses(
            r#"fn f() { assert!(matches!(e, crate::runtime::E::X)); tracing::info!("{}", crate::ui::y()); }"#,
            "bus"
        ),
        ["runtime", "ui"]
    );
}

#[test]
fn comments_strings_and_other_crates_do_not_count() {
    let source = r#"
        // use crate::runtime::X;
        /* crate::runtime */
        /// [`crate::runtime::BridgeView`] in a doc comment
        fn f() {
            let s = "crate::runtime::x";
            println!("crate::simulation {}", s);
            let _ = lj9da_crate::runtime::x;
            let _ = ::crate_b::runtime::y;
            let _ = std::crate_like::z;
        }
    "#;
    assert_eq!(uses(source, "bus"), Vec::<String>::new());
}
