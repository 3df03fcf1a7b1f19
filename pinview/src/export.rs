//! Export: the displayed texture (what the window shows of the render) as PNG, read back from
//! the GPU only when asked.

use std::path::Path;

use anyhow::{Result, anyhow};

/// Reads back an `Rgba8Unorm` texture of `width x height` as RGB bytes, rows top first.
pub fn read_texture_rgb(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    width: u32,
    height: u32,
) -> Result<Vec<u8>> {
    let rgba = read_texture_rgba(device, queue, texture, width, height)?;
    Ok(rgba
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect())
}

/// Reads back an `Rgba8Unorm` texture of `width x height` as RGBA bytes, rows top first.
pub fn read_texture_rgba(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    width: u32,
    height: u32,
) -> Result<Vec<u8>> {
    let row = width * 4;
    let padded =
        row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("screenshot"),
        size: u64::from(padded) * u64::from(height),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("screenshot"),
    });
    enc.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded),
                rows_per_image: Some(height),
            },
        },
        wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        },
    );
    queue.submit([enc.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| anyhow!("reading the image back: {e}"))?;
    rx.recv()
        .map_err(|e| anyhow!("reading the image back: {e}"))?
        .map_err(|e| anyhow!("reading the image back: {e}"))?;
    let view = buffer
        .slice(..)
        .get_mapped_range()
        .map_err(|e| anyhow!("reading the image back: {e}"))?;
    let mut rgba = Vec::with_capacity((width * height * 4) as usize);
    for y in 0..height as usize {
        rgba.extend_from_slice(&view[y * padded as usize..y * padded as usize + row as usize]);
    }
    drop(view);
    buffer.unmap();
    Ok(rgba)
}

/// Writes 8-bit RGB as a PNG (through a temporary file beside it, then renamed).
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let named = |e: &dyn std::fmt::Display| anyhow!("{}: {e}", path.display());
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let tmp = dir.join(format!(
        ".{}.pinview-tmp",
        path.file_name()
            .map_or("out".into(), |n| n.to_string_lossy())
    ));
    let result = (|| -> Result<()> {
        let file = std::fs::File::create(&tmp).map_err(|e| named(&e))?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(|e| named(&e))?;
        writer.write_image_data(rgb).map_err(|e| named(&e))?;
        writer.finish().map_err(|e| named(&e))?;
        std::fs::rename(&tmp, path).map_err(|e| named(&e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
