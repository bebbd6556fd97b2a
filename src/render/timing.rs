//! GPU timing with timestamp queries: each pass of a frame is a named span between two
//! timestamps, and the frame's time runs from its first timestamp to its last. Read back
//! either blocking (the CLI and the bench, which report the GPU's own time) or a few frames
//! later without stalling (the viewer).
//!
//! Whoever encodes a pass names it through the frame's [`PassSpans`]: a pass gets its
//! timestamp writes from [`PassSpans::render_pass`] or [`PassSpans::compute_pass`], and
//! draws inside a render pass are split into spans of their own with [`PassSpans::mark`]
//! where the adapter can write timestamps inside passes. Without timestamp queries the
//! spans record nothing and a frame has no pass times.
//!
//! The spans tile the frame: each runs from the end of the one before (the first from its
//! pass's beginning) to its own end, so that they add up to the frame and what runs
//! between two passes counts to the second. Ends are what a binning rasteriser records
//! faithfully: lavapipe (llvmpipe) takes a timestamp when its rasteriser reaches it, in the
//! batch of work *after* the flush it triggers, so a timestamp written just before draws
//! is recorded while they rasterise. A pass's end is followed by the next timestamp (the
//! next pass's beginning, or the resolve), which closes its batch; a mark inside a pass
//! writes two timestamps back to back and keeps the first for the same reason.

use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

use serde::ser::{SerializeSeq, SerializeStruct};
use serde::{Serialize, Serializer};

use super::GpuContext;

const FREE: u8 = 0;
const PENDING: u8 = 1;
const MAPPED: u8 = 2;
const SLOTS: usize = 3;

/// Timestamps one frame may write (two a pass, one a mark inside a pass); passes past it
/// go untimed.
pub const MAX_TIMESTAMPS: u32 = 96;

/// Distinct pass names one frame reports (same-named spans are summed).
pub const MAX_PASSES: usize = 16;

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

/// One pass's GPU time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PassTime {
    pub name: &'static str,
    pub ms: f64,
}

/// A frame's pass times in the order the passes first ran, spans of the same name summed
/// (the four sun cascades are one entry). Fixed capacity, so that frame statistics stay
/// plain values; serialised as a list of `{name, ms}`.
#[derive(Clone, Copy, Default, PartialEq)]
pub struct PassTimes {
    len: usize,
    items: [PassTime; MAX_PASSES],
}

impl PassTimes {
    /// Adds `ms` to the pass `name` (a new entry at the end when it is new). False when
    /// the list is full and `name` is not in it (the time is dropped).
    pub fn add(&mut self, name: &'static str, ms: f64) -> bool {
        if let Some(p) = self.items[..self.len].iter_mut().find(|p| p.name == name) {
            p.ms += ms;
            return true;
        }
        if self.len == MAX_PASSES {
            return false;
        }
        self.items[self.len] = PassTime { name, ms };
        self.len += 1;
        true
    }

    pub fn iter(&self) -> impl Iterator<Item = &PassTime> {
        self.items[..self.len].iter()
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The time of the pass `name`, if the frame had it.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.iter().find(|p| p.name == name).map(|p| p.ms)
    }

    /// The sum of the passes' times (ms).
    pub fn total_ms(&self) -> f64 {
        self.iter().map(|p| p.ms).sum()
    }

    /// Per pass, the median of `frames`' times (a pass missing from a frame counts 0 there),
    /// in the order of the frame that names the most passes.
    pub fn median(frames: &[PassTimes]) -> PassTimes {
        let mut out = PassTimes::default();
        let Some(order) = frames.iter().max_by_key(|f| f.len()) else {
            return out;
        };
        for p in order.iter() {
            let mut v: Vec<f64> = frames
                .iter()
                .map(|f| f.get(p.name).unwrap_or(0.0))
                .collect();
            v.sort_by(f64::total_cmp);
            out.add(p.name, v[v.len() / 2]);
        }
        out
    }
}

impl std::fmt::Debug for PassTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_map()
            .entries(self.iter().map(|p| (p.name, p.ms)))
            .finish()
    }
}

impl Serialize for PassTimes {
    fn serialize<S: Serializer>(&self, ser: S) -> Result<S::Ok, S::Error> {
        let mut seq = ser.serialize_seq(Some(self.len))?;
        for p in self.iter() {
            seq.serialize_element(p)?;
        }
        seq.end()
    }
}

/// A frame's GPU times: the whole frame and each pass.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameTiming {
    /// From the frame's first timestamp to its last (ms).
    pub frame_ms: f64,
    pub passes: PassTimes,
}

impl Serialize for FrameTiming {
    fn serialize<S: Serializer>(&self, ser: S) -> Result<S::Ok, S::Error> {
        let mut s = ser.serialize_struct("FrameTiming", 2)?;
        s.serialize_field("frame_ms", &self.frame_ms)?;
        s.serialize_field("passes", &self.passes)?;
        s.end()
    }
}

