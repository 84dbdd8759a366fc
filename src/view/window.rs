//! `octolod view`: the interactive window.
//!
//! Takes: a store and [`WindowOptions`]. Gives: a winit window redrawn
//! continuously; each frame runs the viewer core ([`Viewer::frame`]: poll
//! loads, upload within the per-frame byte limit, select the cut, request
//! loads), draws [`Viewer::draw_list`] with the [`Renderer`], and shows the
//! statistics overlay. Nothing in a frame waits on disk.
//!
//! Navigation (speeds scale with the model's size):
//! * examine (1): left-drag orbits around the target, right-drag or
//!   shift+left-drag pans, the wheel dollies towards the target;
//! * fly (2): WASD moves, Q/E down/up, left-drag looks around, the wheel
//!   changes the speed, shift moves 5x faster;
//! * walk (3): fly with forward/sideways motion kept perpendicular to the up
//!   axis (Q/E still change height explicitly);
//! * Tab cycles the modes; R resets the view, F frames everything from the
//!   current direction; Z toggles wireframe; T toggles the textures (when
//!   the store has any; every material's at once) and the shaded view; + / - or ] / [ change the field
//!   of view; F1 or H toggles the overlay; V toggles vsync; U cycles the up
//!   axis (+Z, +Y, +X; the start is `--up`, by default guessed: Y up, or
//!   the thin axis of a height field, see [`super::camera::guess_up`]);
//!   Esc quits.
//!
//! Mouse look is drag-to-look (no pointer grab), so the window behaves the
//! same under X11, Wayland and remote desktops.

use super::camera::{Camera, Up};
use super::gpu::{GpuMesh, Renderer, RendererOptions};
use super::headless::draw_params;
use super::overlay::{overlay_text, OverlayImage};
use super::viewer::{FrameStats, ViewOptions, Viewer};
use crate::error::{Error, Result};
use crate::mesh::Aabb;
use glam::DVec3;
use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

/// Settings of `octolod view`.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    pub store: PathBuf,
    pub view: ViewOptions,
    pub width: u32,
    pub height: u32,
    /// Present with vsync (else the lowest-latency mode available).
    pub vsync: bool,
    /// No statistics line on stderr.
    pub quiet: bool,
    /// The model's up axis (given or guessed from the bounds).
    pub up: Up,
    pub fov_deg: f64,
    pub wireframe: bool,
    /// Show the store's textures (if it has any, each face with its own;
    /// T toggles all of them). Off: no texture is even loaded, and their
    /// bytes stay free for nodes.
    pub texture: bool,
    /// Show the statistics overlay at start.
    pub overlay: bool,
    /// Quit after this many frames (scripted runs).
    pub max_frames: Option<u64>,
}

/// Navigation mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Examine,
    Fly,
    Walk,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Mode::Examine => "examine",
            Mode::Fly => "fly",
            Mode::Walk => "walk",
        }
    }
    fn next(self) -> Mode {
        match self {
            Mode::Examine => Mode::Fly,
            Mode::Fly => Mode::Walk,
            Mode::Walk => Mode::Examine,
        }
    }
}

