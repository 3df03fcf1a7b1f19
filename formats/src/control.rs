//! The control section (kind 9, format 1.1): per brick of a grid that tiles the grid box, a
//! control extinction, a residual majorant and a majorant, which a renderer's residual ratio
//! tracking reads (docs/format.md section 5.8). Its zero-copy view, the length check a parse
//! makes before any count is used, the per-brick rules of verify, and the owned form a baker
//! fills.

use crate::error::{FormatError, Result};
use crate::layout::{ControlHeader, SectionKind};

const KIND: SectionKind = SectionKind::Control;

/// A view of the control section borrowing the file's bytes: three arrays of one value per
/// brick, `x` fastest. After [`ControlView::parse`] the three lengths equal the brick count;
/// the values are checked by [`ControlView::check_values`] (linear, so part of verify).
#[derive(Clone, Copy, Debug)]
pub struct ControlView<'a> {
    pub dims: [u32; 3],
    /// The control extinction `c` per brick.
    pub control: &'a [f32],
    /// The residual majorant `m` per brick: the rate of the residual's tentative collisions.
    pub residual: &'a [f32],
    /// The majorant `M` per brick: a bound of the extinction (distance sampling).
    pub majorant: &'a [f32],
}

fn bad(problem: impl Into<String>) -> FormatError {
    FormatError::BadData(KIND, problem.into())
}

/// Bricks of `dims`, every dim `>= 1`, without overflow.
fn bricks(dims: [u32; 3]) -> Result<u64> {
    if dims.contains(&0) {
        return Err(bad("zero dimension"));
    }
    dims.iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(u64::from(d)))
        .ok_or_else(|| bad("brick grid size overflows"))
}

impl<'a> ControlView<'a> {
    /// Checks the header and the length `16 + 12 n` against the section's size `b.len()`
    /// (which the reader has checked against the file's), then views the arrays in place.
    pub fn parse(b: &'a [u8]) -> Result<Self> {
        let head_len = size_of::<ControlHeader>();
        if b.len() < head_len {
            return Err(bad(format!(
                "section is {} bytes but its header needs {head_len}",
                b.len()
            )));
        }
        let header: ControlHeader = bytemuck::pod_read_unaligned(&b[..head_len]);
        let n = bricks(header.dims)?;
        let want = n
            .checked_mul(12)
            .and_then(|x| x.checked_add(head_len as u64))
            .ok_or_else(|| bad("size overflows"))?;
        if b.len() as u64 != want {
            return Err(bad(format!(
                "section is {} bytes but {n} bricks of three f32 need {want}",
                b.len()
            )));
        }
        let body: &[f32] =
            bytemuck::try_cast_slice(&b[head_len..]).map_err(|e| bad(format!("{e:?}")))?;
        let n = n as usize;
        Ok(Self {
            dims: header.dims,
            control: &body[..n],
            residual: &body[n..2 * n],
            majorant: &body[2 * n..],
        })
    }

    /// Bricks in the grid.
    pub fn len(&self) -> usize {
        self.control.len()
    }

    pub fn is_empty(&self) -> bool {
        self.control.is_empty()
    }

    /// The rules of verify (docs/format.md section 5.8): every value finite and `>= 0`, the
    /// control at most the majorant, and a residual majorant of 0 only in an empty brick
    /// (control and majorant 0), the one brick whose extinction the section pins down
    /// exactly. The first brick that breaks one, as a message.
    pub fn check_values(&self) -> Result<()> {
        for i in 0..self.len() {
            check_brick(i, self.control[i], self.residual[i], self.majorant[i])?;
        }
        Ok(())
    }
}

/// The rules of verify for brick `i`, whose control, residual majorant and majorant are `c`,
/// `m` and `mx` (see [`ControlView::check_values`]).
pub(crate) fn check_brick(i: usize, c: f32, m: f32, mx: f32) -> Result<()> {
    let ok = |v: f32| v.is_finite() && v >= 0.0;
    if !(ok(c) && ok(m) && ok(mx)) {
        return Err(bad(format!(
            "brick {i} has control {c}, residual {m}, majorant {mx}: each must be finite and >= 0"
        )));
    }
    if c > mx {
        return Err(bad(format!(
            "brick {i} has control {c} above its majorant {mx}"
        )));
    }
    if m == 0.0 && mx != 0.0 {
        return Err(bad(format!(
            "brick {i} has residual majorant 0 but majorant {mx}: only an empty brick may have 0"
        )));
    }
    Ok(())
}

/// The control section in memory, as a baker fills it.
#[derive(Clone, Debug, PartialEq)]
pub struct OwnedControl {
    pub dims: [u32; 3],
    pub control: Vec<f32>,
    pub residual: Vec<f32>,
    pub majorant: Vec<f32>,
}

impl OwnedControl {
    /// The section's bytes as the file holds them.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let n =
            bricks(self.dims).map_err(|e| FormatError::InvalidInput(format!("control: {e}")))?;
        if [&self.control, &self.residual, &self.majorant]
            .iter()
            .any(|v| v.len() as u64 != n)
        {
            return Err(FormatError::InvalidInput(format!(
                "control: dims {:?} need {n} values per array",
                self.dims
            )));
        }
        let header = ControlHeader {
            dims: self.dims,
            reserved: 0,
        };
        let mut out = Vec::with_capacity(16 + 12 * n as usize);
        out.extend_from_slice(bytemuck::bytes_of(&header));
        for v in [&self.control, &self.residual, &self.majorant] {
            out.extend_from_slice(bytemuck::cast_slice(v));
        }
        Ok(out)
    }

    pub fn from_view(v: &ControlView<'_>) -> Self {
        Self {
            dims: v.dims,
            control: v.control.to_vec(),
            residual: v.residual.to_vec(),
            majorant: v.majorant.to_vec(),
        }
    }
}
