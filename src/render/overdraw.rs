//! The overdraw view: how many fragments each pixel shaded, and how many images they read,
//! counted by every colour pass of every method (`count_fragment` in `shaders/frame.wgsl`,
//! atomic adds into two counters per pixel bound in group 0) and drawn over the finished
//! frame as a heat map with its scale (`shaders/overdraw.wgsl`).
//!
//! The counts are of fragments rasterised and shaded: a fragment shader that writes to a
//! buffer runs before the depth test, so while the view is on, fragments that an opaque
//! surface in front hides count too (they may not be shaded when it is off). Blended
//! trees, which write no depth, are shaded either way.

use crate::{Error, Result};

use super::GpuContext;

/// What the heat map shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OverdrawView {
    /// Fragments shaded per pixel (scale 0, 1, 2, 4 ... 256).
    #[default]
    Fragments,
    /// Images read by those fragments per pixel (scale 0, 8, 16, 32 ... 2048).
    Reads,
}

impl OverdrawView {
    pub const ALL: [OverdrawView; 2] = [OverdrawView::Fragments, OverdrawView::Reads];

    pub fn name(self) -> &'static str {
        match self {
            OverdrawView::Fragments => "fragments",
            OverdrawView::Reads => "reads",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|v| v.name() == s)
    }

    /// `Frame::overdraw.w` in the shaders.
    pub fn index(self) -> u32 {
        match self {
            OverdrawView::Fragments => 0,
            OverdrawView::Reads => 1,
        }
    }
}

/// Means over a frame's pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct OverdrawMeans {
    pub fragments_per_pixel: f64,
    pub reads_per_pixel: f64,
}

/// The counters: two `u32` per pixel of the largest target counted so far (a placeholder
/// of one pixel until the view is first turned on).
pub struct OverdrawCounts {
    buffer: wgpu::Buffer,
    pixels: u64,
}

impl OverdrawCounts {
    pub fn new(ctx: &GpuContext, pixels: u64) -> Result<Self> {
        let pixels = pixels.max(1);
        let size = pixels
            .checked_mul(8)
            .filter(|s| *s <= ctx.device.limits().max_storage_buffer_binding_size)
            .ok_or_else(|| {
                Error::BadInput(format!(
                    "the overdraw view needs {pixels} pixels' counters, more than this GPU binds; draw a smaller image"
                ))
            })?;
        let buffer = ctx.checked("allocating the overdraw counters", || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("overdraw counts"),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        Ok(Self { buffer, pixels })
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The number of pixels the counters hold.
    pub fn pixels(&self) -> u64 {
        self.pixels
    }

    /// Zeroes the counters of a `width` x `height` frame.
    pub fn clear(&self, encoder: &mut wgpu::CommandEncoder, width: u32, height: u32) {
        let bytes = (u64::from(width) * u64::from(height) * 8).min(self.buffer.size());
        encoder.clear_buffer(&self.buffer, 0, Some(bytes));
    }

    /// The means of a `width` x `height` frame's counters (blocking until the GPU is done).
    pub fn means(&self, ctx: &GpuContext, width: u32, height: u32) -> Result<OverdrawMeans> {
        let pixels = u64::from(width) * u64::from(height);
        if pixels == 0 || pixels > self.pixels {
            return Err(Error::Gpu(
                "the overdraw counters were not sized for this frame".into(),
            ));
        }
        let bytes = pixels * 8;
        let read = ctx.checked("allocating the overdraw readback", || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("overdraw readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("overdraw readback"),
            });
        encoder.copy_buffer_to_buffer(&self.buffer, 0, &read, 0, bytes);
        ctx.queue.submit([encoder.finish()]);
        let data = super::target::map_read(ctx, &read)?;
        Ok(means_of(&data))
    }
}

/// The means of counters laid out as the shaders write them: (fragments, reads) per pixel.
pub fn means_of(data: &[u8]) -> OverdrawMeans {
    let (mut fragments, mut reads, mut n) = (0u64, 0u64, 0u64);
    for px in data.chunks_exact(8) {
        fragments += u64::from(u32::from_le_bytes([px[0], px[1], px[2], px[3]]));
        reads += u64::from(u32::from_le_bytes([px[4], px[5], px[6], px[7]]));
        n += 1;
    }
    let n = n.max(1) as f64;
    OverdrawMeans {
        fragments_per_pixel: fragments as f64 / n,
        reads_per_pixel: reads as f64 / n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn means_average_both_counters_over_the_pixels() {
        let mut data = Vec::new();
        for (f, r) in [(1u32, 15u32), (3, 0), (0, 0), (4, 45)] {
            data.extend_from_slice(&f.to_le_bytes());
            data.extend_from_slice(&r.to_le_bytes());
        }
        let m = means_of(&data);
        assert_eq!(m.fragments_per_pixel, 2.0);
        assert_eq!(m.reads_per_pixel, 15.0);
        assert_eq!(OverdrawView::parse("reads"), Some(OverdrawView::Reads));
        assert_eq!(OverdrawView::parse("pixels"), None);
    }
}
