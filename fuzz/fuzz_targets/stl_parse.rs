//! Fuzz target: STL reader (`octolod::input::stl`: `looks_like_stl`,
//! `read_info`, `read_body`).
//!
//! The reader takes a path, so each input is written to a per-process temp
//! file (overwritten every iteration) and read from there. Any `Err` is an
//! accepted outcome; a panic, abort, OOM or timeout is a bug.
#![no_main]

use libfuzzer_sys::fuzz_target;
use octolod::input::stl;
use octolod::ply::read::CollectSink;
use octolod::progress::Progress;
use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

fn scratch_path() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("octolod-fuzz-stl-{}.stl", std::process::id())))
}

fuzz_target!(|data: &[u8]| {
    let path = scratch_path();
    {
        let mut f = std::fs::File::create(path).expect("create scratch file");
        f.write_all(data).expect("write scratch file");
    }
    let sniffed = stl::looks_like_stl(&data[..data.len().min(1024)], data.len() as u64);
    let Ok(info) = stl::read_info(path) else { return };
    assert_eq!(info.bytes, data.len() as u64);
    if info.binary {
        assert!(sniffed, "a binary STL whose size matches its count is sniffed as one");
    }
    let mut sink = CollectSink::default();
    if let Ok(stats) = stl::read_body(path, &info, &mut sink, &Progress::hidden()) {
        // Cheap consistency checks on accepted inputs.
        assert_eq!(stats.faces, info.triangles);
        assert_eq!(stats.triangles + stats.degenerate, stats.faces);
        assert_eq!(stats.vertices, 3 * stats.triangles);
        assert_eq!(stats.polygons, 0);
        assert_eq!(stats.bytes, info.bytes);
        assert_eq!(sink.vertices.len() as u64, stats.vertices);
        assert_eq!(sink.triangles.len() as u64, stats.triangles);
        for (k, t) in sink.triangles.iter().enumerate() {
            let k = k as u64;
            assert_eq!(*t, [3 * k, 3 * k + 1, 3 * k + 2]);
            let p = t.map(|i| sink.vertices[i as usize].pos.map(f64::to_bits));
            assert!(p[0] != p[1] && p[1] != p[2] && p[0] != p[2], "degenerate triangle {k} kept");
        }
        for v in &sink.vertices {
            assert!(v.pos.iter().all(|c| c.is_finite() && (*c as f32) as f64 == *c));
        }
    }
});
