//! Where the memory goes: the process's resident memory, and the GPU's allocations grouped
//! by what they hold (their labels), from the allocator's own report. On a software
//! renderer (lavapipe) the GPU's memory is the process's own, so the GPU parts are most of
//! the resident memory; on a GPU they are device memory.

use serde::Serialize;

/// Resident memory of this process (Linux /proc; 0 where it cannot be read).
pub fn resident_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4096)
}

/// The most this process has had resident (Linux /proc `VmHWM`; 0 where it cannot be read).
pub fn resident_peak_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
            line.split_whitespace().nth(1)?.parse::<u64>().ok()
        })
        .map_or(0, |kib| kib * 1024)
}

/// The C heap's bytes in use and bytes held free in its arenas (freed, not given back):
/// resident growth with the first flat is fragmentation, not a leak. Zeros off glibc.
pub fn heap_bytes() -> (u64, u64) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallinfo2 only reads the allocator's counters.
        let m = unsafe { libc::mallinfo2() };
        ((m.uordblks + m.hblkhd) as u64, m.fordblks as u64)
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        (0, 0)
    }
}

/// One part of the memory: what it holds, and its bytes.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct MemoryPart {
    pub name: String,
    pub bytes: u64,
    /// Allocations it is made of.
    pub count: u32,
}

/// The memory of a renderer at one moment.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct MemoryReport {
    /// The process's resident memory now, and its peak so far.
    pub resident_bytes: u64,
    pub resident_peak_bytes: u64,
    /// The GPU allocations' bytes, and what the allocator holds for them (its blocks);
    /// absent where the backend gives no report.
    pub gpu_allocated_bytes: Option<u64>,
    pub gpu_reserved_bytes: Option<u64>,
    /// The GPU allocations grouped by what they hold, largest first.
    pub gpu_parts: Vec<MemoryPart>,
    /// What the renderer keeps on the CPU besides (the bake's tables, the meshes' CPU
    /// copies), largest first.
    pub cpu_parts: Vec<MemoryPart>,
}

impl MemoryReport {
    /// The GPU's allocations now (grouped), the process's memory, and `cpu_parts`.
    pub fn new(device: &wgpu::Device, cpu_parts: Vec<MemoryPart>) -> Self {
        let mut report = Self {
            resident_bytes: resident_bytes(),
            resident_peak_bytes: resident_peak_bytes(),
            cpu_parts: sorted(cpu_parts),
            ..Default::default()
        };
        if let Some(r) = device.generate_allocator_report() {
            report.gpu_allocated_bytes = Some(r.total_allocated_bytes);
            report.gpu_reserved_bytes = Some(r.total_reserved_bytes);
            report.gpu_parts = group(r.allocations.iter().map(|a| (a.name.as_str(), a.size)));
        }
        report
    }

    /// The report as lines for a terminal or the log: totals, then each part of at
    /// least `min_bytes`.
    pub fn lines(&self, min_bytes: u64) -> Vec<String> {
        let mb = |b: u64| b as f64 / 1e6;
        let mut out = vec![format!(
            "resident {:.1} MB (peak {:.1} MB); GPU allocations {}",
            mb(self.resident_bytes),
            mb(self.resident_peak_bytes),
            match (self.gpu_allocated_bytes, self.gpu_reserved_bytes) {
                (Some(a), Some(r)) => format!("{:.1} MB in {:.1} MB of blocks", mb(a), mb(r)),
                _ => "not reported by this backend".into(),
            }
        )];
        for (kind, parts) in [("GPU", &self.gpu_parts), ("CPU", &self.cpu_parts)] {
            let (shown, rest): (Vec<_>, Vec<_>) = parts.iter().partition(|p| p.bytes >= min_bytes);
            for p in shown {
                let n = if p.count > 1 {
                    format!(" ({} of them)", p.count)
                } else {
                    String::new()
                };
                out.push(format!("  {kind} {:>8.1} MB  {}{n}", mb(p.bytes), p.name));
            }
            if !rest.is_empty() {
                let b: u64 = rest.iter().map(|p| p.bytes).sum();
                out.push(format!(
                    "  {kind} {:>8.1} MB  {} smaller parts",
                    mb(b),
                    rest.len()
                ));
            }
        }
        out
    }
}

/// Allocations grouped by label, numbers in the labels ignored ("timestamp resolve 2" is a
/// "timestamp resolve #"), largest group first.
pub fn group<'a>(allocations: impl Iterator<Item = (&'a str, u64)>) -> Vec<MemoryPart> {
    let mut parts: Vec<MemoryPart> = Vec::new();
    for (name, bytes) in allocations {
        let name = generic_name(name);
        match parts.iter_mut().find(|p| p.name == name) {
            Some(p) => {
                p.bytes += bytes;
                p.count += 1;
            }
            None => parts.push(MemoryPart {
                name,
                bytes,
                count: 1,
            }),
        }
    }
    sorted(parts)
}

fn sorted(mut parts: Vec<MemoryPart>) -> Vec<MemoryPart> {
    parts.sort_by(|a, b| b.bytes.cmp(&a.bytes).then_with(|| a.name.cmp(&b.name)));
    parts
}

/// A label with each run of digits replaced by `#`.
fn generic_name(label: &str) -> String {
    let mut out = String::with_capacity(label.len());
    let mut in_digits = false;
    for c in label.chars() {
        if c.is_ascii_digit() {
            if !in_digits {
                out.push('#');
            }
            in_digits = true;
        } else {
            out.push(c);
            in_digits = false;
        }
    }
    out
}

/// Bytes of a CPU vector's contents.
pub fn vec_bytes<T>(v: &[T]) -> u64 {
    std::mem::size_of_val(v) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn allocations_are_grouped_by_label_without_their_numbers() {
        let parts = group(
            [
                ("timestamp resolve 0", 8),
                ("BTF atlas", 100),
                ("timestamp resolve 1", 8),
                ("shadow cascades", 40),
            ]
            .into_iter(),
        );
        let got: Vec<_> = parts
            .iter()
            .map(|p| (p.name.as_str(), p.bytes, p.count))
            .collect();
        assert_eq!(
            got,
            [
                ("BTF atlas", 100, 1),
                ("shadow cascades", 40, 1),
                ("timestamp resolve #", 16, 2)
            ]
        );
    }

    #[test]
    fn this_process_has_resident_memory_and_a_peak_at_least_as_high() {
        let now = resident_bytes();
        assert!(now > 0);
        assert!(resident_peak_bytes() >= now);
    }

    #[test]
    fn small_parts_are_summed_on_one_line() {
        let report = MemoryReport {
            resident_bytes: 10_000_000,
            resident_peak_bytes: 12_000_000,
            gpu_allocated_bytes: Some(3_000_000),
            gpu_reserved_bytes: Some(4_000_000),
            gpu_parts: vec![
                MemoryPart {
                    name: "big".into(),
                    bytes: 2_500_000,
                    count: 1,
                },
                MemoryPart {
                    name: "a".into(),
                    bytes: 300_000,
                    count: 2,
                },
                MemoryPart {
                    name: "b".into(),
                    bytes: 200_000,
                    count: 1,
                },
            ],
            cpu_parts: vec![],
        };
        let lines = report.lines(1_000_000);
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[1].contains("2.5 MB  big"), "{lines:?}");
        assert!(lines[2].contains("0.5 MB  2 smaller parts"), "{lines:?}");
    }
}
