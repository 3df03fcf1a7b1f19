// The reference volumetric path tracer on the GPU (pinrender::gpu_render).
//
// Appended to shaders/pin.wgsl (the Rust side concatenates the two sources). Pin queries are
// pin.wgsl's `query`, unchanged, pointed at one instance's grid through its private `G`,
// `G_PIN_BASE` and `G_INDEX_BASE`: every distinct pin grid of the scene is concatenated into
// the `pins` and `cell_index` buffers of group 0, and `rt_grids` holds each instance's grid
// parameters with its own placement composed in. Bindings 0, 3 and 4 of group 0 belong to
// pin.wgsl's own entry point and are not used here. This file adds group 1 and the entry
// point `render_main`; all its names start with `rt_` / `Rt` so nothing collides.
//
// The estimator is the one of pinrender::render (tracer.rs, `Ctx::trace`), with the media of the
// scene combined additively (distance sampling: nearest collision over the instances, each
// searching only up to the nearest so far; transmittance: the product):
//
// * camera ray through a uniformly jittered point of the pixel (pinhole, box filter);
// * the camera ray scores env * T;
// * albedo 0 or max_bounces 0: done. Otherwise distance sampling along the camera ray; at each
//   collision the throughput is weighted by the albedo, the sun adds
//   phase * T(shadow ray) * radiance, one direction w is sampled from Henyey-Greenstein, the
//   environment adds env * T(w) (phase pdf and value cancel), and the path continues along w
//   by distance sampling; an escape of the continuation scores nothing. At most max_bounces
//   scattering events.
// * a non-finite sample is dropped (counts as 0), as on the CPU.
//
// Per query the estimator is `RT_PRIMARY` (camera rays and the shadow rays of the first
// scattering vertex) or `RT_SECONDARY` (everything after): 0 ray marching,
// 1 delta tracking, 2 ratio tracking (delta tracking for distances), 3 pins, 6 residual ratio
// tracking (`residual`, `residual@min`, `pinres`: the control of slot `RP.seed.z` of each
// medium's control table); any other code is an extension kernel (`rt_kernel_transmittance`,
// distances by delta tracking). PinMS is (2, 3), "pins for
// everything" (3, 3). The trackers and the marcher are ports of
// render/estimator.rs and render/majorant.rs in f32 (the CPU works in f64).
//
// Random numbers: a per-sample path generator (`rt_next`, xoshiro128** seeded by hashing
// (seed, pixel, pass)) drives the pixel jitter, the phase sampling and the trackers; each pin
// query is seeded from two path draws, `rng_state = pcg_hash(pcg_hash(a) ^ b)`, exactly as
// the CPU adapter seeds `Rng::for_query(a, b)`. The streams differ from the CPU renderer's
// (PCG there), so CPU and GPU agree in distribution, not bit for bit.

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
    // albedo (clamped to [0, 1]), HG g (clamped to +-0.99999), ray-marching relative step,
    // unused.
    material: vec4<f32>,
    // width, height, max_bounces, number of media.
    size: vec4<u32>,
    // seed low word, seed high word, residual control slot (RT_EST_RESIDUAL), where the media
    // hierarchy's nodes start in `rt_data` (0: none; `rt_media_next`).
    seed: vec4<u32>,
}

// The estimators, fixed per pipeline (pipeline-overridable constants): the compiler drops the
// code of the estimators a pipeline does not use, which keeps a pins-only path tracer as
// small as before the trackers existed.
override RT_PRIMARY: u32 = 3u;
override RT_SECONDARY: u32 = 3u;
// The scene has exactly one medium (a specialisation, not a different result).
override RT_ONE_MEDIUM: bool = false;
// Some density of the scene is bricked (without, the compiler drops the bricked fetch).
override RT_BRICKS: bool = false;

struct RtPass {
    index: u32,
    // First image row of this dispatch: a progressive session slices a pass into bands of
    // rows so that no submission runs long (0 for a whole pass).
    row0: u32,
    pad1: u32,
    pad2: u32,
}

// One medium instance (gpu_render/media.rs, `MediumRecord`).
struct RtMedium {
    // x: first pin entry of its grid in `pins`, y: first word of its cell index in
    // `cell_index`, z: flags (1 pins, 2 density, 4 majorants, 8 density placed in an asset's
    // frame, 16 that placement a translation), w: density kind (1 voxels, 2 cosine waves,
    // 3 bricked voxels).
    ids: vec4<u32>,
    // x: first value of the density (voxels, waves; bricks: the brick index) in `rt_data`,
    // y: number of cosine waves, z: first majorant in `rt_data`, w: first word of its
    // residual control table in `rt_data` (`RT_CONTROL_WORDS` per slot; see `RtGrid`).
    offs: vec4<u32>,
    // Voxel counts (x, y, z), unused.
    vdims: vec4<u32>,
    // Majorant brick counts (x, y, z), unused.
    mdims: vec4<u32>,
    // World (the asset's frame where placed) = density-local + translation; w: longest edge
    // of the clip box.
    translation: vec4<f32>,
    // World (asset) clip box of the density (extinction 0 outside); clip_lo.w: cosine
    // density.
    clip_lo: vec4<f32>,
    clip_hi: vec4<f32>,
    // Voxels: density-local position of the grid box's minimum corner, and 1 / spacing.
    vox_origin: vec4<f32>,
    vox_inv: vec4<f32>,
    // World (asset) box of the majorant grid.
    maj_lo: vec4<f32>,
    maj_hi: vec4<f32>,
    // World box of the placed pin grid (conservative), to skip missed instances cheaply.
    pin_lo: vec4<f32>,
    pin_hi: vec4<f32>,
    // Bricks: first index entry in `rt_data` (one u32 per brick, x fastest, 0xffffffff for an
    // empty brick, else its slot), bricks along x and y, first word of its values in the
    // brick value space.
    bidx: vec4<u32>,
    // Bricks: log2 of the brick edge, 1 for f16 values (two per word, the lower half first)
    // else f32, words per value binding (a brick never straddles two), unused.
    bfmt: vec4<u32>,
    // With flag 8 (`RT_PLACED`): world to the asset's frame, rows (A_i0, A_i1, A_i2, b_i).
    // The density's boxes, majorants and controls (and `translation`) are then in that frame
    // and every density query is asked there (`rt_local`).
    to_local0: vec4<f32>,
    to_local1: vec4<f32>,
    to_local2: vec4<f32>,
}

