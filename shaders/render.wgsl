// The reference volumetric path tracer on the GPU, "pins for everything" (pinrt::gpu_render).
//
// Appended to shaders/pin.wgsl (the Rust side concatenates the two sources): every
// transmittance and distance query is pin.wgsl's `query`, through the grid bound at group 0
// (binding 0 the grid parameters `P`, 1 the pins, 2 the cell index; bindings 3 and 4 of
// pin.wgsl belong to its own entry point and are not used here). This file adds group 1 and
// the entry point `render_main`; all its names start with `rt_` / `Rt` so nothing collides.
//
// The estimator is the one of pinrt::render (tracer.rs, `Ctx::trace`), for one medium whose
// primary and secondary estimators are both the pin grid:
//
// * camera ray through a uniformly jittered point of the pixel (pinhole, box filter);
// * the camera ray scores env * T (a pin transmittance estimate);
// * albedo 0 or max_bounces 0: done. Otherwise distance sampling along the camera ray; at each
//   collision the throughput is weighted by the albedo, the sun adds
//   phase * T(shadow ray) * radiance, one direction w is sampled from Henyey-Greenstein, the
//   environment adds env * T(w) (phase pdf and value cancel), and the path continues along w
//   by distance sampling; an escape of the continuation scores nothing. At most max_bounces
//   scattering events.
// * a non-finite sample is dropped (counts as 0), as on the CPU.
//
// Random numbers: a per-sample path generator (`rt_next`, xoshiro128** seeded by hashing
// (seed, pixel, pass)) drives the pixel jitter and the phase sampling; each pin query is
// seeded from two path draws, `rng_state = pcg_hash(pcg_hash(a) ^ b)`, exactly as the CPU
// adapter seeds `Rng::for_query(a, b)`. The streams differ from the CPU renderer's (PCG64
// there), so CPU and GPU agree in distribution, not bit for bit.

struct RtParams {
    // Camera origin, tan(vfov / 2).
    cam_o: vec4<f32>,
    // Forward (unit), aspect = width / height.
    cam_f: vec4<f32>,
    // Right (unit), width as f32.
    cam_r: vec4<f32>,
    // Up (unit), height as f32.
    cam_u: vec4<f32>,
    // Unit direction towards the sun, 1.0 if there is a sun else 0.0.
    sun_dir: vec4<f32>,
    // Sun radiance (irradiance perpendicular to its direction), unused w.
    sun_rad: vec4<f32>,
    // Environment radiance, 1.0 if non-zero else 0.0.
    env: vec4<f32>,
    // albedo (clamped to [0, 1]), HG g (clamped to +-0.99999), unused, unused.
    material: vec4<f32>,
    // width, height, max_bounces, unused.
    size: vec4<u32>,
    // seed low word, seed high word, unused, unused.
    seed: vec4<u32>,
}

struct RtPass {
    index: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(1) @binding(0) var<uniform> RP: RtParams;
@group(1) @binding(1) var<uniform> RPASS: RtPass;
// Two vec4 per pixel: the running sum (rgb, w unused) and its Kahan compensation.
@group(1) @binding(2) var<storage, read_write> rt_accum: array<vec4<f32>>;

const RT_TAU: f32 = 0x1.921fb6p2f;
const RT_INV_4PI: f32 = 0x1.45f306p-4f;

// Path generator: xoshiro128** (Blackman and Vigna), 128 bits of state per sample.
var<private> rt_s: vec4<u32>;

fn rt_rotl(x: u32, k: u32) -> u32 {
    // k in 1..=31 only (WGSL takes shift amounts mod 32).
    return (x << k) | (x >> (32u - k));
}

fn rt_next() -> u32 {
    let result = rt_rotl(rt_s.y * 5u, 7u) * 9u;
    let t = rt_s.y << 9u;
    rt_s.z = rt_s.z ^ rt_s.x;
    rt_s.w = rt_s.w ^ rt_s.y;
    rt_s.y = rt_s.y ^ rt_s.z;
    rt_s.x = rt_s.x ^ rt_s.w;
    rt_s.z = rt_s.z ^ t;
    rt_s.w = rt_rotl(rt_s.w, 11u);
    return result;
}

// Seeds the path generator of sample `pass_index` of `pixel`: each state word is its own
// hash chain of (seed, pixel, pass), so two samples share a state only if all four 32-bit
// chains collide at once.
fn rt_seed(pixel: u32, pass_index: u32) {
    let key = pcg_hash(RP.seed.x ^ pcg_hash(RP.seed.y));
    for (var i = 0u; i < 4u; i = i + 1u) {
        rt_s[i] = pcg_hash(pcg_hash(pcg_hash(key + i * 0x9e3779b9u) ^ pixel) ^ pass_index);
    }
    if (all(rt_s == vec4<u32>(0u, 0u, 0u, 0u))) {
        rt_s.x = 1u;
    }
}

fn rt_f32() -> f32 {
    return f32(rt_next() >> 8u) * TWO_M24;
}

fn rt_finite3(v: vec3<f32>) -> bool {
    return is_finite_bits(v.x) && is_finite_bits(v.y) && is_finite_bits(v.z);
}

// One pin query along o + t d, t in [0, inf), seeded from the path generator.
fn rt_query(o: vec3<f32>, d: vec3<f32>) -> QueryResult {
    let a = rt_next();
    let b = rt_next();
    rng_state = pcg_hash(pcg_hash(a) ^ b);
    return query(Ray(o, bitcast<f32>(inf_bits), d, 0u));
}

fn rt_transmittance(o: vec3<f32>, d: vec3<f32>) -> f32 {
    return rt_query(o, d).transmittance;
}

// Henyey-Greenstein value (per steradian), the cancellation-free forms of render::phase.
fn rt_hg_phase(g: f32, cos_theta: f32) -> f32 {
    var c = cos_theta;
    if (!(c == c)) {
        c = 0.0;
    }
    c = clamp(c, -1.0, 1.0);
    var denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - c);
    if (g < 0.0) {
        denom = (1.0 + g) * (1.0 + g) - 2.0 * g * (1.0 + c);
    }
    return (1.0 - g) * (1.0 + g) * RT_INV_4PI / (denom * sqrt(denom));
}

