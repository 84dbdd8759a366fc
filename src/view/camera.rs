//! Camera, view frustum and projected-error maths for the viewer.
//!
//! Takes: an eye, a target, an up axis and a field of view, in world
//! coordinates (f64). Gives: the f32 view-projection matrix for vertices
//! stored relative to the store's origin (so data 1e6 from the world origin
//! renders without f32 jitter), the world-space frustum used for culling,
//! and the pixels-per-unit factor that turns an object-space error into a
//! projected error in pixels. Navigation helpers (orbit, pan, dolly, fly,
//! walk) move the camera; camera paths for `octolod render` are parsed here.

use crate::error::{Error, IoContext, Result};
use crate::mesh::Aabb;
use glam::{DMat4, DVec3, DVec4, Mat4};
use std::path::Path;

/// A perspective camera looking from `eye` at `target`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: DVec3,
    pub target: DVec3,
    /// World up axis (unit); walking keeps the eye's height along it.
    pub up: DVec3,
    /// Vertical field of view in radians.
    pub fov_y: f64,
    pub near: f64,
    pub far: f64,
}

pub fn dvec(a: [f64; 3]) -> DVec3 {
    DVec3::new(a[0], a[1], a[2])
}

/// The model's up axis: given (`--up x|y|z|-x|-y|-z`) or guessed from its
/// bounds (`--up auto`, the default; see [`guess_up`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Up {
    Auto,
    Axis(DVec3),
}

impl Up {
    /// `auto`, or `x`, `y`, `z` with an optional sign.
    pub fn parse(s: &str) -> Result<Up> {
        let t = s.trim().to_ascii_lowercase();
        if t == "auto" {
            return Ok(Up::Auto);
        }
        let (neg, axis) = match t.strip_prefix('-') {
            Some(a) => (true, a),
            None => (false, t.strip_prefix('+').unwrap_or(&t)),
        };
        let v = match axis {
            "x" => DVec3::X,
            "y" => DVec3::Y,
            "z" => DVec3::Z,
            _ => return Err(Error::Usage(format!("--up must be auto, x, y, z, -x, -y or -z, not {s:?}"))),
        };
        Ok(Up::Axis(if neg { -v } else { v }))
    }

    /// The axis for a model with these bounds.
    pub fn resolve(self, b: &Aabb) -> DVec3 {
        match self {
            Up::Auto => guess_up(b),
            Up::Axis(v) => v,
        }
    }

    /// How the axis was chosen, for statistics lines: `+y (auto)`.
    pub fn describe(self, b: &Aabb) -> String {
        let name = axis_name(self.resolve(b));
        match self {
            Up::Auto => format!("{name} (auto)"),
            Up::Axis(_) => name,
        }
    }
}

/// The usual convention for scans and models (Stanford, MeshLab, most
/// scanners and DCC tools) is Y up, so that is the guess — except for
/// height fields (terrain, a city block, a floor), whose thin extent is
/// unmistakable: when one side of the bounds is under a quarter of both
/// others, that axis is up (+). A near-cube (a sphere, a bunny) says
/// nothing, and gets Y.
pub fn guess_up(b: &Aabb) -> DVec3 {
    if b.is_empty() {
        return DVec3::Y;
    }
    let e = dvec(b.max) - dvec(b.min);
    let k = (0..3).min_by(|&i, &j| e[i].total_cmp(&e[j])).unwrap();
    let others = (0..3).filter(|&i| i != k).map(|i| e[i]).fold(f64::INFINITY, f64::min);
    if e[k] < 0.25 * others {
        [DVec3::X, DVec3::Y, DVec3::Z][k]
    } else {
        DVec3::Y
    }
}

/// `+x`, `-y`, … for a coordinate axis; the vector otherwise.
pub fn axis_name(v: DVec3) -> String {
    for (n, a) in [("x", DVec3::X), ("y", DVec3::Y), ("z", DVec3::Z)] {
        if v == a {
            return format!("+{n}");
        }
        if v == -a {
            return format!("-{n}");
        }
    }
    format!("[{:.3}, {:.3}, {:.3}]", v.x, v.y, v.z)
}

