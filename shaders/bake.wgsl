// The GPU bake's per-pin work: the midpoint march of a dense density grid over the 32
// intervals of each pin's chord, t_min and the 32 mask bits (pinbake/src/gpu_bake.rs).
//
// The chord (its f64 geometry) comes from the CPU, one job per pin, rounded to f32 exactly
// where the CPU march rounds it: the interval bases, the index step `du`, the sample count
// and the weight. Here: sample `j` of interval `i` at `base + i * istep + j * du` in f32
// (the CPU takes each base from f64, so positions agree to a few f32 ulps), trilinear values
// as `Cells::interpolate` computes them, each interval summed with a compensated f32 sum
// (the CPU sums in f64), and the mask bits from the CPU's counter RNG: splitmix64 in u32
// pairs, draw `c` = mix64(key + c * golden).
//
// The density may come in z slabs, one dispatch each, in increasing z: each sample belongs
// to the slab holding its lower corner's z, and each interval adds its samples in increasing
// z (forward along a march going up, backward along one going down), its sum and
// compensation carried from slab to slab in `sums`. So the sums, and the bytes, are the same
// for any number of slabs; the last slab draws t_min and the mask bits.

struct Params {
    // nx, ny, nz, voxels per density binding
    dims: vec4<u32>,
    // stride y, stride z, jobs in this dispatch, threads per row of workgroups
    stride: vec4<u32>,
    // offsets of the +1 neighbour along x, y, z (0 on a one-voxel axis)
    step: vec4<u32>,
    // the index clamp: dims - 1
    top: vec4<f32>,
    // the lower corner's clamp: dims - 2
    hi: vec4<f32>,
    // the slab: samples whose lower corner's z lies in [x, y), from the planes z >= x that
    // the density bindings hold; w: the flags below
    slab: vec4<u32>,
}

// The sums so far are in `sums` (every slab but the first).
const CARRIED: u32 = 1u;
// More slabs follow: keep the sums in `sums`, draw no entry yet.
const ONGOING: u32 = 2u;
// The only slab: every sample is in it.
const WHOLE: u32 = 4u;

