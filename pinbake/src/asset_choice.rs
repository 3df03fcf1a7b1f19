//! What the default asset rule weighed and chose (`crate::default_asset`), as the bake's
//! choice and its JSON report carry it. A leaf, so that the choice (`crate::choose`) can
//! hold it without importing the rule.

use serde::Serialize;

use crate::embed_density::EmbedDensity;

/// One alternative the default weighed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Alternative {
    /// `pins` (pins alone), `dense` or `sparse` (an embedded f16 density and a small pin
    /// grid).
    pub representation: &'static str,
    /// Source voxels per embedded voxel along each axis (0 for pins alone).
    pub factor: u32,
    /// The embedded density's voxels per axis (the pins' cells for pins alone).
    pub dims: [u32; 3],
    /// The file's predicted size.
    pub bytes: u64,
    pub predicted_error: f64,
}

/// What the default chose and what it weighed.
#[derive(Clone, Debug, Serialize)]
pub struct AssetChoice {
    /// The alternative chosen (an element of `alternatives`).
    pub chosen: Alternative,
    pub alternatives: Vec<Alternative>,
    /// The byte budget the choice kept to.
    pub max_bytes: u64,
    /// The block error it aimed for.
    pub target_error: f64,
    /// Whether the chosen alternative's predicted error is at most the target.
    pub target_met: bool,
    /// Whether the chosen alternative fits in `max_bytes`.
    pub fits: bool,
    /// One sentence: why this one.
    pub reason: String,
}

impl AssetChoice {
    /// The embedded density of the choice (`None` for pins alone).
    pub fn embed(&self) -> Option<EmbedDensity> {
        let factor = self.chosen.factor;
        match self.chosen.representation {
            "dense" => Some(EmbedDensity::Voxels {
                factor,
                sparse: false,
            }),
            "sparse" => Some(EmbedDensity::Voxels {
                factor,
                sparse: true,
            }),
            _ => None,
        }
    }

    /// The source voxels per embedded voxel (the lattice box's block), 0 for pins alone.
    pub fn factor(&self) -> u32 {
        self.chosen.factor
    }
}
