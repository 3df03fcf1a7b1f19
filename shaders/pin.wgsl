// Pin grid queries on the GPU: distance sampling and transmittance estimation.
//
// This is a line-by-line port of the CPU reference in `pinrt` (modules rng, mask, chord,
// lookup, sampler). The contract (docs/gpu.md): for the same grid, rays, seed and query index
// the integers (entry, popcount, collision interval, status, final RNG state) are identical
// and the floats agree within the bound stated there. To keep that true:
//
// * same f32 operations in the same order (no reassociation, no fused rewrites by hand);
// * min/max written as compare-and-select, NaN/inf tests on bit patterns;
// * shifts only by amounts in 0..=31 (WGSL takes the amount mod 32);
// * integer powers by square-and-multiply (WGSL pow(0, 0) is undefined);
// * the same random draws in the same order (see the sampler module docs).
//
// Bindings: 0 parameters (uniform), 1 pins (the file's pin section as stored: mask, t_min
// bits), 2 cell index (or a dummy), 3 rays, 4 results. `query` reads the grid through the
// private copy `G` (see below), so another entry point can point it at other grids.

struct Params {
    // World -> unit cube rows (A_i0, A_i1, A_i2, b_i).
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    // Spatial strength, directional strength (0 = off), chain stride (intervals per lookup,
    // 1..=32; 0 reads as 32), lookup mode: bit 0 midpoint (1) or segment start (0), bit 1
    // `start_inside`, bits 2 and up the nearest-line lookup's steps (0: off).
    jitter: vec4<f32>,
    // dims x, y, z, z_begin
    dims: vec4<u32>,
    // z_end, pins_per_entry, block_len, stored_cells
    grid: vec4<u32>,
    // direction kind (0 polar, 1 octahedral), res0 (n_phi | n), res1 (n_theta | n), has_index
    dirs: vec4<u32>,
    // seed, first query index, ray count, threads per dispatch row
    run: vec4<u32>,
}

struct Ray {
    origin: vec3<f32>,
    t_max: f32,
    dir: vec3<f32>,
    pad: u32,
}

