//! Retention of a directory of recordings: remove `*.mcap` files older than an age limit, then
//! the oldest while the directory holds more than a size limit. Files in use (recordings
//! still being written) and files changed very recently are never removed.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// What a directory of recordings may hold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RetentionPolicy {
    /// Most bytes of `*.mcap` files in the directory (0: no limit).
    pub max_bytes: u64,
    /// Oldest a recording may be, by its last change (`None`: no limit).
    pub max_age: Option<Duration>,
    /// A file changed more recently than this is never removed (a recording that a closed
    /// session's worker is still finishing).
    pub min_age: Duration,
}

impl RetentionPolicy {
    /// Whether the policy removes anything at all.
    pub fn is_active(&self) -> bool {
        self.max_bytes > 0 || self.max_age.is_some()
    }
}

/// Why a recording was removed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RemovalReason {
    /// Older than [`RetentionPolicy::max_age`].
    Age,
    /// Oldest while the directory was over [`RetentionPolicy::max_bytes`].
    Size,
}

impl RemovalReason {
    /// The name in logs and metrics (`age`, `size`).
    pub fn label(self) -> &'static str {
        match self {
            RemovalReason::Age => "age",
            RemovalReason::Size => "size",
        }
    }
}

/// What one pass of [`enforce`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RetentionReport {
    /// Removed files, their size in bytes and why.
    pub removed: Vec<(PathBuf, u64, RemovalReason)>,
    /// Bytes of `*.mcap` files left in the directory.
    pub kept_bytes: u64,
    /// Files that could not be removed (path, error).
    pub errors: Vec<(PathBuf, String)>,
}

struct Candidate {
    path: PathBuf,
    bytes: u64,
    modified: SystemTime,
}

/// Applies `policy` to the `*.mcap` files directly in `dir` at time `now`, never touching a
/// path in `in_use` nor a file changed less than `policy.min_age` ago. Files go oldest first
/// (by last change; ties by name).
pub fn enforce(
    dir: &Path,
    policy: &RetentionPolicy,
    in_use: &HashSet<PathBuf>,
    now: SystemTime,
) -> std::io::Result<RetentionReport> {
    let mut report = RetentionReport::default();
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if path.extension().and_then(|e| e.to_str()) != Some("mcap") {
            continue;
        }
        let Ok(meta) = entry.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        files.push(Candidate {
            path,
            bytes: meta.len(),
            modified: meta.modified().unwrap_or(now),
        });
    }
    files.sort_by(|a, b| a.modified.cmp(&b.modified).then(a.path.cmp(&b.path)));
    let age = |c: &Candidate| now.duration_since(c.modified).unwrap_or(Duration::ZERO);
    let removable = |c: &Candidate| !in_use.contains(&c.path) && age(c) >= policy.min_age;
    let mut total: u64 = files.iter().map(|c| c.bytes).sum();
    let remove = |c: &Candidate, why: RemovalReason, report: &mut RetentionReport| {
        match std::fs::remove_file(&c.path) {
            Ok(()) => {
                report.removed.push((c.path.clone(), c.bytes, why));
                true
            }
            Err(e) => {
                report.errors.push((c.path.clone(), e.to_string()));
                false
            }
        }
    };
    let mut kept = Vec::new();
    for c in files {
        let too_old = policy.max_age.is_some_and(|m| age(&c) > m);
        if too_old && removable(&c) && remove(&c, RemovalReason::Age, &mut report) {
            total -= c.bytes;
        } else {
            kept.push(c);
        }
    }
    if policy.max_bytes > 0 {
        for c in &kept {
            if total <= policy.max_bytes {
                break;
            }
            if removable(c) && remove(c, RemovalReason::Size, &mut report) {
                total -= c.bytes;
            }
        }
    }
    report.kept_bytes = total;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(dir: &Path, name: &str, bytes: usize, age_s: u64, now: SystemTime) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, vec![7u8; bytes]).unwrap();
        let f = std::fs::File::options().write(true).open(&p).unwrap();
        f.set_modified(now - Duration::from_secs(age_s)).unwrap();
        p
    }

    /// Removal order and limits checked against a hand count of the directory: age first, then
    /// the oldest until the size fits; in-use, recent and non-recording files stay.
    #[test]
    fn old_then_oldest_files_go_until_the_directory_fits() {
        let dir = std::env::temp_dir().join(format!("livereg-retention-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let now = SystemTime::now();
        let ancient = file(&dir, "a.mcap", 100, 10 * 86_400, now);
        let old = file(&dir, "b.mcap", 300, 3_600 * 5, now);
        let in_use = file(&dir, "c.mcap", 400, 3_600 * 4, now);
        let mid = file(&dir, "d.mcap", 200, 3_600 * 3, now);
        let fresh = file(&dir, "e.mcap", 500, 10, now);
        let other = file(&dir, "notes.txt", 5_000, 20 * 86_400, now);
        let policy = RetentionPolicy {
            max_bytes: 1_000,
            max_age: Some(Duration::from_secs(86_400)),
            min_age: Duration::from_secs(60),
        };
        let using: HashSet<PathBuf> = [in_use.clone()].into();
        let r = enforce(&dir, &policy, &using, now).unwrap();
        // 1,500 bytes of recordings: `a` goes by age (1,400 left), then `b` (oldest removable:
        // 1,100 left), then `d` (`c` is in use: 900 left, which fits).
        let removed: Vec<(PathBuf, RemovalReason)> =
            r.removed.iter().map(|(p, _, w)| (p.clone(), *w)).collect();
        assert_eq!(
            removed,
            [
                (ancient, RemovalReason::Age),
                (old, RemovalReason::Size),
                (mid, RemovalReason::Size)
            ]
        );
        assert_eq!(r.kept_bytes, 900);
        assert!(in_use.exists() && fresh.exists() && other.exists());
        // A second pass finds nothing to do.
        let again = enforce(&dir, &policy, &using, now).unwrap();
        assert!(again.removed.is_empty());
        assert_eq!(again.kept_bytes, 900);
        // A size limit below what must stay: nothing removable goes, and the report says so.
        let tight = RetentionPolicy {
            max_bytes: 1,
            ..policy
        };
        let r = enforce(&dir, &tight, &using, now).unwrap();
        assert!(r.removed.is_empty());
        assert_eq!(r.kept_bytes, 900);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
