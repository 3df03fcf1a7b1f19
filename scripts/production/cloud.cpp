// Writes a dense cumulus cloud with OpenVDB itself: a float grid named "density", saved as
// half with Blosc and active-mask compression (how production clouds are shipped), for the
// scale benchmark (scripts/scale-bench.sh) and the production-scale tests.
//
//   c++ -std=c++17 -O2 cloud.cpp -o cloud -lopenvdb -ltbb -lImath
//   cloud OUT.vdb NX NY NZ [SEED] [FRAME]
//
// The cloud fills a box of NX x NY x NZ voxels (y is up). It is the union of "puffs":
// spheres stacked into a flat-bottomed dome, their surface displaced by fractal value noise,
// with a soft edge and a noisy interior, so that the density is billowy like a real cumulus
// rather than a box. Every number comes from the seed, and the shape does not depend on the
// resolution: the same seed at twice the dims is the same cloud at twice the detail. FRAME
// moves the puffs and the noise a little per frame (an animated sequence). Prints one JSON
// line: dims, active voxels, leaves, seconds.
//
// Voxels are evaluated a leaf (8^3) at a time, in parallel over z-slabs of leaves; a leaf
// that no puff's displaced, softened sphere can reach is skipped without evaluating its
// voxels, so the cost is proportional to the cloud, not to its box.

#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>
#include <tbb/parallel_for.h>
#include <tbb/blocked_range.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <vector>

using namespace openvdb;