/// A named span between two timestamps (query indices), either not written yet.
#[derive(Clone, Copy, Debug)]
struct Span {
    name: &'static str,
    start: Option<u32>,
    end: Option<u32>,
}

#[derive(Default)]
struct SpanLog {
    /// Timestamps handed out so far (indices 0..next, every one written by the frame).
    next: u32,
    spans: Vec<Span>,
    /// The span of the render or compute pass being encoded, which [`PassSpans::mark`]
    /// splits.
    current: Option<usize>,
}

impl SpanLog {
    fn take_index(&mut self) -> Option<u32> {
        (self.next < MAX_TIMESTAMPS).then(|| {
            self.next += 1;
            self.next - 1
        })
    }
}

/// Names a span opened by [`PassSpans::open`], for passes that share it.
#[derive(Clone, Copy, Debug)]
pub struct SpanId(usize);

/// The named passes of one frame as they are encoded, each given its timestamps. Off (no
/// query set: no timestamps, or every slot still in flight) it hands out nothing and every
/// call is free.
pub struct PassSpans {
    query_set: Option<wgpu::QuerySet>,
    inside_passes: bool,
    log: RefCell<SpanLog>,
}

impl PassSpans {
    /// Spans that record nothing.
    pub fn off() -> Self {
        Self {
            query_set: None,
            inside_passes: false,
            log: RefCell::default(),
        }
    }

    fn new(query_set: wgpu::QuerySet, inside_passes: bool) -> Self {
        Self {
            query_set: Some(query_set),
            inside_passes,
            log: RefCell::default(),
        }
    }

    /// Whether anything is timed.
    pub fn is_on(&self) -> bool {
        self.query_set.is_some()
    }

    /// Whether [`Self::mark`] splits a pass (the adapter writes timestamps inside passes).
    pub fn splits_passes(&self) -> bool {
        self.is_on() && self.inside_passes
    }

    /// Opens a span named `name` that one or several passes fill: the first gets its
    /// beginning, the last its end (see [`Self::render_writes`]).
    pub fn open(&self, name: &'static str) -> Option<SpanId> {
        self.query_set.as_ref()?;
        let mut log = self.log.borrow_mut();
        log.spans.push(Span {
            name,
            start: None,
            end: None,
        });
        Some(SpanId(log.spans.len() - 1))
    }

    /// The timestamp writes of one pass of `span`: its beginning when `first`, its end when
    /// `last` (None where neither, where the span is off or the frame's timestamps ran out).
    /// The pass must be encoded with them: every timestamp handed out is resolved.
    fn writes(
        &self,
        span: Option<SpanId>,
        first: bool,
        last: bool,
    ) -> Option<(Option<u32>, Option<u32>)> {
        let SpanId(i) = span?;
        let mut log = self.log.borrow_mut();
        if log.next + u32::from(first) + u32::from(last) > MAX_TIMESTAMPS {
            return None;
        }
        let start = if first { log.take_index() } else { None };
        let end = if last { log.take_index() } else { None };
        let s = &mut log.spans[i];
        if start.is_some() {
            s.start = start;
        }
        if end.is_some() {
            s.end = end;
        }
        log.current = Some(i);
        (start.is_some() || end.is_some()).then_some((start, end))
    }

