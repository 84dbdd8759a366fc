// Mesh shading for the octolod viewer.
//
// Lit with per-vertex normals and vertex colors, two-sided: the normal is
// flipped towards the viewer, so scans with inconsistent orientation and views
// from inside closed surfaces are lit like the outside. Vertex colors are
// sRGB-encoded bytes; they are linearised here because the color target is an
// sRGB format (the hardware encodes on write).
//
// Textured meshes (vs_tex / fs_tex) carry uvs in a second vertex buffer and
// sample the texture (an sRGB format: the hardware decodes on read) at
// (u, 1 - v), v = 0 being the image's bottom row as in MeshLab and OpenGL;
// vertex colours tint it only when the store has them (params.z).

struct Globals {
    view_proj: mat4x4<f32>,
    // xyz: eye position, relative to the store's origin.
    eye: vec4<f32>,
    // xyz: unit direction towards the light; w > 0.5: fixed light, else headlight.
    light: vec4<f32>,
    // x: ambient fraction; y > 0.5: the target is not sRGB, encode here;
    // z > 0.5: vertex colours tint the texture.
    params: vec4<f32>,
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(1) @binding(0) var tex: texture_2d<f32>;
@group(1) @binding(1) var tex_sampler: sampler;

struct VsIn {
    @location(0) pos: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec4<f32>,
};

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec4<f32>,
    @location(3) uv: vec2<f32>,
};

fn vertex(v: VsIn) -> VsOut {
    var out: VsOut;
    out.clip = g.view_proj * vec4<f32>(v.pos, 1.0);
    out.world = v.pos;
    out.normal = v.normal;
    out.color = v.color;
    out.uv = vec2<f32>(0.0);
    return out;
}

@vertex
fn vs_main(v: VsIn) -> VsOut {
    return vertex(v);
}

@vertex
fn vs_tex(v: VsIn, @location(3) uv: vec2<f32>) -> VsOut {
    var out = vertex(v);
    out.uv = vec2<f32>(uv.x, 1.0 - uv.y);
    return out;
}

fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let lo = c / 12.92;
    let hi = pow((c + vec3<f32>(0.055)) / 1.055, vec3<f32>(2.4));
    return select(hi, lo, c <= vec3<f32>(0.04045));
}

fn linear_to_srgb(c: vec3<f32>) -> vec3<f32> {
    let lo = c * 12.92;
    let hi = 1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - vec3<f32>(0.055);
    return select(hi, lo, c <= vec3<f32>(0.0031308));
}

// Ambient plus diffuse, two-sided.
fn shade(in: VsOut) -> f32 {
    let to_eye = g.eye.xyz - in.world;
    let dist = length(to_eye);
    var v = vec3<f32>(0.0, 0.0, 1.0);
    if (dist > 0.0) {
        v = to_eye / dist;
    }
    var n = v;
    let nl = length(in.normal);
    if (nl > 1e-20) {
        n = in.normal / nl;
    }
    // Two-sided: face the viewer.
    if (dot(n, v) < 0.0) {
        n = -n;
    }
    var l = v;
    if (g.light.w > 0.5) {
        l = g.light.xyz;
    }
    let ambient = g.params.x;
    let diffuse = max(dot(n, l), 0.0);
    return ambient + (1.0 - ambient) * diffuse;
}

// A lit linear colour as the target wants it.
fn finish(lin: vec3<f32>, a: f32) -> vec4<f32> {
    var rgb = lin;
    if (g.params.y > 0.5) {
        rgb = linear_to_srgb(clamp(rgb, vec3<f32>(0.0), vec3<f32>(1.0)));
    }
    return vec4<f32>(rgb, a);
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    return finish(srgb_to_linear(in.color.rgb) * shade(in), in.color.a);
}

@fragment
fn fs_tex(in: VsOut) -> @location(0) vec4<f32> {
    var c = textureSample(tex, tex_sampler, in.uv);
    if (g.params.z > 0.5) {
        c = vec4<f32>(c.rgb * srgb_to_linear(in.color.rgb), c.a * in.color.a);
    }
    return finish(c.rgb * shade(in), c.a);
}
