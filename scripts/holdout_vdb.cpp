// Writes the default asset's held-out OpenVDB fog volume (docs/scale.md, "The default
// asset"): a float grid "density" of voxel 0.05 with a translation off the voxel lattice,
// three Gaussian puffs of random centres and sizes (seed 5) cut to zero below 0.5, in about
// twenty 8^3 leaves: a small sparse VDB none of the rule's constants were measured on.
// Build: c++ -std=c++17 -O1 scripts/holdout_vdb.cpp -o holdout_vdb -lopenvdb -ltbb -lImath
// Usage: holdout_vdb OUT.vdb
#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdio>
#include <random>

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: holdout_vdb OUT.vdb\n");
        return 2;
    }
    openvdb::initialize();
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> pos(8.0, 16.0), size(2.0, 4.5), peak(8.0, 30.0);
    struct Puff { double x, y, z, s, p; };
    Puff puffs[3];
    for (auto& q : puffs) q = {pos(rng), pos(rng) * 0.6, pos(rng), size(rng), peak(rng)};
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    auto xf = openvdb::math::Transform::createLinearTransform(0.05);
    xf->postTranslate(openvdb::Vec3d(0.013, -0.2, 0.031));
    grid->setTransform(xf);
    auto acc = grid->getAccessor();
    for (int k = -4; k < 28; ++k)
        for (int j = -4; j < 20; ++j)
            for (int i = -4; i < 28; ++i) {
                double v = 0.0;
                for (auto& q : puffs) {
                    double r2 = (i - q.x) * (i - q.x) + (j - q.y) * (j - q.y) + (k - q.z) * (k - q.z);
                    v += q.p * std::exp(-r2 / (2.0 * q.s * q.s));
                }
                if (v >= 0.5) acc.setValue(openvdb::Coord(i, j, k), float(v));
            }
    openvdb::io::File(argv[1]).write({grid});
    std::printf("%s: %zu leaves, %zu active voxels\n", argv[1], size_t(grid->tree().leafCount()),
                size_t(grid->activeVoxelCount()));
    return 0;
}
