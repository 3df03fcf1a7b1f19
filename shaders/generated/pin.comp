#version 450 core
#extension GL_ARB_compute_shader : require
#extension GL_ARB_shader_storage_buffer_object : require
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

struct Params {
    vec4 row0_;
    vec4 row1_;
    vec4 row2_;
    vec4 jitter;
    uvec4 dims;
    uvec4 grid;
    uvec4 dirs;
    uvec4 run;
};
struct Ray {
    vec3 origin;
    float t_max;
    vec3 dir;
    uint pad;
};
struct QueryResult {
    float distance_;
    float transmittance;
    uint hit;
    uint entry;
    uint popcount;
    uint interval;
    uint status;
    uint rng_state;
};
struct Chord {
    bool ok;
    float t_enter;
    float t_exit;
};
struct Segment {
    bool ok;
    float t_enter;
    float interval_len;
    float t0_;
    float t1_;
    float s0_;
    float s1_;
    uint a;
    uint b;
};
const uint STATUS_OK = 0u;
const uint STATUS_MISS = 1u;
const uint STATUS_INVALID = 2u;
const uint NO_ENTRY = 4294967295u;
const uint NO_INTERVAL = 32u;
const uint EMPTY_CELL = 4294967295u;
const uint MAX_NEAREST_LINE_STEPS = 64u;
const float C0_ = 0.999866;
const float C1_ = -0.3302995;
const float C2_ = 0.180141;
const float C3_ = -0.085133;
const float C4_ = 0.0208351;
const float HALF_PI = 1.5707964;
const float PI = 3.1415927;
const float INV_TAU = 0.15915494;
const float MAXF = 3.4028235e38;
const float TWO_M24_ = 5.9604645e-8;
const float TWO_32_ = 4294967300.0;
const uint PCG_MUL = 747796405u;
const uint PCG_INC = 2891336453u;
const uint PCG_OUT_MUL = 277803737u;
const uint MODE_BOTH = 0u;
const uint MODE_TRANSMITTANCE = 1u;
const uint MODE_DISTANCE = 2u;

layout(std140, binding = 0) uniform Params_block_0Compute { Params _group_0_binding_0_cs; };

layout(std430, binding = 1) readonly buffer type_6_block_1Compute { uvec2 _group_0_binding_1_cs[]; };

layout(std430, binding = 2) readonly buffer type_7_block_2Compute { uint _group_0_binding_2_cs[]; };

layout(std430, binding = 3) readonly buffer type_8_block_3Compute { Ray _group_0_binding_3_cs[]; };

layout(std430, binding = 4) buffer type_9_block_4Compute { QueryResult _group_0_binding_4_cs[]; };

Params G = Params(vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0), uvec4(0u), uvec4(0u), uvec4(0u), uvec4(0u));

uint G_PIN_BASE = 0u;

uint G_INDEX_BASE = 0u;

uint inf_bits = 2139095040u;

uint rng_state = 0u;


uint pcg_output(uint state) {
    uint word = (((state >> ((state >> 28u) + 4u)) ^ state) * PCG_OUT_MUL);
    return ((word >> 22u) ^ word);
}

uint pcg_hash(uint x) {
    uint _e5 = pcg_output(((x * PCG_MUL) + PCG_INC));
    return _e5;
}

uint rng_next() {
    uint _e2 = rng_state;
    rng_state = ((_e2 * PCG_MUL) + PCG_INC);
    uint _e8 = rng_state;
    uint _e9 = pcg_output(_e8);
    return _e9;
}

float rng_f32_() {
    uint _e0 = rng_next();
    return (float((_e0 >> 8u)) * TWO_M24_);
}

bool is_finite_bits(float x_1) {
    return ((floatBitsToUint(x_1) & 2139095040u) != 2139095040u);
}

uint interval_bit(uint j) {
    if ((j >= 32u)) {
        return 0u;
    }
    return (2147483648u >> j);
}

uint interval_range(uint a, uint b) {
    bool local = false;
    if (!((a > b))) {
        local = (b > 31u);
    } else {
        local = true;
    }
    bool _e9 = local;
    if (_e9) {
        return 0u;
    }
    return ((4294967295u >> a) & (4294967295u << (31u - b)));
}

float pow_int(float base, uint n) {
    float result = 1.0;
    float b_1 = 0.0;
    uint i = 0u;
    float f = 0.0;
    b_1 = base;
    bool loop_init = true;
    while(true) {
        if (!loop_init) {
            uint _e25 = i;
            i = (_e25 + 1u);
        }
        loop_init = false;
        uint _e7 = i;
        if ((_e7 < 6u)) {
        } else {
            break;
        }
        {
            f = 1.0;
            uint _e12 = i;
            if ((((n >> _e12) & 1u) != 0u)) {
                float _e18 = b_1;
                f = _e18;
            }
            float _e19 = result;
            float _e20 = f;
            result = (_e19 * _e20);
            float _e22 = b_1;
            float _e23 = b_1;
            b_1 = (_e22 * _e23);
        }
    }
    float _e28 = result;
    return _e28;
}

float sanitize_t_min(float t) {
    uint bits = floatBitsToUint(t);
    uint mag = (bits & 2147483647u);
    if ((mag > 2139095040u)) {
        return 1.0;
    }
    if (((bits & 2147483648u) != 0u)) {
        return 0.0;
    }
    if ((mag >= 1065353216u)) {
        return 1.0;
    }
    return t;
}