/// Distance from `p` to the nearest point of `b` (0 inside).
pub fn box_distance(b: &Aabb, p: DVec3) -> f64 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let v = if p[k] < b.min[k] {
            b.min[k] - p[k]
        } else if p[k] > b.max[k] {
            p[k] - b.max[k]
        } else {
            0.0
        };
        d2 += v * v;
    }
    d2.sqrt()
}

fn box_farthest(b: &Aabb, p: DVec3) -> f64 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let v = (p[k] - b.min[k]).abs().max((p[k] - b.max[k]).abs());
        d2 += v * v;
    }
    d2.sqrt()
}

impl Camera {
    pub fn look_at(eye: DVec3, target: DVec3, up: DVec3, fov_y_deg: f64) -> Camera {
        let mut c = Camera { eye, target, up: up.normalize_or(DVec3::Z), fov_y: fov_y_deg.to_radians(), near: 0.01, far: 100.0 };
        if (c.target - c.eye).length_squared() == 0.0 {
            c.target = c.eye + c.default_dir();
        }
        c
    }

    fn default_dir(&self) -> DVec3 {
        // Look slightly down, along a diagonal, whatever the up axis.
        let side = if self.up.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let a = side.cross(self.up).normalize();
        (-(side + 0.6 * a) - 0.45 * self.up).normalize()
    }

    /// A camera that shows all of `b` in a 1:1 viewport.
    pub fn frame_all(b: &Aabb, up: DVec3, fov_y_deg: f64) -> Camera {
        // Equal eye and target: look_at picks the default, slightly
        // downward diagonal for this up axis.
        let mut c = Camera::look_at(DVec3::ZERO, DVec3::ZERO, up, fov_y_deg);
        c.reframe(b);
        c
    }

    /// Keeps the viewing direction and moves the eye back until `b` fits.
    pub fn reframe(&mut self, b: &Aabb) {
        let dir = {
            let d = self.target - self.eye;
            if d.length_squared() > 0.0 && d.is_finite() {
                d.normalize()
            } else {
                self.default_dir()
            }
        };
        let center = if b.is_empty() { DVec3::ZERO } else { dvec(b.center()) };
        let r = (0.5 * b.diagonal()).max(1e-9);
        let dist = r / (0.5 * self.fov_y).sin() * 1.05;
        self.target = center;
        self.eye = center - dir * dist;
        self.fit_clip(b);
    }

    /// Unit viewing direction.
    pub fn forward(&self) -> DVec3 {
        (self.target - self.eye).normalize_or(DVec3::Y)
    }
    pub fn right(&self) -> DVec3 {
        let r = self.forward().cross(self.up);
        if r.length_squared() < 1e-12 {
            self.forward().any_orthonormal_vector()
        } else {
            r.normalize()
        }
    }
    /// The camera's own up (orthogonal to the viewing direction).
    pub fn cam_up(&self) -> DVec3 {
        self.right().cross(self.forward())
    }

    /// Chooses near and far planes from the scene bounds: far beyond the
    /// farthest corner, near at the nearest point (bounded below so the
    /// depth buffer keeps ~17 bits of range).
    pub fn fit_clip(&mut self, b: &Aabb) {
        if b.is_empty() {
            return;
        }
        let far = box_farthest(b, self.eye) * 1.01 + 1e-9;
        let near = (box_distance(b, self.eye) * 0.9).max(far * 2e-5);
        self.near = near;
        self.far = far.max(near * 2.0);
    }

    fn view(&self, origin: DVec3) -> DMat4 {
        let up = if self.forward().cross(self.up).length_squared() < 1e-12 { self.cam_up() } else { self.up };
        look_at_rh(self.eye - origin, self.target - origin, up)
    }

    fn proj(&self, aspect: f64) -> DMat4 {
        perspective_rh(self.fov_y, aspect.max(1e-6), self.near, self.far)
    }

    /// View-projection for vertices given relative to `origin` (wgpu clip
    /// space, depth 0..1).
    pub fn view_proj(&self, origin: DVec3, aspect: f64) -> Mat4 {
        (self.proj(aspect) * self.view(origin)).as_mat4()
    }

    /// Eye position relative to `origin`, for lighting.
    pub fn eye_rel(&self, origin: DVec3) -> glam::Vec3 {
        (self.eye - origin).as_vec3()
    }