namespace {

// One 64-bit mix per lattice point: the noise is a pure function of position and seed.
inline uint64_t mix(uint64_t x) {
    x ^= x >> 30;
    x *= 0xbf58476d1ce4e5b9ULL;
    x ^= x >> 27;
    x *= 0x94d049bb133111ebULL;
    x ^= x >> 31;
    return x;
}

inline float lattice(int64_t x, int64_t y, int64_t z, uint64_t seed) {
    uint64_t h = mix(uint64_t(x) * 0x9E3779B97F4A7C15ULL ^ mix(uint64_t(y) + seed) ^
                     (uint64_t(z) << 21) * 0xC2B2AE3D27D4EB4FULL);
    return float(h >> 40) * (2.0f / 16777216.0f) - 1.0f;  // in [-1, 1)
}

inline float smooth(float t) { return t * t * (3.0f - 2.0f * t); }

// Trilinear value noise in [-1, 1] with a smooth fade.
float value_noise(float x, float y, float z, uint64_t seed) {
    float fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
    int64_t ix = int64_t(fx), iy = int64_t(fy), iz = int64_t(fz);
    float tx = smooth(x - fx), ty = smooth(y - fy), tz = smooth(z - fz);
    float c[8];
    for (int n = 0; n < 8; ++n) {
        c[n] = lattice(ix + (n & 1), iy + ((n >> 1) & 1), iz + ((n >> 2) & 1), seed);
    }
    float x00 = c[0] + (c[1] - c[0]) * tx, x10 = c[2] + (c[3] - c[2]) * tx;
    float x01 = c[4] + (c[5] - c[4]) * tx, x11 = c[6] + (c[7] - c[6]) * tx;
    float y0 = x00 + (x10 - x00) * ty, y1 = x01 + (x11 - x01) * ty;
    return y0 + (y1 - y0) * tz;
}

// Four octaves, lacunarity 2, gain 0.5; about [-1, 1].
float fbm(float x, float y, float z, uint64_t seed) {
    float sum = 0.0f, amp = 0.5333f, f = 1.0f;
    for (int o = 0; o < 4; ++o) {
        sum += amp * value_noise(x * f, y * f, z * f, seed + uint64_t(o) * 7919);
        f *= 2.03f;
        amp *= 0.5f;
    }
    return sum;
}

struct Lcg {
    uint64_t s;
    explicit Lcg(uint64_t seed) : s(mix(seed + 1)) {}
    double uniform() {
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        return double(s >> 11) * (1.0 / 9007199254740992.0);
    }
};

// A puff: a sphere in unit coordinates (the box's long axis spans [0, 1]).
struct Puff {
    double cx, cy, cz, r;
};

// The cloud's shape in unit coordinates: a flat-bottomed dome of puffs, large ones low and
// central, smaller ones on the flanks and the crown.
std::vector<Puff> make_puffs(double ex, double ey, double ez, uint64_t seed, int frame,
                             double amp_margin) {
    Lcg rng(seed);
    std::vector<Puff> puffs;
    const int count = 70;
    const double base = 0.05 * ey;  // the flat bottom, above the box floor
    for (int i = 0; i < count; ++i) {
        double a = rng.uniform() * 6.283185307179586, rad = std::sqrt(rng.uniform());
        double x = 0.5 * ex + std::cos(a) * rad * 0.36 * ex;
        double z = 0.5 * ez + std::sin(a) * rad * 0.36 * ez;
        // Lower and smaller towards the edge of the dome.
        double edge = 1.0 - 0.55 * rad;
        double r = (0.175 + 0.155 * rng.uniform()) * edge * std::min(ex, std::min(ey * 1.8, ez));
        double y = base + r * 0.6 + rng.uniform() * (0.48 * ey) * edge * edge;
        // Frames: each puff drifts and breathes a little.
        double ph = rng.uniform() * 6.283185307179586;
        double t = 0.05 * frame;
        x += 0.01 * ex * std::sin(t + ph);
        y += 0.006 * ey * t;
        r *= 1.0 + 0.04 * std::sin(1.7 * t + ph);
        // Inside the box with room for the displaced edge: the box is the cloud's own
        // bounding box, never a cut through it.
        const double m = r + amp_margin;
        x = std::min(std::max(x, m), ex - m);
        y = std::min(y, ey - m);
        z = std::min(std::max(z, m), ez - m);
        puffs.push_back({x, y, z, r});
    }
    return puffs;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 5) {
        std::fprintf(stderr, "usage: %s OUT.vdb NX NY NZ [SEED] [FRAME]\n", argv[0]);
        return 2;
    }
    const std::string out = argv[1];
    const int nx = std::atoi(argv[2]), ny = std::atoi(argv[3]), nz = std::atoi(argv[4]);
    const uint64_t seed = argc > 5 ? std::strtoull(argv[5], nullptr, 10) : 1;
    const int frame = argc > 6 ? std::atoi(argv[6]) : 0;
    if (nx < 8 || ny < 8 || nz < 8 || nx > 100000 || ny > 100000 || nz > 100000) {
        std::fprintf(stderr, "%s: dims must be 8..100000 per axis\n", argv[0]);
        return 2;
    }
    auto t0 = std::chrono::steady_clock::now();
    openvdb::initialize();

    // Unit coordinates: the longest axis spans [0, 1].
    const double longest = double(std::max(nx, std::max(ny, nz)));
    const double ex = nx / longest, ey = ny / longest, ez = nz / longest;
    // Surface displacement and soft edge, in unit lengths.
    const double amp = 0.035, soft = 0.012;
    const std::vector<Puff> puffs = make_puffs(ex, ey, ez, seed, frame, amp + soft);
    const float noise_freq = 22.0f, drift = 0.02f * float(frame);
    const double inv = 1.0 / longest;