uint exact_sample_mask(float t_1) {
    uint tq = 0u;
    bool local_1 = false;
    bool local_2 = false;
    uint result_1 = 0u;
    uint undecided = 4294967295u;
    uint j_1 = 31u;
    bool local_3 = false;
    if ((t_1 >= 1.0)) {
        return 0u;
    }
    float x_4 = (t_1 * TWO_32_);
    uint fl = uint(x_4);
    float frac = (x_4 - float(fl));
    tq = fl;
    if (!((frac > 0.5))) {
        if ((frac == 0.5)) {
            local_2 = ((fl & 1u) == 1u);
        } else {
            local_2 = false;
        }
        bool _e24 = local_2;
        local_1 = _e24;
    } else {
        local_1 = true;
    }
    bool _e26 = local_1;
    if (_e26) {
        tq = (fl + 1u);
    }
    uint _e29 = tq;
    if ((_e29 == 0u)) {
        return 4294967295u;
    }
    uint _e34 = tq;
    uint q = (0u - _e34);
    uint stop = min(uint(findLSB(q)), 32u);
    while(true) {
        uint _e43 = rng_next();
        uint _e45 = j_1;
        uint qb = (0u - ((q >> _e45) & 1u));
        uint _e50 = result_1;
        uint _e51 = undecided;
        result_1 = (_e50 | ((_e51 & ~(_e43)) & qb));
        uint _e56 = undecided;
        undecided = (_e56 & ~((_e43 ^ qb)));
        uint _e60 = undecided;
        if (!((_e60 == 0u))) {
            uint _e66 = j_1;
            local_3 = (_e66 == stop);
        } else {
            local_3 = true;
        }
        bool _e69 = local_3;
        if (_e69) {
            break;
        }
        uint _e70 = j_1;
        j_1 = (_e70 - 1u);
    }
    uint _e73 = result_1;
    return _e73;
}

uint bin(float x_2, uint n_1) {
    if (!((x_2 >= 1.0))) {
        return 0u;
    }
    if ((x_2 >= float(n_1))) {
        return (n_1 - 1u);
    }
    return min(uint(x_2), (n_1 - 1u));
}

Chord unit_cube_chord(vec3 o, vec3 d) {
    Chord c = Chord(false, 0.0, 0.0);
    float lo = -3.4028235e38;
    float hi = MAXF;
    bool constrained = false;
    uint a_1 = 0u;
    bool parallel = false;
    float inv = 0.0;
    bool local_4 = false;
    float n_2 = 0.0;
    float f_1 = 0.0;
    bool local_5 = false;
    bool local_6 = false;
    bool local_7 = false;
    bool loop_init_1 = true;
    while(true) {
        if (!loop_init_1) {
            uint _e64 = a_1;
            a_1 = (_e64 + 1u);
        }
        loop_init_1 = false;
        uint _e15 = a_1;
        if ((_e15 < 3u)) {
        } else {
            break;
        }
        {
            uint _e18 = a_1;
            float oa = o[_e18];
            uint _e20 = a_1;
            float da = d[_e20];
            parallel = (da == 0.0);
            inv = 0.0;
            bool _e27 = parallel;
            if (!(_e27)) {
                inv = (1.0 / da);
                float _e31 = inv;
                bool _e32 = is_finite_bits(_e31);
                parallel = !(_e32);
            }
            bool _e34 = parallel;
            if (_e34) {
                if ((oa >= 0.0)) {
                    local_4 = (oa <= 1.0);
                } else {
                    local_4 = false;
                }
                bool _e42 = local_4;
                if (!(_e42)) {
                    Chord _e44 = c;
                    return _e44;
                }
                continue;
            }
            float _e46 = inv;
            float t0_2 = (-(oa) * _e46);
            float _e50 = inv;
            float t1_1 = ((1.0 - oa) * _e50);
            n_2 = t1_1;
            f_1 = t0_2;
            if ((t0_2 < t1_1)) {
                n_2 = t0_2;
                f_1 = t1_1;
            }
            float _e55 = n_2;
            float _e56 = lo;
            if ((_e55 > _e56)) {
                float _e58 = n_2;
                lo = _e58;
            }
            float _e59 = f_1;
            float _e60 = hi;
            if ((_e59 < _e60)) {
                float _e62 = f_1;
                hi = _e62;
            }
            constrained = true;
        }
    }
    bool _e67 = constrained;
    if (!(!(_e67))) {
        float _e72 = lo;
        float _e73 = hi;
        local_5 = !((_e72 < _e73));
    } else {
        local_5 = true;
    }
    bool _e77 = local_5;
    if (!(_e77)) {
        float _e81 = lo;
        bool _e82 = is_finite_bits(_e81);
        local_6 = !(_e82);
    } else {
        local_6 = true;
    }
    bool _e85 = local_6;
    if (!(_e85)) {
        float _e89 = hi;
        bool _e90 = is_finite_bits(_e89);
        local_7 = !(_e90);
    } else {
        local_7 = true;
    }
    bool _e93 = local_7;
    if (_e93) {
        Chord _e94 = c;
        return _e94;
    }
    c.ok = true;
    float _e98 = lo;
    c.t_enter = _e98;
    float _e100 = hi;
    c.t_exit = _e100;
    Chord _e101 = c;
    return _e101;
}

