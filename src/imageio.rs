//! Writing images without ever leaving half a file (through [`crate::atomic_file`]), and
//! the screenshots' file names.

use std::path::{Path, PathBuf};

use image::RgbaImage;

use crate::{Error, Result};

/// Saves `img` as a PNG at `path`, atomically. Parent folders are created.
pub fn save_png(path: &Path, img: &RgbaImage) -> Result<()> {
    let fail = |reason: String| Error::WriteImage {
        path: path.to_path_buf(),
        reason,
    };
    if path.as_os_str().is_empty() {
        return Err(fail("the path is empty".into()));
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .map_err(|e| fail(format!("cannot create {}: {e}", parent.display())))?;
    }
    crate::atomic_file::write_atomic(path, |w| {
        img.write_with_encoder(image::codecs::png::PngEncoder::new(w))
            .map_err(std::io::Error::other)
    })
    .map_err(|e| fail(format!("{} failed: {}", e.step, e.source)))
}

/// `screenshots/canopy-YYYYMMDD-HHMMSS.png` under `dir`, with a counter if that exists.
pub fn timestamped_path(dir: &Path) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let (y, mo, d, h, mi, s) = civil_from_unix(secs);
    let stem = format!("canopy-{y:04}{mo:02}{d:02}-{h:02}{mi:02}{s:02}");
    let mut p = dir.join(format!("{stem}.png"));
    let mut k = 1;
    while p.exists() {
        p = dir.join(format!("{stem}-{k}.png"));
        k += 1;
    }
    p
}

/// UTC date and time of a Unix timestamp (Howard Hinnant's civil-from-days).
fn civil_from_unix(secs: u64) -> (i64, u32, u32, u32, u32, u32) {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (
        y,
        m,
        d,
        (rem / 3600) as u32,
        (rem % 3600 / 60) as u32,
        (rem % 60) as u32,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_unix(0), (1970, 1, 1, 0, 0, 0));
        assert_eq!(civil_from_unix(1_795_000_000), (2026, 11, 18, 11, 6, 40));
    }

    #[test]
    fn save_is_atomic_and_reports_unwritable_paths() {
        let dir = std::env::temp_dir().join(format!("canopy-imageio-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let img = RgbaImage::from_pixel(3, 2, image::Rgba([10, 20, 30, 255]));
        let p = dir.join("a/b.png");
        save_png(&p, &img).unwrap();
        assert_eq!(image::open(&p).unwrap().to_rgba8(), img);
        let leftovers: Vec<_> = std::fs::read_dir(dir.join("a")).unwrap().collect();
        assert_eq!(leftovers.len(), 1, "no temporary file left behind");
        // A path under a regular file cannot be written.
        let bad = p.join("c.png");
        let err = save_png(&bad, &img).unwrap_err().to_string();
        assert!(err.contains("c.png"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