@group(1) @binding(0) var<uniform> RP: RtParams;
@group(1) @binding(1) var<uniform> RPASS: RtPass;
// Two vec4 per pixel: the running sum (rgb, w unused) and its Kahan compensation.
@group(1) @binding(2) var<storage, read_write> rt_accum: array<vec4<f32>>;
// Per medium: the pin grid parameters with the instance's placement (pin.wgsl's `Params`).
@group(1) @binding(3) var<storage, read> rt_grids: array<Params>;
@group(1) @binding(4) var<storage, read> rt_media: array<RtMedium>;
// Voxel values, cosine waves (8 floats each: w.xyz, amplitude, phase, 3 unused) and
// majorants as f32 bits, and brick indices, at the offsets of `RtMedium.offs`.
@group(1) @binding(5) var<storage, read> rt_data: array<u32>;
// Medium 0's grid parameters again, as a uniform: with one medium (`RT_ONE_MEDIUM`) the
// query reads its grid from here, which compilers keep in scalar registers.
@group(1) @binding(6) var<uniform> rt_grid0: Params;
// Brick values of the bricked densities: one space of 32-bit words (f16 pairs or f32 bits)
// split over bindings of `RtMedium.bfmt.z` words each. This file declares sixteen; the
// renderer generates the declarations and `rt_brick_word` between the `value bindings`
// markers for as many as a scene needs and the device binds (gpu_render's `render_wgsl`).
// value bindings {
@group(1) @binding(7) var<storage, read> rt_bricks0: array<u32>;
@group(1) @binding(8) var<storage, read> rt_bricks1: array<u32>;
@group(1) @binding(9) var<storage, read> rt_bricks2: array<u32>;
@group(1) @binding(10) var<storage, read> rt_bricks3: array<u32>;
@group(1) @binding(11) var<storage, read> rt_bricks4: array<u32>;
@group(1) @binding(12) var<storage, read> rt_bricks5: array<u32>;
@group(1) @binding(13) var<storage, read> rt_bricks6: array<u32>;
@group(1) @binding(14) var<storage, read> rt_bricks7: array<u32>;
@group(1) @binding(15) var<storage, read> rt_bricks8: array<u32>;
@group(1) @binding(16) var<storage, read> rt_bricks9: array<u32>;
@group(1) @binding(17) var<storage, read> rt_bricks10: array<u32>;
@group(1) @binding(18) var<storage, read> rt_bricks11: array<u32>;
@group(1) @binding(19) var<storage, read> rt_bricks12: array<u32>;
@group(1) @binding(20) var<storage, read> rt_bricks13: array<u32>;
@group(1) @binding(21) var<storage, read> rt_bricks14: array<u32>;
@group(1) @binding(22) var<storage, read> rt_bricks15: array<u32>;
// } value bindings

const RT_TAU: f32 = 0x1.921fb6p2f;
const RT_INV_4PI: f32 = 0x1.45f306p-4f;
const RT_TWO_M32: f32 = 0x1.000000p-32f;
const RT_TWO_M33: f32 = 0x1.000000p-33f;

// The estimator codes. Every `switch kind` is an estimator dispatch, and the host keeps only
// the cases a pipeline's two estimators reach (gpu_render/wgsl.rs, `specialise`), so the
// driver never inlines a walk the pipeline cannot take. Each dispatch has one shape: a case
// is one block, `case RT_EST_A, RT_EST_B: {` or `default: {` (the codes no label names),
// closed by a `}` at the case's own indentation, with only comment lines between cases.
const RT_EST_MARCH: u32 = 0u;
const RT_EST_DELTA: u32 = 1u;
const RT_EST_RATIO: u32 = 2u;
const RT_EST_PINS: u32 = 3u;
const RT_EST_RESIDUAL: u32 = 6u;

// The walks of `rt_track`.
const RT_WALK_DELTA: u32 = 0u;
const RT_WALK_RATIO: u32 = 1u;
const RT_WALK_DEPTH: u32 = 2u;
const RT_WALK_PAIR: u32 = 3u;
const RT_WALK_RESIDUAL: u32 = 4u;
// Words per slot of a medium's residual control table (gpu_render/media.rs, `CONTROL_WORDS`):
// 0-2 the residual grid's world box minimum, 3 the first control value, 4-6 its maximum,
// 7 the first residual majorant, 8-10 its brick counts, 11 the first value of the majorants
// that distances and paired queries track, 12-14 their brick counts, 16-18 and 20-22 their
// world box. Values per brick, x fastest, as f32 bits in `rt_data`.
const RT_CONTROL_WORDS: u32 = 24u;

const RT_HAS_PINS: u32 = 1u;
const RT_HAS_DENSITY: u32 = 2u;
const RT_HAS_MAJORANTS: u32 = 4u;
const RT_PLACED: u32 = 8u;
const RT_SHIFTED: u32 = 16u;
const RT_KIND_VOXELS: u32 = 1u;
const RT_KIND_COSINE: u32 = 2u;
const RT_KIND_BRICKS: u32 = 3u;
const RT_EMPTY_BRICK: u32 = 0xffffffffu;

// Safety valves of render/estimator.rs: tentative collisions per tracker query, steps per
// marched segment.
const RT_MAX_TRACKING_STEPS: u32 = 4194304u;
const RT_MAX_MARCH_STEPS: f32 = 16777216.0;
// Russian roulette threshold of ratio tracking.
const RT_RR: f32 = 0.1;

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

// A unit-rate exponential sample: -ln(u) with u in (0, 1] from 32 random bits (the half-step
// offset keeps u > 0; the largest sample is about 22.9, a tail cut below 2^-32).
fn rt_exp() -> f32 {
    let u = f32(rt_next()) * RT_TWO_M32 + RT_TWO_M33;
    return max(-log(u), 0.0);
}

fn rt_finite3(v: vec3<f32>) -> bool {
    return is_finite_bits(v.x) && is_finite_bits(v.y) && is_finite_bits(v.z);
}

fn rt_inf() -> f32 {
    return bitcast<f32>(inf_bits);
}

// ---------------------------------------------------------------------------------------------
// Boxes and densities
// ---------------------------------------------------------------------------------------------