Segment make_segment(Chord ch, float t_max) {
    Segment s = Segment(false, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0u, 0u);
    float t0_ = 0.0;
    float t1_ = 0.0;
    bool local_8 = false;
    float s0_ = 0.0;
    float s1_ = 32.0;
    uint b_2 = 0u;
    bool local_9 = false;
    float te = ch.t_enter;
    float tx = ch.t_exit;
    if ((te > 0.0)) {
        t0_ = te;
    }
    t1_ = tx;
    if ((t_max < tx)) {
        t1_ = t_max;
    }
    float _e21 = t0_;
    float _e22 = t1_;
    if (!((_e21 < _e22))) {
        Segment _e25 = s;
        return _e25;
    }
    float c_4 = (tx - te);
    float k_1 = (32.0 / c_4);
    bool _e29 = is_finite_bits(c_4);
    if (!(!(_e29))) {
        bool _e34 = is_finite_bits(k_1);
        local_8 = !(_e34);
    } else {
        local_8 = true;
    }
    bool _e37 = local_8;
    if (_e37) {
        Segment _e38 = s;
        return _e38;
    }
    float _e41 = t0_;
    if ((_e41 != te)) {
        float _e43 = t0_;
        s0_ = ((_e43 - te) * k_1);
        float _e46 = s0_;
        if (!((_e46 < 32.0))) {
            s0_ = 32.0;
        }
    }
    float _e53 = t1_;
    if ((_e53 != tx)) {
        float _e55 = t1_;
        s1_ = ((_e55 - te) * k_1);
        float _e58 = s1_;
        if (!((_e58 < 32.0))) {
            s1_ = 32.0;
        }
    }
    float _e63 = s0_;
    uint _e65 = bin(_e63, 32u);
    float _e66 = s1_;
    uint _e68 = bin(_e66, 32u);
    b_2 = _e68;
    float _e71 = s1_;
    if ((float(_e68) == _e71)) {
        local_9 = (_e68 > 0u);
    } else {
        local_9 = false;
    }
    bool _e78 = local_9;
    if (_e78) {
        b_2 = (_e68 - 1u);
    }
    uint _e81 = b_2;
    if ((_e81 < _e65)) {
        b_2 = _e65;
    }
    s.ok = true;
    s.t_enter = te;
    s.interval_len = (c_4 * 0.03125);
    float _e90 = t0_;
    s.t0_ = _e90;
    float _e92 = t1_;
    s.t1_ = _e92;
    float _e94 = s0_;
    s.s0_ = _e94;
    float _e96 = s1_;
    s.s1_ = _e96;
    s.a = _e65;
    uint _e99 = b_2;
    s.b = _e99;
    Segment _e100 = s;
    return _e100;
}

float atan2_turns(float y, float x_3) {
    float mx = 0.0;
    float mn = 0.0;
    float r = 0.0;
    float turns = 0.0;
    float ax = abs(x_3);
    float ay = abs(y);
    mx = ay;
    mn = ax;
    if ((ax > ay)) {
        mx = ax;
        mn = ay;
    }
    float _e7 = mx;
    if ((_e7 == 0.0)) {
        return 0.0;
    }
    float _e11 = mn;
    float _e12 = mx;
    float a_2 = (_e11 / _e12);
    float s_1 = (a_2 * a_2);
    r = (a_2 * (C0_ + (s_1 * (C1_ + (s_1 * (C2_ + (s_1 * (C3_ + (s_1 * C4_)))))))));
    if ((ay > ax)) {
        float _e32 = r;
        r = (HALF_PI - _e32);
    }
    if ((x_3 < 0.0)) {
        float _e37 = r;
        r = (PI - _e37);
    }
    if ((y < 0.0)) {
        float _e41 = r;
        r = -(_e41);
    }
    float _e43 = r;
    turns = (_e43 * INV_TAU);
    float _e47 = turns;
    if ((_e47 < 0.0)) {
        float _e50 = turns;
        turns = (_e50 + 1.0);
    }
    float _e53 = turns;
    if ((_e53 >= 1.0)) {
        return 0.0;
    }
    float _e57 = turns;
    return _e57;
}

