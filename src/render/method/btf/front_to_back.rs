//! The `btf` billboards drawn front to back into the trees' layer
//! ([`crate::render::layer`], knob `front_to_back`): the batches they are drawn in and
//! their passes after the main pass.

use super::settings::BtfSettings;
use super::{BtfAssets, BtfFrame, far};
use crate::render::compositor::CompositorInput;
use crate::render::frame::FrameStats;
use crate::render::method::interface::AfterCx;

impl BtfAssets {
    /// A frame's billboards drawn front to back into the trees' layer in
    /// `bf.layer_batches` batches (sorted on the GPU with the far trees' billboards, or on
    /// the CPU), the pixels it has made opaque marked between batches, then the layer put
    /// over the frame; all timed as `billboards`.
    pub(crate) fn draw_layer(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        cx: &AfterCx<'_>,
        pipeline: Option<&wgpu::RenderPipeline>,
        bf: &BtfFrame,
        stats: &mut FrameStats,
    ) {
        let batches = bf.layer_batches;
        let far = self
            .far
            .as_ref()
            .and_then(Option::as_ref)
            .filter(|_| bf.far);
        if let Some(knobs) = bf.compositor
            && let Some(c) = &self.compositor
        {
            let (records, count) = match far.and_then(|f| f.compositor_records()) {
                Some((group, buffer, word)) => (group, (buffer, word)),
                None => (
                    &self.bind_group,
                    (c.set_cpu_count(cx.ctx, bf.billboards), 0),
                ),
            };
            let max_records = match far {
                Some(f) => f.sorted_capacity(),
                None => u64::from(bf.billboards),
            };
            let input = CompositorInput {
                records,
                count,
                max_records: max_records.min(u64::from(u32::MAX)) as u32,
            };
            c.encode(
                cx.ctx,
                encoder,
                cx.frame_group,
                &input,
                (cx.depth, cx.layer),
                (cx.target, cx.format),
                knobs,
                cx.spans,
            );
            return;
        }
        let span = cx.spans.open("billboards");
        for k in 0..batches {
            let Some(mut pass) = cx.layer.batch_pass(
                encoder,
                cx.depth,
                k == 0,
                cx.spans.render_writes(span, k == 0, false),
            ) else {
                return;
            };
            pass.set_bind_group(0, cx.frame_group, &[]);
            if let Some(pipeline) = pipeline {
                pass.set_pipeline(pipeline);
                match far {
                    Some(f) => f.draw_batch(&mut pass, k),
                    None => {
                        let n = bf.billboards;
                        let (first, end) =
                            (batch_start(n, k, batches), batch_start(n, k + 1, batches));
                        if end > first {
                            pass.set_bind_group(1, &self.bind_group, &[]);
                            pass.draw(0..6, first..end);
                        }
                    }
                }
                stats.draw_calls += 1;
            }
            drop(pass);
            if k + 1 < batches {
                cx.layer.mark_opaque(encoder, cx.depth);
            }
        }
        cx.layer.composite(
            encoder,
            cx.target,
            cx.format,
            cx.spans.render_writes(span, false, true),
        );
    }
}

/// The first of `n` records in batch `k` of `batches` (equal shares; `k == batches`: `n`).
fn batch_start(n: u32, k: u32, batches: u32) -> u32 {
    (u64::from(n) * u64::from(k) / u64::from(batches.max(1))) as u32
}

/// The batches the CPU's billboards (`count`) are drawn in for the trees' layer (0: back to
/// front in the main pass).
pub(super) fn cpu_layer_batches(settings: &BtfSettings, count: usize) -> u32 {
    // Direct draws start past instance 0 on every adapter.
    if count > 0 {
        far::layer_batches(settings, true)
    } else {
        0
    }
}