// Slab clip of o + t d, t in [t0, t1], against the closed box [lo, hi] (majorant.rs,
// `clip_box`): axes with d = 0 constrain nothing if o is within the slab and reject otherwise.
// Returns (tn, tf); empty when !(tn < tf).
fn rt_clip(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>, t0: f32, t1: f32) -> vec2<f32> {
    var tn = t0;
    var tf = t1;
    for (var a = 0u; a < 3u; a = a + 1u) {
        let oa = o[a];
        let da = d[a];
        if (da == 0.0) {
            if (oa < lo[a] || oa > hi[a]) {
                return vec2<f32>(1.0, 0.0);
            }
        } else {
            let inv = 1.0 / da;
            var n = (lo[a] - oa) * inv;
            var f = (hi[a] - oa) * inv;
            if (n > f) {
                let s = n;
                n = f;
                f = s;
            }
            if (n > tn) {
                tn = n;
            }
            if (f < tf) {
                tf = f;
            }
        }
    }
    return vec2<f32>(tn, tf);
}

// Extinction as the estimators use it: NaN and negatives are 0, +inf stays (opaque).
fn rt_clean(s: f32) -> f32 {
    if (s > 0.0) {
        return s;
    }
    return 0.0;
}

fn rt_f(i: u32) -> f32 {
    return bitcast<f32>(rt_data[i]);
}

// Word `a` of the brick value space.
// brick word {
fn rt_brick_word(a: u32, cap: u32) -> u32 {
    let k = a / cap;
    let i = a - k * cap;
    switch k {
        case 0u: {
            return rt_bricks0[i];
        }
        case 1u: {
            return rt_bricks1[i];
        }
        case 2u: {
            return rt_bricks2[i];
        }
        case 3u: {
            return rt_bricks3[i];
        }
        case 4u: {
            return rt_bricks4[i];
        }
        case 5u: {
            return rt_bricks5[i];
        }
        case 6u: {
            return rt_bricks6[i];
        }
        case 7u: {
            return rt_bricks7[i];
        }
        case 8u: {
            return rt_bricks8[i];
        }
        case 9u: {
            return rt_bricks9[i];
        }
        case 10u: {
            return rt_bricks10[i];
        }
        case 11u: {
            return rt_bricks11[i];
        }
        case 12u: {
            return rt_bricks12[i];
        }
        case 13u: {
            return rt_bricks13[i];
        }
        case 14u: {
            return rt_bricks14[i];
        }
        default: {
            return rt_bricks15[i];
        }
    }
}
// } brick word

// An f16 (the bits in the low half) as f32, exactly: subnormals by a scale, so that no
// device's flushing of f16 denormals changes a value. Bricks hold no infinity or NaN (the
// values are cleaned, and an infinity stays f32).
fn rt_half(h: u32) -> f32 {
    let e = (h >> 10u) & 0x1fu;
    let m = h & 0x3ffu;
    var v = f32(m) * 0x1p-24f;
    if (e != 0u) {
        v = bitcast<f32>(((e + 112u) << 23u) | (m << 13u));
    }
    if ((h & 0x8000u) != 0u) {
        v = -v;
    }
    return v;
}

// Voxel (x, y, z) of a bricked density (render/bricks.rs, `BrickGrid::at`).
fn rt_brick_voxel(m: u32, x: u32, y: u32, z: u32) -> f32 {
    let bi = rt_media[m].bidx;
    let bf = rt_media[m].bfmt;
    let s = bf.x;
    let slot = rt_data[bi.x + (x >> s) + bi.y * ((y >> s) + bi.z * (z >> s))];
    if (slot == RT_EMPTY_BRICK) {
        return 0.0;
    }
    let mask = (1u << s) - 1u;
    let local = (x & mask) | ((y & mask) << s) | ((z & mask) << (2u * s));
    if (bf.y != 0u) {
        // Half a brick's words per slot (s >= 1 for f16 bricks).
        let w = rt_brick_word(bi.w + (slot << (3u * s - 1u)) + (local >> 1u), bf.z);
        return rt_half((w >> (16u * (local & 1u))) & 0xffffu);
    }
    return bitcast<f32>(rt_brick_word(bi.w + (slot << (3u * s)) + local, bf.z));
}

// The trilinear value of a bricked density between the voxels i0 and i1 = i0 + 1 (clamped)
// with weights f: the dense path's mixes in the dense path's order over the same eight values,
// so the same bits. One fetch in a loop (not eight inlined copies of the binding switch).
fn rt_brick_trilinear(m: u32, i0: vec3<u32>, i1: vec3<u32>, f: vec3<f32>) -> f32 {
    var v: array<f32, 8>;
    for (var c = 0u; c < 8u; c = c + 1u) {
        let x = select(i0.x, i1.x, (c & 1u) != 0u);
        let y = select(i0.y, i1.y, (c & 2u) != 0u);
        let z = select(i0.z, i1.z, (c & 4u) != 0u);
        v[c] = rt_brick_voxel(m, x, y, z);
    }
    let c00 = mix(v[0], v[1], f.x);
    let c10 = mix(v[2], v[3], f.x);
    let c01 = mix(v[4], v[5], f.x);
    let c11 = mix(v[6], v[7], f.x);
    let c0 = mix(c00, c10, f.y);
    let c1 = mix(c01, c11, f.y);
    return mix(c0, c1, f.z);
}

fn rt_voxel(base: u32, dims: vec3<u32>, x: u32, y: u32, z: u32) -> f32 {
    return rt_f(base + x + dims.x * (y + dims.y * z));
}

