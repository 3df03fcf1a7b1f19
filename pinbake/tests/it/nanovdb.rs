//! A minimal NanoVDB writer for tests: one grid of one upper and one lower node (voxels in
//! `[0, 128)^3`, plus optional root tiles), in NanoVDB 32.4's layout (`nanovdb/NanoVDB.h`,
//! `nanovdb/util/IO.h`), uncompressed or ZIP. It lets the hostile-input tests damage every
//! field of a valid file and the reader tests cover types `nanovdb_convert` cannot write
//! (half, double). Shared by `hostile.rs` and `nanovdb_corpus.rs`.

#![allow(dead_code)]

use std::io::Write;

pub const MAGIC: &[u8; 8] = b"NanoVDB0";
pub const VERSION: u32 = (32 << 21) | (4 << 10) | 2;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Type {
    Float,
    Double,
    Half,
    Fp4,
    Fp8,
    Fp16,
    /// FpN with every leaf at this many bits (1, 2, 4, 8 or 16).
    FpN(u32),
}

impl Type {
    pub fn code(self) -> u32 {
        match self {
            Type::Float => 1,
            Type::Double => 2,
            Type::Half => 9,
            Type::Fp4 => 13,
            Type::Fp8 => 14,
            Type::Fp16 => 15,
            Type::FpN(_) => 16,
        }
    }
    fn double(self) -> bool {
        self == Type::Double
    }
    fn bits(self) -> Option<u32> {
        match self {
            Type::Fp4 => Some(4),
            Type::Fp8 => Some(8),
            Type::Fp16 => Some(16),
            Type::FpN(b) => Some(b),
            _ => None,
        }
    }
}

/// One leaf: origin (a multiple of 8 inside `[0, 128)^3`), values in NanoVDB order
/// (`x * 64 + y * 8 + z`) and the active mask.
#[derive(Clone, Debug)]
pub struct Leaf {
    pub origin: [i32; 3],
    pub values: Vec<f32>,
    pub active: Vec<bool>,
}

/// What to write.
#[derive(Clone, Debug)]
pub struct Grid {
    pub name: String,
    pub ty: Type,
    pub level_set: bool,
    /// Row-major 3x3 and translation (index to world).
    pub mat: [f64; 9],
    pub vec: [f64; 3],
    pub leaves: Vec<Leaf>,
    /// Constant tiles of the lower node (index in its 16^3 table, value, active).
    pub lower_tiles: Vec<(usize, f32, bool)>,
    /// Root tiles besides the one holding the upper node: (origin, value, active).
    pub root_tiles: Vec<([i32; 3], f32, bool)>,
}

impl Grid {
    pub fn new(ty: Type, leaves: Vec<Leaf>) -> Self {
        Grid {
            name: "density".into(),
            ty,
            level_set: false,
            mat: [0.5, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.5],
            vec: [1.0, -2.0, 3.0],
            leaves,
            lower_tiles: Vec::new(),
            root_tiles: Vec::new(),
        }
    }
}

/// Offsets of the parts of the grid buffer `grid_bytes` returns, for tests that damage them.
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    pub tree: usize,
    pub root: usize,
    pub upper: usize,
    pub lower: usize,
    pub first_leaf: usize,
    pub leaf_size: usize,
}

fn put(b: &mut [u8], off: usize, bytes: &[u8]) {
    b[off..off + bytes.len()].copy_from_slice(bytes);
}

fn leaf_size(ty: Type) -> usize {
    match ty {
        Type::Float => 2144,
        Type::Double => 4224,
        Type::Half | Type::Fp16 => 1120,
        Type::Fp4 => 352,
        Type::Fp8 => 608,
        Type::FpN(b) => 96 + 64 * b as usize,
    }
}

fn root_key(o: [i32; 3]) -> u64 {
    let k = |c: i32| u64::from((c as u32) >> 12);
    (k(o[0]) << 42) | (k(o[1]) << 21) | k(o[2])
}

/// The value of a tile or root field for `ty` at `off` (f64 for double, f16 for half).
fn put_value(b: &mut [u8], off: usize, ty: Type, v: f32) {
    match ty {
        Type::Double => put(b, off, &f64::from(v).to_le_bytes()),
        Type::Half => put(b, off, &half::f16::from_f32(v).to_bits().to_le_bytes()),
        _ => put(b, off, &v.to_le_bytes()),
    }
}

