//! The operator cache under `<data>/operators` (shape operators, DRT ray units and bases, level
//! transports, DNRT grids: every engine cache), trimmed least-recently-used to a byte budget.
//!
//! Use is the file's modification time: the engine's caches set it on every hit and every write,
//! so the oldest files are the least recently used. Files whose name starts with `.` are writes
//! in flight (temp files renamed into place) and are never removed.
//!
//! Invariant: trimming only costs time. An entry removed while a bake reads it is either read
//! whole before the removal or missed and recomputed (the engine's caches read whole files and
//! treat a missing entry as a miss), so no bake fails or changes because of a trim.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// What a trim found and did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TrimReport {
    /// Bytes in the cache after the trim.
    pub bytes: u64,
    pub removed_files: u64,
    pub removed_bytes: u64,
}

/// Every cache file under `dir` (one level of subdirectories): (last use, bytes, path).
fn entries(dir: &Path) -> Vec<(SystemTime, u64, PathBuf)> {
    let mut out = Vec::new();
    let mut dirs = vec![(dir.to_path_buf(), 0)];
    while let Some((d, depth)) = dirs.pop() {
        let Ok(read) = fs::read_dir(&d) else { continue };
        for entry in read.flatten() {
            let path = entry.path();
            let Ok(meta) = entry.metadata() else { continue };
            if meta.is_dir() {
                if depth == 0 {
                    dirs.push((path, depth + 1));
                }
                continue;
            }
            if entry.file_name().to_string_lossy().starts_with('.') {
                continue;
            }
            let used = meta.modified().unwrap_or(SystemTime::UNIX_EPOCH);
            out.push((used, meta.len(), path));
        }
    }
    out
}

/// Removes the least recently used files until the cache holds at most `budget` bytes.
pub fn trim(dir: &Path, budget: u64) -> TrimReport {
    let mut files = entries(dir);
    let mut report = TrimReport {
        bytes: files.iter().map(|f| f.1).sum(),
        ..TrimReport::default()
    };
    if report.bytes <= budget {
        return report;
    }
    files.sort_by(|a, b| a.0.cmp(&b.0).then_with(|| a.2.cmp(&b.2)));
    for (_, len, path) in files {
        if report.bytes <= budget {
            break;
        }
        if fs::remove_file(&path).is_ok() {
            report.bytes -= len;
            report.removed_files += 1;
            report.removed_bytes += len;
        }
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn trims_the_least_recently_used_files_to_the_budget_and_keeps_writes_in_flight() {
        let dir = std::env::temp_dir().join(format!("lf-optrim-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(dir.join("drt")).unwrap();
        let now = SystemTime::now();
        let write = |name: &str, len: usize, age_s: u64| {
            let path = dir.join(name);
            fs::write(&path, vec![7u8; len]).unwrap();
            let f = fs::File::options().append(true).open(&path).unwrap();
            f.set_modified(now - Duration::from_secs(age_s)).unwrap();
        };
        write("old.lfshape", 400, 300);
        write("drt/mid.lfrays", 300, 200);
        write("new.lfshape", 200, 10);
        write("drt/.tmp-write.tmp", 1000, 1000);
        let report = trim(&dir, 600);
        assert_eq!(report.removed_files, 1);
        assert_eq!(report.removed_bytes, 400);
        assert_eq!(report.bytes, 500);
        assert!(!dir.join("old.lfshape").exists());
        assert!(dir.join("drt/mid.lfrays").exists() && dir.join("new.lfshape").exists());
        assert!(
            dir.join("drt/.tmp-write.tmp").exists(),
            "a write in flight was removed"
        );
        // Within budget: nothing happens.
        assert_eq!(trim(&dir, 500).removed_files, 0);
        let _ = fs::remove_dir_all(&dir);
    }
}