// Extinction of medium m at world point p (0 outside its clip box).
fn rt_extinction(m: u32, p: vec3<f32>) -> f32 {
    let lo = rt_media[m].clip_lo.xyz;
    let hi = rt_media[m].clip_hi.xyz;
    if (!(all(p >= lo) && all(p <= hi))) {
        return 0.0;
    }
    let q = p - rt_media[m].translation.xyz;
    let base = rt_media[m].offs.x;
    if (rt_media[m].ids.w == RT_KIND_COSINE) {
        let n = rt_media[m].offs.y;
        var s = 1.0;
        for (var k = 0u; k < n; k = k + 1u) {
            let at = base + 8u * k;
            let w = vec3<f32>(rt_f(at), rt_f(at + 1u), rt_f(at + 2u));
            // Range reduction in turns keeps cos accurate where w . q is hundreds of radians.
            let turns = (dot(w, q) + rt_f(at + 4u)) * INV_TAU;
            s = s + rt_f(at + 3u) * cos(RT_TAU * fract(turns));
        }
        return max(rt_media[m].clip_lo.w * s, 0.0);
    }
    // Voxels, dense or bricked, the shared convention: trilinear between voxel centres, the
    // edge voxel's value in the outer half voxel.
    let dims = rt_media[m].vdims.xyz;
    let nmax = vec3<f32>(dims) - vec3<f32>(1.0);
    let u = clamp((q - rt_media[m].vox_origin.xyz) * rt_media[m].vox_inv.xyz - vec3<f32>(0.5), vec3<f32>(0.0), nmax);
    let fl = floor(u);
    let i0 = vec3<u32>(fl);
    let i1 = min(i0 + vec3<u32>(1u), dims - vec3<u32>(1u));
    let f = u - fl;
    if (RT_BRICKS && rt_media[m].ids.w == RT_KIND_BRICKS) {
        return rt_brick_trilinear(m, i0, i1, f);
    }
    let c00 = mix(rt_voxel(base, dims, i0.x, i0.y, i0.z), rt_voxel(base, dims, i1.x, i0.y, i0.z), f.x);
    let c10 = mix(rt_voxel(base, dims, i0.x, i1.y, i0.z), rt_voxel(base, dims, i1.x, i1.y, i0.z), f.x);
    let c01 = mix(rt_voxel(base, dims, i0.x, i0.y, i1.z), rt_voxel(base, dims, i1.x, i0.y, i1.z), f.x);
    let c11 = mix(rt_voxel(base, dims, i0.x, i1.y, i1.z), rt_voxel(base, dims, i1.x, i1.y, i1.z), f.x);
    let c0 = mix(c00, c10, f.y);
    let c1 = mix(c01, c11, f.y);
    return mix(c0, c1, f.z);
}

// ---------------------------------------------------------------------------------------------
// Ray marching (estimator.rs, `RayMarching`): midpoint rule, steps from the segment start,
// the last one shortened. Returns (collision distance or +inf, transmittance); a distance is
// sampled only when `want_distance` is true (target optical depth -ln(u), linear inside a
// step). Like every estimator here it draws random numbers only for a ray that reaches its
// box (the CPU draws some before clipping); the draws are independent either way.
// ---------------------------------------------------------------------------------------------

fn rt_march(m: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32, want_distance: bool) -> vec2<f32> {
    let none = vec2<f32>(rt_inf(), 1.0);
    let ch = rt_clip(o, d, rt_media[m].clip_lo.xyz, rt_media[m].clip_hi.xyz, 0.0, t_max);
    if (!(ch.x < ch.y)) {
        return none;
    }
    var goal = 0.0;
    if (want_distance) {
        goal = rt_exp();
    }
    let t0 = ch.x;
    let t1 = ch.y;
    let len = t1 - t0;
    let h = max(RP.material.z * rt_media[m].translation.w, len / RT_MAX_MARCH_STEPS);
    let n = u32(max(ceil(len / h), 1.0));
    var tau = 0.0;
    for (var i = 0u; i < n; i = i + 1u) {
        let a = t0 + f32(i) * h;
        var b = min(a + h, t1);
        if (i + 1u == n) {
            b = t1;
        }
        if (!(b > a)) {
            continue;
        }
        let sigma = rt_clean(rt_extinction(m, o + d * (0.5 * (a + b))));
        let dt = sigma * (b - a);
        if (want_distance && tau + dt >= goal && sigma > 0.0) {
            return vec2<f32>(min(a + (goal - tau) / sigma, b), 0.0);
        }
        tau = tau + dt;
        if (!want_distance && !is_finite_bits(tau)) {
            break;
        }
    }
    if (want_distance) {
        return none;
    }
    return vec2<f32>(rt_inf(), exp(-tau));
}

// ---------------------------------------------------------------------------------------------
// Trackers over a grid of bricks (estimator.rs `Tracker`, majorant.rs `Dda`), by `mode`:
// RT_WALK_DELTA: delta tracking, returns (collision distance or +inf, 1);
// RT_WALK_RATIO: ratio tracking, returns (+inf, transmittance weight);
// RT_WALK_DEPTH: no tracking and no random draws, returns (+inf, majorant optical depth of
//   the segment inside the grid's box) for the comb estimators' lookup count;
// RT_WALK_PAIR: ratio tracking's transmittance and delta tracking's collision from one walk
//   (estimator.rs `Tracker::ratio_and_delta`): at each tentative collision, until one is
//   accepted, delta tracking's draw, then ratio tracking's step until its weight is final;
//   returns (collision distance or +inf, transmittance weight);
// RT_WALK_RESIDUAL: residual ratio tracking (estimator.rs `ResidualRatioTracking::
//   residual_walk` and `residual_step`): the grid's values are the residual majorants, `cbase`
//   the first of the controls (same bricks); the control's depth is summed exactly per brick,
//   the residual `sigma - c` is ratio-tracked at rate `m`, and Russian roulette acts on the
//   whole weight exp(-control depth so far) * weight; returns (+inf, transmittance).
// ---------------------------------------------------------------------------------------------

// A grid of bricks over a world box, its values (f32 bits) from `base` in `rt_data`.
struct RtGrid {
    lo: vec3<f32>,
    hi: vec3<f32>,
    dims: vec3<u32>,
    base: u32,
}

// Medium m's own majorant grid.
fn rt_majorant_grid(m: u32) -> RtGrid {
    return RtGrid(rt_media[m].maj_lo.xyz, rt_media[m].maj_hi.xyz, rt_media[m].mdims.xyz, rt_media[m].offs.z);
}

fn rt_vec3_at(i: u32) -> vec3<f32> {
    return vec3<f32>(rt_f(i), rt_f(i + 1u), rt_f(i + 2u));
}

fn rt_uvec3_at(i: u32) -> vec3<u32> {
    return vec3<u32>(rt_data[i], rt_data[i + 1u], rt_data[i + 2u]);
}

// First word of medium m's control of this render (slot RP.seed.z).
fn rt_control_entry(m: u32) -> u32 {
    return rt_media[m].offs.w + RT_CONTROL_WORDS * RP.seed.z;
}