/// The grid buffer (what a file stores after its metadata, uncompressed).
pub fn grid_bytes(g: &Grid) -> (Vec<u8>, Layout) {
    let ty = g.ty;
    let tree = 672;
    let root = tree + 64;
    let root_data = if ty.double() { 96 } else { 64 };
    let tiles = 1 + g.root_tiles.len();
    let upper = root + root_data + 32 * tiles;
    let lower = upper + 270_400;
    let first_leaf = lower + 33_856;
    let ls = leaf_size(ty);
    let size = first_leaf + ls * g.leaves.len();
    let mut b = vec![0u8; size];
    put(&mut b, 0, MAGIC);
    put(&mut b, 16, &VERSION.to_le_bytes());
    put(&mut b, 28, &1u32.to_le_bytes());
    put(&mut b, 32, &(size as u64).to_le_bytes());
    put(&mut b, 40, g.name.as_bytes());
    for i in 0..9 {
        put(&mut b, 296 + 4 * i, &(g.mat[i] as f32).to_le_bytes());
        put(&mut b, 384 + 8 * i, &g.mat[i].to_le_bytes());
    }
    for i in 0..3 {
        put(&mut b, 368 + 4 * i, &(g.vec[i] as f32).to_le_bytes());
        put(&mut b, 528 + 8 * i, &g.vec[i].to_le_bytes());
    }
    put(
        &mut b,
        632,
        &(if g.level_set { 1u32 } else { 2 }).to_le_bytes(),
    );
    put(&mut b, 636, &ty.code().to_le_bytes());
    // Tree: offsets of the first leaf, lower, upper and root from the tree; node counts.
    for (i, o) in [first_leaf, lower, upper, root].iter().enumerate() {
        put(&mut b, tree + 8 * i, &((o - tree) as u64).to_le_bytes());
    }
    for (i, n) in [g.leaves.len(), 1, 1].iter().enumerate() {
        put(&mut b, tree + 32 + 4 * i, &(*n as u32).to_le_bytes());
    }
    // Root: table size, then the tile of the upper node and the value tiles.
    put(&mut b, root + 24, &(tiles as u32).to_le_bytes());
    let t0 = root + root_data;
    put(&mut b, t0, &root_key([0, 0, 0]).to_le_bytes());
    put(&mut b, t0 + 8, &((upper - root) as i64).to_le_bytes());
    let value_at = if ty.double() { 24 } else { 20 };
    for (i, (o, v, a)) in g.root_tiles.iter().enumerate() {
        let t = t0 + 32 * (i + 1);
        put(&mut b, t, &root_key(*o).to_le_bytes());
        put(&mut b, t + 16, &u32::from(*a).to_le_bytes());
        put_value(&mut b, t + value_at, ty, *v);
    }
    // Upper: child 0 is the lower node.
    put(&mut b, upper + 4128, &1u64.to_le_bytes());
    put(
        &mut b,
        upper + 8256,
        &((lower - upper) as i64).to_le_bytes(),
    );
    // Lower: leaves by their index in the 16^3 table, and constant tiles.
    for (i, l) in g.leaves.iter().enumerate() {
        let o = l.origin.map(|c| (c >> 3) as usize);
        let n = (o[0] << 8) | (o[1] << 4) | o[2];
        let w = lower + 544 + 8 * (n >> 6);
        let m = u64::from_le_bytes(b[w..w + 8].try_into().unwrap()) | (1 << (n & 63));
        put(&mut b, w, &m.to_le_bytes());
        let at = first_leaf + ls * i;
        put(
            &mut b,
            lower + 1088 + 8 * n,
            &((at - lower) as i64).to_le_bytes(),
        );
        write_leaf(&mut b[at..at + ls], ty, l);
    }
    for (n, v, a) in &g.lower_tiles {
        if *a {
            let w = lower + 32 + 8 * (n >> 6);
            let m = u64::from_le_bytes(b[w..w + 8].try_into().unwrap()) | (1 << (n & 63));
            put(&mut b, w, &m.to_le_bytes());
        }
        put_value(&mut b, lower + 1088 + 8 * n, ty, *v);
    }
    let layout = Layout {
        tree,
        root,
        upper,
        lower,
        first_leaf,
        leaf_size: ls,
    };
    (b, layout)
}