uint direction_cell(vec3 d_1, bool jitter, float strength, float xi0_, float xi1_) {
    float ct = 0.0;
    float cp = 0.0;
    float cu = 0.0;
    float cv = 0.0;
    uint _e8 = G.dirs.x;
    if ((_e8 == 0u)) {
        uint n_phi = G.dirs.y;
        uint n_theta = G.dirs.z;
        float len2_ = (((d_1.x * d_1.x) + (d_1.y * d_1.y)) + (d_1.z * d_1.z));
        float z = (d_1.z / sqrt(len2_));
        ct = ((1.0 - z) * float(n_theta));
        float _e40 = atan2_turns(d_1.y, d_1.x);
        cp = (_e40 * float(n_phi));
        if (jitter) {
            float _e44 = ct;
            ct = (_e44 + ((xi0_ - 0.5) * strength));
            float _e49 = cp;
            cp = (_e49 + ((xi1_ - 0.5) * strength));
            float n_4 = float(n_phi);
            float _e55 = cp;
            if ((_e55 < 0.0)) {
                float _e58 = cp;
                cp = (_e58 + n_4);
            } else {
                float _e60 = cp;
                if ((_e60 >= n_4)) {
                    float _e62 = cp;
                    cp = (_e62 - n_4);
                }
            }
        }
        float _e64 = ct;
        uint _e65 = bin(_e64, n_theta);
        float _e67 = cp;
        uint _e68 = bin(_e67, n_phi);
        return ((_e65 * n_phi) + _e68);
    }
    uint n_5 = G.dirs.y;
    float sum = ((abs(d_1.x) + abs(d_1.y)) + d_1.z);
    float px = (d_1.x / sum);
    float py = (d_1.y / sum);
    float u = (((px + py) + 1.0) * 0.5);
    float v_1 = (((px - py) + 1.0) * 0.5);
    cu = (u * float(n_5));
    cv = (v_1 * float(n_5));
    if (jitter) {
        float _e101 = cu;
        cu = (_e101 + ((xi0_ - 0.5) * strength));
        float _e106 = cv;
        cv = (_e106 + ((xi1_ - 0.5) * strength));
    }
    float _e111 = cv;
    uint _e112 = bin(_e111, n_5);
    float _e114 = cu;
    uint _e115 = bin(_e114, n_5);
    return ((_e112 * n_5) + _e115);
}

vec3 octahedral_cell_axis(uint n_3, uint dcell) {
    float zc = 0.0;
    float nf = float(n_3);
    float df = float(dcell);
    float row = floor(((df + 0.5) / nf));
    float col = (df - (row * nf));
    float u_1 = ((col + 0.5) / nf);
    float v_2 = ((row + 0.5) / nf);
    float px_1 = ((u_1 + v_2) - 1.0);
    float py_1 = (u_1 - v_2);
    float z_1 = ((1.0 - abs(px_1)) - abs(py_1));
    if ((z_1 > 0.0)) {
        zc = z_1;
    }
    float _e29 = zc;
    return vec3(px_1, py_1, _e29);
}

float nearest_line_score(uvec3 k, vec3 c_1, vec3 w, float ww) {
    float rx = ((float(k.x) + 0.5) - c_1.x);
    float ry = ((float(k.y) + 0.5) - c_1.y);
    float rz = ((float(k.z) + 0.5) - c_1.z);
    float rr = (((rx * rx) + (ry * ry)) + (rz * rz));
    float rw = (((rx * w.x) + (ry * w.y)) + (rz * w.z));
    return ((rr * ww) - (rw * rw));
}

uvec3 nearest_line_cell(vec3 c_2, uint dcell_1, uint steps) {
    bool local_10 = false;
    float m = 0.0;
    uvec3 best = uvec3(0u);
    float best_score = 0.0;
    uint step_ = 1u;
    uint side = 0u;
    float lam = 0.0;
    uint _e7 = G.dims.x;
    uint _e8 = bin(c_2.x, _e7);
    uint _e13 = G.dims.y;
    uint _e14 = bin(c_2.y, _e13);
    uint _e19 = G.dims.z;
    uint _e20 = bin(c_2.z, _e19);
    uvec3 home = uvec3(_e8, _e14, _e20);
    uint _e25 = G.dirs.x;
    if (!((_e25 != 1u))) {
        local_10 = (steps == 0u);
    } else {
        local_10 = true;
    }
    bool _e34 = local_10;
    if (_e34) {
        return home;
    }
    uint _e38 = G.dirs.y;
    vec3 _e39 = octahedral_cell_axis(_e38, dcell_1);
    uint _e43 = G.dims.x;
    uint _e48 = G.dims.y;
    uint _e53 = G.dims.z;
    vec3 dims = vec3(float(_e43), float(_e48), float(_e53));
    vec3 w_1 = vec3((_e39.x * dims.x), (_e39.y * dims.y), (_e39.z * dims.z));
    float ww_1 = (((w_1.x * w_1.x) + (w_1.y * w_1.y)) + (w_1.z * w_1.z));
    float ax_1 = abs(w_1.x);
    float ay_1 = abs(w_1.y);
    float az = abs(w_1.z);
    m = ay_1;
    if ((ax_1 > ay_1)) {
        m = ax_1;
    }
    float _e85 = m;
    if ((az > _e85)) {
        m = az;
    }
    float _e87 = m;
    float h = (1.0 / _e87);
    best = home;
    float _e91 = nearest_line_score(home, c_2, w_1, ww_1);
    best_score = _e91;
    uint n_6 = min(steps, MAX_NEAREST_LINE_STEPS);
    bool loop_init_2 = true;
    while(true) {
        if (!loop_init_2) {
            uint _e153 = step_;
            step_ = (_e153 + 1u);
        }
        loop_init_2 = false;
        uint _e97 = step_;
        if ((_e97 <= n_6)) {
        } else {
            break;
        }
        {
            uint _e99 = step_;
            float along = (float(_e99) * h);
            side = 0u;
            bool loop_init_3 = true;
            while(true) {
                if (!loop_init_3) {
                    uint _e150 = side;
                    side = (_e150 + 1u);
                }
                loop_init_3 = false;
                uint _e104 = side;
                if ((_e104 < 2u)) {
                } else {
                    break;
                }
                {
                    lam = along;
                    uint _e108 = side;
                    if ((_e108 == 1u)) {
                        lam = -(along);
                    }
                    float _e113 = lam;
                    float _e118 = lam;
                    float _e123 = lam;
                    vec3 q_1 = vec3((c_2.x + (_e113 * w_1.x)), (c_2.y + (_e118 * w_1.y)), (c_2.z + (_e123 * w_1.z)));
                    uint _e132 = G.dims.x;
                    uint _e133 = bin(q_1.x, _e132);
                    uint _e138 = G.dims.y;
                    uint _e139 = bin(q_1.y, _e138);
                    uint _e144 = G.dims.z;
                    uint _e145 = bin(q_1.z, _e144);
                    uvec3 k_2 = uvec3(_e133, _e139, _e145);
                    float _e147 = nearest_line_score(k_2, c_2, w_1, ww_1);
                    float _e148 = best_score;
                    if ((_e147 < _e148)) {
                        best = k_2;
                        best_score = _e147;
                    }
                }
            }
        }
    }
    uvec3 _e156 = best;
    return _e156;
}

