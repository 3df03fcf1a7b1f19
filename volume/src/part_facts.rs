//! What a voxel grid's reader learns about its leaves for a bake split by volume
//! (`pinbake::part`): in the sources' room, because the VDB and NanoVDB readers fill it in and
//! the part files and the merge only carry and compare it.

/// The non-zero leaves of a voxel grid, or of one slab of it: how many, the inclusive index
/// box of their non-zero voxels (`None` when there are none) and their largest value, after
/// the density scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeafSummary {
    pub nonzero_leaves: u64,
    pub nonzero_box: Option<[[i32; 3]; 2]>,
    pub max_value: f32,
}

impl LeafSummary {
    /// No leaves.
    pub const EMPTY: Self = Self {
        nonzero_leaves: 0,
        nonzero_box: None,
        max_value: 0.0,
    };

    /// The summary of the leaves of `self` and of `other` together (disjoint sets of leaves).
    pub fn union(self, other: Self) -> Self {
        let nonzero_box = match (self.nonzero_box, other.nonzero_box) {
            (Some([a0, a1]), Some([b0, b1])) => Some([
                std::array::from_fn(|i| a0[i].min(b0[i])),
                std::array::from_fn(|i| a1[i].max(b1[i])),
            ]),
            (a, None) => a,
            (None, b) => b,
        };
        Self {
            nonzero_leaves: self.nonzero_leaves.saturating_add(other.nonzero_leaves),
            nonzero_box,
            max_value: self.max_value.max(other.max_value),
        }
    }
}

impl std::fmt::Display for LeafSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.nonzero_box {
            Some([lo, hi]) => write!(
                f,
                "{} non-zero leaves in index box {lo:?}..={hi:?}, largest value {}",
                self.nonzero_leaves, self.max_value
            ),
            None => write!(f, "{} non-zero leaves", self.nonzero_leaves),
        }
    }
}

/// What a part of a voxel grid knows about the grid's leaves, for the merge to check the
/// parts against each other: the whole grid's facts it baked with (from `--grid-stats`, or
/// from its own read of every leaf) and what it found in the leaves of its own slab (not its
/// margin). The slabs tile the grid, so the slabs' summaries together must be the whole
/// grid's: statistics that overstate or understate the grid fail that test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartFacts {
    pub grid: LeafSummary,
    /// Active negative values of the grid clamped to 0 (leaves and tiles).
    pub negative_values: u64,
    pub slab: LeafSummary,
    /// Active negative values in the slab's leaves, and in the tiles (every part reads them
    /// all): over the parts, the slabs' and the tiles' make the grid's.
    pub slab_negative_values: u64,
    pub tile_negative_values: u64,
}