    /// The world-space view frustum.
    pub fn frustum(&self, aspect: f64) -> Frustum {
        let m = self.proj(aspect) * self.view(DVec3::ZERO);
        let r = [m.row(0), m.row(1), m.row(2), m.row(3)];
        // Gribb–Hartmann, wgpu depth 0..1: 0 ≤ z ≤ w.
        let planes = [r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[2], r[3] - r[2]];
        Frustum { planes: planes.map(|p| p / p.truncate().length().max(f64::MIN_POSITIVE)) }
    }

    /// Pixels covered by one world unit at distance `dist` (viewport height
    /// `height_px`): height / (2 tan(fov/2) dist).
    pub fn pixels_per_unit(&self, dist: f64, height_px: f64) -> f64 {
        height_px / (2.0 * (0.5 * self.fov_y).tan() * dist.max(self.near.max(1e-12)))
    }

    /// Orbit around the target: yaw about the up axis, pitch about the right
    /// axis (kept away from the poles).
    pub fn orbit(&mut self, yaw: f64, pitch: f64) {
        let off = self.eye - self.target;
        let r = off.length();
        let q = glam::DQuat::from_axis_angle(self.up, -yaw);
        let mut off = q * off;
        let cur = (off.normalize().dot(self.up)).clamp(-1.0, 1.0).asin();
        let new = (cur + pitch).clamp(-1.50, 1.50);
        let axis = off.cross(self.up).normalize_or(self.right());
        off = glam::DQuat::from_axis_angle(axis, new - cur) * off;
        self.eye = self.target + off.normalize() * r;
    }

    /// Moves eye and target in the view plane by fractions of the distance.
    pub fn pan(&mut self, dx: f64, dy: f64) {
        let d = (self.target - self.eye).length();
        let m = self.right() * (-dx * d) + self.cam_up() * (dy * d);
        self.eye += m;
        self.target += m;
    }

    /// Moves the eye towards the target by `factor` (< 1 closer).
    pub fn dolly(&mut self, factor: f64) {
        let off = self.eye - self.target;
        let len = (off.length() * factor).max(1e-9);
        self.eye = self.target + off.normalize_or(-self.forward()) * len;
    }

    /// Turns the view in place (fly/walk mouse look).
    pub fn turn(&mut self, yaw: f64, pitch: f64) {
        let d = self.target - self.eye;
        let r = d.length().max(1e-9);
        let mut f = glam::DQuat::from_axis_angle(self.up, -yaw) * d.normalize_or(self.forward());
        let cur = f.dot(self.up).clamp(-1.0, 1.0).asin();
        let new = (cur + pitch).clamp(-1.50, 1.50);
        let axis = f.cross(self.up).normalize_or(self.right());
        f = glam::DQuat::from_axis_angle(axis, new - cur) * f;
        self.target = self.eye + f.normalize() * r;
    }

    /// Fly: moves eye and target along (right, up, forward) of the camera.
    pub fn fly(&mut self, local: DVec3) {
        let m = self.right() * local.x + self.cam_up() * local.y + self.forward() * local.z;
        self.eye += m;
        self.target += m;
    }

    /// Walk: like fly, but forward/right stay perpendicular to the up axis
    /// and vertical motion follows the up axis.
    pub fn walk(&mut self, local: DVec3) {
        let f = self.forward();
        let flat = (f - self.up * f.dot(self.up)).normalize_or(self.cam_up());
        let right = flat.cross(self.up).normalize_or(self.right());
        let m = right * local.x + self.up * local.y + flat * local.z;
        self.eye += m;
        self.target += m;
    }
}

