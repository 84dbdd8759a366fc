//! Keeps libwayland's complaint about a missing desktop session out of
//! successful `view` and `render` runs.
//!
//! `wl_display_connect` prints "error: XDG_RUNTIME_DIR is invalid or not
//! set in the environment." through libwayland-client's log handler
//! whenever `XDG_RUNTIME_DIR` is unset or relative (and `WAYLAND_DISPLAY`
//! is not an absolute path), and several libraries in our process (Mesa's
//! Vulkan device-select layer, wgpu's EGL backend, winit) merely *probe*
//! for a Wayland display and go on without one.
//!
//! Takes: the environment. Gives: [`quiet_wayland_probes`], which replaces
//! libwayland-client's log handler once, before any of those libraries
//! runs: the handler drops exactly that message ([`dropped`]) and forwards
//! every other Wayland log line to stderr as "octolod: wayland: …".
//!
//! Invariants:
//! * It changes nothing but which lines are printed, and only when no
//!   Wayland session can exist (`XDG_RUNTIME_DIR` unset or relative): in a
//!   desktop session nothing is installed and winit's handler stays in charge.
//! * libwayland's handler is one global per loaded library; every later user
//!   (a `DT_NEEDED` dependency of the Vulkan layer or of libEGL, wgpu's and
//!   winit's `dlopen`s) gets the same, already loaded, instance by its soname.
//! * The handler's C signature is `void (const char *fmt, va_list ap)`. On
//!   x86_64 and aarch64 Linux a `va_list` argument is passed as a pointer
//!   (x86_64: an array type, decayed; aarch64: a 32-byte struct, passed by
//!   reference), so the handler takes it as an opaque pointer and hands it
//!   on to `vsnprintf` unchanged. Other targets get no handler.
//!
//! Which libraries probe, and why not environment variables:
//! `docs/viewer.md`, "The Wayland message".

/// Whether libwayland's log line with this format string is dropped: the
/// "no runtime directory" probe failure ("error: XDG_RUNTIME_DIR is invalid
/// or not set in the environment.", or before libwayland 1.20 "error:
/// XDG_RUNTIME_DIR not set in the environment.").
pub fn dropped(fmt: &[u8]) -> bool {
    fmt.starts_with(b"error: XDG_RUNTIME_DIR ") && fmt.ends_with(b" set in the environment.\n")
}

/// The stderr line for a forwarded libwayland log message.
pub fn forwarded_line(msg: &[u8]) -> Vec<u8> {
    let mut line = b"octolod: wayland: ".to_vec();
    line.extend_from_slice(msg);
    if !line.ends_with(b"\n") {
        line.push(b'\n');
    }
    line
}

/// Whether this process cannot reach a Wayland session by the runtime
/// directory (so a probe would print the message [`dropped`] drops).
fn no_runtime_dir() -> bool {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        None => true,
        Some(d) => !std::path::Path::new(&d).is_absolute(),
    }
}

/// Installs the filtering log handler in libwayland-client (see [`self`])
/// when `XDG_RUNTIME_DIR` is unset or relative and the
/// library exists. Call it at the start of `view` and `render`, before any
/// wgpu or winit call. Returns whether a handler is installed (also by an
/// earlier call).
pub fn quiet_wayland_probes() -> bool {
    static DONE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *DONE.get_or_init(|| no_runtime_dir() && imp::install())
}

fn forward(msg: &[u8]) {
    use std::io::Write;
    let line = forwarded_line(msg);
    #[cfg(test)]
    tests::CAPTURED.lock().unwrap_or_else(|e| e.into_inner()).push(String::from_utf8_lossy(&line).into_owned());
    // One write per line; a closed or failing stderr is not worth a panic
    // inside a C callback.
    let _ = std::io::stderr().lock().write_all(&line);
}

#[cfg(all(target_os = "linux", any(target_arch = "x86_64", target_arch = "aarch64")))]
mod imp {
    use std::ffi::{c_char, c_int, c_void, CStr};

    /// `wl_log_func_t`: `void (*)(const char *fmt, va_list ap)`, the
    /// `va_list` as the pointer it is at this ABI.
    type LogFn = unsafe extern "C" fn(*const c_char, *mut c_void);

    extern "C" {
        fn vsnprintf(buf: *mut c_char, size: usize, fmt: *const c_char, ap: *mut c_void) -> c_int;
    }

