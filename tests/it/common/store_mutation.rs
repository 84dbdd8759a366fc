//! Store mutation harness, shared by the store fuzz target
//! (`fuzz/fuzz_targets/store_open.rs`, which includes this file) and
//! `tests/it/reliability.rs` (a fixed-seed run of the same mutations, plus the
//! fuzzer's regressions).
//!
//! Takes: a small store's files and bytes saying how to damage them. Gives:
//! the damaged store on disk, and a run of what `info`, `extract` and one
//! viewer frame do on it. A damaged store may fail with an error; it may not
//! panic, hang, allocate beyond reason, or hand out triangles whose indices
//! or coordinates are garbage.

use octolod::store::Store;
use octolod::view::camera::Camera;
use octolod::view::select::{Hierarchy, SelectOptions, Selector};
use std::path::Path;

/// A store's files as (name, bytes), in name order.
pub fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .expect("read the store directory")
        .map(|e| {
            let e = e.expect("a directory entry");
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).expect("read a store file"))
        })
        .collect();
    files.sort();
    files
}

/// Applies the edits `data` encodes, each `[op, file, offset u32 LE, len, bytes...]`:
/// op % 4 = 0 overwrites `len` bytes at the offset (taken modulo the file's
/// size), 1 XORs them, 2 truncates the file there, 3 inserts the bytes.
/// The file index is taken modulo the number of files.
pub fn mutate(files: &mut [(String, Vec<u8>)], mut data: &[u8]) {
    while data.len() >= 7 && !files.is_empty() {
        let (op, file) = (data[0] % 4, data[1] as usize % files.len());
        let at = u32::from_le_bytes([data[2], data[3], data[4], data[5]]) as usize;
        let len = (data[6] as usize).min(data.len() - 7);
        let bytes = &data[7..7 + len];
        data = &data[7 + len..];
        let b = &mut files[file].1;
        let at = if b.is_empty() { 0 } else { at % b.len() };
        match op {
            0 => {
                for (i, &x) in bytes.iter().enumerate() {
                    if let Some(y) = b.get_mut(at + i) {
                        *y = x;
                    }
                }
            }
            1 => {
                for (i, &x) in bytes.iter().enumerate() {
                    if let Some(y) = b.get_mut(at + i) {
                        *y ^= x;
                    }
                }
            }
            2 => b.truncate(at),
            _ => {
                b.splice(at..at, bytes.iter().copied());
            }
        }
    }
}

/// Replaces the store at `dir` with `files`.
pub fn write(dir: &Path, files: &[(String, Vec<u8>)]) {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).expect("create the store directory");
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).expect("write a store file");
    }
}

/// What `info`, `extract` and one viewer frame do, on the store at `dir`:
/// open it; read every level's cut and an error cut node by node (the
/// payload checks run on each read); one selection step from a frame-all
/// camera. Returns how many triangles were read. Panics when something
/// accepted is garbage.
pub fn exercise(dir: &Path) -> u64 {
    let Ok(store) = Store::open(dir) else { return 0 };
    let n = store.nodes.len();
    let mut read = 0u64;
    let mut cuts = Vec::new();
    for l in 0..=store.top_level() {
        if store.check_level(l).is_ok() {
            cuts.push(store.level_cut(l));
        }
    }
    cuts.push(store.error_cut(0.0));
    cuts.push(store.error_cut(f64::INFINITY));
    for cut in &cuts {
        for &i in &cut.drawn {
            assert!(i < n, "a cut draws node {i} of {n}");
            let Ok(nm) = store.read_node(i) else { continue };
            let m = cut.drawn_mesh(&nm);
            let nv = m.vertices.len() as u32;
            for t in &m.triangles {
                assert!(t.iter().all(|&k| k < nv), "node {i}: index past its {nv} vertices");
            }
            for v in &m.vertices {
                assert!(v.pos.iter().all(|c| c.is_finite()), "node {i}: non-finite position accepted");
            }
            read += m.triangles.len() as u64;
        }
    }
    let h = Hierarchy::new(&store);
    let b = h.bounds;
    if b.min.iter().chain(b.max.iter()).all(|c| c.is_finite()) && (0..3).all(|k| b.min[k] <= b.max[k]) {
        let mut cam = Camera::frame_all(&b, glam::DVec3::Z, 50.0);
        cam.fit_clip(&b);
        let mut sel = Selector::new(SelectOptions::default());
        let s = sel.select(&h, &cam, (320, 240), &|_| true);
        assert!(s.cut.iter().all(|&u| (u as usize) < n));
    }
    read
}