/// Right-handed view matrix (camera looks down −z).
fn look_at_rh(eye: DVec3, target: DVec3, up: DVec3) -> DMat4 {
    let f = (target - eye).normalize();
    let s = f.cross(up).normalize();
    let u = s.cross(f);
    DMat4::from_cols(
        DVec4::new(s.x, u.x, -f.x, 0.0),
        DVec4::new(s.y, u.y, -f.y, 0.0),
        DVec4::new(s.z, u.z, -f.z, 0.0),
        DVec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection to wgpu clip space (depth 0..1).
fn perspective_rh(fov_y: f64, aspect: f64, near: f64, far: f64) -> DMat4 {
    let h = 1.0 / (0.5 * fov_y).tan();
    let r = far / (near - far);
    DMat4::from_cols(DVec4::new(h / aspect, 0.0, 0.0, 0.0), DVec4::new(0.0, h, 0.0, 0.0), DVec4::new(0.0, 0.0, r, -1.0), DVec4::new(0.0, 0.0, r * near, 0.0))
}

/// Six inward-facing world-space planes: `n·p + d ≥ 0` inside.
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    pub planes: [DVec4; 6],
}

impl Frustum {
    /// True when the box lies entirely outside one plane (all 8 corners
    /// outside), the conservative test: a box is culled only when provably
    /// invisible.
    pub fn culls(&self, b: &Aabb) -> bool {
        if b.is_empty() {
            return true;
        }
        self.planes.iter().any(|p| {
            // The corner farthest along the plane normal.
            let c = DVec3::new(
                if p.x >= 0.0 { b.max[0] } else { b.min[0] },
                if p.y >= 0.0 { b.max[1] } else { b.min[1] },
                if p.z >= 0.0 { b.max[2] } else { b.min[2] },
            );
            p.truncate().dot(c) + p.w < 0.0
        })
    }
}

/// One camera pose of a path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub eye: DVec3,
    pub target: DVec3,
}

/// A camera path file, as read (the format is [`CameraPath`]'s doc);
/// unknown fields are ignored.
#[derive(serde::Deserialize)]
struct PathFile {
    #[serde(default = "default_fov")]
    fov_y_deg: f64,
    up: Option<[f64; 3]>,
    #[serde(default)]
    space: Space,
    frames: Option<Vec<PoseFile>>,
    keyframes: Option<Vec<PoseFile>>,
    #[serde(default = "default_between")]
    frames_between: f64,
    #[serde(default)]
    hold: f64,
}

/// One pose of a path file.
#[derive(serde::Deserialize)]
struct PoseFile {
    eye: [f64; 3],
    target: [f64; 3],
}

/// The coordinates a path file uses.
#[derive(serde::Deserialize, Default, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum Space {
    /// As in the mesh.
    #[default]
    World,
    /// 0..1 over the store's bounds on each axis.
    Bbox,
}

fn default_fov() -> f64 {
    50.0
}

fn default_between() -> f64 {
    10.0
}

/// Most frames one `octolod render` run takes, all counted: the path's
/// poses (the orbit's `--frames`, or a path file's after expansion) plus
/// `--settle` (far more than any real run needs).
pub const MAX_FRAMES: usize = 100_000;

impl PathFile {
    /// The poses the file expands to, computed without expanding them; an
    /// error naming the field when `hold`, `frames_between` or the total
    /// exceeds [`MAX_FRAMES`].
    fn pose_count(&self) -> std::result::Result<usize, String> {
        let limit = MAX_FRAMES as f64;
        if !(self.hold <= limit) {
            return Err(format!("\"hold\": {} is more than {MAX_FRAMES} frames", self.hold));
        }
        let hold = self.hold.max(0.0) as usize;
        let listed = if let Some(fr) = &self.frames {
            fr.len()
        } else if let Some(kf) = &self.keyframes {
            if !(self.frames_between <= limit) {
                return Err(format!("\"frames_between\": {} is more than {MAX_FRAMES} frames", self.frames_between));
            }
            let between = self.frames_between.max(1.0) as usize;
            kf.len().saturating_sub(1).saturating_mul(between).saturating_add(kf.len().min(1))
        } else {
            return Err("needs \"frames\" or \"keyframes\"".into());
        };
        let total = listed.saturating_add(hold);
        if total > MAX_FRAMES {
            return Err(format!(
                "the path expands to {total} frames ({listed} from \"frames\" or \"keyframes\" and \"frames_between\", {hold} of \"hold\"), more than {MAX_FRAMES}"
            ));
        }
        Ok(total)
    }
}

/// Largest camera path file read (a path of 100,000 frames is a few MB).
const MAX_PATH_FILE: u64 = 64 << 20;

