//! Where the lab's plots are drawn: an RGB buffer in memory, written as PNG by the project's
//! `png` encoder, with text in a font the binary carries (`epaint_default_fonts`' Ubuntu
//! Light, registered as plotters' "sans-serif"). So the `pinrender` binary needs no system
//! font library at run time (fontconfig, freetype) and the build no second `image` crate.

use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::{Context, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

/// One plot being drawn: its pixels and the file they go to.
pub struct Canvas {
    path: PathBuf,
    size: (u32, u32),
    rgb: Vec<u8>,
}

impl Canvas {
    /// A white canvas of `size` pixels for `path`.
    pub fn new(path: &Path, size: (u32, u32)) -> Self {
        register_fonts();
        Canvas {
            path: path.to_path_buf(),
            size,
            rgb: vec![255; size.0 as usize * size.1 as usize * 3],
        }
    }

    /// The drawing area over the whole canvas (present it before [`Canvas::save`]).
    pub fn area(&mut self) -> DrawingArea<BitMapBackend<'_>, Shift> {
        BitMapBackend::with_buffer(&mut self.rgb, self.size).into_drawing_area()
    }

    /// Writes the canvas as an 8-bit RGB PNG.
    pub fn save(self) -> Result<()> {
        let file = std::fs::File::create(&self.path)
            .with_context(|| format!("{}: cannot create", self.path.display()))?;
        let mut enc = png::Encoder::new(BufWriter::new(file), self.size.0, self.size.1);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc
            .write_header()
            .with_context(|| self.path.display().to_string())?;
        w.write_image_data(&self.rgb)
            .with_context(|| self.path.display().to_string())?;
        w.finish().with_context(|| self.path.display().to_string())
    }
}

/// Registers the carried font once per process as "sans-serif", the family every plot asks
/// for.
fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType font; a failure would only leave the text out.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        );
    });
}
