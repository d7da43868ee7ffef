//! Tidy (rust-analyzer's habit): every module a file declares appears in that file's `//!`
//! layout list, so the docs a newcomer reads first stay true to the tree. Checks every `mod.rs`,
//! `lib.rs` and `main.rs` (and any other file declaring modules) under the workspace's crates.

use std::path::{Path, PathBuf};

/// The crates' source folders, from this crate's manifest directory.
fn source_roots() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    ["server/src", "client/src", "client/capi/src", "proto/src"]
        .iter()
        .map(|p| root.join(p))
        .collect()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Names of the modules `text` declares at its top level (`mod x;`, `pub mod x;`,
/// `pub(crate) mod x;`), not inline ones (`mod tests {`).
fn declared_modules(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| !l.starts_with(' ') && !l.starts_with('\t'))
        .filter_map(|l| {
            let l = l.trim_end();
            let rest = l
                .strip_prefix("pub mod ")
                .or_else(|| l.strip_prefix("mod "))
                .or_else(|| l.strip_prefix("pub(crate) mod "))?;
            rest.strip_suffix(';').map(str::to_string)
        })
        .collect()
}

/// The file's leading `//!` doc.
fn module_doc(text: &str) -> String {
    text.lines()
        .take_while(|l| l.starts_with("//!") || l.trim().is_empty())
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn every_module_is_in_its_parents_layout_list() {
    let mut missing = Vec::new();
    let mut checked = 0;
    for root in source_roots() {
        let mut files = Vec::new();
        rust_files(&root, &mut files);
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            let modules = declared_modules(&text);
            if modules.is_empty() {
                continue;
            }
            checked += 1;
            let doc = module_doc(&text);
            for m in modules {
                if !doc.contains(&format!("`{m}`")) && !doc.contains(&format!("`{m}/`")) {
                    missing.push(format!("{}: `{m}`", file.display()));
                }
            }
        }
    }
    assert!(checked >= 10, "only {checked} files declare modules");
    assert!(
        missing.is_empty(),
        "modules missing from their parent's //! layout list:\n{}",
        missing.join("\n")
    );
}

#[test]
fn declared_modules_are_read_from_top_level_lines_only() {
    let text = "//! doc\npub mod a;\nmod b;\npub(crate) mod c;\nmod tests {\n    mod inner;\n}\n";
    assert_eq!(declared_modules(text), ["a", "b", "c"]);
}
