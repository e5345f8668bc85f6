//! Who writes what in a run folder that several processes share (shards started together by a
//! Slurm job array, or two runs started into one `--out`).
//!
//! Two kinds of advisory file lock (`flock`; the kernel releases them when a process dies, so a
//! crashed writer leaves no stale claim behind):
//! - `DIR/.gfcal-run.lock`: every process writing the folder holds it shared for its whole run.
//!   A process that gets it exclusively is alone: it may create, refuse, clear or clean up the
//!   folder, then shares it. A process that cannot get it exclusively joins the run in progress
//!   (and is refused if its config differs). The last process to leave removes it (and the
//!   emptied `locks/` folder); a process that locked a file removed meanwhile opens the new one.
//! - `DIR/locks/part-NNNNNN.lock`: held exclusively by the one process computing that part, and
//!   removed once the part's files are written. A process that cannot take it leaves the part to
//!   its holder; one that takes it checks again that the part is not done before running it.
//!
//! The shared file system must support `flock` (local disks, NFS v4 and Lustre/GPFS mounted with
//! locking do); where it does not, the run stops with an error saying so rather than risk two
//! writers of one part.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::{Path, PathBuf};

/// The folder-wide lock of one process.
#[derive(Debug)]
pub struct RunLock {
    file: File,
    path: PathBuf,
}

/// Whether this process has the folder to itself.
#[derive(Debug)]
pub enum Entry {
    /// No other gfcal process is writing the folder (the lock is held exclusively until
    /// [`RunLock::share`]).
    Alone(RunLock),
    /// Other processes are writing it (the lock is held shared).
    Joining(RunLock),
}

fn unsupported(path: &Path, e: std::io::Error) -> std::io::Error {
    std::io::Error::new(
        e.kind(),
        format!(
            "cannot lock {} ({e}); concurrent writers of a run folder need a file system with file locks (flock)",
            path.display()
        ),
    )
}

fn open_lock_file(path: &Path) -> std::io::Result<File> {
    OpenOptions::new().read(true).write(true).create(true).truncate(false).open(path)
}

/// Whether the lock file we hold is still the one at `path` (the last process to leave a run
/// removes the file: a lock taken on a removed file locks nothing that others can see).
#[cfg(unix)]
fn still_at(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn still_at(_file: &File, path: &Path) -> bool {
    path.exists()
}

/// Enters the run folder `dir` (which must exist): exclusively if no other process holds it,
/// otherwise shared, waiting until the process that has it exclusively has prepared it.
pub fn enter(dir: &Path) -> std::io::Result<Entry> {
    let path = dir.join(".gfcal-run.lock");
    loop {
        let file = open_lock_file(&path)?;
        let entry = match file.try_lock() {
            Ok(()) => Entry::Alone(RunLock { file, path: path.clone() }),
            Err(TryLockError::WouldBlock) => {
                file.lock_shared().map_err(|e| unsupported(&path, e))?;
                Entry::Joining(RunLock { file, path: path.clone() })
            }
            Err(TryLockError::Error(e)) => return Err(unsupported(&path, e)),
        };
        // The file was removed (by the last process leaving) between opening and locking it:
        // open the one that is there now.
        let lock = match &entry {
            Entry::Alone(l) | Entry::Joining(l) => l,
        };
        if still_at(&lock.file, &path) {
            return Ok(entry);
        }
    }
}

impl RunLock {
    /// Lets other processes join (turns an exclusive lock into a shared one).
    pub fn share(self) -> std::io::Result<RunLock> {
        self.file.lock_shared().map_err(|e| unsupported(&self.path, e))?;
        Ok(self)
    }

    /// Leaves the run folder `dir`. The last process to leave (the one that can take the lock
    /// exclusively: no other is writing) removes the lock file and the `locks/` folder if empty,
    /// so a finished run leaves neither behind; the others leave them to it.
    pub fn leave(self, dir: &Path) {
        if self.file.try_lock().is_ok() {
            let _ = std::fs::remove_dir(dir.join("locks"));
            let _ = std::fs::remove_file(&self.path);
        }
        drop(self.file);
    }
}

/// The claim of one process on one part; released (and its file removed) by [`PartClaim::release`]
/// or when dropped.
#[derive(Debug)]
pub struct PartClaim {
    file: Option<File>,
    path: PathBuf,
}

/// The lock file of part `p`.
pub fn part_lock_path(dir: &Path, p: u64) -> PathBuf {
    dir.join("locks").join(format!("part-{p:06}.lock"))
}

/// Claims part `p` of the run in `dir`; `None` when another process holds it.
pub fn claim_part(dir: &Path, p: u64) -> std::io::Result<Option<PartClaim>> {
    let path = part_lock_path(dir, p);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent)?;
    }
    let file = open_lock_file(&path)?;
    match file.try_lock() {
        Ok(()) => Ok(Some(PartClaim { file: Some(file), path })),
        Err(TryLockError::WouldBlock) => Ok(None),
        Err(TryLockError::Error(e)) => Err(unsupported(&path, e)),
    }
}