/// A camera path file's text, read once (a FIFO works) and at most
/// [`MAX_PATH_FILE`] bytes (a link to /dev/zero is an error, not a hang).
fn read_path_file(path: &Path) -> Result<String> {
    use std::io::Read;
    let f = std::fs::File::open(path).ctx(path, "read camera path")?;
    let mut b = Vec::new();
    f.take(MAX_PATH_FILE + 1).read_to_end(&mut b).ctx(path, "read camera path")?;
    if b.len() as u64 > MAX_PATH_FILE {
        return Err(Error::Usage(format!("{}: a camera path over {MAX_PATH_FILE} bytes", path.display())));
    }
    String::from_utf8(b).map_err(|_| Error::Usage(format!("{}: a camera path is UTF-8 JSON", path.display())))
}

/// A camera path for `octolod render`, in JSON:
///
/// ```json
/// { "fov_y_deg": 50, "up": [0, 0, 1], "space": "bbox",
///   "keyframes": [ {"eye": [1.5, -0.5, 0.8], "target": [0.5, 0.5, 0.5]}, ... ],
///   "frames_between": 10, "hold": 20 }
/// ```
///
/// `space` is `"world"` (coordinates as in the mesh) or `"bbox"` (0..1 over
/// the store's bounds on each axis, so one path fits any store). Poses are
/// interpolated linearly, `frames_between` frames per keyframe interval;
/// `hold` repeats the last pose so loading can settle. `"frames"` may list
/// every pose instead of `keyframes`. A path expands to at most
/// [`MAX_FRAMES`] poses (checked before any is made).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    pub fov_y_deg: f64,
    pub up: DVec3,
    pub poses: Vec<Pose>,
}

impl CameraPath {
    /// Reads a path file; `up` is used when the file names none.
    pub fn load(path: &Path, bounds: &Aabb, up: DVec3) -> Result<CameraPath> {
        CameraPath::load_text(&read_path_file(path)?, path, bounds, up)
    }

    /// A path file's text, read once (a FIFO works) and bounded: read it
    /// with this, then count ([`CameraPath::count_text`]) and parse
    /// ([`CameraPath::load_text`]) the same text.
    pub fn read_text(path: &Path) -> Result<String> {
        read_path_file(path)
    }

    /// [`CameraPath::load`] of text read from `path` (named in errors).
    pub fn load_text(text: &str, path: &Path, bounds: &Aabb, up: DVec3) -> Result<CameraPath> {
        CameraPath::parse(text, bounds, up).map_err(|m| Error::Usage(format!("{}: {m}", path.display())))
    }

    /// The poses a path file expands to (at most [`MAX_FRAMES`]), without
    /// making them: `render` checks its counts with it before any work.
    pub fn count_file(path: &Path) -> Result<usize> {
        CameraPath::count_text(&read_path_file(path)?, path)
    }

    /// [`CameraPath::count_file`] of text read from `path`.
    pub fn count_text(text: &str, path: &Path) -> Result<usize> {
        let f: PathFile = serde_json::from_str(text).map_err(|e| Error::Usage(format!("{}: not a valid camera path: {e}", path.display())))?;
        f.pose_count().map_err(|m| Error::Usage(format!("{}: {m}", path.display())))
    }