    /// [`Self::writes`] for a render pass.
    pub fn render_writes(
        &self,
        span: Option<SpanId>,
        first: bool,
        last: bool,
    ) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        let (start, end) = self.writes(span, first, last)?;
        Some(wgpu::RenderPassTimestampWrites {
            query_set: self.query_set.as_ref()?,
            beginning_of_pass_write_index: start,
            end_of_pass_write_index: end,
        })
    }

    /// The timestamp writes of a render pass that is a span of its own, `name`.
    pub fn render_pass(&self, name: &'static str) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        self.render_writes(self.open(name), true, true)
    }

    /// The timestamp writes of a compute pass that is a span of its own, `name`.
    pub fn compute_pass(&self, name: &'static str) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let (start, end) = self.writes(self.open(name), true, true)?;
        Some(wgpu::ComputePassTimestampWrites {
            query_set: self.query_set.as_ref()?,
            beginning_of_pass_write_index: start,
            end_of_pass_write_index: end,
        })
    }

    /// From here on, the draws of the render pass being encoded (opened with timestamp
    /// writes from these spans) are timed as `name`. Where the adapter cannot write
    /// timestamps inside passes the whole pass keeps the name it has.
    pub fn mark(&self, pass: &mut wgpu::RenderPass<'_>, name: &'static str) {
        if let Some((q, at, closer)) = self.split(name) {
            pass.write_timestamp(q, at);
            pass.write_timestamp(q, closer);
        }
    }

    /// Renames what the pass being encoded has drawn since its beginning or last mark
    /// (no timestamp): how a method names its first draws when the core opened them under
    /// a general name.
    pub fn rename(&self, name: &'static str) {
        let mut log = self.log.borrow_mut();
        if let Some(i) = log.current
            && self.splits_passes()
        {
            log.spans[i].name = name;
        }
    }

    /// Splits the current span at a new timestamp: it ends there and `name` begins. Also
    /// hands out the timestamp written right after it, which only closes its batch.
    fn split(&self, name: &'static str) -> Option<(&wgpu::QuerySet, u32, u32)> {
        if !self.splits_passes() {
            return None;
        }
        let q = self.query_set.as_ref()?;
        let mut log = self.log.borrow_mut();
        let i = log.current?;
        let current = log.spans[i];
        if current.name == name || current.start.is_none() || log.next + 2 > MAX_TIMESTAMPS {
            return None;
        }
        let at = log.take_index()?;
        let closer = log.take_index()?;
        log.spans[i].end = Some(at);
        log.spans.push(Span {
            name,
            start: Some(at),
            end: current.end,
        });
        log.current = Some(log.spans.len() - 1);
        Some((q, at, closer))
    }

    /// The timestamps written (0..n) and the finished spans.
    fn finish(self) -> (u32, Vec<(&'static str, u32, u32)>) {
        let log = self.log.into_inner();
        let spans = log
            .spans
            .iter()
            .filter_map(|s| Some((s.name, s.start?, s.end?)))
            .collect();
        (log.next, spans)
    }
}

