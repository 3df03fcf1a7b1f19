// The mean of a progressive render's Kahan sums, tone-mapped as `pinrender render` writes its
// PNG (`tone_map` in pinrender/src/render/image.rs): times the exposure, NaN and negatives 0,
// Reinhard x / (1 + x) (+inf: 1), the sRGB transfer function, rounded to 8 bits. The target
// is a non-sRGB 8-bit format: the value written is already the 8-bit code divided by 255.

struct ToneParams {
    // width, height, first row of the pass in progress not yet rendered (0: none), -
    size: vec4<u32>,
    // 1 / passes (0 before the first), exposure, 1 / (passes + 1) for the rows above the
    // pass in progress, -
    scale: vec4<f32>,
}

@group(0) @binding(0) var<uniform> TP: ToneParams;
@group(0) @binding(1) var<storage, read> accum: array<vec4<f32>>;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the target.
    let x = f32((i << 1u) & 2u);
    let y = f32(i & 2u);
    return vec4<f32>(x * 2.0 - 1.0, 1.0 - y * 2.0, 0.0, 1.0);
}

fn tone(c: f32, exposure: f32) -> f32 {
    var x = c * exposure;
    if (!(x > 0.0)) {
        x = 0.0;
    }
    var y = 1.0;
    if (x <= 3.40282347e+38) {
        y = x / (1.0 + x);
    }
    var s = 12.92 * y;
    if (y > 0.0031308) {
        s = 1.055 * pow(y, 1.0 / 2.4) - 0.055;
    }
    return floor(clamp(s * 255.0 + 0.5, 0.0, 255.0)) / 255.0;
}

@fragment
fn fs_main(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let x = u32(p.x);
    let y = u32(p.y);
    if (x >= TP.size.x || y >= TP.size.y) {
        return vec4<f32>(0.0, 0.0, 0.0, 1.0);
    }
    let i = 2u * (y * TP.size.x + x);
    var inv = TP.scale.x;
    if (y < TP.size.z) {
        inv = TP.scale.z;
    }
    let m = (accum[i].xyz - accum[i + 1u].xyz) * inv;
    let e = TP.scale.y;
    return vec4<f32>(tone(m.x, e), tone(m.y, e), tone(m.z, e), 1.0);
}