struct QueryResult {
    distance: f32,
    transmittance: f32,
    hit: u32,
    entry: u32,
    popcount: u32,
    interval: u32,
    status: u32,
    rng_state: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> pins: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> cell_index: array<u32>;
@group(0) @binding(3) var<storage, read> rays: array<Ray>;
@group(0) @binding(4) var<storage, read_write> results: array<QueryResult>;

// The grid that `query` reads: its parameters and where its entries and cell index start in
// `pins` and `cell_index`. `main` copies `P` with bases 0; the path tracer (render.wgsl) sets
// one instance's grid per query, so several grids and placements share the two buffers.
var<private> G: Params;
var<private> G_PIN_BASE: u32;
var<private> G_INDEX_BASE: u32;

const STATUS_OK: u32 = 0u;
const STATUS_MISS: u32 = 1u;
const STATUS_INVALID: u32 = 2u;
const NO_ENTRY: u32 = 0xffffffffu;
const NO_INTERVAL: u32 = 32u;
const EMPTY_CELL: u32 = 0xffffffffu;
// pinrt::lookup::MAX_NEAREST_LINE_STEPS.
const MAX_NEAREST_LINE_STEPS: u32 = 64u;

// f32 constants as exact hexadecimal literals (decimal ones could round twice via
// AbstractFloat; naga cannot const-evaluate bitcast).
const C0: f32 = 0x1.ffee70p-1f;
const C1: f32 = -0x1.523a08p-2f;
const C2: f32 = 0x1.70edc4p-3f;
const C3: f32 = -0x1.5cb46cp-4f;
const C4: f32 = 0x1.555cbep-6f;
const HALF_PI: f32 = 0x1.921fb6p0f;
const PI: f32 = 0x1.921fb6p1f;
const INV_TAU: f32 = 0x1.45f306p-3f;
const MAXF: f32 = 0x1.fffffep127f;
const TWO_M24: f32 = 0x1.000000p-24f;
const TWO_32: f32 = 0x1.000000p32f;
// +inf built at run time: a constant expression may not evaluate to an infinity.
var<private> inf_bits: u32 = 0x7f800000u;

// ---------------------------------------------------------------------------------------------
// RNG (pinrt::rng)
// ---------------------------------------------------------------------------------------------

const PCG_MUL: u32 = 747796405u;
const PCG_INC: u32 = 2891336453u;
const PCG_OUT_MUL: u32 = 277803737u;

var<private> rng_state: u32;

fn pcg_output(state: u32) -> u32 {
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * PCG_OUT_MUL;
    return (word >> 22u) ^ word;
}

fn pcg_hash(x: u32) -> u32 {
    return pcg_output(x * PCG_MUL + PCG_INC);
}

fn rng_next() -> u32 {
    rng_state = rng_state * PCG_MUL + PCG_INC;
    return pcg_output(rng_state);
}

fn rng_f32() -> f32 {
    return f32(rng_next() >> 8u) * TWO_M24;
}

// ---------------------------------------------------------------------------------------------
// Bits and numbers (pinrt::mask)
// ---------------------------------------------------------------------------------------------

fn is_finite_bits(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn interval_bit(j: u32) -> u32 {
    if (j >= 32u) {
        return 0u;
    }
    return 0x80000000u >> j;
}

fn interval_range(a: u32, b: u32) -> u32 {
    if (a > b || b > 31u) {
        return 0u;
    }
    return (0xffffffffu >> a) & (0xffffffffu << (31u - b));
}

fn pow_int(base: f32, n: u32) -> f32 {
    var result = 1.0;
    var b = base;
    for (var i = 0u; i < 6u; i = i + 1u) {
        var f = 1.0;
        if (((n >> i) & 1u) != 0u) {
            f = b;
        }
        result = result * f;
        b = b * b;
    }
    return result;
}

fn sanitize_t_min(t: f32) -> f32 {
    let bits = bitcast<u32>(t);
    let mag = bits & 0x7fffffffu;
    if (mag > 0x7f800000u) {
        return 1.0;
    }
    if ((bits & 0x80000000u) != 0u) {
        return 0.0;
    }
    if (mag >= 0x3f800000u) {
        return 1.0;
    }
    return t;
}

// The exact sample mask: each bit set with probability Q / 2^32, Q = round((1 - t) 2^32).
fn exact_sample_mask(t: f32) -> u32 {
    if (t >= 1.0) {
        return 0u;
    }
    // Round to nearest, ties to even, with integer steps (as the CPU does).
    let x = t * TWO_32;
    let fl = u32(x);
    let frac = x - f32(fl);
    var tq = fl;
    if (frac > 0.5 || (frac == 0.5 && (fl & 1u) == 1u)) {
        tq = fl + 1u;
    }
    if (tq == 0u) {
        return 0xffffffffu;
    }
    let q = 0u - tq;
    let stop = countTrailingZeros(q);
    var result = 0u;
    var undecided = 0xffffffffu;
    var j = 31u;
    loop {
        let r = rng_next();
        let qb = 0u - ((q >> j) & 1u);
        result = result | (undecided & ~r & qb);
        undecided = undecided & ~(r ^ qb);
        if (undecided == 0u || j == stop) {
            break;
        }
        j = j - 1u;
    }
    return result;
}

// ---------------------------------------------------------------------------------------------
// Chord and segment (pinrt::chord)
// ---------------------------------------------------------------------------------------------

fn bin(x: f32, n: u32) -> u32 {
    // floor(x) clamped to [0, n - 1]; NaN -> 0 (Rust's saturating `as u32` then min).
    if (!(x >= 1.0)) {
        return 0u;
    }
    if (x >= f32(n)) {
        return n - 1u;
    }
    return min(u32(x), n - 1u);
}

struct Chord {
    ok: bool,
    t_enter: f32,
    t_exit: f32,
}

fn unit_cube_chord(o: vec3<f32>, d: vec3<f32>) -> Chord {
    var c = Chord(false, 0.0, 0.0);
    var lo = -MAXF;
    var hi = MAXF;
    var constrained = false;
    for (var a = 0u; a < 3u; a = a + 1u) {
        let oa = o[a];
        let da = d[a];
        var parallel = da == 0.0;
        var inv = 0.0;
        if (!parallel) {
            inv = 1.0 / da;
            parallel = !is_finite_bits(inv);
        }
        if (parallel) {
            if (!(oa >= 0.0 && oa <= 1.0)) {
                return c;
            }
            continue;
        }
        let t0 = -oa * inv;
        let t1 = (1.0 - oa) * inv;
        var n = t1;
        var f = t0;
        if (t0 < t1) {
            n = t0;
            f = t1;
        }
        if (n > lo) {
            lo = n;
        }
        if (f < hi) {
            hi = f;
        }
        constrained = true;
    }
    if (!constrained || !(lo < hi) || !is_finite_bits(lo) || !is_finite_bits(hi)) {
        return c;
    }
    c.ok = true;
    c.t_enter = lo;
    c.t_exit = hi;
    return c;
}

struct Segment {
    ok: bool,
    t_enter: f32,
    interval_len: f32,
    t0: f32,
    t1: f32,
    s0: f32,
    s1: f32,
    a: u32,
    b: u32,
}

fn make_segment(ch: Chord, t_max: f32) -> Segment {
    var s = Segment(false, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0u, 0u);
    let te = ch.t_enter;
    let tx = ch.t_exit;
    var t0 = 0.0;
    if (te > 0.0) {
        t0 = te;
    }
    var t1 = tx;
    if (t_max < tx) {
        t1 = t_max;
    }
    if (!(t0 < t1)) {
        return s;
    }
    let c = tx - te;
    let k = 32.0 / c;
    if (!is_finite_bits(c) || !is_finite_bits(k)) {
        return s;
    }
    var s0 = 0.0;
    if (t0 != te) {
        s0 = (t0 - te) * k;
        if (!(s0 < 32.0)) {
            s0 = 32.0;
        }
    }
    var s1 = 32.0;
    if (t1 != tx) {
        s1 = (t1 - te) * k;
        if (!(s1 < 32.0)) {
            s1 = 32.0;
        }
    }
    let a = bin(s0, 32u);
    let fl = bin(s1, 32u);
    var b = fl;
    if (f32(fl) == s1 && fl > 0u) {
        b = fl - 1u;
    }
    if (b < a) {
        b = a;
    }
    s.ok = true;
    s.t_enter = te;
    s.interval_len = c * 0.03125;
    s.t0 = t0;
    s.t1 = t1;
    s.s0 = s0;
    s.s1 = s1;
    s.a = a;
    s.b = b;
    return s;
}

// ---------------------------------------------------------------------------------------------
// Lookup (pinrt::lookup, pin_format::Directions)
// ---------------------------------------------------------------------------------------------

fn atan2_turns(y: f32, x: f32) -> f32 {
    let ax = abs(x);
    let ay = abs(y);
    var mx = ay;
    var mn = ax;
    if (ax > ay) {
        mx = ax;
        mn = ay;
    }
    if (mx == 0.0) {
        return 0.0;
    }
    let a = mn / mx;
    let s = a * a;
    var r = a * (C0 + s * (C1 + s * (C2 + s * (C3 + s * C4))));
    if (ay > ax) {
        r = HALF_PI - r;
    }
    if (x < 0.0) {
        r = PI - r;
    }
    if (y < 0.0) {
        r = -r;
    }
    var turns = r * INV_TAU;
    if (turns < 0.0) {
        turns = turns + 1.0;
    }
    if (turns >= 1.0) {
        return 0.0;
    }
    return turns;
}

// Direction cell of d (z >= 0), optionally jittered by (xi - 0.5) * strength in cell units.
fn direction_cell(d: vec3<f32>, jitter: bool, strength: f32, xi0: f32, xi1: f32) -> u32 {
    if (G.dirs.x == 0u) {
        let n_phi = G.dirs.y;
        let n_theta = G.dirs.z;
        let len2 = d.x * d.x + d.y * d.y + d.z * d.z;
        let z = d.z / sqrt(len2);
        var ct = (1.0 - z) * f32(n_theta);
        var cp = atan2_turns(d.y, d.x) * f32(n_phi);
        if (jitter) {
            ct = ct + (xi0 - 0.5) * strength;
            cp = cp + (xi1 - 0.5) * strength;
            let n = f32(n_phi);
            if (cp < 0.0) {
                cp = cp + n;
            } else if (cp >= n) {
                cp = cp - n;
            }
        }
        return bin(ct, n_theta) * n_phi + bin(cp, n_phi);
    }
    let n = G.dirs.y;
    let sum = abs(d.x) + abs(d.y) + d.z;
    let px = d.x / sum;
    let py = d.y / sum;
    let u = (px + py + 1.0) * 0.5;
    let v = (px - py + 1.0) * 0.5;
    var cu = u * f32(n);
    var cv = v * f32(n);
    if (jitter) {
        cu = cu + (xi0 - 0.5) * strength;
        cv = cv + (xi1 - 0.5) * strength;
    }
    return bin(cv, n) * n + bin(cu, n);
}

// The centre direction of octahedral direction cell `dcell`, not normalised
// (pinrt::lookup::octahedral_cell_axis).
fn octahedral_cell_axis(n: u32, dcell: u32) -> vec3<f32> {
    let nf = f32(n);
    let df = f32(dcell);
    let row = floor((df + 0.5) / nf);
    let col = df - row * nf;
    let u = (col + 0.5) / nf;
    let v = (row + 0.5) / nf;
    let px = u + v - 1.0;
    let py = u - v;
    let z = 1.0 - abs(px) - abs(py);
    var zc = 0.0;
    if (z > 0.0) {
        zc = z;
    }
    return vec3<f32>(px, py, zc);
}

// |w|^2 times the squared distance of cell k's centre line (along w) from the point c, in
// cell units.
fn nearest_line_score(k: vec3<u32>, c: vec3<f32>, w: vec3<f32>, ww: f32) -> f32 {
    let rx = f32(k.x) + 0.5 - c.x;
    let ry = f32(k.y) + 0.5 - c.y;
    let rz = f32(k.z) + 0.5 - c.z;
    let rr = rx * rx + ry * ry + rz * rz;
    let rw = rx * w.x + ry * w.y + rz * w.z;
    return rr * ww - rw * rw;
}

// The nearest-line lookup (pinrt::lookup::nearest_line_cell): of the cells the line through c
// (cell units) along the direction cell's axis crosses within `steps` one-cell steps each
// side, the one whose centre line passes nearest c; the home cell first, then +1, -1, +2, ...
fn nearest_line_cell(c: vec3<f32>, dcell: u32, steps: u32) -> vec3<u32> {
    let home = vec3<u32>(bin(c.x, G.dims.x), bin(c.y, G.dims.y), bin(c.z, G.dims.z));
    if (G.dirs.x != 1u || steps == 0u) {
        return home;
    }
    let a = octahedral_cell_axis(G.dirs.y, dcell);
    let dims = vec3<f32>(f32(G.dims.x), f32(G.dims.y), f32(G.dims.z));
    let w = vec3<f32>(a.x * dims.x, a.y * dims.y, a.z * dims.z);
    let ww = w.x * w.x + w.y * w.y + w.z * w.z;
    let ax = abs(w.x);
    let ay = abs(w.y);
    let az = abs(w.z);
    var m = ay;
    if (ax > ay) {
        m = ax;
    }
    if (az > m) {
        m = az;
    }
    let h = 1.0 / m;
    var best = home;
    var best_score = nearest_line_score(home, c, w, ww);
    let n = min(steps, MAX_NEAREST_LINE_STEPS);
    for (var step = 1u; step <= n; step = step + 1u) {
        let along = f32(step) * h;
        for (var side = 0u; side < 2u; side = side + 1u) {
            var lam = along;
            if (side == 1u) {
                lam = -along;
            }
            let q = vec3<f32>(c.x + lam * w.x, c.y + lam * w.y, c.z + lam * w.z);
            // A point beyond the grid names the border cell, as the lookup clamps.
            let k = vec3<u32>(bin(q.x, G.dims.x), bin(q.y, G.dims.y), bin(q.z, G.dims.z));
            let sc = nearest_line_score(k, c, w, ww);
            if (sc < best_score) {
                best = k;
                best_score = sc;
            }
        }
    }
    return best;
}

// ---------------------------------------------------------------------------------------------
// The query (pinrt::sampler)
// ---------------------------------------------------------------------------------------------

fn xf_point(p: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        G.row0.x * p.x + G.row0.y * p.y + G.row0.z * p.z + G.row0.w,
        G.row1.x * p.x + G.row1.y * p.y + G.row1.z * p.z + G.row1.w,
        G.row2.x * p.x + G.row2.y * p.y + G.row2.z * p.z + G.row2.w,
    );
}

fn xf_vector(v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        G.row0.x * v.x + G.row0.y * v.y + G.row0.z * v.z,
        G.row1.x * v.x + G.row1.y * v.y + G.row1.z * v.z,
        G.row2.x * v.x + G.row2.y * v.y + G.row2.z * v.z,
    );
}