    pub fn parse(text: &str, bounds: &Aabb, default_up: DVec3) -> std::result::Result<CameraPath, String> {
        let f: PathFile = serde_json::from_str(text).map_err(|e| format!("not a valid camera path: {e}"))?;
        let count = f.pose_count()?;
        let map = |p: [f64; 3], what: &str| -> std::result::Result<DVec3, String> {
            let p = DVec3::from(p);
            if !p.is_finite() {
                return Err(format!("{what} is not finite"));
            }
            Ok(match f.space {
                Space::World => p,
                Space::Bbox => {
                    let lo = dvec(bounds.min);
                    let ext = dvec(bounds.max) - lo;
                    lo + p * ext.max(DVec3::splat(ext.max_element() * 1e-3))
                }
            })
        };
        let up = match f.up {
            Some(u) => DVec3::from(u).normalize_or(default_up),
            None => default_up,
        };
        let pose = |(i, p): (usize, &PoseFile)| -> std::result::Result<Pose, String> {
            let (eye, target) = (map(p.eye, "eye")?, map(p.target, "target")?);
            if eye == target {
                return Err(format!("frame {i}: eye equals target"));
            }
            Ok(Pose { eye, target })
        };
        let mut poses = Vec::new();
        if let Some(fr) = &f.frames {
            poses = fr.iter().enumerate().map(pose).collect::<std::result::Result<_, _>>()?;
        } else if let Some(kf) = &f.keyframes {
            let keys: Vec<Pose> = kf.iter().enumerate().map(pose).collect::<std::result::Result<_, _>>()?;
            let between = f.frames_between.max(1.0) as usize;
            for w in keys.windows(2) {
                for s in 0..between {
                    let t = s as f64 / between as f64;
                    poses.push(Pose { eye: w[0].eye.lerp(w[1].eye, t), target: w[0].target.lerp(w[1].target, t) });
                }
            }
            if let Some(last) = keys.last() {
                poses.push(*last);
            }
        } else {
            return Err("needs \"frames\" or \"keyframes\"".into());
        }
        if poses.is_empty() {
            return Err("the path has no frames".into());
        }
        let last = *poses.last().unwrap();
        poses.extend(std::iter::repeat_n(last, f.hold.max(0.0) as usize));
        debug_assert_eq!(poses.len(), count);
        if !(1.0..=170.0).contains(&f.fov_y_deg) {
            return Err(format!("fov_y_deg {} is outside 1..170", f.fov_y_deg));
        }
        Ok(CameraPath { fov_y_deg: f.fov_y_deg, up, poses })
    }

    /// A default path: a half orbit about the `up` axis around the bounds,
    /// closing in, looking down, then a hold.
    pub fn orbit(bounds: &Aabb, frames: usize, hold: usize, up: DVec3) -> CameraPath {
        let c = dvec(bounds.center());
        let r = 0.5 * bounds.diagonal().max(1e-9);
        // (e1, e2, up) right-handed; for +Z exactly (X, Y, Z).
        let up = up.normalize_or(DVec3::Z);
        let e1 = if up.z.abs() > 0.9 {
            DVec3::X * up.z.signum()
        } else if up.y.abs() > 0.9 {
            DVec3::Z * up.y.signum()
        } else {
            up.any_orthonormal_vector()
        };
        let e2 = up.cross(e1);
        let mut poses = Vec::new();
        for i in 0..frames.max(1) {
            let t = i as f64 / frames.max(1) as f64;
            let a = std::f64::consts::PI * (0.25 + t);
            let dist = r * (2.6 - 1.2 * t);
            let eye = c + e1 * (a.cos() * dist) + e2 * (a.sin() * dist) + up * (0.45 * dist);
            poses.push(Pose { eye, target: c });
        }
        let last = *poses.last().unwrap();
        poses.extend(std::iter::repeat_n(last, hold));
        CameraPath { fov_y_deg: 50.0, up, poses }
    }