vec3 xf_point(vec3 p) {
    float _e4 = G.row0_.x;
    float _e10 = G.row0_.y;
    float _e17 = G.row0_.z;
    float _e24 = G.row0_.w;
    float _e29 = G.row1_.x;
    float _e35 = G.row1_.y;
    float _e42 = G.row1_.z;
    float _e49 = G.row1_.w;
    float _e54 = G.row2_.x;
    float _e60 = G.row2_.y;
    float _e67 = G.row2_.z;
    float _e74 = G.row2_.w;
    return vec3(((((_e4 * p.x) + (_e10 * p.y)) + (_e17 * p.z)) + _e24), ((((_e29 * p.x) + (_e35 * p.y)) + (_e42 * p.z)) + _e49), ((((_e54 * p.x) + (_e60 * p.y)) + (_e67 * p.z)) + _e74));
}

vec3 xf_vector(vec3 v) {
    float _e4 = G.row0_.x;
    float _e10 = G.row0_.y;
    float _e17 = G.row0_.z;
    float _e24 = G.row1_.x;
    float _e30 = G.row1_.y;
    float _e37 = G.row1_.z;
    float _e44 = G.row2_.x;
    float _e50 = G.row2_.y;
    float _e57 = G.row2_.z;
    return vec3((((_e4 * v.x) + (_e10 * v.y)) + (_e17 * v.z)), (((_e24 * v.x) + (_e30 * v.y)) + (_e37 * v.z)), (((_e44 * v.x) + (_e50 * v.y)) + (_e57 * v.z)));
}

QueryResult empty_result(uint status) {
    uint _e2 = inf_bits;
    uint _e9 = rng_state;
    return QueryResult(uintBitsToFloat(_e2), 1.0, 0u, NO_ENTRY, 0u, NO_INTERVAL, status, _e9);
}

