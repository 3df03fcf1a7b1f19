//! Float RGB images: EXR and PNG output (atomic), error metrics.

use super::error::RenderError;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A linear float RGB image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
}

/// `eps` in [`relative_mse`]: keeps near-black reference pixels from dominating (the usual
/// choice in denoising and rendering papers for images of order-one radiance).
pub const RELATIVE_MSE_EPS: f64 = 1e-2;

impl Image {
    /// A black image; zero width or height is an error.
    pub fn new(width: u32, height: u32) -> Result<Self, RenderError> {
        let n = pixel_count(width, height)?;
        Ok(Image {
            width,
            height,
            rgb: vec![[0.0; 3]; n],
        })
    }

    /// Pixel `(x, y)`, `y = 0` the top row; `None` outside.
    pub fn get(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        if x < self.width && y < self.height {
            self.rgb
                .get(y as usize * self.width as usize + x as usize)
                .copied()
        } else {
            None
        }
    }

    fn check(&self) -> Result<usize, RenderError> {
        let n = pixel_count(self.width, self.height)?;
        if self.rgb.len() != n {
            return Err(RenderError::Invalid {
                what: "image",
                why: format!(
                    "{}x{} needs {n} pixels, has {}",
                    self.width,
                    self.height,
                    self.rgb.len()
                ),
            });
        }
        Ok(n)
    }

    /// Linear f32 RGB OpenEXR, written to a temporary file beside `path` and renamed.
    pub fn write_exr(&self, path: impl AsRef<Path>) -> Result<(), RenderError> {
        self.write_exr_at(path.as_ref())
    }

    // The generic entry points are thin shells over these non-generic bodies: exr's reader
    // and writer are generic, and a generic body would compile them again at full
    // optimisation in every crate that calls it (the binaries, the viewer, each test binary).
    fn write_exr_at(&self, path: &Path) -> Result<(), RenderError> {
        let bytes = self.exr_bytes()?;
        write_atomic(path, |out| {
            out.write_all(&bytes)
                .map_err(|e| RenderError::Exr(e.to_string()))
        })
    }