/// The quantisation NanoVDB's converter applies: codes of `(v - min) / quantum`, rounded.
pub fn quantum(l: &Leaf, bits: u32) -> (f32, f32) {
    let min = l.values.iter().copied().fold(f32::INFINITY, f32::min);
    let max = l.values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    (min, (max - min) / ((1u32 << bits) - 1) as f32)
}

fn write_leaf(b: &mut [u8], ty: Type, l: &Leaf) {
    put(b, 0, &l.origin.map(|c| c.to_le_bytes()).concat());
    for (k, a) in l.active.iter().enumerate() {
        if *a {
            b[16 + k / 8] |= 1 << (k % 8);
        }
    }
    match ty {
        Type::Float => {
            for (k, v) in l.values.iter().enumerate() {
                put(b, 96 + 4 * k, &v.to_le_bytes());
            }
        }
        Type::Double => {
            for (k, v) in l.values.iter().enumerate() {
                put(b, 128 + 8 * k, &f64::from(*v).to_le_bytes());
            }
        }
        Type::Half => {
            for (k, v) in l.values.iter().enumerate() {
                put(
                    b,
                    96 + 2 * k,
                    &half::f16::from_f32(*v).to_bits().to_le_bytes(),
                );
            }
        }
        _ => {
            let bits = ty.bits().unwrap();
            if let Type::FpN(_) = ty {
                b[15] = (bits.trailing_zeros() as u8) << 5;
            }
            let (min, q) = quantum(l, bits);
            put(b, 80, &min.to_le_bytes());
            put(b, 84, &q.to_le_bytes());
            for (k, v) in l.values.iter().enumerate() {
                let code = if q > 0.0 {
                    ((v - min) / q + 0.5) as u32
                } else {
                    0
                };
                if bits == 16 {
                    put(b, 96 + 2 * k, &(code as u16).to_le_bytes());
                } else {
                    let bit = k * bits as usize;
                    b[96 + bit / 8] |= (code << (bit % 8)) as u8;
                }
            }
        }
    }
}

/// A whole file holding `g`, with codec 0 (none) or 1 (ZIP).
pub fn file_bytes(g: &Grid, codec: u16) -> Vec<u8> {
    let (grid, _) = grid_bytes(g);
    let stored = if codec == 1 {
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(&grid).unwrap();
        let z = z.finish().unwrap();
        let mut s = (z.len() as u64).to_le_bytes().to_vec();
        s.extend_from_slice(&z);
        s
    } else {
        grid.clone()
    };
    let mut f = Vec::new();
    f.extend_from_slice(MAGIC);
    f.extend_from_slice(&VERSION.to_le_bytes());
    f.extend_from_slice(&1u16.to_le_bytes());
    f.extend_from_slice(&codec.to_le_bytes());
    let mut meta = vec![0u8; 176];
    put(&mut meta, 0, &(grid.len() as u64).to_le_bytes());
    put(&mut meta, 8, &(stored.len() as u64).to_le_bytes());
    put(&mut meta, 32, &g.ty.code().to_le_bytes());
    put(
        &mut meta,
        36,
        &(if g.level_set { 1u32 } else { 2 }).to_le_bytes(),
    );
    put(&mut meta, 136, &(g.name.len() as u32 + 1).to_le_bytes());
    put(&mut meta, 140, &(g.leaves.len() as u32).to_le_bytes());
    put(&mut meta, 168, &codec.to_le_bytes());
    put(&mut meta, 172, &VERSION.to_le_bytes());
    f.extend_from_slice(&meta);
    f.extend_from_slice(g.name.as_bytes());
    f.push(0);
    f.extend_from_slice(&stored);
    f
}

/// Bytes before the grid buffer in a one-grid file named `name`.
pub fn grid_offset(name: &str) -> usize {
    16 + 176 + name.len() + 1
}

/// A leaf at `origin` whose voxel k holds `f(k)`, every voxel active.
pub fn leaf(origin: [i32; 3], f: impl Fn(usize) -> f32) -> Leaf {
    Leaf {
        origin,
        values: (0..512).map(f).collect(),
        active: vec![true; 512],
    }
}
