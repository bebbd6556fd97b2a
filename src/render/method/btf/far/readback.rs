//! Reading the far trees' buffers back: the counts of billboards made, without stalling, and
//! whole buffers for tests.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::render::GpuContext;
use crate::render::timing::MappedRead;

pub(super) use crate::render::target::read_buffer;

/// The build passes' counts of billboards made (far; near per level), copied out after a
/// frame and read when the GPU has done it, without stalling (as the frame timer's
/// timestamps are).
pub(super) struct CountReadback {
    read: MappedRead,
    /// This frame copied into `read`.
    copied: AtomicBool,
    /// The latest counts read (None before any).
    last: Mutex<Option<[u32; 8]>>,
}

impl CountReadback {
    pub(super) fn new(ctx: &GpuContext) -> Self {
        Self {
            read: MappedRead::new(ctx, "far count read", 32),
            copied: AtomicBool::new(false),
            last: Mutex::new(None),
        }
    }

    /// Copies the far count of `args` when the last copy has been read.
    pub(super) fn copy(&self, encoder: &mut wgpu::CommandEncoder, args: &wgpu::Buffer) {
        if self.read.is_free() && !self.copied.swap(true, Ordering::SeqCst) {
            encoder.copy_buffer_to_buffer(args, 16, self.read.buffer(), 0, 32);
        }
    }

    /// Maps a copy just submitted; reads a mapped one; with `wait`, blocks until the
    /// copy is read. The latest count read.
    pub(super) fn collect(&self, ctx: &GpuContext, wait: bool) -> Option<[u32; 8]> {
        if self.copied.swap(false, Ordering::SeqCst) {
            self.read.map();
        }
        let poll = if wait && self.read.is_pending() {
            wgpu::PollType::wait_indefinitely()
        } else {
            wgpu::PollType::Poll
        };
        let _ = ctx.device.poll(poll);
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = self.read.read(|view| {
            std::array::from_fn(|w| {
                u32::from_le_bytes([
                    view[4 * w],
                    view[4 * w + 1],
                    view[4 * w + 2],
                    view[4 * w + 3],
                ])
            })
        }) {
            *last = Some(n);
        }
        *last
    }
}
