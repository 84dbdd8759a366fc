//! Embeds the browser viewer's bundle, every file of `web/dist/`, into the
//! binary for `octolod serve` (src/serve.rs), so an installed `octolod`
//! needs no checkout. Generates `$OUT_DIR/web_dist.rs`: `WEB_FILES`, a
//! sorted table of (path relative to web/dist with `/` separators,
//! `include_bytes!`), and `WEB_MTIME`, the newest file's modification time
//! (seconds since the epoch; 0 when unknown) for Last-Modified and ETags.
//! A missing bundle (or one without `index.html`) gets a small placeholder
//! `index.html` that says so.
//!
//! Rebuilds: `web/dist` is watched when it exists; until then `web` (when
//! it exists), so that the first bundle is picked up. A watched path that
//! does not exist would rerun this script, and so rebuild the crate, on
//! every build.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

const PLACEHOLDER: &str = r#"<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>octolod serve</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>octolod serve</h1>
<p>The browser viewer bundle (<code>web/dist/</code>) was missing when this
<code>octolod</code> was built, so no viewer page is embedded. Build the
bundle (see <code>web/</code>), then rebuild <code>octolod</code>.</p>
<p>The tileset itself is served: <a href="tiles/tileset.json">tiles/tileset.json</a>
(any 3D Tiles viewer, e.g. a CesiumJS page, can load it from this URL).</p>
</body></html>
"#;

fn main() {
    let root = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let dist = root.join("web").join("dist");
    println!("cargo:rerun-if-changed=build.rs");
    let mut files = Vec::new();
    if dist.is_dir() {
        println!("cargo:rerun-if-changed=web/dist");
        walk(&dist, "", &mut files);
    } else if root.join("web").is_dir() {
        println!("cargo:rerun-if-changed=web");
    }
    files.sort();
    let mtime =
        files.iter().filter_map(|(_, p)| std::fs::metadata(p).ok()?.modified().ok()?.duration_since(UNIX_EPOCH).ok()).map(|d| d.as_secs()).max().unwrap_or(0);

    // (name, the expression of its bytes), sorted by name.
    let mut table: Vec<(String, String)> =
        files.iter().map(|(n, p)| (n.clone(), format!("include_bytes!({:?})", p.to_str().expect("checked to be UTF-8 in walk")))).collect();
    if !files.iter().any(|(n, _)| n == "index.html") {
        if dist.is_dir() {
            println!("cargo:warning=web/dist has no index.html: `octolod serve` embeds a placeholder page");
        }
        table.push(("index.html".into(), format!("{PLACEHOLDER:?}.as_bytes()")));
    }
    table.sort();
    let mut src = String::from("/// The viewer page's files: (path under web/dist, bytes), sorted by path.\npub static WEB_FILES: &[(&str, &[u8])] = &[\n");
    for (name, bytes) in &table {
        writeln!(src, "    ({name:?}, {bytes}),").unwrap();
    }
    src.push_str("];\n");
    writeln!(src, "/// The newest embedded file's modification time, seconds since the epoch (0: unknown).\npub const WEB_MTIME: u64 = {mtime};").unwrap();
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR")).join("web_dist.rs");
    std::fs::write(&out, src).expect("write web_dist.rs");
}

/// Adds the regular files under `dir` (following symlinks), named `prefix`
/// + their relative path; hidden names and non-UTF-8 paths are skipped.
fn walk(dir: &Path, prefix: &str, files: &mut Vec<(String, PathBuf)>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        println!("cargo:warning=cannot read {}", dir.display());
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let Some(name) = e.file_name().to_str().map(str::to_owned) else {
            println!("cargo:warning=skipping non-UTF-8 path {}", path.display());
            continue;
        };
        if name.starts_with('.') || path.to_str().is_none() {
            continue;
        }
        let Ok(meta) = std::fs::metadata(&path) else { continue };
        if meta.is_dir() {
            walk(&path, &format!("{prefix}{name}/"), files);
        } else if meta.is_file() {
            files.push((format!("{prefix}{name}"), path));
        }
    }
}
