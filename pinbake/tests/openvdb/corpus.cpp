// Writes the VDB compatibility corpus with OpenVDB itself, then reads every file back with
// OpenVDB and dumps what OpenVDB sees (grid names and types, active bounding boxes, index-to-
// world at a few points, voxel values and active states at sampled voxels) to manifest.json.
//
// Built and run by pinbake/tests/vdb_corpus.rs (and tests/tests/vdb_rotated.rs) at test time:
//   c++ -std=c++17 -O0 corpus.cpp -o corpus -lopenvdb -ltbb && ./corpus OUT_DIR
// Needs Debian's libopenvdb-dev (OpenVDB 10). The Python bindings cannot choose a file's
// compression, which is why this is C++.
//
// Every value is deterministic (a fixed LCG), so the corpus is the same on every run.

#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

using namespace openvdb;

namespace {

struct Lcg {
    uint64_t s;
    explicit Lcg(uint64_t seed) : s(seed) {}
    uint32_t next() {
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        return uint32_t(s >> 33);
    }
    // Uniform in [lo, hi).
    int range(int lo, int hi) { return lo + int(next() % uint32_t(hi - lo)); }
    // A positive value that is exact in half precision only sometimes.
    float value() { return 0.05f + float(next() % 100000) / 37000.0f; }
};

std::string fmt_f(double v) {
    char b[64];
    std::snprintf(b, sizeof b, "%.17g", v);
    return b;
}

std::string json_str(const std::string& s) {
    std::string o = "\"";
    for (unsigned char c : s) {
        if (c == '"' || c == '\\') {
            o += '\\';
            o += char(c);
        } else if (c < 0x20) {
            char b[8];
            std::snprintf(b, sizeof b, "\\u%04x", c);
            o += b;
        } else {
            o += char(c);
        }
    }
    return o + "\"";
}

// ---------------------------------------------------------------------------------------------
// Grid builders
// ---------------------------------------------------------------------------------------------

// Leaves with random values, a filled leaf, tiles at levels 1 and 2, and inactive voxels
// with one, two and many distinct non-zero values (each selects another of OpenVDB's
// per-node mask-compression cases).
template <typename GridT>
typename GridT::Ptr mixed_grid(const std::string& name, uint64_t seed) {
    using V = typename GridT::ValueType;
    auto g = GridT::create(V(0));
    g->setName(name);
    g->setGridClass(GRID_FOG_VOLUME);
    auto& tree = g->tree();
    auto acc = g->getAccessor();
    Lcg r(seed);
    // Scattered active voxels.
    for (int n = 0; n < 3000; ++n) {
        Coord c(r.range(-60, 60), r.range(-40, 70), r.range(-50, 50));
        acc.setValueOn(c, V(r.value()));
    }
    // A completely filled leaf (all 512 active).
    for (int x = 0; x < 8; ++x)
        for (int y = 0; y < 8; ++y)
            for (int z = 0; z < 8; ++z) acc.setValueOn(Coord(200 + x, 8 + y, 16 + z), V(r.value()));
    // Leaf with one inactive non-zero value.
    for (int k = 0; k < 40; ++k) acc.setValueOn(Coord(240 + (k % 8), 0 + (k / 8), 0), V(r.value()));
    for (int k = 0; k < 30; ++k) acc.setValueOff(Coord(240 + (k % 8), 7, 1 + k / 8), V(0.75));
    // Leaf with two distinct inactive values besides the background.
    for (int k = 0; k < 40; ++k) acc.setValueOn(Coord(256 + (k % 8), 0 + (k / 8), 0), V(r.value()));
    for (int x = 0; x < 8; ++x)
        for (int y = 0; y < 8; ++y)
            for (int z = 1; z < 8; ++z) acc.setValueOff(Coord(256 + x, y, z), V(z < 4 ? 0.5 : 1.25));
    // Leaf with many distinct inactive values (stored with all values).
    for (int k = 0; k < 20; ++k) acc.setValueOn(Coord(272 + (k % 8), 0, k / 8), V(r.value()));
    for (int k = 0; k < 64; ++k) acc.setValueOff(Coord(272 + (k % 8), 4, k / 8), V(0.01f * float(k + 1)));
    // Level-1 tiles (8^3) and level-2 tiles (128^3), active and inactive.
    tree.addTile(1, Coord(512, 0, 0), V(0.625), true);
    tree.addTile(1, Coord(520, 8, 0), V(1.5), true);
    tree.addTile(1, Coord(528, 0, 0), V(0.375), false);
    tree.addTile(2, Coord(1024, 0, 0), V(0.3125), true);
    tree.addTile(2, Coord(1152, 0, 0), V(2.0), false);
    return g;
}

// One active 4096^3 root tile next to a few leaf voxels, with a non-zero background.
template <typename GridT>
typename GridT::Ptr root_tile_grid(const std::string& name) {
    using V = typename GridT::ValueType;
    auto g = GridT::create(V(0.25));
    g->setName(name);
    g->setGridClass(GRID_FOG_VOLUME);
    g->tree().addTile(3, Coord(4096, 0, 0), V(0.125), true);
    g->tree().addTile(3, Coord(0, 4096, 0), V(3.0), false);
    auto acc = g->getAccessor();
    acc.setValueOn(Coord(-3, 2, 1), V(1.75));
    acc.setValueOn(Coord(4, 5, 6), V(0.5));
    return g;
}

FloatGrid::Ptr box_grid(const std::string& name, Coord lo, Coord hi, float v) {
    auto g = FloatGrid::create(0.0f);
    g->setName(name);
    g->setGridClass(GRID_FOG_VOLUME);
    g->denseFill(CoordBBox(lo, hi), v, true);
    return g;
}

math::Mat4d rotation_scale_translate(double deg, Vec3d axis, Vec3d scale, Vec3d t) {
    math::Mat4d m = math::Mat4d::identity();
    m.setToScale(scale);
    math::Mat4d rot = math::rotation<math::Mat4d>(axis.unit(), deg * M_PI / 180.0);
    m = m * rot;  // row vectors: scale first, then rotate
    m.postTranslate(t);
    return m;
}

// ---------------------------------------------------------------------------------------------
// Dump of what OpenVDB reads back
// ---------------------------------------------------------------------------------------------

template <typename GridT>
void dump_values(std::ostream& js, const GridT& g, uint64_t seed) {
    using V = typename GridT::ValueType;
    auto acc = g.getConstAccessor();
    std::set<Coord> pts;
    CoordBBox bb = g.evalActiveVoxelBoundingBox();
    // Every voxel of up to 64 leaves (active and inactive).
    int leaves = 0;
    for (auto it = g.tree().cbeginLeaf(); it && leaves < 64; ++it, ++leaves) {
        for (Index i = 0; i < 512; i += (leaves < 8 ? 1 : 7)) pts.insert(it->offsetToGlobalCoord(i));
    }
    // Tiles other than the background: corners, centre, and just outside.
    int tiles = 0;
    for (auto it = g.tree().cbeginValueAll(); it && tiles < 400; ++it) {
        // Inactive tiles holding the background are everywhere; skip those.
        if (it.isVoxelValue() || (!it.isValueOn() && *it == g.background())) continue;
        ++tiles;
        CoordBBox t;
        it.getBoundingBox(t);
        pts.insert(t.min());
        pts.insert(t.max());
        pts.insert((t.min() + t.max()) >> 1);
        pts.insert(t.min() - Coord(1, 0, 0));
        pts.insert(t.max() + Coord(0, 0, 1));
        pts.insert(Coord(t.min().x(), t.max().y(), t.min().z()));
    }
    // Random voxels in and around the active box.
    if (!bb.empty()) {
        Lcg r(seed);
        auto span = [&](int a) {
            int64_t lo = int64_t(bb.min()[a]) - 9, hi = int64_t(bb.max()[a]) + 10;
            return lo + int64_t(r.next() % uint64_t(hi - lo));
        };
        for (int n = 0; n < 3000; ++n) pts.insert(Coord(int(span(0)), int(span(1)), int(span(2))));
        pts.insert(bb.min());
        pts.insert(bb.max());
    }
    // The range of every value stored in a leaf, active or not: what bounds the quantum
    // of NanoVDB's quantised leaves (tests/nanovdb_corpus.rs).
    double lo = 0.0, hi = 0.0;
    bool any = false;
    for (auto it = g.tree().cbeginLeaf(); it; ++it) {
        for (Index i = 0; i < 512; ++i) {
            double v = double(it->getValue(i));
            lo = any ? std::min(lo, v) : v;
            hi = any ? std::max(hi, v) : v;
            any = true;
        }
    }
    js << "\"leaf_range\":[" << fmt_f(lo) << "," << fmt_f(hi) << "],";
    js << "\"samples\":[";
    bool first = true;
    for (const Coord& c : pts) {
        V v = acc.getValue(c);
        js << (first ? "" : ",") << "[" << c.x() << "," << c.y() << "," << c.z() << ","
           << fmt_f(double(v)) << "," << (acc.isValueOn(c) ? 1 : 0) << "]";
        first = false;
    }
    js << "]";
}

void dump_grid(std::ostream& js, io::File& f, const std::string& shown) {
    GridBase::Ptr base = f.readGrid(shown);
    js << "{\"name\":" << json_str(shown) << ",\"type\":" << json_str(base->type())
       << ",\"class\":" << json_str(GridBase::gridClassToString(base->getGridClass()))
       << ",\"half\":" << (base->saveFloatAsHalf() ? "true" : "false");
    const math::Transform& xf = base->transform();
    js << ",\"map\":" << json_str(xf.mapType()) << ",\"index_to_world\":[";
    const Vec3d probes[] = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0, 0, 1),
                            Vec3d(17.5, -5.25, 3), Vec3d(-1000, 250, 4000)};
    for (size_t i = 0; i < 6; ++i) {
        Vec3d w = xf.indexToWorld(probes[i]);
        js << (i ? "," : "") << "[[" << fmt_f(probes[i].x()) << "," << fmt_f(probes[i].y()) << ","
           << fmt_f(probes[i].z()) << "],[" << fmt_f(w.x()) << "," << fmt_f(w.y()) << ","
           << fmt_f(w.z()) << "]]";
    }
    js << "]";
    CoordBBox bb = base->evalActiveVoxelBoundingBox();
    js << ",\"active_bbox\":[[" << bb.min().x() << "," << bb.min().y() << "," << bb.min().z()
       << "],[" << bb.max().x() << "," << bb.max().y() << "," << bb.max().z() << "]]";
    js << ",\"active_voxels\":" << base->activeVoxelCount() << ",";
    uint64_t seed = std::hash<std::string>()(shown) ^ 0x9E3779B97F4A7C15ULL;
    if (auto g = GridBase::grid<FloatGrid>(base)) {
        js << "\"scalar\":true,";
        dump_values(js, *g, seed);
    } else if (auto g = GridBase::grid<DoubleGrid>(base)) {
        js << "\"scalar\":true,";
        dump_values(js, *g, seed);
    } else {
        js << "\"scalar\":false,\"samples\":[]";
    }
    js << "}";
}

