// Screen-space overlay: one textured quad at a pixel-exact position, texels
// fetched 1:1 (no filtering), alpha-blended over the frame.

struct Rect {
    // Top-left corner and size of the quad in pixels; size of the target.
    origin: vec2<f32>,
    size: vec2<f32>,
    screen: vec2<f32>,
    pad: vec2<f32>,
};

@group(0) @binding(0) var<uniform> r: Rect;
@group(0) @binding(1) var tex: texture_2d<f32>;

@vertex
fn vs_overlay(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // Triangle strip: (0,0) (1,0) (0,1) (1,1).
    let corner = vec2<f32>(f32(i & 1u), f32((i >> 1u) & 1u));
    let px = r.origin + corner * r.size;
    let ndc = vec2<f32>(px.x / r.screen.x * 2.0 - 1.0, 1.0 - px.y / r.screen.y * 2.0);
    return vec4<f32>(ndc, 0.0, 1.0);
}

@fragment
fn fs_overlay(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let ip = vec2<i32>(floor(p.xy - r.origin));
    let dims = vec2<i32>(textureDimensions(tex));
    if (any(ip < vec2<i32>(0)) || any(ip >= dims)) {
        discard;
    }
    return textureLoad(tex, ip, 0);
}
