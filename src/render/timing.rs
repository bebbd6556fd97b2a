//! GPU frame timing with timestamp queries: a timestamp when the frame's first pass begins
//! and one when its last pass ends. Read back either blocking (the CLI and the bench, which
//! report the GPU's own time) or a few frames later without stalling (the viewer).

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use super::GpuContext;

const FREE: u8 = 0;
const PENDING: u8 = 1;
const MAPPED: u8 = 2;
const SLOTS: usize = 3;

/// A MAP_READ buffer that a frame copies into, mapped after its submit without stalling
/// and read once the GPU is done: free, then pending (mapping asked), then mapped.
pub struct MappedRead {
    buffer: wgpu::Buffer,
    state: Arc<AtomicU8>,
}

impl MappedRead {
    pub fn new(ctx: &GpuContext, label: &str, size: u64) -> Self {
        Self {
            buffer: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            state: Arc::new(AtomicU8::new(FREE)),
        }
    }

    /// The buffer to copy into (while [`Self::is_free`]).
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// Neither waiting for its mapping nor holding an unread one.
    pub fn is_free(&self) -> bool {
        self.state.load(Ordering::SeqCst) == FREE
    }

    /// After the submit that copied into it: asks for the mapping.
    pub fn map(&self) {
        self.state.store(PENDING, Ordering::SeqCst);
        let state = self.state.clone();
        self.buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            state.store(if r.is_ok() { MAPPED } else { FREE }, Ordering::SeqCst);
        });
    }

    /// Whether a mapping has been asked for and has not come yet.
    pub fn is_pending(&self) -> bool {
        self.state.load(Ordering::SeqCst) == PENDING
    }

    /// Reads a finished mapping with `f` and frees the buffer; None while there is none
    /// (poll the device first).
    pub fn read<T>(&self, f: impl FnOnce(&[u8]) -> T) -> Option<T> {
        if self.state.load(Ordering::SeqCst) != MAPPED {
            return None;
        }
        let out = self.buffer.get_mapped_range(..).ok().map(|view| f(&view));
        self.buffer.unmap();
        self.state.store(FREE, Ordering::SeqCst);
        out
    }
}

struct Slot {
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    read: MappedRead,
}

/// Timestamp queries around a frame's passes.
pub struct GpuTimer {
    slots: Vec<Slot>,
    period_ns: f64,
    current: Option<usize>,
    /// Most recent completed measurement (ms).
    pub last_ms: Option<f64>,
}

impl GpuTimer {
    /// None when the adapter cannot write timestamps.
    pub fn new(ctx: &GpuContext) -> Option<Self> {
        if !ctx.timestamps {
            return None;
        }
        let slots = (0..SLOTS)
            .map(|i| Slot {
                query_set: ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("frame timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2,
                }),
                resolve: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("timestamp resolve {i}")),
                    size: 16,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                read: MappedRead::new(ctx, &format!("timestamp read {i}"), 16),
            })
            .collect();
        Some(Self {
            slots,
            period_ns: f64::from(ctx.queue.get_timestamp_period()),
            current: None,
            last_ms: None,
        })
    }

    /// Picks a free slot for this frame; None (no timing this frame) if all are in flight.
    pub fn begin(&mut self) -> Option<&wgpu::QuerySet> {
        self.current = self.slots.iter().position(|s| s.read.is_free());
        self.current.map(|i| &self.slots[i].query_set)
    }

    /// Records the resolve and copy for the frame's queries.
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        if let Some(i) = self.current {
            let s = &self.slots[i];
            encoder.resolve_query_set(&s.query_set, 0..2, &s.resolve, 0);
            encoder.copy_buffer_to_buffer(&s.resolve, 0, s.read.buffer(), 0, 16);
        }
    }

    /// After the frame's submit: asks for the read buffer to be mapped when the GPU is done.
    pub fn after_submit(&mut self) {
        if let Some(i) = self.current.take() {
            self.slots[i].read.map();
        }
    }

    /// Collects finished measurements; with `block`, waits for the GPU first.
    pub fn collect(&mut self, ctx: &GpuContext, block: bool) -> Option<f64> {
        let poll = if block {
            wgpu::PollType::wait_indefinitely()
        } else {
            wgpu::PollType::Poll
        };
        let _ = ctx.device.poll(poll);
        let mut newest = None;
        for s in &self.slots {
            if let Some(ms) = s.read.read(|view| {
                let t0: u64 = bytemuck::pod_read_unaligned(&view[0..8]);
                let t1: u64 = bytemuck::pod_read_unaligned(&view[8..16]);
                t1.saturating_sub(t0) as f64 * self.period_ns / 1.0e6
            }) {
                newest = Some(ms);
            }
        }
        if newest.is_some() {
            self.last_ms = newest;
        }
        newest
    }
}