fn empty_result(status: u32) -> QueryResult {
    return QueryResult(bitcast<f32>(inf_bits), 1.0, 0u, NO_ENTRY, 0u, NO_INTERVAL, status, rng_state);
}

// What a dispatch computes (the CPU's `Mode`): both estimates (`main`, the contract's
// reference), the transmittance only (`main_transmittance`: no draws 5-6, distance +inf, no
// hit) or the distance only (`main_distance`: transmittance 1, the chain stops at the first
// collision). Each gives the integers and floats of the CPU's query of the same mode.
const MODE_BOTH: u32 = 0u;
const MODE_TRANSMITTANCE: u32 = 1u;
const MODE_DISTANCE: u32 = 2u;

fn query(ray: Ray) -> QueryResult {
    return query_mode(ray, MODE_BOTH);
}

fn query_mode(ray: Ray, mode: u32) -> QueryResult {
    let o = xf_point(ray.origin);
    let d = xf_vector(ray.dir);
    let finite = is_finite_bits(o.x) && is_finite_bits(o.y) && is_finite_bits(o.z)
        && is_finite_bits(d.x) && is_finite_bits(d.y) && is_finite_bits(d.z);
    let nan_tmax = (bitcast<u32>(ray.t_max) & 0x7fffffffu) > 0x7f800000u;
    if (!finite || nan_tmax || (d.x == 0.0 && d.y == 0.0 && d.z == 0.0)) {
        return empty_result(STATUS_INVALID);
    }
    let ch = unit_cube_chord(o, d);
    if (!ch.ok) {
        return empty_result(STATUS_MISS);
    }
    let seg = make_segment(ch, ray.t_max);
    if (!seg.ok) {
        return empty_result(STATUS_MISS);
    }

    // Chained lookups (pinrt::sampler::piece_of): one lookup per piece of the segment cut at
    // every `stride`-th interval boundary; stride 32 is the single lookup.
    var stride = u32(G.jitter.z);
    if (stride == 0u || stride > 32u) {
        stride = 32u;
    }
    let want_t = mode != MODE_DISTANCE;
    var piece = seg.a / stride;
    var r = piece_query(o, d, piece_of(seg, piece, stride), mode == MODE_TRANSMITTANCE, want_t);
    // Like the CPU's `query` (Mode::Both): after a collision the remaining pieces still
    // multiply into the transmittance, without draws 5-6. A distance query stops at its
    // collision.
    loop {
        let cur = piece_of(seg, piece, stride);
        if (cur.b >= seg.b || (mode == MODE_DISTANCE && r.hit != 0u)) {
            break;
        }
        piece = piece + 1u;
        let skip_d = mode == MODE_TRANSMITTANCE || (mode == MODE_BOTH && r.hit != 0u);
        let n = piece_query(o, d, piece_of(seg, piece, stride), skip_d, want_t);
        r.transmittance = r.transmittance * n.transmittance;
        r.popcount = r.popcount + n.popcount;
        if (r.hit == 0u && n.hit != 0u) {
            r.hit = 1u;
            r.distance = n.distance;
            r.interval = n.interval;
        }
    }
    r.rng_state = rng_state;
    return r;
}