    /// The bytes of [`Image::write_exr`].
    pub fn exr_bytes(&self) -> Result<Vec<u8>, RenderError> {
        use exr::prelude::{SpecificChannels, Vec2, WritableImage};
        self.check()?;
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
            let p = self.rgb[y * w + x];
            (p[0], p[1], p[2])
        });
        let mut out = std::io::Cursor::new(Vec::new());
        // Sequential compression: exr's parallel writer stores the chunks in the order its
        // threads finish them, so the same image gave different bytes from run to run.
        exr::prelude::Image::from_channels((w, self.height as usize), channels)
            .write()
            .non_parallel()
            .to_buffered(&mut out)
            .map_err(|e| RenderError::Exr(e.to_string()))?;
        Ok(out.into_inner())
    }

    /// The bytes of [`Image::write_exr`] into `out` (for files written together with others,
    /// `pin_volume::files::write_together`).
    pub fn encode_exr<W: Write + std::io::Seek>(&self, out: &mut W) -> Result<(), RenderError> {
        let bytes = self.exr_bytes()?;
        out.write_all(&bytes)
            .map_err(|e| RenderError::Exr(e.to_string()))
    }

    /// Reads the first RGB(A) layer of an EXR file (for references written by
    /// [`Image::write_exr`]). The file is opened by the one input rule
    /// (`pin_format::input::open_regular`): a FIFO or a device is refused, never opened.
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Image, RenderError> {
        Self::read_exr_at(path.as_ref(), None)
    }

    /// [`Image::read_exr`], refused from the file's header, before its pixels are allocated
    /// or decoded, unless it is `size` (width, height) pixels: a reference of another size
    /// fails before a render starts, whatever size the file claims.
    pub fn read_exr_of_size(
        path: impl AsRef<Path>,
        size: Option<(u32, u32)>,
    ) -> Result<Image, RenderError> {
        Self::read_exr_at(path.as_ref(), size)
    }

    fn read_exr_at(path: &Path, size: Option<(u32, u32)>) -> Result<Image, RenderError> {
        use exr::prelude::{ReadChannels, ReadLayers, Vec2};
        use std::io::{BufReader, Seek};
        let (file, _) = pin_format::input::open_regular(path).map_err(|e| {
            use pin_format::input::InputError as E;
            RenderError::Input(match e {
                E::IsDirectory(_) => "is a directory".into(),
                E::NotRegular(_) => "not a regular file".into(),
                E::Io { err, .. } => err.to_string(),
                E::OutOfMemory { bytes, .. } => format!("out of memory for {bytes} bytes"),
            })
        })?;
        let mut reader = BufReader::new(file);
        let exr_err = |e: exr::error::Error| RenderError::Exr(e.to_string());
        if let Some((w, h)) = size {
            let meta =
                exr::meta::MetaData::read_from_buffered(&mut reader, false).map_err(exr_err)?;
            let sizes: Vec<(usize, usize)> = meta
                .headers
                .iter()
                .map(|h| (h.layer_size.0, h.layer_size.1))
                .collect();
            if sizes.first() != Some(&(w as usize, h as usize)) {
                let (fw, fh) = sizes.first().copied().unwrap_or((0, 0));
                return Err(RenderError::Invalid {
                    what: "reference",
                    why: format!("the image is {fw}x{fh}, the render {w}x{h}"),
                });
            }
            reader
                .rewind()
                .map_err(|e| RenderError::Exr(e.to_string()))?;
        }
        let img = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .rgba_channels(
                |res: Vec2<usize>, _| (res.0, vec![[0f32; 3]; res.0 * res.1]),
                |px: &mut (usize, Vec<[f32; 3]>),
                 pos: Vec2<usize>,
                 (r, g, b, _a): (f32, f32, f32, f32)| {
                    px.1[pos.1 * px.0 + pos.0] = [r, g, b];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_buffered(reader)
            .map_err(exr_err)?;
        let size = img.layer_data.size;
        let out = Image {
            width: u32::try_from(size.0).map_err(|_| RenderError::Exr("too wide".into()))?,
            height: u32::try_from(size.1).map_err(|_| RenderError::Exr("too tall".into()))?,
            rgb: img.layer_data.channel_data.pixels.1,
        };
        out.check()?;
        Ok(out)
    }

    /// 8-bit sRGB PNG: `exposure * value`, Reinhard `x / (1 + x)`, sRGB transfer, rounded.
    /// NaN and negative values map to 0. Written atomically.
    pub fn write_png(&self, path: impl AsRef<Path>, exposure: f32) -> Result<(), RenderError> {
        self.write_png_at(path.as_ref(), exposure)
    }

    fn write_png_at(&self, path: &Path, exposure: f32) -> Result<(), RenderError> {
        write_atomic(path, |out| self.encode_png(out, exposure))
    }

    /// The bytes of [`Image::write_png`] into `out`.
    pub fn encode_png<W: Write>(&self, out: &mut W, exposure: f32) -> Result<(), RenderError> {
        self.check()?;
        if !exposure.is_finite() || exposure < 0.0 {
            return Err(RenderError::Invalid {
                what: "exposure",
                why: format!("{exposure} must be finite and >= 0"),
            });
        }
        let bytes: Vec<u8> = self
            .rgb
            .iter()
            .flat_map(|p| p.map(|c| tone_map(c, exposure)))
            .collect();
        let mut enc = png::Encoder::new(out, self.width, self.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png_err = |e: png::EncodingError| RenderError::Png(e.to_string());
        let mut writer = enc.write_header().map_err(png_err)?;
        writer.write_image_data(&bytes).map_err(png_err)?;
        writer.finish().map_err(png_err)
    }
}

/// Reinhard then the sRGB transfer function, to 8 bits.
pub fn tone_map(c: f32, exposure: f32) -> u8 {
    let x = c * exposure;
    let x = if x > 0.0 { x } else { 0.0 }; // NaN and negatives
    let y = if x.is_infinite() { 1.0 } else { x / (1.0 + x) };
    let s = if y <= 0.003_130_8 {
        12.92 * y
    } else {
        1.055 * y.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

fn pixel_count(width: u32, height: u32) -> Result<usize, RenderError> {
    let n = (width as u64) * (height as u64);
    if n == 0 || n > (1u64 << 31) {
        return Err(RenderError::Invalid {
            what: "image size",
            why: format!("{width}x{height}: need 1 ..= 2^31 pixels"),
        });
    }
    Ok(n as usize)
}

/// Write through `f` into a fresh temporary file in the target's directory, fsync, rename
/// over `path`. On any error the temporary file is removed and `path` is untouched.
pub(crate) fn write_atomic(
    path: &Path,
    f: impl FnOnce(&mut BufWriter<File>) -> Result<(), RenderError>,
) -> Result<(), RenderError> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let io = |p: &Path, e: std::io::Error| RenderError::Io {
        path: p.to_path_buf(),
        source: e,
    };
    let name = path.file_name().ok_or_else(|| RenderError::Invalid {
        what: "output path",
        why: format!("{} has no file name", path.display()),
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let tmp = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| io(&tmp, e))?;
        let mut out = BufWriter::new(file);
        f(&mut out)?;
        out.flush().map_err(|e| io(&tmp, e))?;
        out.get_ref().sync_all().map_err(|e| io(&tmp, e))?;
        drop(out);
        std::fs::rename(&tmp, path).map_err(|e| io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

fn same_size(a: &Image, b: &Image) -> Result<usize, RenderError> {
    let n = a.check()?;
    b.check()?;
    if a.width != b.width || a.height != b.height {
        return Err(RenderError::Invalid {
            what: "image pair",
            why: format!("{}x{} vs {}x{}", a.width, a.height, b.width, b.height),
        });
    }
    Ok(n)
}

/// Root mean squared error over all pixels and channels (f64 accumulation).
pub fn rmse(a: &Image, b: &Image) -> Result<f64, RenderError> {
    let n = same_size(a, b)?;
    let mut s = 0.0f64;
    for (p, q) in a.rgb.iter().zip(&b.rgb) {
        for c in 0..3 {
            let e = p[c] as f64 - q[c] as f64;
            s += e * e;
        }
    }
    Ok((s / (3 * n) as f64).sqrt())
}

/// Mean over pixels and channels of `(a - b)^2 / (b^2 + eps)`, `b` the reference and
/// `eps` = [`RELATIVE_MSE_EPS`] = 0.01.
pub fn relative_mse(a: &Image, reference: &Image) -> Result<f64, RenderError> {
    let n = same_size(a, reference)?;
    let mut s = 0.0f64;
    for (p, q) in a.rgb.iter().zip(&reference.rgb) {
        for c in 0..3 {
            let (x, r) = (p[c] as f64, q[c] as f64);
            s += (x - r) * (x - r) / (r * r + RELATIVE_MSE_EPS);
        }
    }
    Ok(s / (3 * n) as f64)
}

/// The bias of an image against a converged `reference`, as `docs/evaluation.md` measures it, on the
/// channel mean of each pixel: `(mean error, block rms error)`.
///
/// * mean error: `(mean(a) - mean(ref)) / mean(ref)` over the whole image;
/// * block rms error: the root mean square over the whole `block x block` tiles (a partial
///   tile at the right or bottom edge is left out) of `(A - R) / R`, `A` and `R` the tile
///   means, tiles whose reference mean is not positive left out.
///
/// Averaging over tiles first removes most of the per-pixel noise of a finite-spp render, so
/// what remains is bias (blocky or smooth) plus a noise floor of `sigma / (block * sqrt(spp))`.
/// Errors: different sizes, `block == 0`, or no tile with a positive reference mean.
pub fn block_bias(a: &Image, reference: &Image, block: u32) -> Result<(f64, f64), RenderError> {
    same_size(a, reference)?;
    let lum = |p: &[f32; 3]| (f64::from(p[0]) + f64::from(p[1]) + f64::from(p[2])) / 3.0;
    let (bx, by) = match block {
        0 => (0, 0),
        b => (a.width / b, a.height / b),
    };
    let mut sq = 0.0f64;
    let mut tiles = 0u64;
    for ty in 0..by {
        for tx in 0..bx {
            let (mut sa, mut sr) = (0.0f64, 0.0f64);
            for y in ty * block..(ty + 1) * block {
                for x in tx * block..(tx + 1) * block {
                    let i = y as usize * a.width as usize + x as usize;
                    sa += lum(&a.rgb[i]);
                    sr += lum(&reference.rgb[i]);
                }
            }
            if sr > 0.0 {
                let e = (sa - sr) / sr;
                sq += e * e;
                tiles += 1;
            }
        }
    }
    let mean_a: f64 = a.rgb.iter().map(lum).sum();
    let mean_r: f64 = reference.rgb.iter().map(lum).sum();
    if tiles == 0 || !(mean_r > 0.0) {
        return Err(RenderError::Invalid {
            what: "reference image",
            why: format!("no {block}x{block} tile with a positive mean"),
        });
    }
    Ok(((mean_a - mean_r) / mean_r, (sq / tiles as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_image() -> Image {
        let mut img = Image::new(5, 3).unwrap();
        for (i, p) in img.rgb.iter_mut().enumerate() {
            *p = [i as f32 * 0.25, 1.0 / (i as f32 + 1.0), 1e-3 * i as f32];
        }
        img
    }

    #[test]
    fn exr_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        let img = test_image();
        img.write_exr(&path).unwrap();
        let back = Image::read_exr(&path).unwrap();
        assert_eq!(back, img);
        // No temporary files left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// The same image gives the same EXR bytes every time. With exr's parallel writer the
    /// chunk order followed its threads (run-to-run differences in rendered files); a picture of
    /// many chunks written several times exposes that (the mutation: drop `.non_parallel()`).
    #[test]
    fn exr_bytes_are_deterministic() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Image::new(96, 512).unwrap();
        let mut x = 0x9e37_79b9_u32;
        for p in img.rgb.iter_mut() {
            for c in p.iter_mut() {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                *c = (x >> 8) as f32 / (1u32 << 24) as f32;
            }
        }
        let first = dir.path().join("0.exr");
        img.write_exr(&first).unwrap();
        let want = std::fs::read(&first).unwrap();
        for i in 1..8 {
            let path = dir.path().join(format!("{i}.exr"));
            img.write_exr(&path).unwrap();
            assert!(std::fs::read(&path).unwrap() == want, "write {i} differs");
        }
    }

    #[test]
    fn png_written() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let mut img = test_image();
        img.rgb[0] = [f32::NAN, -1.0, f32::INFINITY];
        img.write_png(&path, 1.0).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let reader = dec.read_info().unwrap();
        assert_eq!((reader.info().width, reader.info().height), (5, 3));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(img.write_png(&path, f32::NAN).is_err());
        assert!(
            img.write_png(dir.path().join("no/such/dir.png"), 1.0)
                .is_err()
        );
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn tone_map_values() {
        assert_eq!(tone_map(0.0, 1.0), 0);
        assert_eq!(tone_map(f32::NAN, 1.0), 0);
        assert_eq!(tone_map(f32::INFINITY, 1.0), 255);
        // x = 1 -> 0.5 -> sRGB 0.7354 -> 188.
        assert_eq!(tone_map(1.0, 1.0), 188);
    }

    #[test]
    fn metrics() {
        let a = test_image();
        let mut b = a.clone();
        assert_eq!(rmse(&a, &b).unwrap(), 0.0);
        b.rgb[0][0] += 3.0;
        let expect = (9.0f64 / 45.0).sqrt();
        assert!((rmse(&b, &a).unwrap() - expect).abs() < 1e-12);
        let rel = relative_mse(&b, &a).unwrap();
        assert!((rel - 9.0 / (0.0 + RELATIVE_MSE_EPS) / 45.0).abs() < 1e-9);
        assert!(rmse(&a, &Image::new(1, 1).unwrap()).is_err());
        assert!(Image::new(0, 4).is_err());
        let bad = Image {
            width: 2,
            height: 2,
            rgb: vec![],
        };
        assert!(rmse(&bad, &bad).is_err());
        assert!(bad.write_exr("x.exr").is_err());
    }

    #[test]
    fn block_bias_measures_mean_and_tiles() {
        let mut r = Image::new(16, 8).unwrap();
        for p in r.rgb.iter_mut() {
            *p = [1.0; 3];
        }
        assert_eq!(block_bias(&r, &r, 8).unwrap(), (0.0, 0.0));
        // +10% everywhere: both metrics 0.1.
        let mut a = r.clone();
        a.rgb.iter_mut().for_each(|p| *p = [1.1; 3]);
        let (m, b) = block_bias(&a, &r, 8).unwrap();
        assert!((m - 0.1).abs() < 1e-6 && (b - 0.1).abs() < 1e-6, "{m} {b}");
        // +20% on the left tile, -20% on the right: the mean cancels, the tiles do not.
        for (i, p) in a.rgb.iter_mut().enumerate() {
            *p = [if i % 16 < 8 { 1.2 } else { 0.8 }; 3];
        }
        let (m, b) = block_bias(&a, &r, 8).unwrap();
        assert!(m.abs() < 1e-6 && (b - 0.2).abs() < 1e-6, "{m} {b}");
        // Pixel noise that cancels within a tile does not count.
        for (i, p) in a.rgb.iter_mut().enumerate() {
            *p = [if i % 2 == 0 { 1.5 } else { 0.5 }; 3];
        }
        let (m, b) = block_bias(&a, &r, 8).unwrap();
        assert!(m.abs() < 1e-6 && b < 1e-6, "{m} {b}");
        assert!(block_bias(&a, &r, 0).is_err());
        assert!(block_bias(&a, &r, 9).is_err());
        assert!(block_bias(&Image::new(4, 4).unwrap(), &r, 8).is_err());
    }
}