struct Entry {
    std::string file;
    std::string encoding;
};

void write_file(const std::string& dir, const std::string& file, GridPtrVec grids,
                uint32_t compression, std::vector<Entry>& out, const std::string& encoding) {
    io::File f(dir + "/" + file);
    f.setCompression(compression);
    f.write(grids);
    f.close();
    out.push_back({file, encoding});
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s OUT_DIR\n", argv[0]);
        return 2;
    }
    const std::string dir = argv[1];
    openvdb::initialize();
    std::vector<Entry> files;

    // 1. Every encoding: {float, half} x {none, ZIP, Blosc} x {with, without active mask}.
    const struct {
        const char* tag;
        uint32_t bits;
    } comps[] = {{"none", io::COMPRESS_NONE},
                 {"zip", io::COMPRESS_ZIP},
                 {"blosc", io::COMPRESS_BLOSC},
                 {"mask", io::COMPRESS_ACTIVE_MASK},
                 {"zip+mask", io::COMPRESS_ZIP | io::COMPRESS_ACTIVE_MASK},
                 {"blosc+mask", io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK}};
    for (int half = 0; half < 2; ++half) {
        for (const auto& c : comps) {
            GridPtrVec grids;
            auto density = mixed_grid<FloatGrid>("density", 11);
            density->setSaveFloatAsHalf(half != 0);
            auto roots = root_tile_grid<FloatGrid>("roots");
            roots->setSaveFloatAsHalf(half != 0);
            auto dbl = mixed_grid<DoubleGrid>("density64", 12);
            dbl->setSaveFloatAsHalf(half != 0);
            // A vector grid stored before the float grids, so that reading them has to skip it.
            auto vel = Vec3SGrid::create(Vec3s(0));
            vel->setName("vel");
            vel->getAccessor().setValueOn(Coord(1, 2, 3), Vec3s(1, -2, 3));
            vel->tree().addTile(1, Coord(64, 0, 0), Vec3s(0.5f), true);
            auto mask = BoolGrid::create(false);
            mask->setName("mask");
            mask->getAccessor().setValueOn(Coord(5, 5, 5), true);
            grids.push_back(vel);
            grids.push_back(density);
            grids.push_back(roots);
            grids.push_back(dbl);
            grids.push_back(mask);
            std::string enc = std::string(half ? "half" : "float") + "/" + c.tag;
            std::string name = std::string("enc_") + (half ? "half_" : "float_") + c.tag + ".vdb";
            for (auto& ch : name)
                if (ch == '+') ch = '_';
            write_file(dir, name, grids, c.bits, files, enc);
        }
    }

    // 2. Transforms, one grid each, a small box of voxels.
    {
        GridPtrVec grids;
        auto add = [&](const std::string& name, math::Transform::Ptr xf) {
            auto g = box_grid(name, Coord(-2, 0, 1), Coord(5, 3, 9), 1.0f);
            g->getAccessor().setValueOn(Coord(6, 4, 10), 2.5f);
            g->setTransform(xf);
            grids.push_back(g);
        };
        add("uniform", math::Transform::createLinearTransform(0.5));
        math::Mat4d s = math::Mat4d::identity();
        s.setToScale(Vec3d(0.5, 1.0, 2.0));
        add("nonuniform", math::Transform::createLinearTransform(s));
        auto ut = math::Transform::createLinearTransform(0.25);
        ut->postTranslate(Vec3d(10, -3, 0.5));
        add("translated", ut);
        math::Mat4d st = s;
        st.setTranslation(Vec3d(-7, 2, 1.5));
        add("scaletranslate", math::Transform::createLinearTransform(st));
        math::Mat4d t = math::Mat4d::identity();
        t.setTranslation(Vec3d(3, 4, 5));
        add("translation", math::Transform::createLinearTransform(t));
        add("rotated", math::Transform::createLinearTransform(
                           rotation_scale_translate(30.0, Vec3d(1, 2, 3), Vec3d(0.2), Vec3d(1, -2, 0.5))));
        add("rotated_nonuniform",
            math::Transform::createLinearTransform(
                rotation_scale_translate(-65.0, Vec3d(0, 0, 1), Vec3d(0.1, 0.3, 0.2), Vec3d(0, 0, 0))));
        math::Mat4d shear = math::Mat4d::identity();
        shear.setToShear(math::X_AXIS, math::Y_AXIS, 0.4);
        shear.postTranslate(Vec3d(0.5, 0.5, 0.5));
        add("shear", math::Transform::createLinearTransform(shear));
        write_file(dir, "transforms.vdb", grids, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK, files,
                   "float/blosc+mask");
    }

    // 3. Names: repeated "density", other names, one-voxel grids, huge sparse extents.
    {
        GridPtrVec grids;
        auto one = FloatGrid::create(0.0f);
        one->setName("density");
        one->getAccessor().setValueOn(Coord(3, -2, 7), 0.75f);
        auto one_b = FloatGrid::create(0.0f);
        one_b->setName("density");
        one_b->getAccessor().setValueOn(Coord(-100, 0, 0), 4.0f);
        auto heat = FloatGrid::create(0.0f);
        heat->setName("heat with spaces/and:punct");
        heat->getAccessor().setValueOn(Coord(0, 0, 0), 1.0f);
        heat->getAccessor().setValueOn(Coord(1, 0, 0), 0.5f);
        auto sparse = FloatGrid::create(0.0f);
        sparse->setName("sparse_x");
        sparse->getAccessor().setValueOn(Coord(-100000, 3, 4), 1.0f);
        sparse->getAccessor().setValueOn(Coord(100000, -3, 2), 2.0f);
        sparse->getAccessor().setValueOn(Coord(0, 0, 0), 0.5f);
        auto sparse3 = FloatGrid::create(0.0f);
        sparse3->setName("sparse_xyz");
        sparse3->getAccessor().setValueOn(Coord(-100000, -100000, -100000), 1.0f);
        sparse3->getAccessor().setValueOn(Coord(100000, 100000, 100000), 2.0f);
        grids.push_back(one);
        grids.push_back(one_b);
        grids.push_back(heat);
        grids.push_back(sparse);
        grids.push_back(sparse3);
        write_file(dir, "names.vdb", grids, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK, files,
                   "float/blosc+mask");
        for (auto& g : grids) g->setSaveFloatAsHalf(true);
        write_file(dir, "names_half_zip.vdb", grids, io::COMPRESS_ZIP | io::COMPRESS_ACTIVE_MASK, files,
                   "half/zip+mask");
    }

    // 4. A level set (baked with levelset-to-fog), in half + Blosc and float + ZIP.
    {
        auto ls = tools::createLevelSetSphere<FloatGrid>(6.0f, Vec3f(1, 2, 3), 0.5f, 3.0f);
        ls->setName("surface");
        GridPtrVec grids{ls};
        write_file(dir, "levelset_float_zip.vdb", grids, io::COMPRESS_ZIP | io::COMPRESS_ACTIVE_MASK,
                   files, "float/zip+mask");
        ls->setSaveFloatAsHalf(true);
        write_file(dir, "levelset_half_blosc.vdb", grids, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK,
                   files, "half/blosc+mask");
    }

    // 5. A frustum transform: a valid file this reader does not support.
    {
        auto g = box_grid("density", Coord(0, 0, 0), Coord(7, 7, 7), 1.0f);
        g->setTransform(math::Transform::createFrustumTransform(
            BBoxd(Vec3d(0, 0, 0), Vec3d(7, 7, 7)), /*taper=*/0.5, /*depth=*/2.0, /*voxelDim=*/0.25));
        GridPtrVec grids{g};
        write_file(dir, "frustum.vdb", grids, io::COMPRESS_BLOSC | io::COMPRESS_ACTIVE_MASK, files,
                   "float/blosc+mask");
    }

    // Eight active 4096^3 root tiles and nothing else: a few hundred bytes that declare 2^39
    // voxels, for the budget tests. Not in the manifest, whose files the tests bake whole.
    {
        auto g = FloatGrid::create(0.0f);
        g->setName("density");
        g->setGridClass(GRID_FOG_VOLUME);
        for (int i = 0; i < 8; ++i)
            g->tree().addTile(3, Coord(4096 * (i & 1), 4096 * ((i >> 1) & 1), 4096 * (i >> 2)),
                              0.5f, true);
        io::File f(dir + "/root_tiles.vdb");
        f.write({g});
        f.close();
    }

    // A 512^3 box of active 8^3 tiles (no leaf): a small file whose dense copy is 512 MiB,
    // for the renderer's budget tests. Not in the manifest either.
    {
        auto g = FloatGrid::create(0.0f);
        g->setName("density");
        g->setGridClass(GRID_FOG_VOLUME);
        for (int z = 0; z < 512; z += 8)
            for (int y = 0; y < 512; y += 8)
                for (int x = 0; x < 512; x += 8)
                    g->tree().addTile(1, Coord(x, y, z), 0.25f + 0.125f * ((x + y + z) / 8 % 5),
                                      true);
        io::File f(dir + "/tiles_512.vdb");
        f.write({g});
        f.close();
    }

    // Read everything back with OpenVDB and dump what it sees.
    std::ofstream js(dir + "/manifest.json");
    js << "{\"openvdb\":" << json_str(getLibraryVersionString()) << ",\"files\":[";
    for (size_t i = 0; i < files.size(); ++i) {
        io::File f(dir + "/" + files[i].file);
        f.open();
        js << (i ? "," : "") << "{\"file\":" << json_str(files[i].file)
           << ",\"encoding\":" << json_str(files[i].encoding) << ",\"grids\":[";
        bool first = true;
        for (auto it = f.beginName(); it != f.endName(); ++it) {
            js << (first ? "" : ",");
            dump_grid(js, f, it.gridName());
            first = false;
        }
        js << "]}";
        f.close();
    }
    js << "]}\n";
    js.close();
    if (!js) {
        std::fprintf(stderr, "writing manifest.json failed\n");
        return 1;
    }
    return 0;
}