// Piece `j` of `full` cut every `stride` intervals (pinrt::sampler::piece_of).
fn piece_of(full: Segment, j: u32, stride: u32) -> Segment {
    let lo = j * stride;
    var hi = lo + stride;
    if (hi > 32u) {
        hi = 32u;
    }
    var p = full;
    if (full.a < lo) {
        p.a = lo;
        p.s0 = f32(lo);
        let t = full.t_enter + f32(lo) * full.interval_len;
        p.t0 = full.t0;
        if (t > full.t0) {
            p.t0 = t;
        }
    }
    if (full.b >= hi) {
        p.b = hi - 1u;
        p.s1 = f32(hi);
        let t = full.t_enter + f32(hi) * full.interval_len;
        p.t1 = full.t1;
        if (t < full.t1) {
            p.t1 = t;
        }
    }
    return p;
}

// One lookup over the piece `seg` (draws 1-6); `transmittance_only` skips draws 5-6 (a
// transmittance query, or a collision was already sampled in an earlier piece);
// `want_transmittance` false leaves the transmittance 1 (a distance query).
fn piece_query(o: vec3<f32>, d: vec3<f32>, seg: Segment, transmittance_only: bool, want_transmittance: bool) -> QueryResult {
    // Draws 1-3: pin number, spatial jitter, directional jitter.
    let ppe = G.grid.y;
    let k = ((rng_next() >> 8u) * ppe) >> 24u;
    let sj = G.jitter.x > 0.0 && is_finite_bits(G.jitter.x);
    var sxi = vec3<f32>(0.0, 0.0, 0.0);
    if (sj) {
        sxi.x = rng_f32();
        sxi.y = rng_f32();
        sxi.z = rng_f32();
    }
    let dj = G.jitter.y > 0.0 && is_finite_bits(G.jitter.y);
    var dxi0 = 0.0;
    var dxi1 = 0.0;
    if (dj) {
        dxi0 = rng_f32();
        dxi1 = rng_f32();
    }

    let reversed = d.z < 0.0;
    var dl = d;
    if (reversed) {
        dl = -d;
    }
    // Lookup point: bit 0 of G.jitter.w the middle, bit 1 `start_inside` (a piece starting
    // inside the box is looked up at its start without spatial jitter).
    let mode = u32(G.jitter.w);
    let inside = (mode & 2u) != 0u && seg.s0 > 0.0;
    var t0 = seg.t0;
    if ((mode & 1u) != 0u && !inside) {
        t0 = 0.5 * (seg.t0 + seg.t1);
    }
    let p = vec3<f32>(o.x + d.x * t0, o.y + d.y * t0, o.z + d.z * t0);
    var c = vec3<f32>(p.x * f32(G.dims.x), p.y * f32(G.dims.y), p.z * f32(G.dims.z));
    let dcell = direction_cell(dl, dj, G.jitter.y, dxi0, dxi1);
    // Bits 2 and up of the lookup mode: the nearest-line lookup's steps (0: off), which
    // replaces the spatial jitter.
    let near = mode >> 2u;
    var cell = vec3<u32>(0u, 0u, 0u);
    if (near > 0u) {
        cell = nearest_line_cell(c, dcell, near);
    } else {
        if (sj && !inside) {
            c.x = c.x + (sxi.x - 0.5) * G.jitter.x;
            c.y = c.y + (sxi.y - 0.5) * G.jitter.x;
            c.z = c.z + (sxi.z - 0.5) * G.jitter.x;
        }
        cell = vec3<u32>(bin(c.x, G.dims.x), bin(c.y, G.dims.y), bin(c.z, G.dims.z));
    }
    let cx = cell.x;
    let cy = cell.y;
    let cz = cell.z;

    // Address: covered slab, sparse index, block.
    var entry_id = NO_ENTRY;
    var mask = 0u;
    var t_min = 1.0;
    if (cz >= G.dims.w && cz < G.grid.x) {
        let local = cx + G.dims.x * (cy + G.dims.y * (cz - G.dims.w));
        var block = local;
        var present = true;
        if (G.dirs.w != 0u) {
            block = cell_index[G_INDEX_BASE + local];
            present = block != EMPTY_CELL && block < G.grid.w;
        }
        let within = dcell * ppe + k;
        if (present && within < G.grid.z) {
            entry_id = block * G.grid.z + within;
            let e = pins[G_PIN_BASE + entry_id];
            mask = e.x;
            t_min = bitcast<f32>(e.y);
        }
    }

    // Draw 4: partial first and last interval.
    let xa = rng_f32();
    let xb = rng_f32();
    t_min = sanitize_t_min(t_min);
    if (reversed) {
        mask = reverseBits(mask);
    }
    var part = interval_range(seg.a, seg.b);
    if (seg.a == seg.b) {
        if (!(xa < seg.s1 - seg.s0)) {
            part = 0u;
        }
    } else {
        if (!(xa < f32(seg.a + 1u) - seg.s0)) {
            part = part & ~interval_bit(seg.a);
        }
        if (!(xb < seg.s1 - f32(seg.b))) {
            part = part & ~interval_bit(seg.b);
        }
    }
    let popcount = countOneBits(mask & part);
    var r = QueryResult(bitcast<f32>(inf_bits), 1.0, 0u, entry_id, popcount, NO_INTERVAL, STATUS_OK, 0u);
    if (want_transmittance) {
        r.transmittance = pow_int(t_min, popcount);
    }

    if (transmittance_only) {
        r.rng_state = rng_state;
        return r;
    }
    // Draws 5-6: sample mask, position in the collision interval.
    let h = exact_sample_mask(t_min);
    let m = mask & part & h;
    if (m != 0u) {
        let j = countLeadingZeros(m);
        var lo = f32(j);
        if (j == seg.a) {
            lo = seg.s0;
        }
        var hi = f32(j + 1u);
        if (j == seg.b) {
            hi = seg.s1;
        }
        let xi = rng_f32();
        let s = lo + xi * (hi - lo);
        var t = seg.t_enter + s * seg.interval_len;
        if (!(t > seg.t0)) {
            t = seg.t0;
        }
        if (!(t < seg.t1)) {
            t = seg.t1;
        }
        r.distance = t;
        r.hit = 1u;
        r.interval = j;
    }
    r.rng_state = rng_state;
    return r;
}

// One query of `mode` for invocation `gid` (shared by the three entry points).
fn run_query(gid: vec3<u32>, mode: u32) {
    let i = gid.x + gid.y * P.run.w;
    if (i >= P.run.z) {
        return;
    }
    rng_state = pcg_hash(pcg_hash(P.run.x) ^ (P.run.y + i));
    G = P;
    G_PIN_BASE = 0u;
    G_INDEX_BASE = 0u;
    results[i] = query_mode(rays[i], mode);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    run_query(gid, MODE_BOTH);
}

@compute @workgroup_size(64)
fn main_transmittance(@builtin(global_invocation_id) gid: vec3<u32>) {
    run_query(gid, MODE_TRANSMITTANCE);
}

@compute @workgroup_size(64)
fn main_distance(@builtin(global_invocation_id) gid: vec3<u32>) {
    run_query(gid, MODE_DISTANCE);
}