    const int lx = (nx + 7) / 8, ly = (ny + 7) / 8, lz = (nz + 7) / 8;
    FloatGrid::Ptr grid = FloatGrid::create(0.0f);
    std::mutex merge;
    size_t active = 0;
    tbb::parallel_for(tbb::blocked_range<int>(0, lz), [&](const tbb::blocked_range<int>& zs) {
        FloatTree local(0.0f);
        size_t local_active = 0;
        std::vector<const Puff*> near;
        for (int bz = zs.begin(); bz < zs.end(); ++bz) {
            for (int by = 0; by < ly; ++by) {
                for (int bx = 0; bx < lx; ++bx) {
                    // The leaf's box in unit coordinates and the puffs that can reach it.
                    const double x0 = bx * 8 * inv, y0 = by * 8 * inv, z0 = bz * 8 * inv;
                    const double x1 = x0 + 8 * inv, y1 = y0 + 8 * inv, z1 = z0 + 8 * inv;
                    near.clear();
                    for (const Puff& p : puffs) {
                        double dx = std::max(0.0, std::max(x0 - p.cx, p.cx - x1));
                        double dy = std::max(0.0, std::max(y0 - p.cy, p.cy - y1));
                        double dz = std::max(0.0, std::max(z0 - p.cz, p.cz - z1));
                        if (std::sqrt(dx * dx + dy * dy + dz * dz) < p.r + amp + soft) {
                            near.push_back(&p);
                        }
                    }
                    if (near.empty()) continue;
                    FloatTree::LeafNodeType* leaf = nullptr;
                    for (int i = 0; i < 8; ++i) {
                        const int x = bx * 8 + i;
                        if (x >= nx) break;
                        for (int j = 0; j < 8; ++j) {
                            const int y = by * 8 + j;
                            if (y >= ny) break;
                            for (int k = 0; k < 8; ++k) {
                                const int z = bz * 8 + k;
                                if (z >= nz) break;
                                const double ux = (x + 0.5) * inv, uy = (y + 0.5) * inv,
                                             uz = (z + 0.5) * inv;
                                // Distance to the union of the puffs (negative inside).
                                double d = 1e9;
                                for (const Puff* p : near) {
                                    double qx = ux - p->cx, qy = uy - p->cy, qz = uz - p->cz;
                                    d = std::min(d, std::sqrt(qx * qx + qy * qy + qz * qz) - p->r);
                                }
                                if (d > amp + soft) continue;
                                const float n = fbm(float(ux) * noise_freq + drift,
                                                    float(uy) * noise_freq,
                                                    float(uz) * noise_freq - drift, seed);
                                // The flat base: density fades out just below the lowest puffs.
                                const double floor_d = (0.05 * ey - uy) * 0.7;
                                const double dd = std::max(d + amp * n, floor_d);
                                if (dd >= 0.0) continue;
                                const double edge = std::min(1.0, -dd / soft);
                                const float v = float(edge * edge * (3.0 - 2.0 * edge)) *
                                                (0.72f + 0.28f * n);
                                if (v <= 0.0f) continue;
                                if (!leaf) leaf = local.touchLeaf(Coord(bx * 8, by * 8, bz * 8));
                                leaf->setValueOn(Coord(x, y, z), v);
                                ++local_active;
                            }
                        }
                    }
                }
            }
        }
        std::lock_guard<std::mutex> lock(merge);
        grid->tree().merge(local, MERGE_ACTIVE_STATES);
        active += local_active;
    });

    grid->setName("density");
    grid->setGridClass(GRID_FOG_VOLUME);
    grid->setSaveFloatAsHalf(true);
    // World size independent of the resolution: the long axis spans 10 units.
    grid->setTransform(math::Transform::createLinearTransform(10.0 / longest));
    io::File file(out);
    file.setCompression(io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK);
    GridPtrVec grids{grid};
    file.write(grids);
    file.close();
    const CoordBBox bbox = grid->evalActiveVoxelBoundingBox();
    const double secs =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf(
        "{\"file\":\"%s\",\"dims\":[%d,%d,%d],\"seed\":%llu,\"frame\":%d,\"active_voxels\":%zu,"
        "\"leaves\":%zu,\"active_box\":[[%d,%d,%d],[%d,%d,%d]],\"seconds\":%.2f}\n",
        out.c_str(), nx, ny, nz, (unsigned long long)seed, frame, active,
        size_t(grid->tree().leafCount()), bbox.min().x(), bbox.min().y(), bbox.min().z(),
        bbox.max().x(), bbox.max().y(), bbox.max().z(), secs);
    return 0;
}