/// The frame's times from its resolved timestamps (`ticks`) and spans (in the order they
/// ran), `period_ns` a tick: each span from the end of the one before (the first from its
/// beginning) to its end. A span whose end was not written counts to the next.
fn timing_of(ticks: &[u64], spans: &[(&'static str, u32, u32)], period_ns: f64) -> FrameTiming {
    let ms = |t: u64| t as f64 * period_ns / 1.0e6;
    let at = |i: u32| ticks.get(i as usize).copied();
    let mut timing = FrameTiming::default();
    let Some(first) = spans.first().and_then(|&(_, s, _)| at(s)) else {
        return timing;
    };
    let mut from = first;
    for &(name, _, e) in spans {
        let Some(end) = at(e) else { continue };
        timing.passes.add(name, ms(end.saturating_sub(from)));
        from = from.max(end);
    }
    timing.frame_ms = ms(from - first);
    timing
}

struct Slot {
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    read: MappedRead,
    /// The spans of the frame whose timestamps the slot holds.
    spans: Vec<(&'static str, u32, u32)>,
    /// Timestamps that frame wrote.
    written: u32,
}

/// Timestamp queries for a frame's passes, in a few slots so that the viewer's frames need
/// not wait for the GPU.
pub struct GpuTimer {
    slots: Vec<Slot>,
    period_ns: f64,
    inside_passes: bool,
    current: Option<usize>,
    /// Most recent completed frame time (ms).
    pub last_ms: Option<f64>,
    /// Most recent completed frame's pass times.
    pub last: Option<FrameTiming>,
}

impl GpuTimer {
    /// None when the adapter cannot write timestamps.
    pub fn new(ctx: &GpuContext) -> Option<Self> {
        if !ctx.timestamps {
            return None;
        }
        let bytes = u64::from(MAX_TIMESTAMPS) * 8;
        let slots = (0..SLOTS)
            .map(|i| Slot {
                query_set: ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("pass timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: MAX_TIMESTAMPS,
                }),
                resolve: ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(&format!("timestamp resolve {i}")),
                    size: bytes,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                read: MappedRead::new(ctx, &format!("timestamp read {i}"), bytes),
                spans: Vec::new(),
                written: 0,
            })
            .collect();
        Some(Self {
            slots,
            period_ns: f64::from(ctx.queue.get_timestamp_period()),
            inside_passes: ctx.timestamps_inside_passes,
            current: None,
            last_ms: None,
            last: None,
        })
    }

    /// The spans of a new frame, on a free slot; off (no timing this frame) if all are in
    /// flight.
    pub fn begin(&mut self) -> PassSpans {
        self.current = self.slots.iter().position(|s| s.read.is_free());
        match self.current {
            Some(i) => PassSpans::new(self.slots[i].query_set.clone(), self.inside_passes),
            None => PassSpans::off(),
        }
    }

    /// Records the resolve and copy of the frame's timestamps (`spans`, from
    /// [`Self::begin`]); a frame that wrote none is not timed.
    pub fn resolve(&mut self, spans: PassSpans, encoder: &mut wgpu::CommandEncoder) {
        let Some(i) = self.current else { return };
        let (written, list) = spans.finish();
        if written == 0 || list.is_empty() {
            self.current = None;
            return;
        }
        let s = &mut self.slots[i];
        encoder.resolve_query_set(&s.query_set, 0..written, &s.resolve, 0);
        encoder.copy_buffer_to_buffer(&s.resolve, 0, s.read.buffer(), 0, u64::from(written) * 8);
        s.spans = list;
        s.written = written;
    }

    /// After the frame's submit: asks for the read buffer to be mapped when the GPU is done.
    pub fn after_submit(&mut self) {
        if let Some(i) = self.current.take() {
            self.slots[i].read.map();
        }
    }

    /// Collects finished measurements; with `block`, waits for the GPU first. Returns the
    /// newest frame collected now.
    pub fn collect(&mut self, ctx: &GpuContext, block: bool) -> Option<FrameTiming> {
        let poll = if block {
            wgpu::PollType::wait_indefinitely()
        } else {
            wgpu::PollType::Poll
        };
        let _ = ctx.device.poll(poll);
        let mut newest = None;
        for s in &self.slots {
            let n = s.written as usize;
            if let Some(t) = s.read.read(|view| {
                let ticks: Vec<u64> = view[..n * 8]
                    .chunks_exact(8)
                    .map(bytemuck::pod_read_unaligned)
                    .collect();
                timing_of(&ticks, &s.spans, self.period_ns)
            }) {
                newest = Some(t);
            }
        }
        if let Some(t) = newest {
            self.last_ms = Some(t.frame_ms);
            self.last = Some(t);
        }
        newest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_named_passes_are_summed_in_first_order() {
        let mut p = PassTimes::default();
        p.add("cascades", 1.0);
        p.add("sky", 2.0);
        p.add("cascades", 0.5);
        let names: Vec<_> = p.iter().map(|p| p.name).collect();
        assert_eq!(names, ["cascades", "sky"]);
        assert_eq!(p.get("cascades"), Some(1.5));
        assert_eq!(p.total_ms(), 3.5);
    }

    #[test]
    fn a_full_list_drops_new_names_only() {
        const NAMES: [&str; MAX_PASSES + 1] = [
            "a", "b", "c", "d", "e", "f", "g", "h", "i", "j", "k", "l", "m", "n", "o", "p", "q",
        ];
        let mut p = PassTimes::default();
        for n in NAMES {
            p.add(n, 1.0);
        }
        assert_eq!(p.len(), MAX_PASSES);
        assert!(!p.add("q", 1.0));
        assert!(p.add("a", 1.0));
        assert_eq!(p.get("a"), Some(2.0));
    }

    #[test]
    fn spans_tile_the_frame_from_its_first_timestamp_to_its_last() {
        // Ticks of 1 µs: a compute pass 0..2000, cascades 2100..3000 (the 100 between
        // them counts to the cascades), main 3000..9000 split at 4000 (sky | terrain) and
        // 5000 (terrain | trees).
        let ticks = [0, 2000, 2100, 3000, 3050, 9000, 4000, 4001, 5000, 5001];
        let spans = [
            ("far trees", 0, 1),
            ("cascades", 2, 3),
            ("sky", 4, 6),
            ("terrain", 6, 8),
            ("trees", 8, 5),
        ];
        let t = timing_of(&ticks, &spans, 1000.0);
        assert!((t.frame_ms - 9.0).abs() < 1e-9);
        let got: Vec<_> = t.passes.iter().map(|p| (p.name, p.ms)).collect();
        assert_eq!(
            got,
            [
                ("far trees", 2.0),
                ("cascades", 1.0),
                ("sky", 1.0),
                ("terrain", 1.0),
                ("trees", 4.0)
            ]
        );
        assert!((t.passes.total_ms() - t.frame_ms).abs() < 1e-9);
        // Nothing written, nothing timed.
        assert_eq!(timing_of(&[], &spans, 1.0), FrameTiming::default());
    }

    #[test]
    fn median_takes_each_pass_alone() {
        let mut a = PassTimes::default();
        a.add("sky", 1.0);
        a.add("trees", 10.0);
        let mut b = PassTimes::default();
        b.add("sky", 3.0);
        let mut c = PassTimes::default();
        c.add("sky", 2.0);
        c.add("trees", 12.0);
        let m = PassTimes::median(&[a, b, c]);
        assert_eq!(m.get("sky"), Some(2.0));
        assert_eq!(m.get("trees"), Some(10.0));
        assert!(PassTimes::median(&[]).is_empty());
    }

    #[test]
    fn spans_that_are_off_hand_out_nothing() {
        let s = PassSpans::off();
        assert!(!s.is_on() && !s.splits_passes());
        assert!(s.open("x").is_none());
        assert!(s.render_pass("x").is_none());
        assert!(s.compute_pass("x").is_none());
        s.rename("y");
        let (n, list) = s.finish();
        assert_eq!((n, list.len()), (0, 0));
    }
}