// Inverse-CDF sample of cos(theta), the branch-free expansion of render::phase::hg_sample_cos.
fn rt_hg_sample_cos(g: f32, u: f32) -> f32 {
    let s = clamp(2.0 * u - 1.0, -1.0, 1.0);
    let a = 1.0 + g * s;
    let num = s + 0.5 * g * (3.0 + s * s) + g * g * s + 0.5 * g * g * g * (s * s - 1.0);
    let c = num / (a * a);
    if (is_finite_bits(c)) {
        return clamp(c, -1.0, 1.0);
    }
    return s;
}

// A direction around unit d with pdf hg_phase(g, dot(d, w)) (render::phase::sample_hg).
fn rt_sample_hg(d: vec3<f32>, g: f32, u1: f32, u2: f32) -> vec3<f32> {
    let c = rt_hg_sample_cos(g, u1);
    let s = sqrt(max(1.0 - c * c, 0.0));
    let phi = RT_TAU * u2;
    // Duff et al. 2017 basis; the sign of -0.0 is negative, like Rust's copysign.
    var sgn = 1.0;
    if ((bitcast<u32>(d.z) & 0x80000000u) != 0u) {
        sgn = -1.0;
    }
    let a = -1.0 / (sgn + d.z);
    let b = d.x * d.y * a;
    let t = vec3<f32>(1.0 + sgn * d.x * d.x * a, sgn * b, -sgn * d.x);
    let bb = vec3<f32>(b, sgn + d.y * d.y * a, -d.y);
    let w = t * (s * cos(phi)) + bb * (s * sin(phi)) + d * c;
    let len2 = dot(w, w);
    if (!(len2 > 0.0) || !is_finite_bits(len2)) {
        return d;
    }
    let n = w / sqrt(len2);
    if (!rt_finite3(n)) {
        return d;
    }
    return n;
}

// One path sample of the radiance arriving at o from -d (tracer.rs, Ctx::trace).
fn rt_trace(o: vec3<f32>, d_in: vec3<f32>) -> vec3<f32> {
    var l = vec3<f32>(0.0, 0.0, 0.0);
    let len2 = dot(d_in, d_in);
    if (!(len2 > 0.0) || !is_finite_bits(len2) || !rt_finite3(o)) {
        return l;
    }
    let d = d_in / sqrt(len2);
    let has_env = RP.env.w != 0.0;
    let env = RP.env.xyz;
    let has_sun = RP.sun_dir.w != 0.0;
    let sun_dir = RP.sun_dir.xyz;
    let sun_rad = RP.sun_rad.xyz;
    let albedo = RP.material.x;
    let g = RP.material.y;
    let max_bounces = RP.size.z;
    if (has_env) {
        l = l + env * rt_transmittance(o, d);
    }
    if (albedo <= 0.0 || max_bounces == 0u) {
        return l;
    }
    let first = rt_query(o, d);
    if (first.hit == 0u) {
        return l;
    }
    var x = o + d * first.distance;
    var dir = d;
    var beta = albedo;
    var depth = 1u;
    loop {
        if (has_sun) {
            let ph = rt_hg_phase(g, dot(dir, sun_dir));
            if (ph > 0.0) {
                let tr = rt_transmittance(x, sun_dir);
                l = l + sun_rad * (beta * ph * tr);
            }
        }
        let u1 = rt_f32();
        let u2 = rt_f32();
        let w = rt_sample_hg(dir, g, u1, u2);
        if (has_env) {
            l = l + env * (beta * rt_transmittance(x, w));
        }
        if (depth >= max_bounces) {
            break;
        }
        let next = rt_query(x, w);
        if (next.hit == 0u) {
            break;
        }
        x = x + w * next.distance;
        dir = w;
        beta = beta * albedo;
        depth = depth + 1u;
    }
    return l;
}

@compute @workgroup_size(8, 8)
fn render_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = RP.size.x;
    let height = RP.size.y;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let pixel = gid.y * width + gid.x;
    rt_seed(pixel, RPASS.index);

    let jx = rt_f32();
    let jy = rt_f32();
    let px = f32(gid.x) + jx;
    let py = f32(gid.y) + jy;
    let sx = (2.0 * px / RP.cam_r.w - 1.0) * RP.cam_o.w * RP.cam_f.w;
    let sy = (1.0 - 2.0 * py / RP.cam_u.w) * RP.cam_o.w;
    let dv = RP.cam_f.xyz + RP.cam_r.xyz * sx + RP.cam_u.xyz * sy;
    var c = rt_trace(RP.cam_o.xyz, dv);
    if (!rt_finite3(c)) {
        c = vec3<f32>(0.0, 0.0, 0.0);
    }

    // Kahan summation over the passes.
    let i = 2u * pixel;
    let sum = rt_accum[i].xyz;
    let comp = rt_accum[i + 1u].xyz;
    let y = c - comp;
    let t = sum + y;
    rt_accum[i + 1u] = vec4<f32>((t - sum) - y, 0.0);
    rt_accum[i] = vec4<f32>(t, 0.0);
}