/// Opens the store and runs the window until it is closed (or Esc).
pub fn run_window(opts: WindowOptions) -> Result<()> {
    let mut view = opts.view.clone();
    let store = crate::store::Store::open(&opts.store)?;
    let textures = super::texture::prepare(&store, &mut view, opts.texture)?;
    let viewer: Viewer<GpuMesh> = Viewer::with_store(store, view)?;
    let event_loop =
        EventLoop::new().map_err(|e| Error::Usage(format!("cannot open a window ({e}); without a display use `octolod render` to render offscreen")))?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App::new(opts, viewer);
    app.textures = textures;
    event_loop.run_app(&mut app).map_err(|e| Error::Usage(format!("window event loop failed: {e}")))?;
    match app.error.take() {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// Frames-per-second over a sliding one-second window, and the once-a-second log.
struct FpsCounter {
    since: Instant,
    frames: u32,
    fps: f64,
}

impl FpsCounter {
    /// Counts a frame; true when a new one-second figure is ready.
    fn tick(&mut self, now: Instant) -> bool {
        self.frames += 1;
        let dt = now - self.since;
        if dt >= Duration::from_secs(1) {
            self.fps = self.frames as f64 / dt.as_secs_f64();
            self.frames = 0;
            self.since = now;
            true
        } else {
            false
        }
    }
}

/// What a key asks the window to do besides moving the camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    None,
    Quit,
    ToggleWireframe,
    ToggleOverlay,
    ToggleVsync,
    ToggleTexture,
}

/// Camera navigation state, independent of the window system: keys held,
/// mouse buttons and the mode turn input into camera motion.
#[derive(Clone, Debug)]
pub struct Navigator {
    pub cam: Camera,
    pub mode: Mode,
    pub up: DVec3,
    pub fov_deg: f64,
    bounds: Aabb,
    /// Scene diagonal: the unit of all speeds.
    size: f64,
    /// Fly/walk speed in world units per second.
    pub speed: f64,
    keys: HashSet<KeyCode>,
    left: bool,
    right: bool,
    shift: bool,
    cursor: Option<(f64, f64)>,
}

impl Navigator {
    pub fn new(bounds: Aabb, up: DVec3, fov_deg: f64) -> Navigator {
        let size = bounds.diagonal().max(1e-9);
        let mut n = Navigator {
            cam: Camera::look_at(DVec3::ZERO, DVec3::ONE, up, fov_deg),
            mode: Mode::Examine,
            up,
            fov_deg,
            bounds,
            size,
            speed: 0.0,
            keys: HashSet::new(),
            left: false,
            right: false,
            shift: false,
            cursor: None,
        };
        n.reset_view();
        n
    }

    /// Frames the whole model from the default direction (along a diagonal,
    /// looking slightly down); default speed.
    pub fn reset_view(&mut self) {
        let c = if self.bounds.is_empty() { DVec3::ZERO } else { super::camera::dvec(self.bounds.center()) };
        // Eye == target makes the camera pick its default direction.
        self.cam = Camera::look_at(c, c, self.up, self.fov_deg);
        self.cam.reframe(&self.bounds);
        self.speed = 0.25 * self.size;
    }

    /// A key went down (`pressed`) or up.
    pub fn key(&mut self, code: KeyCode, pressed: bool, repeat: bool) -> Action {
        if !pressed {
            self.keys.remove(&code);
            return Action::None;
        }
        self.keys.insert(code);
        match code {
            KeyCode::Escape => return Action::Quit,
            KeyCode::Digit1 | KeyCode::Numpad1 => self.mode = Mode::Examine,
            KeyCode::Digit2 | KeyCode::Numpad2 => self.mode = Mode::Fly,
            KeyCode::Digit3 | KeyCode::Numpad3 => self.mode = Mode::Walk,
            KeyCode::Tab if !repeat => self.mode = self.mode.next(),
            KeyCode::KeyR if !repeat => self.reset_view(),
            KeyCode::KeyF if !repeat => self.cam.reframe(&self.bounds),
            KeyCode::KeyZ if !repeat => return Action::ToggleWireframe,
            KeyCode::F1 | KeyCode::KeyH if !repeat => return Action::ToggleOverlay,
            KeyCode::KeyV if !repeat => return Action::ToggleVsync,
            KeyCode::KeyT if !repeat => return Action::ToggleTexture,
            KeyCode::KeyU if !repeat => {
                self.up = if self.up == DVec3::Z {
                    DVec3::Y
                } else if self.up == DVec3::Y {
                    DVec3::X
                } else {
                    DVec3::Z
                };
                self.reset_view();
            }
            KeyCode::Equal | KeyCode::NumpadAdd | KeyCode::BracketRight => self.set_fov(self.fov_deg + 5.0),
            KeyCode::Minus | KeyCode::NumpadSubtract | KeyCode::BracketLeft => self.set_fov(self.fov_deg - 5.0),
            _ => {}
        }
        Action::None
    }

    pub fn set_fov(&mut self, deg: f64) {
        self.fov_deg = deg.clamp(10.0, 120.0);
        self.cam.fov_y = self.fov_deg.to_radians();
    }

    pub fn set_shift(&mut self, shift: bool) {
        self.shift = shift;
    }

    pub fn button(&mut self, left: bool, down: bool) {
        if left {
            self.left = down;
        } else {
            self.right = down;
        }
    }

    /// Focus lost: releases of keys and buttons will not arrive.
    pub fn release_all(&mut self) {
        self.keys.clear();
        self.left = false;
        self.right = false;
        self.cursor = None;
    }

    pub fn cursor_left(&mut self) {
        self.cursor = None;
    }

    /// The cursor moved to (`x`, `y`) in a viewport `height` pixels high.
    pub fn mouse_moved(&mut self, x: f64, y: f64, height: f64) {
        let prev = self.cursor.replace((x, y));
        let Some((px, py)) = prev else { return };
        let (dx, dy) = (x - px, y - py);
        if dx == 0.0 && dy == 0.0 {
            return;
        }
        if self.right || (self.left && self.shift) {
            // A pixel of motion moves the scene a pixel at the target's distance.
            let k = 2.0 * (0.5 * self.cam.fov_y).tan() / height.max(1.0);
            self.cam.pan(dx * k, dy * k);
        } else if self.left {
            match self.mode {
                Mode::Examine => self.cam.orbit(dx * 0.005, dy * 0.005),
                Mode::Fly | Mode::Walk => self.cam.turn(dx * 0.003, -dy * 0.003),
            }
        }
    }

    /// Wheel by `lines` notches (positive: away from the user).
    pub fn wheel(&mut self, lines: f64) {
        match self.mode {
            Mode::Examine => self.cam.dolly(0.9f64.powf(lines)),
            Mode::Fly | Mode::Walk => self.speed = (self.speed * 1.2f64.powf(lines)).clamp(1e-4 * self.size, 10.0 * self.size),
        }
    }

    /// Moves the camera by the keys held for `dt` seconds; true if it moved.
    pub fn integrate(&mut self, dt: f64) -> bool {
        let k = |c: KeyCode| self.keys.contains(&c) as i32 as f64;
        let x = k(KeyCode::KeyD) - k(KeyCode::KeyA) + k(KeyCode::ArrowRight) - k(KeyCode::ArrowLeft);
        let z = k(KeyCode::KeyW) - k(KeyCode::KeyS) + k(KeyCode::ArrowUp) - k(KeyCode::ArrowDown);
        let y = k(KeyCode::KeyE) - k(KeyCode::KeyQ);
        if x == 0.0 && y == 0.0 && z == 0.0 {
            return false;
        }
        let fast = if self.shift { 5.0 } else { 1.0 };
        let step = DVec3::new(x, y, z) * self.speed * fast * dt;
        match self.mode {
            Mode::Examine | Mode::Fly => self.cam.fly(step),
            Mode::Walk => self.cam.walk(step),
        }
        true
    }

    /// The camera for this frame, with clip planes fitted to the model.
    pub fn camera(&mut self) -> Camera {
        self.cam.fit_clip(&self.bounds);
        self.cam
    }
}

struct App {
    opts: WindowOptions,
    viewer: Viewer<GpuMesh>,
    window: Option<Arc<Window>>,
    renderer: Option<Renderer>,
    error: Option<Error>,
    nav: Navigator,
    wireframe: bool,
    /// The textures, until the renderer takes them.
    textures: super::texture::TextureSet,
    /// Draw with the textures (when the renderer has any).
    textured: bool,
    show_overlay: bool,
    last_frame: Instant,
    fps: FpsCounter,
    stats: FrameStats,
    overlay: Option<OverlayImage>,
    overlay_lines: Vec<String>,
    overlay_at: Instant,
    frames: u64,
    /// Load-failure messages already written to the log.
    failures_logged: usize,
}

impl App {
    fn new(opts: WindowOptions, viewer: Viewer<GpuMesh>) -> App {
        let now = Instant::now();
        App {
            nav: Navigator::new(viewer.bounds(), opts.up.resolve(&viewer.bounds()), opts.fov_deg),
            wireframe: opts.wireframe,
            textures: Default::default(),
            textured: opts.texture,
            show_overlay: opts.overlay,
            opts,
            viewer,
            window: None,
            renderer: None,
            error: None,
            last_frame: now,
            fps: FpsCounter { since: now, frames: 0, fps: 0.0 },
            stats: FrameStats::default(),
            overlay: None,
            overlay_lines: Vec::new(),
            overlay_at: now - Duration::from_secs(1),
            frames: 0,
            failures_logged: 0,
        }
    }

    fn fail(&mut self, event_loop: &ActiveEventLoop, e: Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        event_loop.exit();
    }

    fn key(&mut self, event_loop: &ActiveEventLoop, code: KeyCode, pressed: bool, repeat: bool) {
        match self.nav.key(code, pressed, repeat) {
            Action::None => {}
            Action::Quit => event_loop.exit(),
            Action::ToggleWireframe => self.wireframe = !self.wireframe,
            Action::ToggleTexture => self.textured = !self.textured,
            Action::ToggleOverlay => self.show_overlay = !self.show_overlay,
            Action::ToggleVsync => {
                if let Some(r) = &mut self.renderer {
                    let v = !r.vsync();
                    r.set_vsync(v);
                }
            }
        }
    }

    fn redraw(&mut self, event_loop: &ActiveEventLoop) {
        let now = Instant::now();
        // Real-time motion even at low frame rates, without leaps after a stall.
        let dt = (now - self.last_frame).as_secs_f64().min(0.5);
        self.last_frame = now;
        self.nav.integrate(dt);
        let cam = self.nav.camera();
        let Some(renderer) = self.renderer.as_mut() else { return };
        let (w, h) = renderer.size();
        let mut stats = self.viewer.frame(&cam, (w, h), &mut |m| renderer.upload(m));
        let mut p = draw_params(&cam, self.viewer.origin(), w, h, self.wireframe);
        p.textured = self.textured;
        let t = Instant::now();
        let list = self.viewer.draw_list();
        let overlay = if self.show_overlay { self.overlay.as_ref() } else { None };
        if let Err(e) = renderer.render_to_surface(&p, &list, overlay) {
            return self.fail(event_loop, e);
        }
        stats.draw_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats = stats;
        self.frames += 1;
        self.log_load_failures();
        if self.fps.tick(Instant::now()) {
            if let Some(win) = &self.window {
                win.set_title(&self.title());
            }
            if !self.opts.quiet {
                eprintln!("{}", self.log_line());
            }
        }
        if self.show_overlay && (now - self.overlay_at >= Duration::from_millis(250) || self.overlay.is_none()) {
            self.overlay_at = now;
            let lines = self.overlay_lines();
            if lines != self.overlay_lines {
                self.overlay = Some(overlay_text(&lines));
                self.overlay_lines = lines;
            }
        }
        if self.opts.max_frames.is_some_and(|n| self.frames >= n) {
            event_loop.exit();
        }
    }

    /// A node that failed to load is an error whatever `--quiet` says: its
    /// message goes to the log once (the first 16; the overlay counts all).
    fn log_load_failures(&mut self) {
        let (_, msgs) = self.viewer.load_failures();
        for m in &msgs[self.failures_logged.min(msgs.len())..] {
            eprintln!("octolod: error: view: node load failed: {m}");
        }
        self.failures_logged = msgs.len();
    }

    fn title(&self) -> String {
        let name = self.opts.store.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        format!("octolod view — {name} — {} — {:.1} fps", self.nav.mode.name(), self.fps.fps)
    }

    fn overlay_lines(&self) -> Vec<String> {
        let mut lines = self.stats.overlay_lines(self.fps.fps);
        let (vsync, adapter) = match &self.renderer {
            Some(r) => {
                let i = r.adapter_info();
                (r.vsync(), format!("{} ({:?})", i.name, i.backend))
            }
            None => (false, String::new()),
        };
        lines.push(format!(
            "{} mode  up {}  fov {:.0}  {}{}  {}",
            self.nav.mode.name(),
            self.up_text(),
            self.nav.fov_deg,
            match (self.wireframe, self.textured && self.renderer.as_ref().is_some_and(|r| r.has_texture())) {
                (true, _) => "wireframe",
                (false, true) => "textured",
                (false, false) => "shaded",
            },
            if vsync { "  vsync" } else { "" },
            adapter
        ));
        lines.push("1/2/3 Tab: mode  R: reset  F: frame  Z: wire  T: texture  +/-: fov  H: hide  Esc: quit".into());
        lines
    }

    /// The up axis in use: the option's (`+y (auto)`) until U changes it.
    fn up_text(&self) -> String {
        let b = self.viewer.bounds();
        if self.nav.up == self.opts.up.resolve(&b) {
            self.opts.up.describe(&b)
        } else {
            super::camera::axis_name(self.nav.up)
        }
    }

    fn log_line(&self) -> String {
        let s = &self.stats;
        let mb = |b: u64| b as f64 / (1u64 << 20) as f64;
        let lv: Vec<String> = s.nodes_per_level.iter().enumerate().filter(|(_, &n)| n > 0).map(|(l, n)| format!("L{l}:{n}")).collect();
        format!(
            "view: {:.1} fps  select {:.2} ms  upload {:.2} ms  draw {:.2} ms  {} tris  {} nodes [{}]  resident {:.1}/{:.1} MB  pending {}  hit {:.1}%  {}",
            self.fps.fps,
            s.select_ms,
            s.upload_ms,
            s.draw_ms,
            s.triangles,
            s.nodes,
            lv.join(" "),
            mb(s.resident_bytes),
            mb(s.budget_bytes),
            s.pending_loads,
            100.0 * s.hit_rate,
            self.nav.mode.name()
        )
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let attrs = Window::default_attributes().with_title("octolod view").with_inner_size(winit::dpi::PhysicalSize::new(self.opts.width, self.opts.height));
        let window = match event_loop.create_window(attrs) {
            Ok(w) => Arc::new(w),
            Err(e) => return self.fail(event_loop, Error::Usage(format!("cannot create a window: {e}"))),
        };
        let opts = RendererOptions { vsync: self.opts.vsync, ..Default::default() };
        match Renderer::for_window_with(window.clone(), opts) {
            Ok(mut r) => {
                let textures = std::mem::take(&mut self.textures);
                if !textures.is_empty() {
                    if let Err(e) = r.set_textures(textures.slots.iter().map(Option::as_ref), self.viewer.store.payload_layout.attrs.color()) {
                        return self.fail(event_loop, e);
                    }
                }
                if !self.opts.quiet {
                    let i = r.adapter_info();
                    eprintln!(
                        "view: {} ({:?}, {:?}), {:?}, present {:?}, wireframe by {:?}; up {} (U cycles)",
                        i.name,
                        i.backend,
                        i.device_type,
                        r.format(),
                        r.present_mode(),
                        r.wireframe_mode(),
                        self.up_text()
                    );
                }
                self.renderer = Some(r);
            }
            Err(e) => return self.fail(event_loop, e),
        }
        window.request_redraw();
        self.window = Some(window);
        self.last_frame = Instant::now();
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested | WindowEvent::Destroyed => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(r) = &mut self.renderer {
                    r.resize(size.width, size.height);
                }
            }
            WindowEvent::RedrawRequested => self.redraw(event_loop),
            WindowEvent::KeyboardInput { event, .. } => {
                if let PhysicalKey::Code(code) = event.physical_key {
                    self.key(event_loop, code, event.state == ElementState::Pressed, event.repeat);
                }
            }
            WindowEvent::ModifiersChanged(m) => self.nav.set_shift(m.state().shift_key()),
            WindowEvent::MouseInput { state, button, .. } => {
                let down = state == ElementState::Pressed;
                match button {
                    MouseButton::Left => self.nav.button(true, down),
                    MouseButton::Right | MouseButton::Middle => self.nav.button(false, down),
                    _ => {}
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let h = self.renderer.as_ref().map_or(self.opts.height, |r| r.size().1) as f64;
                self.nav.mouse_moved(position.x, position.y, h);
            }
            WindowEvent::CursorLeft { .. } => self.nav.cursor_left(),
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.nav.wheel(lines);
            }
            // Keys released while unfocused never arrive.
            WindowEvent::Focused(false) => self.nav.release_all(),
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        // A signal closes the window between frames (io::signal).
        if let Err(e) = crate::io::signal::check() {
            self.error.get_or_insert(e);
            event_loop.exit();
            return;
        }
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nav() -> Navigator {
        Navigator::new(Aabb { min: [0.0, 0.0, 0.0], max: [10.0, 10.0, 2.0] }, DVec3::Z, 50.0)
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-9 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn examine_orbits_around_the_target_pans_and_dollies() {
        let mut n = nav();
        let t0 = n.cam.target;
        let r0 = (n.cam.eye - t0).length();
        n.button(true, true);
        n.mouse_moved(100.0, 100.0, 800.0);
        n.mouse_moved(160.0, 90.0, 800.0);
        assert_eq!(n.cam.target, t0);
        assert!(close((n.cam.eye - t0).length(), r0));
        n.button(true, false);
        // Right-drag pans eye and target together.
        let d0 = n.cam.eye - n.cam.target;
        n.button(false, true);
        n.mouse_moved(300.0, 300.0, 800.0);
        assert_ne!(n.cam.target, t0);
        assert!((n.cam.eye - n.cam.target - d0).length() < 1e-9 * r0);
        n.button(false, false);
        // Wheel forward brings the eye closer.
        let r1 = (n.cam.eye - n.cam.target).length();
        n.wheel(2.0);
        assert!(close((n.cam.eye - n.cam.target).length(), r1 * 0.81));
    }

    #[test]
    fn fly_moves_at_a_speed_scaled_to_the_model_and_walk_keeps_height() {
        let mut n = nav();
        assert_eq!(n.key(KeyCode::Digit2, true, false), Action::None);
        assert_eq!(n.mode, Mode::Fly);
        let e0 = n.cam.eye;
        let f = n.cam.forward();
        n.key(KeyCode::KeyW, true, false);
        assert!(n.integrate(0.5));
        let moved = n.cam.eye - e0;
        assert!(close(moved.length(), 0.5 * n.speed));
        assert!(moved.normalize().dot(f) > 0.999);
        assert!(close(n.speed, 0.25 * (204f64).sqrt()));
        n.key(KeyCode::KeyW, false, false);
        assert!(!n.integrate(0.5));
        // Walk: the camera looks down, yet W keeps the height along +Z.
        n.key(KeyCode::Digit3, true, false);
        assert!(n.cam.forward().z < -0.1);
        let z0 = n.cam.eye.z;
        n.key(KeyCode::KeyW, true, false);
        n.key(KeyCode::KeyD, true, false);
        n.integrate(0.3);
        assert!(close(n.cam.eye.z, z0));
        n.key(KeyCode::KeyW, false, false);
        n.key(KeyCode::KeyD, false, false);
        // E rises along the up axis; shift is 5x faster.
        n.set_shift(true);
        n.key(KeyCode::KeyE, true, false);
        n.integrate(0.1);
        assert!(close(n.cam.eye.z - z0, 0.5 * n.speed));
        // Wheel in fly/walk changes speed, not position.
        let (s, e) = (n.speed, n.cam.eye);
        n.wheel(1.0);
        assert!(close(n.speed, 1.2 * s));
        assert_eq!(n.cam.eye, e);
    }

    #[test]
    fn keys_switch_modes_fov_and_reset() {
        let mut n = nav();
        let home = n.cam;
        // The default view looks down onto the model.
        assert!(home.forward().dot(DVec3::Z) < -0.2);
        n.key(KeyCode::Tab, true, false);
        assert_eq!(n.mode, Mode::Fly);
        n.key(KeyCode::Tab, false, false);
        n.key(KeyCode::Tab, true, false);
        assert_eq!(n.mode, Mode::Walk);
        n.key(KeyCode::Digit1, true, false);
        assert_eq!(n.mode, Mode::Examine);
        n.key(KeyCode::Equal, true, false);
        assert!(close(n.fov_deg, 55.0));
        for _ in 0..30 {
            n.key(KeyCode::BracketLeft, true, true);
        }
        assert!(close(n.fov_deg, 10.0));
        assert!(close(n.cam.fov_y, 10f64.to_radians()));
        assert_eq!(n.key(KeyCode::KeyZ, true, false), Action::ToggleWireframe);
        assert_eq!(n.key(KeyCode::KeyT, true, false), Action::ToggleTexture);
        assert_eq!(n.key(KeyCode::F1, true, false), Action::ToggleOverlay);
        assert_eq!(n.key(KeyCode::KeyH, true, false), Action::ToggleOverlay);
        assert_eq!(n.key(KeyCode::Escape, true, false), Action::Quit);
        n.set_fov(50.0);
        n.wheel(5.0);
        n.key(KeyCode::KeyR, true, false);
        assert_eq!(n.cam, home);
        // F frames from the current direction: the target is the centre again.
        n.cam.pan(3.0, 1.0);
        n.key(KeyCode::KeyF, true, false);
        assert!((n.cam.target - DVec3::new(5.0, 5.0, 1.0)).length() < 1e-9);
        // The clip planes enclose the model.
        let c = n.camera();
        assert!(c.near > 0.0 && c.far > (c.eye - DVec3::new(5.0, 5.0, 1.0)).length());
    }

    #[test]
    fn modes_cycle() {
        assert_eq!(Mode::Examine.next().next().next(), Mode::Examine);
        assert_eq!(Mode::Fly.name(), "fly");
    }
}