QueryResult piece_query(vec3 o_1, vec3 d_2, Segment seg, bool transmittance_only, bool want_transmittance) {
    bool local_11 = false;
    vec3 sxi = vec3(0.0, 0.0, 0.0);
    bool local_12 = false;
    float dxi0_ = 0.0;
    float dxi1_ = 0.0;
    vec3 dl = vec3(0.0);
    bool local_13 = false;
    float t0_1 = 0.0;
    bool local_14 = false;
    vec3 c_3 = vec3(0.0);
    uvec3 cell = uvec3(0u, 0u, 0u);
    bool local_15 = false;
    uint entry_id = NO_ENTRY;
    uint mask = 0u;
    float t_min = 1.0;
    bool local_16 = false;
    uint block = 0u;
    bool present = true;
    bool local_17 = false;
    bool local_18 = false;
    uint part = 0u;
    QueryResult r_1 = QueryResult(0.0, 0.0, 0u, 0u, 0u, 0u, 0u, 0u);
    float lo_1 = 0.0;
    float hi_1 = 0.0;
    float t_2 = 0.0;
    uint ppe = G.grid.y;
    uint _e9 = rng_next();
    uint k_3 = (((_e9 >> 8u) * ppe) >> 24u);
    float _e18 = G.jitter.x;
    if ((_e18 > 0.0)) {
        float _e26 = G.jitter.x;
        bool _e27 = is_finite_bits(_e26);
        local_11 = _e27;
    } else {
        local_11 = false;
    }
    bool sj = local_11;
    if (sj) {
        float _e36 = rng_f32_();
        sxi.x = _e36;
        float _e38 = rng_f32_();
        sxi.y = _e38;
        float _e40 = rng_f32_();
        sxi.z = _e40;
    }
    float _e44 = G.jitter.y;
    if ((_e44 > 0.0)) {
        float _e52 = G.jitter.y;
        bool _e53 = is_finite_bits(_e52);
        local_12 = _e53;
    } else {
        local_12 = false;
    }
    bool dj = local_12;
    if (dj) {
        float _e60 = rng_f32_();
        dxi0_ = _e60;
        float _e61 = rng_f32_();
        dxi1_ = _e61;
    }
    bool reversed = (d_2.z < 0.0);
    dl = d_2;
    if (reversed) {
        dl = -(d_2);
    }
    float _e70 = G.jitter.w;
    uint mode_2 = uint(_e70);
    if (((mode_2 & 2u) != 0u)) {
        local_13 = (seg.s0_ > 0.0);
    } else {
        local_13 = false;
    }
    bool inside = local_13;
    t0_1 = seg.t0_;
    if (((mode_2 & 1u) != 0u)) {
        local_14 = !(inside);
    } else {
        local_14 = false;
    }
    bool _e93 = local_14;
    if (_e93) {
        t0_1 = (0.5 * (seg.t0_ + seg.t1_));
    }
    float _e101 = t0_1;
    float _e106 = t0_1;
    float _e111 = t0_1;
    vec3 p_2 = vec3((o_1.x + (d_2.x * _e101)), (o_1.y + (d_2.y * _e106)), (o_1.z + (d_2.z * _e111)));
    uint _e119 = G.dims.x;
    uint _e126 = G.dims.y;
    uint _e133 = G.dims.z;
    c_3 = vec3((p_2.x * float(_e119)), (p_2.y * float(_e126)), (p_2.z * float(_e133)));
    vec3 _e138 = dl;
    float _e142 = G.jitter.y;
    float _e143 = dxi0_;
    float _e144 = dxi1_;
    uint _e145 = direction_cell(_e138, dj, _e142, _e143, _e144);
    uint near = (mode_2 >> 2u);
    if ((near > 0u)) {
        vec3 _e155 = c_3;
        uvec3 _e156 = nearest_line_cell(_e155, _e145, near);
        cell = _e156;
    } else {
        if (sj) {
            local_15 = !(inside);
        } else {
            local_15 = false;
        }
        bool _e161 = local_15;
        if (_e161) {
            float _e164 = c_3.x;
            float _e166 = sxi.x;
            float _e172 = G.jitter.x;
            c_3.x = (_e164 + ((_e166 - 0.5) * _e172));
            float _e177 = c_3.y;
            float _e179 = sxi.y;
            float _e185 = G.jitter.x;
            c_3.y = (_e177 + ((_e179 - 0.5) * _e185));
            float _e190 = c_3.z;
            float _e192 = sxi.z;
            float _e198 = G.jitter.x;
            c_3.z = (_e190 + ((_e192 - 0.5) * _e198));
        }
        float _e202 = c_3.x;
        uint _e206 = G.dims.x;
        uint _e207 = bin(_e202, _e206);
        float _e209 = c_3.y;
        uint _e213 = G.dims.y;
        uint _e214 = bin(_e209, _e213);
        float _e216 = c_3.z;
        uint _e220 = G.dims.z;
        uint _e221 = bin(_e216, _e220);
        cell = uvec3(_e207, _e214, _e221);
    }
    uint cx = cell.x;
    uint cy = cell.y;
    uint cz = cell.z;
    uint _e238 = G.dims.w;
    if ((cz >= _e238)) {
        uint _e245 = G.grid.x;
        local_16 = (cz < _e245);
    } else {
        local_16 = false;
    }
    bool _e248 = local_16;
    if (_e248) {
        uint _e252 = G.dims.x;
        uint _e256 = G.dims.y;
        uint _e260 = G.dims.w;
        uint local_34 = (cx + (_e252 * (cy + (_e256 * (cz - _e260)))));
        block = local_34;
        uint _e272 = G.dirs.w;
        if ((_e272 != 0u)) {
            uint _e277 = G_INDEX_BASE;
            uint _e280 = _group_0_binding_2_cs[(_e277 + local_34)];
            block = _e280;
            uint _e281 = block;
            if ((_e281 != EMPTY_CELL)) {
                uint _e286 = block;
                uint _e290 = G.grid.w;
                local_17 = (_e286 < _e290);
            } else {
                local_17 = false;
            }
            bool _e293 = local_17;
            present = _e293;
        }
        uint within = ((_e145 * ppe) + k_3);
        bool _e296 = present;
        if (_e296) {
            uint _e302 = G.grid.z;
            local_18 = (within < _e302);
        } else {
            local_18 = false;
        }
        bool _e305 = local_18;
        if (_e305) {
            uint _e306 = block;
            uint _e310 = G.grid.z;
            entry_id = ((_e306 * _e310) + within);
            uint _e315 = G_PIN_BASE;
            uint _e316 = entry_id;
            uvec2 e = _group_0_binding_1_cs[(_e315 + _e316)];
            mask = e.x;
            t_min = uintBitsToFloat(e.y);
        }
    }
    float _e323 = rng_f32_();
    float _e324 = rng_f32_();
    float _e325 = t_min;
    float _e326 = sanitize_t_min(_e325);
    t_min = _e326;
    if (reversed) {
        uint _e327 = mask;
        mask = bitfieldReverse(_e327);
    }
    uint _e331 = interval_range(seg.a, seg.b);
    part = _e331;
    if ((seg.a == seg.b)) {
        if (!((_e323 < (seg.s1_ - seg.s0_)))) {
            part = 0u;
        }
    } else {
        if (!((_e323 < (float((seg.a + 1u)) - seg.s0_)))) {
            uint _e350 = part;
            uint _e352 = interval_bit(seg.a);
            part = (_e350 & ~(_e352));
        }
        if (!((_e324 < (seg.s1_ - float(seg.b))))) {
            uint _e361 = part;
            uint _e363 = interval_bit(seg.b);
            part = (_e361 & ~(_e363));
        }
    }
    uint _e366 = mask;
    uint _e367 = part;
    uint popcount = uint(bitCount((_e366 & _e367)));
    uint _e371 = inf_bits;
    uint _e374 = entry_id;
    r_1 = QueryResult(uintBitsToFloat(_e371), 1.0, 0u, _e374, popcount, NO_INTERVAL, STATUS_OK, 0u);
    if (want_transmittance) {
        float _e382 = t_min;
        float _e383 = pow_int(_e382, popcount);
        r_1.transmittance = _e383;
    }
    if (transmittance_only) {
        uint _e386 = rng_state;
        r_1.rng_state = _e386;
        QueryResult _e387 = r_1;
        return _e387;
    }
    float _e388 = t_min;
    uint _e389 = exact_sample_mask(_e388);
    uint _e390 = mask;
    uint _e391 = part;
    uint m_1 = ((_e390 & _e391) & _e389);
    if ((m_1 != 0u)) {
        uint j_3 = uint(31 - findMSB(m_1));
        lo_1 = float(j_3);
        if ((j_3 == seg.a)) {
            lo_1 = seg.s0_;
        }
        hi_1 = float((j_3 + 1u));
        if ((j_3 == seg.b)) {
            hi_1 = seg.s1_;
        }
        float _e409 = rng_f32_();
        float _e410 = lo_1;
        float _e411 = hi_1;
        float _e412 = lo_1;
        float s_2 = (_e410 + (_e409 * (_e411 - _e412)));
        t_2 = (seg.t_enter + (s_2 * seg.interval_len));
        float _e421 = t_2;
        if (!((_e421 > seg.t0_))) {
            t_2 = seg.t0_;
        }
        float _e426 = t_2;
        if (!((_e426 < seg.t1_))) {
            t_2 = seg.t1_;
        }
        float _e432 = t_2;
        r_1.distance_ = _e432;
        r_1.hit = 1u;
        r_1.interval = j_3;
    }
    uint _e438 = rng_state;
    r_1.rng_state = _e438;
    QueryResult _e439 = r_1;
    return _e439;
}

