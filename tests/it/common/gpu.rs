//! Rendering on a real adapter (Mesa lavapipe in CI). A missing adapter
//! fails the test, so a missing driver cannot pass for working rendering;
//! OCTOLOD_SKIP_GPU_TESTS=1 skips the GPU tests explicitly.

use octolod::view::gpu::{Renderer, RendererOptions};
use std::process::Command;

/// An offscreen renderer of `w` x `h` with `opts`, as `view` and `render`
/// make one (libwayland's "XDG_RUNTIME_DIR" probe line quieted first);
/// `None` (skip) only when there is no adapter and
/// OCTOLOD_SKIP_GPU_TESTS=1.
pub fn renderer(w: u32, h: u32, opts: RendererOptions) -> Option<Renderer> {
    octolod::view::quiet::quiet_wayland_probes();
    match Renderer::headless_with(w, h, opts) {
        Ok(r) => Some(r),
        Err(e) if super::gpu_tests_skipped() => {
            eprintln!("({e})");
            None
        }
        Err(e) => panic!("{e} (set OCTOLOD_SKIP_GPU_TESTS=1 to skip GPU tests)"),
    }
}

/// What tells a process it runs in a desktop session (and the backend
/// choice): [`without_desktop_session`] removes them.
pub const DESKTOP_SESSION_VARS: [&str; 6] =
    ["XDG_RUNTIME_DIR", "WAYLAND_DISPLAY", "WAYLAND_SOCKET", "NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT", "WGPU_BACKEND"];

/// `cmd` as on a headless machine: no desktop session variables, on wgpu's
/// default backends or (`backend` "gl") on GL only.
pub fn without_desktop_session(cmd: &mut Command, backend: &str) {
    for v in DESKTOP_SESSION_VARS {
        cmd.env_remove(v);
    }
    if backend == "gl" {
        cmd.env("WGPU_BACKEND", "gl");
    }
}
