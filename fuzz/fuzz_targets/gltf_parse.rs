//! Fuzz target: glTF reader (`octolod::input::gltf`: `looks_like_gltf`,
//! `read_info`, `read_body`) on GLB files.
//!
//! The reader takes a path, so each input is written to a per-process temp
//! file (overwritten every iteration) and read from there. Any `Err` is an
//! accepted outcome; a panic, abort, OOM or timeout is a bug.
#![no_main]

use libfuzzer_sys::fuzz_target;
use octolod::input::gltf;
use octolod::ply::read::CollectSink;
use octolod::progress::Progress;
use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

fn scratch_path() -> &'static PathBuf {
    static P: OnceLock<PathBuf> = OnceLock::new();
    P.get_or_init(|| std::env::temp_dir().join(format!("octolod-fuzz-gltf-{}.glb", std::process::id())))
}

fuzz_target!(|data: &[u8]| {
    let path = scratch_path();
    {
        let mut f = std::fs::File::create(path).expect("create scratch file");
        f.write_all(data).expect("write scratch file");
    }
    let _ = gltf::looks_like_gltf(&data[..data.len().min(1024)]);
    let Ok(info) = gltf::read_info(path) else { return };
    let mut sink = CollectSink::default();
    if let Ok(stats) = gltf::read_body(path, &info, &mut sink, &Progress::hidden()) {
        // Cheap consistency checks on accepted inputs.
        assert_eq!(sink.vertices.len() as u64, stats.vertices);
        assert_eq!(sink.triangles.len() as u64, stats.triangles);
        for t in &sink.triangles {
            for &i in t {
                assert!(i < stats.vertices, "triangle index {i} >= vertex count {}", stats.vertices);
            }
        }
        for v in &sink.vertices {
            assert!(v.pos.iter().all(|c| c.is_finite()), "non-finite position accepted");
        }
    }
});