Segment piece_of(Segment full, uint j_2, uint stride) {
    uint hi_2 = 0u;
    Segment p_1 = Segment(false, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0u, 0u);
    uint lo_2 = (j_2 * stride);
    hi_2 = (lo_2 + stride);
    uint _e6 = hi_2;
    if ((_e6 > 32u)) {
        hi_2 = 32u;
    }
    p_1 = full;
    if ((full.a < lo_2)) {
        p_1.a = lo_2;
        p_1.s0_ = float(lo_2);
        float t_3 = (full.t_enter + (float(lo_2) * full.interval_len));
        p_1.t0_ = full.t0_;
        if ((t_3 > full.t0_)) {
            p_1.t0_ = t_3;
        }
    }
    uint _e27 = hi_2;
    if ((full.b >= _e27)) {
        uint _e30 = hi_2;
        p_1.b = (_e30 - 1u);
        uint _e34 = hi_2;
        p_1.s1_ = float(_e34);
        uint _e37 = hi_2;
        float t_4 = (full.t_enter + (float(_e37) * full.interval_len));
        p_1.t1_ = full.t1_;
        if ((t_4 < full.t1_)) {
            p_1.t1_ = t_4;
        }
    }
    Segment _e47 = p_1;
    return _e47;
}

QueryResult query_mode(Ray ray, uint mode) {
    bool local_19 = false;
    bool local_20 = false;
    bool local_21 = false;
    bool local_22 = false;
    bool local_23 = false;
    bool local_24 = false;
    bool local_25 = false;
    bool local_26 = false;
    bool local_27 = false;
    uint stride_1 = 0u;
    bool local_28 = false;
    uint piece = 0u;
    QueryResult r_2 = QueryResult(0.0, 0.0, 0u, 0u, 0u, 0u, 0u, 0u);
    bool local_29 = false;
    bool local_30 = false;
    bool local_31 = false;
    bool local_32 = false;
    bool local_33 = false;
    vec3 _e3 = xf_point(ray.origin);
    vec3 _e5 = xf_vector(ray.dir);
    bool _e7 = is_finite_bits(_e3.x);
    if (_e7) {
        bool _e11 = is_finite_bits(_e3.y);
        local_19 = _e11;
    } else {
        local_19 = false;
    }
    bool _e13 = local_19;
    if (_e13) {
        bool _e17 = is_finite_bits(_e3.z);
        local_20 = _e17;
    } else {
        local_20 = false;
    }
    bool _e19 = local_20;
    if (_e19) {
        bool _e23 = is_finite_bits(_e5.x);
        local_21 = _e23;
    } else {
        local_21 = false;
    }
    bool _e25 = local_21;
    if (_e25) {
        bool _e29 = is_finite_bits(_e5.y);
        local_22 = _e29;
    } else {
        local_22 = false;
    }
    bool _e31 = local_22;
    if (_e31) {
        bool _e35 = is_finite_bits(_e5.z);
        local_23 = _e35;
    } else {
        local_23 = false;
    }
    bool finite = local_23;
    bool nan_tmax = ((floatBitsToUint(ray.t_max) & 2147483647u) > 2139095040u);
    if (!(!(finite))) {
        local_24 = nan_tmax;
    } else {
        local_24 = true;
    }
    bool _e49 = local_24;
    if (!(_e49)) {
        if ((_e5.x == 0.0)) {
            local_26 = (_e5.y == 0.0);
        } else {
            local_26 = false;
        }
        bool _e62 = local_26;
        if (_e62) {
            local_27 = (_e5.z == 0.0);
        } else {
            local_27 = false;
        }
        bool _e69 = local_27;
        local_25 = _e69;
    } else {
        local_25 = true;
    }
    bool _e71 = local_25;
    if (_e71) {
        QueryResult _e73 = empty_result(STATUS_INVALID);
        return _e73;
    }
    Chord _e74 = unit_cube_chord(_e3, _e5);
    if (!(_e74.ok)) {
        QueryResult _e78 = empty_result(STATUS_MISS);
        return _e78;
    }
    Segment _e80 = make_segment(_e74, ray.t_max);
    if (!(_e80.ok)) {
        QueryResult _e84 = empty_result(STATUS_MISS);
        return _e84;
    }
    float _e88 = G.jitter.z;
    stride_1 = uint(_e88);
    uint _e91 = stride_1;
    if (!((_e91 == 0u))) {
        uint _e97 = stride_1;
        local_28 = (_e97 > 32u);
    } else {
        local_28 = true;
    }
    bool _e101 = local_28;
    if (_e101) {
        stride_1 = 32u;
    }
    bool want_t = (mode != MODE_DISTANCE);
    uint _e106 = stride_1;
    piece = (_e80.a / _e106);
    uint _e109 = piece;
    uint _e110 = stride_1;
    Segment _e111 = piece_of(_e80, _e109, _e110);
    QueryResult _e114 = piece_query(_e3, _e5, _e111, (mode == MODE_TRANSMITTANCE), want_t);
    r_2 = _e114;
    while(true) {
        uint _e116 = piece;
        uint _e117 = stride_1;
        Segment _e118 = piece_of(_e80, _e116, _e117);
        if (!((_e118.b >= _e80.b))) {
            if ((mode == MODE_DISTANCE)) {
                uint _e130 = r_2.hit;
                local_30 = (_e130 != 0u);
            } else {
                local_30 = false;
            }
            bool _e134 = local_30;
            local_29 = _e134;
        } else {
            local_29 = true;
        }
        bool _e136 = local_29;
        if (_e136) {
            break;
        }
        uint _e137 = piece;
        piece = (_e137 + 1u);
        if (!((mode == MODE_TRANSMITTANCE))) {
            if ((mode == MODE_BOTH)) {
                uint _e150 = r_2.hit;
                local_32 = (_e150 != 0u);
            } else {
                local_32 = false;
            }
            bool _e154 = local_32;
            local_31 = _e154;
        } else {
            local_31 = true;
        }
        bool skip_d = local_31;
        uint _e157 = piece;
        uint _e158 = stride_1;
        Segment _e159 = piece_of(_e80, _e157, _e158);
        QueryResult _e160 = piece_query(_e3, _e5, _e159, skip_d, want_t);
        float _e163 = r_2.transmittance;
        r_2.transmittance = (_e163 * _e160.transmittance);
        uint _e168 = r_2.popcount;
        r_2.popcount = (_e168 + _e160.popcount);
        uint _e172 = r_2.hit;
        if ((_e172 == 0u)) {
            local_33 = (_e160.hit != 0u);
        } else {
            local_33 = false;
        }
        bool _e181 = local_33;
        if (_e181) {
            r_2.hit = 1u;
            r_2.distance_ = _e160.distance_;
            r_2.interval = _e160.interval;
        }
    }
    uint _e190 = rng_state;
    r_2.rng_state = _e190;
    QueryResult _e191 = r_2;
    return _e191;
}

QueryResult query(Ray ray_1) {
    QueryResult _e2 = query_mode(ray_1, MODE_BOTH);
    return _e2;
}

void run_query(uvec3 gid_3, uint mode_1) {
    uint _e7 = _group_0_binding_0_cs.run.w;
    uint i_1 = (gid_3.x + (gid_3.y * _e7));
    uint _e13 = _group_0_binding_0_cs.run.z;
    if ((i_1 >= _e13)) {
        return;
    }
    uint _e19 = _group_0_binding_0_cs.run.x;
    uint _e20 = pcg_hash(_e19);
    uint _e24 = _group_0_binding_0_cs.run.y;
    uint _e27 = pcg_hash((_e20 ^ (_e24 + i_1)));
    rng_state = _e27;
    Params _e30 = _group_0_binding_0_cs;
    G = _e30;
    G_PIN_BASE = 0u;
    G_INDEX_BASE = 0u;
    Ray _e39 = _group_0_binding_3_cs[i_1];
    QueryResult _e40 = query_mode(_e39, mode_1);
    _group_0_binding_4_cs[i_1] = _e40;
    return;
}

void main() {
    uvec3 gid = gl_GlobalInvocationID;
    run_query(gid, MODE_BOTH);
    return;
}

