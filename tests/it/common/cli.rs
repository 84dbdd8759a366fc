//! Running the binaries as a user would: commands, generated inputs,
//! directory listings, and runs under a time and an address-space limit
//! (a hang or a runaway allocation fails the test, not the machine).

use std::path::Path;
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

/// The `octolod` binary.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_octolod")
}

/// Runs `octolod ARGS`, waiting for it.
pub fn octolod(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().unwrap()
}

/// Runs `octolod ARGS`, which must succeed.
pub fn octolod_ok(args: &[&str]) -> Output {
    let o = octolod(args);
    assert!(o.status.success(), "{args:?}: {}", err(&o));
    o
}

/// Runs `octolod-gen ARGS`, waiting for it.
pub fn octolod_gen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_octolod-gen")).args(args).output().unwrap()
}

/// A run's standard error as text.
pub fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A run's standard output as text.
pub fn out(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `octolod-gen --shape SHAPE --tris N -o OUT`, which must succeed.
pub fn gen(shape: &str, tris: u64, out: &Path) {
    gen_with(shape, tris, out, &[]);
}

/// [`gen`] with more `octolod-gen` options.
pub fn gen_with(shape: &str, tris: u64, out: &Path, extra: &[&str]) {
    let n = tris.to_string();
    let mut args = vec!["--shape", shape, "--tris", &n, "--quiet", "-o", s(out)];
    args.extend_from_slice(extra);
    let o = octolod_gen(&args);
    assert!(o.status.success(), "{args:?}: {}", err(&o));
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

/// Waits for `child` to end; a child still running `secs` seconds on is
/// killed and fails the test ("`what` still running after N s").
pub fn wait_or_fail(child: &mut Child, secs: u64, what: &str) -> ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        if t.elapsed() > Duration::from_secs(secs) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} still running after {secs} s");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Address space a limited run may map.
pub const LIMIT_AS: u64 = 4 << 30;

/// Runs octolod under a time limit and [`LIMIT_AS`]; gives the exit code
/// (None when killed by a signal) and stderr.
pub fn run_limited(args: &[&str], secs: u64) -> (Option<i32>, String) {
    use std::os::unix::process::CommandExt;
    let mut cmd = Command::new(bin());
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
    // Read stderr alongside, so a chatty child never blocks on a full pipe.
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut e = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut e).unwrap();
        e
    });
    let st = wait_or_fail(&mut child, secs, &format!("{args:?}"));
    (st.code(), reader.join().unwrap())
}

/// A test measured by [`run_measured`] runs octolod from a fresh run of this test binary (doing nothing
/// else) with the arguments in this variable, `\u{1f}`-separated; the
/// child's output files go to the directory in [`MEASURE_OUT`].
const MEASURE: &str = "OCTOLOD_TEST_MEASURE";
const MEASURE_OUT: &str = "OCTOLOD_TEST_MEASURE_OUT";

/// The measuring child's part: runs octolod with the arguments in
/// `$OCTOLOD_TEST_MEASURE`, its output into files, and prints `measured:
/// CODE PEAK_BYTES` (its peak resident set size, from `wait4`).
fn measure(args: &str, dir: &Path) {
    use std::process::Stdio;
    let file = |n: &str| Stdio::from(std::fs::File::create(dir.join(n)).unwrap());
    // Reaped below by wait4 (which gives its rusage), not by `wait()`.
    #[allow(clippy::zombie_processes)]
    let child = Command::new(bin()).args(args.split('\u{1f}')).stdout(file("stdout")).stderr(file("stderr")).spawn().unwrap();
    let mut status = 0;
    // SAFETY: plain structs the kernel fills; the child is ours and not yet reaped.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut ru) };
    assert_eq!(pid, child.id() as libc::pid_t);
    let code = if libc::WIFEXITED(status) { libc::WEXITSTATUS(status) } else { -1 };
    println!("measured: {code} {}", ru.ru_maxrss as u64 * 1024);
}

/// Runs octolod with `args` and gives its exit code, stdout, stderr and
/// peak resident set size in bytes. `wait4`'s `ru_maxrss` also counts the
/// high-water mark of the memory a child execs from — a child of this test
/// process starts in this process's memory (vfork), which the tests running
/// alongside take to hundreds of MiB — so the command is started from a
/// fresh run of this test (`test`, of this module) doing nothing else:
/// [`measure`]. The test must start with `if measuring_child() { return; }`.
pub fn run_measured(module: &str, test: &str, args: &[&str]) -> (Option<i32>, Vec<u8>, String, u64) {
    let d = tempfile::tempdir().unwrap();
    let o = super::this_test_again(module, test).env(MEASURE, args.join("\u{1f}")).env(MEASURE_OUT, d.path()).output().unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    // The harness prints the test's name on the same line first.
    let line = text.split("measured: ").nth(1).and_then(|r| r.lines().next()).unwrap_or_else(|| panic!("{text}{}", err(&o)));
    let (code, peak) = line.split_once(' ').unwrap();
    let read = |n: &str| std::fs::read(d.path().join(n)).unwrap();
    (code.parse().ok(), read("stdout"), String::from_utf8_lossy(&read("stderr")).into_owned(), peak.parse().unwrap())
}

/// In the child [`run_measured`] starts: runs the measurement and gives
/// true (the test then returns at once).
pub fn measuring_child() -> bool {
    match (std::env::var(MEASURE), std::env::var(MEASURE_OUT)) {
        (Ok(args), Ok(dir)) => {
            measure(&args, Path::new(&dir));
            true
        }
        _ => false,
    }
}
