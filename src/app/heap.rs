//! The C heap of a long-running viewer (glibc; elsewhere these do nothing).
//!
//! Left alone, glibc keeps what the viewer frees: lavapipe's per-frame allocations (tens
//! of millions of calls in a soak, most of the heap) are made from several threads, each
//! arena grows to its own high-water mark, and freed pages inside an arena are not given
//! back. Resident memory then climbs in steps over an hour while the bytes in use stay
//! flat (the soak's `heap_used_bytes` and `heap_free_bytes` show which). The viewer
//! therefore caps the arenas and hands free pages back every few seconds.

use std::time::{Duration, Instant};

/// How often [`Upkeep::tend`] gives free heap pages back.
pub const TRIM_EVERY: Duration = Duration::from_secs(5);

/// Most malloc arenas the viewer lets glibc create (its default is 8 per core).
pub const MAX_ARENAS: i32 = 2;

/// Caps the number of malloc arenas; call before the threads that allocate start.
pub fn limit_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, MAX_ARENAS);
    }
}

/// Gives the heap's free pages back to the system (every arena's, not only the top).
pub fn trim() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases memory the allocator holds free.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Trims the heap every [`TRIM_EVERY`], from the viewer's frame loop.
pub struct Upkeep {
    last: Instant,
}

impl Default for Upkeep {
    fn default() -> Self {
        Self {
            last: Instant::now(),
        }
    }
}

impl Upkeep {
    pub fn tend(&mut self) {
        if self.last.elapsed() >= TRIM_EVERY {
            trim();
            self.last = Instant::now();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trimming_keeps_what_is_in_use() {
        let keep: Vec<Vec<u8>> = (0..64).map(|i| vec![i as u8; 100_000]).collect();
        let garbage: Vec<Vec<u8>> = (0..64).map(|_| vec![0u8; 100_000]).collect();
        drop(garbage);
        trim();
        assert!(
            keep.iter()
                .enumerate()
                .all(|(i, v)| v.iter().all(|&b| b == i as u8))
        );
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        assert!(crate::render::memory::heap_bytes().0 >= 64 * 100_000);
    }
}