impl PartClaim {
    /// Gives the part up. Removing the file before unlocking is safe: a process that opened it
    /// earlier gets the lock on the removed file, finds the part done and skips it.
    pub fn release(mut self) {
        self.unlock();
    }

    fn unlock(&mut self) {
        if let Some(file) = self.file.take() {
            let _ = std::fs::remove_file(&self.path);
            drop(file);
        }
    }
}

impl Drop for PartClaim {
    fn drop(&mut self) {
        self.unlock();
    }
}

/// Removes the lock file and the emptied `locks/` folder of the run in `dir` when no process holds
/// it (`gfcal summarize` after a job array's last task: two tasks that left at the same moment may
/// each have seen the other still in).
pub fn tidy(dir: &Path) {
    let path = dir.join(".gfcal-run.lock");
    if let Ok(file) = OpenOptions::new().read(true).write(true).open(&path)
        && still_at(&file, &path)
    {
        RunLock { file, path }.leave(dir);
    }
}

/// Whether another process is writing the run in `dir` now (holds its folder lock).
pub fn in_use(dir: &Path) -> bool {
    let path = dir.join(".gfcal-run.lock");
    let Ok(file) = OpenOptions::new().read(true).open(&path) else { return false };
    matches!(file.try_lock(), Err(TryLockError::WouldBlock))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_part_has_one_holder_at_a_time_and_is_free_after_release() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let first = claim_part(dir.path(), 3).expect("lock").expect("free part");
        assert!(claim_part(dir.path(), 3).expect("lock").is_none(), "a held part was claimed twice");
        assert!(claim_part(dir.path(), 4).expect("lock").is_some(), "another part is free");
        first.release();
        assert!(!part_lock_path(dir.path(), 3).exists());
        assert!(claim_part(dir.path(), 3).expect("lock").is_some());
    }

    #[test]
    fn the_last_to_leave_removes_the_lock_file_and_the_empty_locks_folder() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let Entry::Alone(first) = enter(dir.path()).expect("lock") else { panic!("the first is alone") };
        let first = first.share().expect("share");
        claim_part(dir.path(), 0).expect("lock").expect("free part").release();
        let Entry::Joining(second) = enter(dir.path()).expect("lock") else { panic!("the second joins") };
        first.leave(dir.path());
        assert!(dir.path().join(".gfcal-run.lock").exists(), "another process is still in");
        second.leave(dir.path());
        assert!(!dir.path().join(".gfcal-run.lock").exists());
        assert!(!dir.path().join("locks").exists());
        // A process that had opened the removed file enters the new one, alone.
        assert!(matches!(enter(dir.path()).expect("lock"), Entry::Alone(_)));
    }

    #[test]
    fn the_second_process_to_enter_joins() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let Entry::Alone(first) = enter(dir.path()).expect("lock") else { panic!("the first is alone") };
        let _first = first.share().expect("share");
        assert!(in_use(dir.path()));
        assert!(matches!(enter(dir.path()).expect("lock"), Entry::Joining(_)));
    }
}
