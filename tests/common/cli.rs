//! Running the binaries as a user would: commands, generated inputs,
//! directory listings, and runs under a time and an address-space limit
//! (a hang or a runaway allocation fails the test, not the machine).

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs `octolod ARGS`, waiting for it.
pub fn octolod(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_octolod")).args(args).output().unwrap()
}

/// A run's standard error as text.
pub fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `octolod-gen --shape SHAPE --tris N -o OUT`, which must succeed.
pub fn gen(shape: &str, tris: u64, out: &Path) {
    let o = Command::new(env!("CARGO_BIN_EXE_octolod-gen"))
        .args(["--shape", shape, "--tris", &tris.to_string(), "--quiet", "-o", s(out)])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", err(&o));
}

/// The sorted names in directory `d`.
pub fn names(d: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Address space a limited run may map.
pub const LIMIT_AS: u64 = 4 << 30;

/// Runs octolod under a time limit and [`LIMIT_AS`]; gives the exit code
/// (None when killed by a signal) and stderr.
pub fn run_limited(args: &[&str], secs: u64) -> (Option<i32>, String) {
    use std::os::unix::process::CommandExt;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_octolod"));
    cmd.args(args).stdout(Stdio::null()).stderr(Stdio::piped());
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            let lim = libc::rlimit { rlim_cur: LIMIT_AS, rlim_max: LIMIT_AS };
            if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn().unwrap();
    let t = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            let mut e = String::new();
            use std::io::Read;
            child.stderr.take().unwrap().read_to_string(&mut e).unwrap();
            return (st.code(), e);
        }
        if t.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            panic!("{args:?} still running after {secs} s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