    pub fn camera(&self, i: usize) -> Camera {
        let p = self.poses[i.min(self.poses.len() - 1)];
        Camera::look_at(p.eye, p.target, self.up, self.fov_y_deg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Aabb {
        Aabb { min: [-1.0; 3], max: [1.0; 3] }
    }

    #[test]
    fn frustum_culls_only_boxes_fully_outside() {
        let c = Camera::look_at(DVec3::new(0.0, -10.0, 0.0), DVec3::ZERO, DVec3::Z, 60.0);
        let mut c2 = c;
        c2.near = 0.1;
        c2.far = 100.0;
        let f = c2.frustum(1.0);
        assert!(!f.culls(&unit_box()));
        // Behind the camera.
        assert!(f.culls(&Aabb { min: [-1.0, -20.0, -1.0], max: [1.0, -12.0, 1.0] }));
        // Far to the side (60° fov: half-width at distance 10 is ~5.8).
        assert!(f.culls(&Aabb { min: [20.0, -1.0, -1.0], max: [22.0, 1.0, 1.0] }));
        // Straddling the side plane: kept.
        assert!(!f.culls(&Aabb { min: [5.0, -1.0, -1.0], max: [30.0, 1.0, 1.0] }));
        // Beyond far.
        assert!(f.culls(&Aabb { min: [-1.0, 100.0, -1.0], max: [1.0, 101.0, 1.0] }));
        // A box holding the camera is never culled.
        assert!(!f.culls(&Aabb { min: [-1.0, -11.0, -1.0], max: [1.0, -9.0, 1.0] }));
    }

    #[test]
    fn view_proj_is_relative_to_origin_and_exact_far_away() {
        let far = DVec3::splat(1.0e6);
        let c = Camera::look_at(far + DVec3::new(0.0, -3.0, 0.0), far, DVec3::Z, 60.0);
        let m = c.view_proj(far, 1.0);
        // The target (relative position 0) projects to the centre.
        let p = m * glam::Vec4::new(0.0, 0.0, 0.0, 1.0);
        assert!((p.x / p.w).abs() < 1e-6 && (p.y / p.w).abs() < 1e-6);
        // A millimetre to the right is a visible shift even at 1e6.
        let q = m * glam::Vec4::new(1e-3, 0.0, 0.0, 1.0);
        assert!(q.x / q.w > 1e-4);
    }

    #[test]
    fn pixels_per_unit_matches_the_screen_space_error_formula() {
        let c = Camera::look_at(DVec3::ZERO, DVec3::Y, DVec3::Z, 90.0);
        // tan(45°) = 1: 1000 px / (2 × 10) = 50 px per unit at distance 10.
        assert!((c.pixels_per_unit(10.0, 1000.0) - 50.0).abs() < 1e-9);
        assert_eq!(box_distance(&unit_box(), DVec3::new(0.0, 0.0, 0.5)), 0.0);
        assert!((box_distance(&unit_box(), DVec3::new(4.0, 0.0, 5.0)) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn frame_all_shows_the_whole_box_and_navigation_stays_finite() {
        let b = Aabb { min: [1e6, 1e6, 0.0], max: [1e6 + 10.0, 1e6 + 20.0, 5.0] };
        let mut c = Camera::frame_all(&b, DVec3::Z, 50.0);
        let f = c.frustum(1.0);
        // Every corner is inside every plane.
        for i in 0..8 {
            let p = DVec3::new(
                if i & 1 == 0 { b.min[0] } else { b.max[0] },
                if i & 2 == 0 { b.min[1] } else { b.max[1] },
                if i & 4 == 0 { b.min[2] } else { b.max[2] },
            );
            for pl in &f.planes {
                assert!(pl.truncate().dot(p) + pl.w >= -1e-6, "corner {p} outside");
            }
        }
        c.orbit(0.3, 0.2);
        c.orbit(0.0, 10.0); // clamped away from the pole
        c.pan(0.1, -0.1);
        c.dolly(0.5);
        c.turn(0.2, -0.3);
        c.fly(DVec3::new(1.0, 2.0, 3.0));
        c.walk(DVec3::new(1.0, 0.0, 3.0));
        assert!(c.eye.is_finite() && c.target.is_finite());
        assert!(c.forward().dot(c.up).abs() < 0.999);
        // frame_all looks down at the model, whatever the up axis.
        for up in [DVec3::Z, DVec3::Y, -DVec3::Y, DVec3::X] {
            let c = Camera::frame_all(&b, up, 50.0);
            assert!(c.forward().dot(up) < -0.2, "up {up}: forward {}", c.forward());
        }
    }

    #[test]
    fn camera_paths_parse_interpolate_and_reject_bad_input() {
        let b = Aabb { min: [0.0; 3], max: [10.0, 10.0, 10.0] };
        let p = CameraPath::parse(
            r#"{"space":"bbox","keyframes":[{"eye":[0,0,0],"target":[0.5,0.5,0.5]},{"eye":[1,0,0],"target":[0.5,0.5,0.5]}],"frames_between":4,"hold":2}"#,
            &b,
            DVec3::Z,
        )
        .unwrap();
        assert_eq!(p.poses.len(), 4 + 1 + 2);
        assert_eq!(p.up, DVec3::Z);
        assert_eq!(p.poses[2].eye, DVec3::new(5.0, 0.0, 0.0));
        assert_eq!(p.poses[0].target, DVec3::splat(5.0));
        for bad in [
            "{",
            r#"{"frames":[]}"#,
            r#"{"frames":[{"eye":[0,0,0],"target":[0,0,0]}]}"#,
            r#"{"frames":[{"eye":[0,0],"target":[1,0,0]}]}"#,
            r#"{"frames":[{"eye":[0,0,0],"target":[1,0,0]}],"space":"moon"}"#,
            r#"{"keyframes":[{"eye":[0,0,0]}]}"#,
        ] {
            assert!(CameraPath::parse(bad, &b, DVec3::Z).is_err(), "{bad} accepted");
        }
        assert_eq!(CameraPath::orbit(&b, 10, 3, DVec3::Z).poses.len(), 13);
        // A file's own "up" wins over the default.
        let p = CameraPath::parse(r#"{"up":[0,0,2],"frames":[{"eye":[0,0,0],"target":[1,0,0]}]}"#, &b, DVec3::Y).unwrap();
        assert_eq!(p.up, DVec3::Z);
    }

    #[test]
    fn camera_path_counts_are_bounded_before_expansion() {
        let b = Aabb { min: [0.0; 3], max: [1.0; 3] };
        let key = r#"{"eye":[0,0,0],"target":[1,0,0]},{"eye":[0,1,0],"target":[1,0,0]}"#;
        // Once a capacity overflow (hold) or memory growing until abort
        // (frames_between); now errors naming the field, before any pose.
        for (text, field) in [
            (r#"{"frames":[{"eye":[0,0,0],"target":[1,0,0]}],"hold":1e18}"#.to_string(), "\"hold\""),
            (format!(r#"{{"keyframes":[{key}],"frames_between":1e15}}"#), "\"frames_between\""),
            (format!(r#"{{"keyframes":[{key},{key}],"frames_between":40000}}"#), "expands to 120001 frames"),
            (format!(r#"{{"keyframes":[{key}],"frames_between":60000,"hold":60000}}"#), "expands to 120001 frames"),
        ] {
            let e = CameraPath::parse(&text, &b, DVec3::Z).unwrap_err();
            assert!(e.contains(field) && e.contains(&MAX_FRAMES.to_string()), "{text}: {e}");
        }
        // Up to the limit is fine.
        let p = CameraPath::parse(&format!(r#"{{"keyframes":[{key}],"frames_between":50000,"hold":49999}}"#), &b, DVec3::Z).unwrap();
        assert_eq!(p.poses.len(), MAX_FRAMES);
    }

    #[test]
    fn up_axis_parses_and_is_guessed_from_the_bounds() {
        assert_eq!(Up::parse("auto").unwrap(), Up::Auto);
        assert_eq!(Up::parse("z").unwrap(), Up::Axis(DVec3::Z));
        assert_eq!(Up::parse("-Y").unwrap(), Up::Axis(-DVec3::Y));
        assert_eq!(Up::parse("+x").unwrap(), Up::Axis(DVec3::X));
        assert!(Up::parse("w").is_err());
        // A height field (thin along z) stands on z; a bunny-like or cubic
        // model gets the Y-up convention; a wall thin along x stands on x.
        let terrain = Aabb { min: [0.0, 0.0, -0.1], max: [10.0, 8.0, 1.0] };
        let bunny = Aabb { min: [-0.095, 0.033, -0.062], max: [0.061, 0.187, 0.059] };
        let cube = Aabb { min: [-1.0; 3], max: [1.0; 3] };
        assert_eq!(guess_up(&terrain), DVec3::Z);
        assert_eq!(guess_up(&bunny), DVec3::Y);
        assert_eq!(guess_up(&cube), DVec3::Y);
        assert_eq!(Up::Auto.describe(&terrain), "+z (auto)");
        assert_eq!(Up::Axis(-DVec3::X).describe(&cube), "-x");
        // The default orbit circles the up axis and looks down along it.
        for up in [DVec3::Z, DVec3::Y, -DVec3::Y, DVec3::X] {
            let o = CameraPath::orbit(&cube, 8, 0, up);
            assert_eq!(o.up, up);
            for p in &o.poses {
                let h = (p.eye - p.target).dot(up);
                let d = (p.eye - p.target).length();
                assert!(h > 0.3 * d && h < 0.5 * d, "up {up}: eye {}", p.eye);
            }
        }
        // For +Z the orbit is the historical one (eye starts at 45° in x/y).
        let o = CameraPath::orbit(&cube, 4, 0, DVec3::Z);
        let e = o.poses[0].eye;
        assert!((e.x - e.y).abs() < 1e-12 && e.x > 0.0 && e.z > 0.0, "{e}");
    }
}