// The residual majorants of medium m's control (their grid carries the controls at word 3).
fn rt_residual_grid(e: u32) -> RtGrid {
    return RtGrid(rt_vec3_at(e), rt_vec3_at(e + 4u), rt_uvec3_at(e + 8u), rt_data[e + 7u]);
}

// The majorants that distances and paired queries of medium m's control track.
fn rt_control_majorants(e: u32) -> RtGrid {
    return RtGrid(rt_vec3_at(e + 16u), rt_vec3_at(e + 20u), rt_uvec3_at(e + 12u), rt_data[e + 11u]);
}

fn rt_track(m: u32, grid: RtGrid, cbase: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32, mode: u32) -> vec2<f32> {
    let none = vec2<f32>(rt_inf(), 1.0);
    let lo = grid.lo;
    let hi = grid.hi;
    let ch = rt_clip(o, d, lo, hi, 0.0, t_max);
    if (!(ch.x < ch.y)) {
        return none;
    }
    let depth_only = mode == RT_WALK_DEPTH;
    // Majorant optical depth left to the next tentative collision, carried across bricks.
    var tau = 0.0;
    if (!depth_only) {
        tau = rt_exp();
    }
    // The majorant depth (RT_WALK_DEPTH) or the control depth (RT_WALK_RESIDUAL) to the end of
    // the bricks walked so far.
    var depth = 0.0;
    let dims = grid.dims;
    let mbase = grid.base;
    let t_end = ch.y;
    var t_seg = ch.x;
    let p = o + d * ch.x;
    let scale = vec3<f32>(dims) / (hi - lo);
    var brick = vec3<i32>(0);
    var step = vec3<i32>(0);
    var limit = vec3<i32>(0);
    var next_t = vec3<f32>(rt_inf());
    var delta_t = vec3<f32>(rt_inf());
    for (var a = 0u; a < 3u; a = a + 1u) {
        let n = i32(dims[a]);
        let g = (p[a] - lo[a]) * scale[a];
        let b = clamp(i32(floor(g)), 0, n - 1);
        brick[a] = b;
        let dg = d[a] * scale[a];
        if (dg > 0.0) {
            next_t[a] = ch.x + max(f32(b + 1) - g, 0.0) / dg;
            delta_t[a] = 1.0 / dg;
            step[a] = 1;
            limit[a] = n;
        } else if (dg < 0.0) {
            next_t[a] = ch.x + min(f32(b) - g, 0.0) / dg;
            delta_t[a] = -1.0 / dg;
            step[a] = -1;
            limit[a] = -1;
        }
    }
    var tr = 1.0;
    // RT_WALK_PAIR: the accepted collision, and whether ratio tracking's weight is final.
    var hit = rt_inf();
    var ratio_done = false;
    // RT_WALK_RESIDUAL: false once the step limit is reached (the control depth goes on).
    var tracking = true;
    var steps = 0u;
    // A ray crosses at most dims.x + dims.y + dims.z bricks; the bound only guards rounding.
    let max_segments = dims.x + dims.y + dims.z + 3u;
    for (var s = 0u; s < max_segments; s = s + 1u) {
        var a = 2u;
        if (next_t.x < next_t.y) {
            if (next_t.x < next_t.z) {
                a = 0u;
            }
        } else if (next_t.y < next_t.z) {
            a = 1u;
        }
        let seg_t1 = min(next_t[a], t_end);
        let b = brick;
        let bi = u32(b.x) + dims.x * (u32(b.y) + dims.y * u32(b.z));
        let maj = rt_f(mbase + bi);
        // RT_WALK_RESIDUAL: the brick's control, and the control depth at t inside it is
        // offset + c t.
        var c = 0.0;
        var offset = 0.0;
        if (mode == RT_WALK_RESIDUAL) {
            c = rt_f(cbase + bi);
            offset = depth - c * t_seg;
            depth = depth + c * max(seg_t1 - t_seg, 0.0);
        }
        if (depth_only) {
            depth = depth + maj * max(seg_t1 - t_seg, 0.0);
        } else if (maj > 0.0 && tracking) {
            let inv = 1.0 / maj;
            var t = t_seg;
            loop {
                let t_next = t + tau * inv;
                if (t_next >= seg_t1) {
                    tau = max(tau - (seg_t1 - t) * maj, 0.0);
                    break;
                }
                t = t_next;
                tau = rt_exp();
                // t lies in the clipped segment, so the point is inside the box; rounding can
                // put a point on the entry face a hair outside, where the density reads 0,
                // and a huge majorant (t + tau / majorant == t) would then never move on.
                let pt = clamp(o + d * t, lo, hi);
                let sigma = rt_clean(rt_extinction(m, pt));
                if (mode == RT_WALK_RATIO) {
                    tr = tr * (1.0 - sigma * inv);
                    if (tr == 0.0 || !(tr == tr)) {
                        return vec2<f32>(rt_inf(), 0.0);
                    }
                    if (abs(tr) < RT_RR) {
                        let q = abs(tr) / RT_RR;
                        if (rt_f32() >= q) {
                            return vec2<f32>(rt_inf(), 0.0);
                        }
                        tr = tr / q;
                    }
                } else if (mode == RT_WALK_RESIDUAL) {
                    // residual_step: the residual may be negative (a control above the
                    // extinction); that keeps the expectation, so it is not clamped.
                    tr = tr * (1.0 - (sigma - c) * inv);
                    if (tr == 0.0 || !is_finite_bits(tr)) {
                        return vec2<f32>(rt_inf(), 0.0);
                    }
                    let whole = abs(tr) * exp(-(offset + c * t));
                    if (whole < RT_RR) {
                        let q = whole / RT_RR;
                        if (rt_f32() >= q) {
                            return vec2<f32>(rt_inf(), 0.0);
                        }
                        tr = tr / q;
                    }
                } else if (mode == RT_WALK_PAIR) {
                    if (!(hit < rt_inf()) && rt_f32() * maj < sigma) {
                        hit = t;
                    }
                    if (!ratio_done) {
                        tr = tr * (1.0 - sigma * inv);
                        if (tr == 0.0 || !(tr == tr)) {
                            tr = 0.0;
                            ratio_done = true;
                        } else if (abs(tr) < RT_RR) {
                            let q = abs(tr) / RT_RR;
                            if (rt_f32() >= q) {
                                tr = 0.0;
                                ratio_done = true;
                            } else {
                                tr = tr / q;
                            }
                        }
                    }
                    if (hit < rt_inf() && ratio_done) {
                        return vec2<f32>(hit, tr);
                    }
                } else if (rt_f32() * maj < sigma) {
                    return vec2<f32>(t, 1.0);
                }
                steps = steps + 1u;
                if (steps >= RT_MAX_TRACKING_STEPS) {
                    if (mode == RT_WALK_RESIDUAL) {
                        // The walk stops; the rest of the control depth by itself.
                        tracking = false;
                        break;
                    }
                    return vec2<f32>(hit, tr);
                }
            }
        }
        if (next_t[a] >= t_end) {
            break;
        }
        brick[a] = brick[a] + step[a];
        if (brick[a] == limit[a]) {
            break;
        }
        next_t[a] = next_t[a] + delta_t[a];
        t_seg = seg_t1;
    }
    if (depth_only) {
        return vec2<f32>(rt_inf(), depth);
    }
    if (mode == RT_WALK_RESIDUAL) {
        let t = exp(-depth) * tr;
        // 0 x inf (a roulette survivor's huge weight past an opaque control) is 0.
        if (!is_finite_bits(t)) {
            return vec2<f32>(rt_inf(), 0.0);
        }
        return vec2<f32>(rt_inf(), t);
    }
    return vec2<f32>(hit, tr);
}