    unsafe extern "C" fn handler(fmt: *const c_char, ap: *mut c_void) {
        if fmt.is_null() {
            return;
        }
        // SAFETY: libwayland passes a NUL-terminated format string.
        if super::dropped(unsafe { CStr::from_ptr(fmt) }.to_bytes()) {
            return;
        }
        let mut buf = [0u8; 1024];
        // SAFETY: `fmt` and `ap` come together from libwayland's wl_log;
        // vsnprintf writes at most `buf.len()` bytes, NUL included.
        let n = unsafe { vsnprintf(buf.as_mut_ptr().cast(), buf.len(), fmt, ap) };
        if n < 0 {
            return;
        }
        // Longer messages are cut at the buffer (the va_list is spent).
        super::forward(&buf[..(n as usize).min(buf.len() - 1)]);
    }

    pub fn install() -> bool {
        // SAFETY: plain dlopen/dlsym; the library stays loaded for the
        // process's life (no dlclose), so the handler stays where every
        // later user of libwayland-client finds it.
        unsafe {
            let lib = libc::dlopen(c"libwayland-client.so.0".as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL);
            if lib.is_null() {
                return false;
            }
            let sym = libc::dlsym(lib, c"wl_log_set_handler_client".as_ptr());
            if sym.is_null() {
                return false;
            }
            let set: unsafe extern "C" fn(LogFn) = std::mem::transmute::<*mut c_void, unsafe extern "C" fn(LogFn)>(sym);
            set(handler);
        }
        true
    }
}

#[cfg(not(all(target_os = "linux", any(target_arch = "x86_64", target_arch = "aarch64"))))]
mod imp {
    pub fn install() -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines the handler forwarded (tests only).
    pub(super) static CAPTURED: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

    #[test]
    fn drops_only_the_runtime_dir_message() {
        assert!(dropped(b"error: XDG_RUNTIME_DIR is invalid or not set in the environment.\n"));
        assert!(dropped(b"error: XDG_RUNTIME_DIR not set in the environment.\n"));
        assert!(!dropped(b"error: socket path \"%s\" plus null terminator exceeds %i bytes\n"));
        assert!(!dropped(b"error: XDG_RUNTIME_DIR is invalid or not set in the environment.\nmore\n"));
        assert!(!dropped(b"warning: queue %p destroyed while proxies still attached:\n"));
        assert_eq!(forwarded_line(b"error: x\n"), b"octolod: wayland: error: x\n");
        assert_eq!(forwarded_line(b"no newline"), b"octolod: wayland: no newline\n");
    }

    /// The handler in the real libwayland-client: a message with `%s` and
    /// `%i` arguments comes out formatted (the va_list passes through) and
    /// prefixed. An absolute socket name longer than a socket path makes
    /// `wl_display_connect` log one without needing any environment.
    #[cfg(all(target_os = "linux", any(target_arch = "x86_64", target_arch = "aarch64")))]
    #[test]
    fn forwards_other_wayland_messages_formatted() {
        use std::ffi::{c_char, c_void, CString};
        // SAFETY: dlopen/dlsym of a system library; wl_display_connect
        // with a name it cannot connect to returns NULL.
        unsafe {
            let lib = libc::dlopen(c"libwayland-client.so.0".as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL);
            if lib.is_null() {
                eprintln!("libwayland-client.so.0 is not installed: nothing to test");
                return;
            }
            assert!(imp::install());
            let connect = libc::dlsym(lib, c"wl_display_connect".as_ptr());
            assert!(!connect.is_null());
            let connect: unsafe extern "C" fn(*const c_char) -> *mut c_void = std::mem::transmute(connect);
            let name = format!("/octolod-test-{}", "x".repeat(150));
            let cname = CString::new(name.clone()).unwrap();
            assert!(connect(cname.as_ptr()).is_null());
            let got = CAPTURED.lock().unwrap().clone();
            if got.is_empty() {
                // libwayland before 1.20 joins even absolute names to the
                // runtime directory; without one it logs only the
                // message the handler drops.
                assert!(no_runtime_dir(), "libwayland logged nothing");
                return;
            }
            let line = got.iter().find(|l| l.contains("exceeds")).unwrap_or_else(|| panic!("{got:?}"));
            assert!(line.starts_with("octolod: wayland: error: socket path \""), "{line}");
            assert!(line.contains(&name) && line.contains("exceeds 108 bytes") && line.ends_with('\n'), "{line}");
        }
    }
}