struct PinJob {
    base: vec3<f32>,
    steps: u32,
    istep: vec3<f32>,
    weight: f32,
    du: vec3<f32>,
    counter: u32,
    key: vec2<u32>,
    pad: vec2<u32>,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> jobs: array<PinJob>;
@group(0) @binding(2) var<storage, read_write> entries: array<vec2<u32>>;
// The density in six bindings of `P.dims.w` voxels each: one binding is capped by the
// device's max_storage_buffer_binding_size, which a 512^3 grid exceeds.
@group(0) @binding(3) var<storage, read> d0: array<f32>;
@group(0) @binding(4) var<storage, read> d1: array<f32>;
@group(0) @binding(5) var<storage, read> d2: array<f32>;
@group(0) @binding(6) var<storage, read> d3: array<f32>;
@group(0) @binding(7) var<storage, read> d4: array<f32>;
@group(0) @binding(8) var<storage, read> d5: array<f32>;
// Each pin's 32 (sum, compensation) pairs between slabs (a one-word stand-in with one slab),
// zero where no slab has added to them yet (wgpu zeroes new buffers).
@group(0) @binding(9) var<storage, read_write> sums: array<vec2<f32>>;

fn load(i: u32) -> f32 {
    let b = i / P.dims.w;
    let o = i - b * P.dims.w;
    switch b {
        case 0u: { return d0[o]; }
        case 1u: { return d1[o]; }
        case 2u: { return d2[o]; }
        case 3u: { return d3[o]; }
        case 4u: { return d4[o]; }
        default: { return d5[o]; }
    }
}

// `Cells::locate`: the continuous index `c` clamped to the grid...
fn clamped(c: vec3<f32>) -> vec3<f32> {
    return min(max(c, vec3<f32>(0.0)), P.top.xyz);
}

// ...and its lower corner.
fn lower(cc: vec3<f32>) -> vec3<u32> {
    return vec3<u32>(min(cc, P.hi.xyz));
}

// `Cells::interpolate`: the trilinear value at clamped index `cc`, lower corner `ii` (its z
// in the slab).
fn density(cc: vec3<f32>, ii: vec3<u32>) -> f32 {
    let f = cc - vec3<f32>(ii);
    let b = ii.x + ii.y * P.stride.x + (ii.z - P.slab.x) * P.stride.y;
    let sx = P.step.x;
    let sy = P.step.y;
    let sz = P.step.z;
    let c0 = load(b);
    let c00 = c0 + (load(b + sx) - c0) * f.x;
    let y0 = load(b + sy);
    let c10 = y0 + (load(b + sy + sx) - y0) * f.x;
    let z0 = load(b + sz);
    let c01 = z0 + (load(b + sz + sx) - z0) * f.x;
    let yz = load(b + sz + sy);
    let c11 = yz + (load(b + sz + sy + sx) - yz) * f.x;
    let e0 = c00 + (c10 - c00) * f.y;
    let e1 = c01 + (c11 - c01) * f.y;
    return max(e0 + (e1 - e0) * f.z, 0.0);
}

// The first of the `n` samples from `b` stepping `du` whose lower corner has passed plane
// `t`: at or above it going up, below it going down. Along a march the lower corner's z is
// monotone (so is the f32 position, and the clamp and the truncation keep order), so a
// bisection finds it.
fn first_past(b: vec3<f32>, du: vec3<f32>, n: u32, t: u32, up: bool) -> u32 {
    var lo = 0u;
    var hi = n;
    loop {
        if lo >= hi {
            break;
        }
        let mid = lo + (hi - lo) / 2u;
        let z = lower(clamped(b + f32(mid) * du)).z;
        if select((z < t), (z >= t), up) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// The high 32 bits of the 64-bit product of two u32.
fn mulhi(a: u32, b: u32) -> u32 {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    return p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
}

// u64 as (lo, hi): wrapping product, sum, and right shift by 0 < s < 32.
fn mul64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x * b.x, mulhi(a.x, b.x) + a.x * b.y + a.y * b.x);
}

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn xorshr64(a: vec2<u32>, s: u32) -> vec2<u32> {
    return a ^ vec2<u32>((a.x >> s) | (a.y << (32u - s)), a.y >> s);
}

// rng.rs `mix64` (splitmix64's finaliser).
fn mix64(z0: vec2<u32>) -> vec2<u32> {
    var z = mul64(xorshr64(z0, 30u), vec2<u32>(0x1ce4e5b9u, 0xbf58476du));
    z = mul64(xorshr64(z, 27u), vec2<u32>(0x133111ebu, 0x94d049bbu));
    return xorshr64(z, 31u);
}

// The largest optical depth whose transmittance rounds to 1 in f32 (2^-25): the empty pin.
const EMPTY_TAU: f32 = 2.98023223876953125e-8;
// f32::MAX: a sum above it has overflowed.
const F32_MAX: f32 = 3.40282347e+38;
const GOLDEN: vec2<u32> = vec2<u32>(0x7f4a7c15u, 0x9e3779b9u);

// Draw `c` of the stream `key`: its top 24 bits as a uniform in [0, 1), the CPU's 53-bit
// uniform truncated (never above it, at most 2^-24 below).
fn uniform24(key: vec2<u32>, c: u32) -> f32 {
    let x = mix64(add64(key, mul64(vec2<u32>(c, 0u), GOLDEN)));
    return f32(x.y >> 8u) * (1.0 / 16777216.0);
}

// 1 - exp(-t) for t >= 0, accurate for small t (the CPU's -expm1(-t)).
fn one_minus_exp(t: f32) -> f32 {
    if t < 0.1 {
        return t * (1.0 - t * (0.5 - t * (1.0 / 6.0 - t * (1.0 / 24.0 - t * (1.0 / 120.0)))));
    }
    return 1.0 - exp(-t);
}

@compute @workgroup_size(64)
fn bake(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = gid.x + gid.y * P.stride.w;
    if n >= P.stride.z {
        return;
    }
    let job = jobs[n];
    let flags = P.slab.w;
    let whole = (flags & WHOLE) != 0u;
    let ongoing = (flags & ONGOING) != 0u;
    let up = job.du.z >= 0.0;
    var taus: array<f32, 32>;
    var tau_max = 0.0;
    for (var i = 0u; i < 32u; i++) {
        let b = job.base + f32(i) * job.istep;
        var wa = 0u;
        var wb = job.steps;
        var touched = whole && job.steps > 0u;
        if !whole && job.steps > 0u {
            // The lower corners' z of the interval's first and last samples bound all of
            // its samples' (monotone along the march): most intervals miss a thin slab.
            let za = lower(clamped(b)).z;
            let zb = lower(clamped(b + f32(job.steps - 1u) * job.du)).z;
            let z0 = min(za, zb);
            let z1 = max(za, zb);
            touched = z1 >= P.slab.x && z0 < P.slab.y;
            if touched && (z0 < P.slab.x || z1 >= P.slab.y) {
                // The run of samples in this slab, a sample wider on each side: the test
                // below decides on the very positions the sum reads.
                let ja = first_past(b, job.du, job.steps, select(P.slab.y, P.slab.x, up), up);
                let jb = first_past(b, job.du, job.steps, select(P.slab.x, P.slab.y, up), up);
                wa = max(ja, 1u) - 1u;
                wb = min(jb + 1u, job.steps);
            }
        }
        if !touched && ongoing {
            // Nothing to add and nothing to draw: the carried sums stay as they are.
            continue;
        }
        var s = 0.0;
        var comp = 0.0;
        if (flags & CARRIED) != 0u {
            let carried = sums[n * 32u + i];
            s = carried.x;
            comp = carried.y;
        }
        if touched {
            for (var m = wa; m < wb; m++) {
                // In increasing z: forward going up, backward going down.
                let j = select(wb - 1u - (m - wa), m, up);
                let cc = clamped(b + f32(j) * job.du);
                let ii = lower(cc);
                if ii.z < P.slab.x || ii.z >= P.slab.y {
                    continue;
                }
                let v = density(cc, ii);
                // Neumaier's compensated sum: the f32 sum of many samples keeps the CPU's
                // f64 sum to about one f32 ulp.
                let t = s + v;
                if abs(s) >= abs(v) {
                    comp += (s - t) + v;
                } else {
                    comp += (v - t) + s;
                }
                s = t;
            }
        }
        if ongoing {
            sums[n * 32u + i] = vec2<f32>(s, comp);
            continue;
        }
        // A sum that overflowed f32 (a voxel near f32::MAX): the compensation is then NaN
        // (inf - inf), and the depth infinite, as the CPU's f64 sum gives t = 0 there.
        let tau = select(s + comp, s, abs(s) > F32_MAX) * job.weight;
        taus[i] = tau;
        tau_max = max(tau_max, tau);
    }
    if ongoing {
        return;
    }
    let t_min = exp(-tau_max);
    // The CPU's rule: its t_min, exp(-tau) in f64 rounded to f32, is 1 (the empty pin) for
    // every tau <= 2^-25, and this device's f32 exp need not round as it does (lavapipe
    // gave 0.99999994 for tau = 1e-30).
    if !(tau_max > EMPTY_TAU) || t_min >= 1.0 {
        entries[n] = vec2<u32>(0u, bitcast<u32>(1.0));
        return;
    }
    let denom = one_minus_exp(tau_max);
    var mask = 0u;
    for (var i = 0u; i < 32u; i++) {
        let p = one_minus_exp(taus[i]) / denom;
        if uniform24(job.key, job.counter + 1u + i) < p {
            mask |= 1u << (31u - i);
        }
    }
    entries[n] = vec2<u32>(mask, bitcast<u32>(t_min));
}
