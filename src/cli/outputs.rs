//! Outputs checked before the work: every file and folder a command will write is tried before
//! any data is read, so that an output that cannot be written is bad input (exit 2, the flag and
//! the path named, nothing written) rather than a failure after minutes of work.
//!
//! A file can be written when its folder exists, is a folder, and takes a new file (tried by
//! creating and removing a hidden file there: permission bits, read-only mounts, immutable
//! folders and file systems like /proc are all seen, as root too). A folder can be written when
//! it is one and takes a new file, or, if missing, when the nearest folder above it that exists
//! does (the command creates the rest).

use std::path::{Path, PathBuf};

use super::error::InputError;

/// One output of a command: a file, or a folder the command creates if missing.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Output<'a> {
    /// `(flag, path)`: a file written whole (a temporary name in its folder, then a rename).
    File(&'a str, &'a Path),
    /// `(flag, path)`: a folder the command writes into, created with its parents if missing.
    Folder(&'a str, &'a Path),
}

/// Refuses the first output that cannot be written.
pub(crate) fn check_outputs(outputs: &[Output]) -> Result<(), InputError> {
    for o in outputs {
        let (flag, path, problem) = match *o {
            Output::File(flag, path) => (flag, path, file_problem(path)),
            Output::Folder(flag, path) => (flag, path, folder_problem(path)),
        };
        if let Some(problem) = problem {
            return Err(InputError::Other(format!(
                "{flag}: cannot write {}: {problem}; nothing was read or written",
                path.display()
            )));
        }
    }
    Ok(())
}

/// The folder a relative or bare file name is written in.
fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn file_problem(path: &Path) -> Option<String> {
    if path.is_dir() {
        return Some("it is a folder; give a file name".into());
    }
    let folder = parent_of(path);
    match std::fs::metadata(&folder) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Some(format!("its folder {} does not exist (No such file or directory)", folder.display()))
        }
        Err(e) => Some(format!("its folder {} cannot be read ({e})", folder.display())),
        Ok(m) if !m.is_dir() => Some(format!("{} is not a folder", folder.display())),
        Ok(_) => takes_new_files(&folder).err(),
    }
}

fn folder_problem(path: &Path) -> Option<String> {
    let mut existing = path.to_path_buf();
    loop {
        match std::fs::metadata(&existing) {
            Ok(m) if m.is_dir() => return takes_new_files(&existing).err(),
            Ok(_) if existing == path => return Some("it is a file, not a folder".into()),
            Ok(_) => return Some(format!("{} is a file, not a folder", existing.display())),
            // A path under a file is missing too (ENOTDIR): the file above it is named below.
            Err(e) if matches!(e.kind(), std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory) => {}
            Err(e) => return Some(format!("{} cannot be read ({e})", existing.display())),
        }
        existing = match existing.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if existing == Path::new(".") && std::fs::metadata(".").is_err() {
            return Some("the working folder cannot be read".into());
        }
    }
}

/// Whether `folder` takes a new file: one is created (never over anything) and removed.
fn takes_new_files(folder: &Path) -> Result<(), String> {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let probe = folder.join(format!(".gfcal-write-check-{}-{nanos}", std::process::id()));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(file) => {
            drop(file);
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(format!("the folder {} does not take new files ({e})", folder.display())),
    }
}

/// Writes every `(path, content)` (each atomically), going on past a failure so that one bad
/// output does not cost the others; fails with the first failure once all were tried.
pub(crate) fn write_all(files: &[(&Path, &[u8])]) -> anyhow::Result<()> {
    use anyhow::Context;
    let mut first: Option<anyhow::Error> = None;
    for (path, content) in files {
        match gfcal::io::write_atomic(path, content).with_context(|| format!("cannot write {}", path.display())) {
            Ok(()) => eprintln!("wrote {}", path.display()),
            Err(e) => {
                first.get_or_insert(e);
            }
        }
    }
    first.map_or(Ok(()), Err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writable_places_pass_and_others_are_named() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let d = dir.path();
        let file = d.join("f");
        std::fs::write(&file, "x").expect("write");
        assert!(check_outputs(&[Output::File("--json", &d.join("a.json"))]).is_ok());
        assert!(check_outputs(&[Output::Folder("--out", &d.join("new/deeper"))]).is_ok());
        assert!(check_outputs(&[Output::Folder("--out", d)]).is_ok());
        for (o, words) in [
            (Output::File("--json", &file.join("a.json")), "is not a folder"),
            (Output::File("--json", d), "is a folder"),
            (Output::File("--csv", &d.join("missing/a.csv")), "does not exist"),
            (Output::Folder("--out", &file.join("sub")), "is a file"),
            (Output::Folder("--out", &file), "is a file"),
            (Output::File("--report", Path::new("/proc/gfcal-unit-test.html")), "does not take new files"),
        ] {
            let e = check_outputs(&[o]).expect_err("refused").to_string();
            assert!(e.contains(words) && e.starts_with("--"), "{e}");
        }
        // Nothing is left behind by the checks.
        assert_eq!(std::fs::read_dir(d).expect("list").count(), 1);
        assert!(!d.join("new").exists());
    }
}
