//! Writing a file so that it is never seen half-written: the content goes into a temporary
//! file beside the destination (`tempfile`), which is synced and then renamed over the
//! destination, so the path holds either its old content or the complete new one. On any
//! error the temporary file is removed and the destination is untouched. A leaf module: it
//! imports nothing from the crate.

use std::fmt;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// The step of an atomic write that failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Creating the temporary file beside the destination.
    Create,
    /// Writing the content into it.
    Write,
    /// Syncing it to the disk.
    Sync,
    /// Renaming it over the destination.
    Replace,
}

impl Step {
    /// What was being done, as the start of a message that goes on with the destination's
    /// path: "could not write /x/y.png".
    pub fn action(self) -> &'static str {
        match self {
            Step::Create => "could not create a temporary file next to",
            Step::Write => "could not write",
            Step::Sync => "could not sync",
            Step::Replace => "could not replace",
        }
    }
}

impl fmt::Display for Step {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Step::Create => "creating a temporary file beside it",
            Step::Write => "writing",
            Step::Sync => "syncing",
            Step::Replace => "renaming the temporary file over it",
        })
    }
}

/// An atomic write that failed: the destination, the step and the operating system's error.
#[derive(Debug, thiserror::Error)]
#[error("{} {}: {source}", step.action(), path.display())]
pub struct AtomicWriteError {
    /// The destination, as given.
    pub path: PathBuf,
    pub step: Step,
    #[source]
    pub source: io::Error,
}

/// Writes `path` atomically with what `write` puts into the (buffered) writer it is given:
/// a temporary file in the same folder, synced, then renamed over `path` (and the folder
/// synced on Unix, best effort). The folder must exist.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<(), AtomicWriteError> {
    write_atomic_with_hook(path, write, |_| Ok(()))
}

/// [`write_atomic`] with a hook run on the complete, synced temporary file just before the
/// rename (tests use it to simulate a crash there).
pub(crate) fn write_atomic_with_hook(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> io::Result<()>,
    before_rename: impl FnOnce(&Path) -> io::Result<()>,
) -> Result<(), AtomicWriteError> {
    let fail = |step| {
        move |source| AtomicWriteError {
            path: path.to_owned(),
            step,
            source,
        }
    };
    let Some(name) = path.file_name() else {
        return Err(fail(Step::Create)(io::Error::new(
            io::ErrorKind::InvalidInput,
            "the path has no file name",
        )));
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let prefix = format!(".{}.", name.to_string_lossy());
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".tmp");
    // The permissions a plain `File::create` gives (0o666 less the umask), not the
    // temporary file's owner-only ones.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    // Dropping `temp` on an early return removes the temporary file.
    let mut temp = builder.tempfile_in(dir).map_err(fail(Step::Create))?;
    {
        let mut writer = BufWriter::new(temp.as_file_mut());
        write(&mut writer).map_err(fail(Step::Write))?;
        writer.flush().map_err(fail(Step::Write))?;
    }
    temp.as_file().sync_all().map_err(fail(Step::Sync))?;
    before_rename(temp.path()).map_err(fail(Step::Write))?;
    temp.persist(path)
        .map_err(|e| fail(Step::Replace)(e.error))?;
    // Make the rename itself durable; best effort (not every filesystem allows it).
    #[cfg(unix)]
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// The names in `dir`, sorted: what tests of atomic writes check for leftover files.
#[cfg(test)]
pub(crate) fn dir_entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("canopy-atomic-test-{}-{name}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn writes_and_replaces_leaving_no_temporary_file() {
        let dir = scratch("replace");
        let path = dir.join("out.txt");
        write_atomic(&path, |w| w.write_all(b"one")).unwrap();
        write_atomic(&path, |w| w.write_all(b"two")).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"two");
        assert_eq!(dir_entries(&dir), ["out.txt"]);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = fs::metadata(&path).unwrap().permissions().mode();
            assert_ne!(mode & 0o044, 0, "readable like a plain new file: {mode:o}");
        }
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failure_at_any_step_leaves_the_old_file_and_no_temporary_one() {
        let dir = scratch("fail");
        let path = dir.join("forest.canopy");
        fs::write(&path, b"old").unwrap();
        let err = write_atomic(&path, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("the encoder failed"))
        })
        .unwrap_err();
        assert_eq!(err.step, Step::Write);
        assert!(err.to_string().contains("forest.canopy"), "{err}");
        let mut seen = None;
        let err = write_atomic_with_hook(
            &path,
            |w| w.write_all(b"new"),
            |temp| {
                // The complete new file sits beside the target, hidden, under another name.
                assert_eq!(temp.parent(), Some(dir.as_path()));
                let name = temp.file_name().unwrap().to_string_lossy().into_owned();
                assert!(name.starts_with(".forest.canopy.") && name.ends_with(".tmp"));
                assert_eq!(fs::read(temp)?, b"new");
                seen = Some(temp.to_owned());
                Err(io::Error::other("simulated crash before the rename"))
            },
        )
        .unwrap_err();
        assert_eq!(err.step, Step::Write);
        assert!(
            !seen.expect("the hook ran").exists(),
            "temporary file removed"
        );
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(dir_entries(&dir), ["forest.canopy"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unwritable_destinations_name_the_path_and_the_step() {
        let dir = scratch("unwritable");
        // A missing folder, a path under a regular file, a path with no file name.
        let missing = dir.join("no-such-dir").join("out.canopy");
        let err = write_atomic(&missing, |w| w.write_all(b"x")).unwrap_err();
        assert_eq!(
            (err.step, err.path.as_path()),
            (Step::Create, missing.as_path())
        );
        let file = dir.join("plain.txt");
        fs::write(&file, b"hello").unwrap();
        let under = file.join("out.canopy");
        let err = write_atomic(&under, |w| w.write_all(b"x")).unwrap_err();
        assert!(err.to_string().contains(&*under.to_string_lossy()), "{err}");
        let err = write_atomic(Path::new("/"), |w| w.write_all(b"x")).unwrap_err();
        assert_eq!(err.step, Step::Create);
        // Onto a folder: the rename fails, the temporary file goes.
        let taken = dir.join("taken");
        fs::create_dir(&taken).unwrap();
        let err = write_atomic(&taken, |w| w.write_all(b"x")).unwrap_err();
        assert_eq!(err.step, Step::Replace);
        assert_eq!(dir_entries(&dir), ["plain.txt", "taken"]);
        assert_eq!(fs::read(&file).unwrap(), b"hello");
        fs::remove_dir_all(&dir).unwrap();
    }
}