// Residual ratio tracking's transmittance of medium m along o + t d (RT_EST_RESIDUAL).
fn rt_residual_transmittance(m: u32, o: vec3<f32>, d: vec3<f32>) -> f32 {
    let e = rt_control_entry(m);
    return rt_track(m, rt_residual_grid(e), rt_data[e + 3u], o, d, rt_inf(), RT_WALK_RESIDUAL).y;
}

// ---------------------------------------------------------------------------------------------
// Pins
// ---------------------------------------------------------------------------------------------

// The medium whose grid `G` holds (copied only when the queried medium changes).
var<private> rt_grid_medium: u32 = 0xffffffffu;

// One pin query of medium m along o + t d, t in [0, t_max), seeded from the path generator.
// Instances whose (conservative) world box the segment misses are skipped without a query.
fn rt_pins(m: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> vec2<f32> {
    let ch = rt_clip(o, d, rt_media[m].pin_lo.xyz, rt_media[m].pin_hi.xyz, 0.0, t_max);
    if (!(ch.x < ch.y)) {
        return vec2<f32>(rt_inf(), 1.0);
    }
    let a = rt_next();
    let b = rt_next();
    rng_state = pcg_hash(pcg_hash(a) ^ b);
    if (RT_ONE_MEDIUM) {
        G = rt_grid0;
        G_PIN_BASE = rt_media[0].ids.x;
        G_INDEX_BASE = rt_media[0].ids.y;
    } else if (rt_grid_medium != m) {
        G = rt_grids[m];
        G_PIN_BASE = rt_media[m].ids.x;
        G_INDEX_BASE = rt_media[m].ids.y;
        rt_grid_medium = m;
    }
    let r = query(Ray(o, t_max, d, 0u));
    if (r.hit != 0u) {
        return vec2<f32>(r.distance, r.transmittance);
    }
    return vec2<f32>(rt_inf(), r.transmittance);
}

// ---------------------------------------------------------------------------------------------
// Extension kernels: a further transmittance estimator of an extension crate
// (`pinrender::gpu_render::ShaderKernel`, estimator codes other than the renderer's own) puts
// its WGSL between these markers, defining `rt_kernel_transmittance` (the lab's is
// `shaders/lab_combs.wgsl`). Without one the region holds the function below, which no
// pipeline reaches: the host dispatches a kernel's code only with that kernel's text.
// ---------------------------------------------------------------------------------------------

// extension kernels {
fn rt_kernel_transmittance(kind: u32, m: u32, o: vec3<f32>, d: vec3<f32>) -> f32 {
    return 1.0;
}
// } extension kernels

// ---------------------------------------------------------------------------------------------
// Instances placed by an affine map (instance.rs, `PlacedEstimator`): a density query of a
// medium with `RT_PLACED` is asked in its asset's frame, o_l = A o + b and d_l = A d, the
// direction normalised and lengths scaled by k = |d_l|; a sampled distance is mapped back by
// 1 / k, kept below the segment's end. Optical depth is carried with the volume. Pin queries
// are not mapped: a placed pin grid's own parameters (`rt_grids`) hold its placement.
// ---------------------------------------------------------------------------------------------

// A ray in a medium's asset frame and the factor from world to local lengths (0: the mapped
// direction is degenerate in f32, the medium is not met).
struct RtLocal {
    o: vec3<f32>,
    d: vec3<f32>,
    k: f32,
}

fn rt_local(m: u32, o: vec3<f32>, d: vec3<f32>) -> RtLocal {
    let r0 = rt_media[m].to_local0;
    let r1 = rt_media[m].to_local1;
    let r2 = rt_media[m].to_local2;
    if ((rt_media[m].ids.z & RT_SHIFTED) != 0u) {
        return RtLocal(o + vec3<f32>(r0.w, r1.w, r2.w), d, 1.0);
    }
    let ol = vec3<f32>(dot(r0.xyz, o) + r0.w, dot(r1.xyz, o) + r1.w, dot(r2.xyz, o) + r2.w);
    let dl = vec3<f32>(dot(r0.xyz, d), dot(r1.xyz, d), dot(r2.xyz, d));
    let k = length(dl);
    if (!(k > 0.0) || !is_finite_bits(k)) {
        return RtLocal(o, d, 0.0);
    }
    return RtLocal(ol, dl / k, k);
}

fn rt_placed(m: u32) -> bool {
    return (rt_media[m].ids.z & RT_PLACED) != 0u;
}

// The largest f32 below a positive finite x, x otherwise.
fn rt_before(x: f32) -> f32 {
    if (x > 0.0 && is_finite_bits(x)) {
        return bitcast<f32>(bitcast<u32>(x) - 1u);
    }
    return x;
}

// A distance of the asset's frame in the world, below t_max.
fn rt_back(t: f32, k: f32, t_max: f32) -> f32 {
    if (!(t < rt_inf())) {
        return t;
    }
    return min(t / k, rt_before(t_max));
}

// ---------------------------------------------------------------------------------------------
// The scene's media combined (tracer.rs, `Ctx::transmittance` / `Ctx::distance`)
// ---------------------------------------------------------------------------------------------

fn rt_medium_transmittance(kind: u32, m: u32, o_w: vec3<f32>, d_w: vec3<f32>) -> f32 {
    let inf = rt_inf();
    var o = o_w;
    var d = d_w;
    if (kind != RT_EST_PINS && rt_placed(m)) {
        let l = rt_local(m, o_w, d_w);
        if (l.k == 0.0) {
            return 1.0;
        }
        o = l.o;
        d = l.d;
    }
    switch kind {
        case RT_EST_MARCH: {
            return rt_march(m, o, d, inf, false).y;
        }
        case RT_EST_DELTA: {
            if (rt_track(m, rt_majorant_grid(m), 0u, o, d, inf, RT_WALK_DELTA).x < inf) {
                return 0.0;
            }
            return 1.0;
        }
        case RT_EST_RATIO: {
            return rt_track(m, rt_majorant_grid(m), 0u, o, d, inf, RT_WALK_RATIO).y;
        }
        case RT_EST_RESIDUAL: {
            return rt_residual_transmittance(m, o, d);
        }
        case RT_EST_PINS: {
            return rt_pins(m, o, d, inf).y;
        }
        default: {
            return rt_kernel_transmittance(kind, m, o, d);
        }
    }
}

// The majorants that estimator `kind`'s distances in medium m track (and its paired walk):
// the residual estimators' control's, the others' majorant grid.
fn rt_distance_majorants(kind: u32, m: u32) -> RtGrid {
    if (kind == RT_EST_RESIDUAL) {
        return rt_control_majorants(rt_control_entry(m));
    }
    return rt_majorant_grid(m);
}

fn rt_medium_distance(kind: u32, m: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> f32 {
    if (kind != RT_EST_PINS && rt_placed(m)) {
        let l = rt_local(m, o, d);
        if (l.k == 0.0) {
            return rt_inf();
        }
        return rt_back(rt_frame_distance(kind, m, l.o, l.d, t_max * l.k), l.k, t_max);
    }
    return rt_frame_distance(kind, m, o, d, t_max);
}

// A distance of medium m along a ray of its own frame (the world, or its asset's).
fn rt_frame_distance(kind: u32, m: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> f32 {
    switch kind {
        case RT_EST_MARCH: {
            return rt_march(m, o, d, t_max, true).x;
        }
        case RT_EST_PINS: {
            return rt_pins(m, o, d, t_max).x;
        }
        case RT_EST_DELTA, RT_EST_RATIO, RT_EST_RESIDUAL: {
            let grid = rt_distance_majorants(kind, m);
            return rt_track(m, grid, 0u, o, d, t_max, RT_WALK_DELTA).x;
        }
        // Every extension kernel: delta tracking over the majorants.
        default: {
            return rt_track(m, rt_majorant_grid(m), 0u, o, d, t_max, RT_WALK_DELTA).x;
        }
    }
}

// The media's hierarchy (render/bvh.rs, packed by gpu_render/media.rs): `RP.seed.w - 1` is
// the word of `rt_data` that holds its node count, the nodes follow, eight words each (lo,
// hi, escape index, leaf run `first | count << 29`). `RP.seed.w == 0`: no hierarchy, every
// medium is asked in turn. A walk meets the leaves in media order and a node's box holds its
// media's, so the media asked, and the order they are asked in, are the linear scan's: the
// same bits, with box tests that grow with the media a ray meets (`rt_media_next`).

// Whether the segment [0, t_max] of the ray meets node `base`'s box (slab test).
fn rt_bvh_meets(base: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> bool {
    let lo = vec3<f32>(
        bitcast<f32>(rt_data[base]),
        bitcast<f32>(rt_data[base + 1u]),
        bitcast<f32>(rt_data[base + 2u]),
    );
    let hi = vec3<f32>(
        bitcast<f32>(rt_data[base + 3u]),
        bitcast<f32>(rt_data[base + 4u]),
        bitcast<f32>(rt_data[base + 5u]),
    );
    var t0 = 0.0;
    var t1 = t_max;
    for (var a = 0u; a < 3u; a = a + 1u) {
        if (abs(d[a]) < 1e-30) {
            if (o[a] < lo[a] || o[a] > hi[a]) {
                return false;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let ta = (lo[a] - o[a]) * inv;
        let tb = (hi[a] - o[a]) * inv;
        t0 = max(t0, min(ta, tb));
        t1 = min(t1, max(ta, tb));
    }
    return t0 <= t1;
}

// The next run of media at or after node `*node` whose box [0, t_max] of the ray meets, as
// (first medium, count); count 0 when the walk is over. Leaves `*node` after that run. With
// no hierarchy the one run is every medium.
fn rt_media_next(node: ptr<function, u32>, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> vec2<u32> {
    let start = RP.seed.w;
    if (start == 0u) {
        let first = *node == 0u;
        *node = 1u;
        return select(vec2<u32>(0u, 0u), vec2<u32>(0u, RP.size.w), first);
    }
    let nodes = rt_data[start - 1u];
    var leaf = vec2<u32>(0u, 0u);
    loop {
        if (*node >= nodes) {
            break;
        }
        let base = start + *node * 8u;
        let run = rt_data[base + 7u];
        if (!rt_bvh_meets(base, o, d, t_max)) {
            *node = rt_data[base + 6u];
        } else if ((run >> 29u) != 0u) {
            *node = rt_data[base + 6u];
            leaf = vec2<u32>(run & 0x1fffffffu, run >> 29u);
            break;
        } else {
            *node = *node + 1u;
        }
    }
    return leaf;
}

fn rt_transmittance(kind: u32, o: vec3<f32>, d: vec3<f32>) -> f32 {
    var t = 1.0;
    var node = 0u;
    loop {
        let run = rt_media_next(&node, o, d, rt_inf());
        if (run.y == 0u) {
            break;
        }
        for (var m = run.x; m < run.x + run.y; m = m + 1u) {
            t = t * rt_medium_transmittance(kind, m, o, d);
            if (t == 0.0) {
                return t;
            }
        }
    }
    return t;
}

// Nearest collision over the media, +inf if none.
fn rt_distance(kind: u32, o: vec3<f32>, d: vec3<f32>) -> f32 {
    var best = rt_inf();
    var node = 0u;
    loop {
        // The segment shrinks to the nearest collision so far: later media beyond it are
        // cut there by their own walks, and skipped here when their whole box lies beyond.
        let run = rt_media_next(&node, o, d, best);
        if (run.y == 0u) {
            break;
        }
        for (var m = run.x; m < run.x + run.y; m = m + 1u) {
            let t = rt_medium_distance(kind, m, o, d, best);
            if (t < best) {
                best = t;
            }
        }
    }
    return best;
}

// Whether estimator `kind` answers a transmittance and a distance along one ray together,
// with one medium (tracer.rs `Ctx::paired`): ratio tracking and the residual estimators.
fn rt_pairs(kind: u32) -> bool {
    return (kind == RT_EST_RATIO || kind == RT_EST_RESIDUAL) && RP.size.w == 1u;
}

// Both queries along one ray with one medium (tracer.rs `Ctx::transmittance_and_distance`),
// for a `kind` that `rt_pairs`: ratio tracking's transmittance and delta tracking's collision
// from one walk over the majorants the distances track (the residual estimators: their
// control's, docs/residual.md, "Distances"). Returns (collision distance or +inf,
// transmittance).
fn rt_pair(kind: u32, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    switch kind {
        case RT_EST_RATIO, RT_EST_RESIDUAL: {
            if (rt_placed(0u)) {
                let l = rt_local(0u, o, d);
                if (l.k == 0.0) {
                    return vec2<f32>(rt_inf(), 1.0);
                }
                let grid = rt_distance_majorants(kind, 0u);
                let p = rt_track(0u, grid, 0u, l.o, l.d, rt_inf(), RT_WALK_PAIR);
                return vec2<f32>(rt_back(p.x, l.k, rt_inf()), p.y);
            }
            let grid = rt_distance_majorants(kind, 0u);
            return rt_track(0u, grid, 0u, o, d, rt_inf(), RT_WALK_PAIR);
        }
        // No other estimator pairs (`rt_pairs`): never reached.
        default: {
            return vec2<f32>(rt_inf(), 1.0);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Phase function
// ---------------------------------------------------------------------------------------------

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

// ---------------------------------------------------------------------------------------------
// The path (tracer.rs, `Ctx::trace`)
// ---------------------------------------------------------------------------------------------

fn rt_trace(o: vec3<f32>, d_in: vec3<f32>) -> vec3<f32> {
    var l = vec3<f32>(0.0, 0.0, 0.0);
    let len2 = dot(d_in, d_in);
    if (!(len2 > 0.0) || !is_finite_bits(len2) || !rt_finite3(o)) {
        return l;
    }
    let has_env = RP.env.w != 0.0;
    let env = RP.env.xyz;
    let has_sun = RP.sun_dir.w != 0.0;
    let sun_dir = RP.sun_dir.xyz;
    let sun_rad = RP.sun_rad.xyz;
    let albedo = RP.material.x;
    let g = RP.material.y;
    let max_bounces = RP.size.z;
    let primary = RT_PRIMARY;
    let secondary = RT_SECONDARY;
    // One loop for the camera ray and every bounce, in two kinds of pass. A segment's pass
    // (the camera ray first) asks, from x along w, the environment seen through the segment
    // (estimator `along`, weight `beta`) and the next collision (estimator `collide`) unless
    // the path ends here (`last`). A collision's pass asks the sun's shadow ray and samples
    // the next direction. So a transmittance, a distance and a paired walk are each asked
    // from one place: the driver inlines every call, and when the camera ray, the bounces
    // and the sun had calls of their own, those copies were most of a pipeline's compile
    // (docs/gpu.md, "What a pipeline compiles"). The random numbers are drawn in the order
    // of the steps above.
    var x = o;
    var w = d_in / sqrt(len2);
    var along = primary;
    var collide = primary;
    var last = albedo <= 0.0 || max_bounces == 0u;
    var beta = 1.0;
    var depth = 0u;
    var at_collision = false;
    var dir = w;
    loop {
        // The transmittance this pass asks, if any: the sun's along its shadow ray from a
        // collision, or the environment's along the segment.
        var ray = w;
        var radiance = env;
        var weight = beta;
        var asks = has_env;
        if (at_collision) {
            let ph = rt_hg_phase(g, dot(dir, sun_dir));
            ray = sun_dir;
            radiance = sun_rad;
            weight = beta * ph;
            asks = has_sun && ph > 0.0;
        }
        // tracer.rs `Ctx::paired`: with one medium, an estimator that answers a
        // transmittance and a distance along one ray together gets both from one walk where
        // one estimator answers both: the camera ray (primary for both), and a continuation
        // whose transmittance comes from the estimator that samples its distance (secondary).
        var t = rt_inf();
        if (!at_collision && has_env && !last && along == collide && rt_pairs(collide)) {
            let p = rt_pair(collide, x, w);
            l = l + env * (beta * p.y);
            t = p.x;
        } else {
            if (asks) {
                l = l + radiance * (weight * rt_transmittance(along, x, ray));
            }
            if (at_collision) {
                let u1 = rt_f32();
                let u2 = rt_f32();
                w = rt_sample_hg(dir, g, u1, u2);
                collide = secondary;
                last = depth >= max_bounces;
                at_collision = false;
                continue;
            }
            if (last) {
                break;
            }
            t = rt_distance(collide, x, w);
        }
        if (!(t < rt_inf())) {
            break;
        }
        x = x + w * t;
        dir = w;
        beta = beta * albedo;
        depth = depth + 1u;
        // The first scattering vertex's queries are the primary estimator's.
        along = secondary;
        if (depth == 1u) {
            along = primary;
        }
        at_collision = true;
    }
    return l;
}

@compute @workgroup_size(8, 8)
fn render_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = RP.size.x;
    let height = RP.size.y;
    let row = gid.y + RPASS.row0;
    if (gid.x >= width || row >= height) {
        return;
    }
    let pixel = row * width + gid.x;
    rt_seed(pixel, RPASS.index);

    let jx = rt_f32();
    let jy = rt_f32();
    let px = f32(gid.x) + jx;
    let py = f32(row) + jy;
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
