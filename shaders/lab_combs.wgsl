// The lab's transmittance kernels for the GPU path tracer (the `pinlab` crate's `urm` and
// `jackknife`), compiled into `shaders/render.wgsl` at its extension region by
// `pinrender::gpu_render::render_wgsl_with` when a render asks for one of them. The renderer's
// own estimators never read this file; it uses the path tracer's functions (`rt_extinction`,
// `rt_track`, `rt_clip`, `rt_f32`, ...) and defines the region's one entry point,
// `rt_kernel_transmittance`.

// Estimator codes of the kernels (lab/src/estimator.rs), above the renderer's own.
const RT_EST_URM: u32 = 4u;
const RT_EST_JACKKNIFE: u32 = 5u;
// Always-taken series orders of `urm`, its order cap, and the lookups of one comb at most
// (lab/src/comb.rs).
const RT_URM_ABR: u32 = 2u;
const RT_URM_MAX_ORDER: u32 = 24u;
const RT_MAX_COMB_LOOKUPS: f32 = 1048576.0;
const RT_COMB_PER_DEPTH: f32 = 2.0;

// ---------------------------------------------------------------------------------------------
// Comb estimators (lab/src/comb.rs, comb_estimators.rs `Combed`): jittered equidistant combs over the
// segment inside the majorant box, spacing RP.material.z (1 / lookups) times that box's longest
// edge. `urm`: control comb, power series of exp around it to a random order (elementary
// symmetric means of the further combs); `jackknife`: exp(-mean) cos(half difference) of two
// combs. Transmittance only; distances are delta tracking.
// ---------------------------------------------------------------------------------------------

fn rt_comb(m: u32, o: vec3<f32>, d: vec3<f32>, t0: f32, len: f32, n: u32) -> f32 {
    let h = len / f32(n);
    let u = rt_f32();
    var acc = 0.0;
    for (var j = 0u; j < n; j = j + 1u) {
        acc = acc + rt_clean(rt_extinction(m, o + d * (t0 + (f32(j) + u) * h)));
    }
    return acc * h;
}

fn rt_comb_transmittance(m: u32, o: vec3<f32>, d: vec3<f32>, jackknife: bool) -> f32 {
    let lo = rt_media[m].maj_lo.xyz;
    let hi = rt_media[m].maj_hi.xyz;
    let ch = rt_clip(o, d, lo, hi, 0.0, rt_inf());
    if (!(ch.x < ch.y)) {
        return 1.0;
    }
    let e = hi - lo;
    let spacing = RP.material.z * max(e.x, max(e.y, e.z));
    let len = ch.y - ch.x;
    let maj_depth = rt_track(m, rt_majorant_grid(m), 0u, o, d, rt_inf(), RT_WALK_DEPTH).y;
    let n = u32(clamp(max(ceil(len / spacing), ceil(maj_depth * RT_COMB_PER_DEPTH)), 1.0, RT_MAX_COMB_LOOKUPS));
    if (jackknife) {
        let t1 = rt_comb(m, o, d, ch.x, len, n);
        let t2 = rt_comb(m, o, d, ch.x, len, n);
        if (!(is_finite_bits(t1) && is_finite_bits(t2))) {
            return 0.0;
        }
        return exp(-0.5 * (t1 + t2)) * cos(0.5 * (t1 - t2));
    }
    let tau_c = rt_comb(m, o, d, ch.x, len, n);
    let base = exp(-tau_c);
    // An opaque control gives 0, not 0 * (an overflowing series) = NaN (lab/src/comb.rs).
    if (!(base > 0.0)) {
        return 0.0;
    }
    // P(K >= k) = ABR! / k! above the always-taken orders, drawn before the combs.
    var order = RT_URM_ABR;
    loop {
        if (order >= RT_URM_MAX_ORDER || !(rt_f32() * f32(order + 1u) < 1.0)) {
            break;
        }
        order = order + 1u;
    }
    // Elementary symmetric polynomials of the samples, updated from the top down (an
    // ascending loop over j, so no unsigned counter runs below zero).
    var es: array<f32, 25>;
    for (var k = 0u; k < 25u; k = k + 1u) {
        es[k] = 0.0;
    }
    es[0] = 1.0;
    for (var i = 0u; i < order; i = i + 1u) {
        let tau_i = rt_comb(m, o, d, ch.x, len, n);
        if (!is_finite_bits(tau_i)) {
            return 0.0;
        }
        let x = tau_c - tau_i;
        for (var j = 0u; j <= i; j = j + 1u) {
            let k = i + 1u - j;
            es[k] = es[k] + es[k - 1u] * x;
        }
    }
    var series = 0.0;
    var binom = 1.0;
    var fact = 1.0;
    for (var k = 0u; k <= order; k = k + 1u) {
        if (k > 0u) {
            binom = binom * f32(order + 1u - k) / f32(k);
            fact = fact * f32(k);
        }
        // 1 / (k! P(K >= k)): 1 / k! up to the always-taken order, 1 / ABR! (= 1 / 2) above.
        var w = 1.0 / fact;
        if (k > RT_URM_ABR) {
            w = 0.5;
        }
        series = series + es[k] / binom * w;
    }
    let t = base * series;
    if (!is_finite_bits(t)) {
        return 0.0;
    }
    return t;
}

// The transmittance of kernel `kind` through medium m (its distances are delta tracking over
// the majorants, in render.wgsl).
fn rt_kernel_transmittance(kind: u32, m: u32, o: vec3<f32>, d: vec3<f32>) -> f32 {
    return rt_comb_transmittance(m, o, d, kind == RT_EST_JACKKNIFE);
}
