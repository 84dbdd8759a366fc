//! Fuzz target: PLY header + body parser (`octolod::ply::read::read_all`).
//!
//! The parser API takes a path, so each input is written to a per-process temp
//! file (overwritten every iteration) and parsed from there. Any `Err` is an
//! accepted outcome; a panic, abort, OOM or timeout is a bug.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

fn scratch_path() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("octolod-fuzz-ply-{}.ply", std::process::id())))
}

fuzz_target!(|data: &[u8]| {
    let path = scratch_path();
    {
        let mut f = std::fs::File::create(path).expect("create scratch file");
        f.write_all(data).expect("write scratch file");
    }
    if let Ok((header, sink, stats)) = octolod::ply::read::read_all(path) {
        // Cheap consistency checks on accepted inputs.
        assert_eq!(stats.vertices, header.vertex_count());
        assert_eq!(sink.vertices.len() as u64, stats.vertices);
        assert_eq!(sink.triangles.len() as u64, stats.triangles);
        assert_eq!(stats.faces, header.face_count());
        for t in &sink.triangles {
            for &i in t {
                assert!(i < stats.vertices, "triangle index {i} >= vertex count {}", stats.vertices);
            }
        }
        for v in &sink.vertices {
            assert!(v.pos.iter().all(|c| c.is_finite()));
        }
    }
});
