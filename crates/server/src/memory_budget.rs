//! The server's memory budget for sessions: how many bytes of estimated session memory
//! (`Session::memory_estimate_bytes`, docs/server.md "Memory budget") the open sessions may
//! hold together.
//!
//! `limits.max_memory_mb` sets it; 0 (the default) derives it from the memory this process may
//! use: the cgroup's limit when there is one (a container's `resources.limits.memory`, cgroup
//! v2 `memory.max` or v1 `memory.limit_in_bytes`), else the machine's `MemTotal`, times
//! [`AUTO_BUDGET_FRACTION`]. The rest is left to what no estimate covers: the runtime, the
//! uploads and models being built, recordings' buffers.

use std::path::Path;

/// Share of the available memory the automatic budget gives to sessions.
pub(crate) const AUTO_BUDGET_FRACTION: f64 = 0.75;

/// Where the budget came from, for the start-up log and the metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum BudgetSource {
    /// `limits.max_memory_mb`.
    Configured,
    /// [`AUTO_BUDGET_FRACTION`] of the cgroup's memory limit.
    CgroupLimit,
    /// [`AUTO_BUDGET_FRACTION`] of the machine's `MemTotal`.
    MachineMemory,
    /// Nothing could be read: no budget (every estimate fits).
    Unknown,
}

/// The budget in bytes (`u64::MAX` when unknown) and where it came from.
pub(crate) fn memory_budget(max_memory_mb: u64) -> (u64, BudgetSource) {
    memory_budget_from(
        max_memory_mb,
        Path::new("/sys/fs/cgroup"),
        Path::new("/proc"),
    )
}

/// [`memory_budget`] reading the cgroup file system under `cgroup` and `meminfo` under
/// `proc` (tests point them at fixtures).
pub(crate) fn memory_budget_from(
    max_memory_mb: u64,
    cgroup: &Path,
    proc: &Path,
) -> (u64, BudgetSource) {
    if max_memory_mb > 0 {
        return (
            max_memory_mb.saturating_mul(1 << 20),
            BudgetSource::Configured,
        );
    }
    let share = |bytes: u64| (bytes as f64 * AUTO_BUDGET_FRACTION) as u64;
    if let Some(limit) = cgroup_limit(cgroup) {
        return (share(limit), BudgetSource::CgroupLimit);
    }
    match mem_total(proc) {
        Some(total) => (share(total), BudgetSource::MachineMemory),
        None => (u64::MAX, BudgetSource::Unknown),
    }
}

/// The cgroup's memory limit, bytes: v2 `memory.max`, else v1 `memory/memory.limit_in_bytes`;
/// `None` when absent, `max`, or the v1 "no limit" value (near `i64::MAX`).
fn cgroup_limit(cgroup: &Path) -> Option<u64> {
    let read = |p: &Path| std::fs::read_to_string(p).ok();
    let v2 = read(&cgroup.join("memory.max"));
    let v1 = || read(&cgroup.join("memory/memory.limit_in_bytes"));
    let text = v2.or_else(v1)?;
    let bytes: u64 = text.trim().parse().ok()?;
    (bytes > 0 && bytes < (1 << 60)).then_some(bytes)
}

/// `MemTotal` of `<proc>/meminfo`, bytes.
fn mem_total(proc: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(proc.join("meminfo")).ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut parts = line.split_whitespace().skip(1);
    let value: u64 = parts.next()?.parse().ok()?;
    match parts.next() {
        Some("kB") | None => Some(value * 1024),
        Some(_) => None,
    }
}

/// Bytes as MiB, for messages.
pub(crate) fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 20) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(tag: &str) -> std::path::PathBuf {
        let d =
            std::env::temp_dir().join(format!("livereg-membudget-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("cgroup/memory")).unwrap();
        std::fs::create_dir_all(d.join("proc")).unwrap();
        d
    }

    #[test]
    fn configured_budget_wins() {
        let d = dir("configured");
        std::fs::write(d.join("cgroup/memory.max"), "1073741824\n").unwrap();
        assert_eq!(
            memory_budget_from(512, &d.join("cgroup"), &d.join("proc")),
            (512 << 20, BudgetSource::Configured)
        );
    }

    #[test]
    fn a_container_limit_is_followed_and_max_means_none() {
        let d = dir("cgroup");
        std::fs::write(d.join("cgroup/memory.max"), "2147483648\n").unwrap();
        std::fs::write(
            d.join("proc/meminfo"),
            "MemTotal:       25165824 kB\nMemFree: 1 kB\n",
        )
        .unwrap();
        assert_eq!(
            memory_budget_from(0, &d.join("cgroup"), &d.join("proc")),
            (1_610_612_736, BudgetSource::CgroupLimit)
        );
        std::fs::write(d.join("cgroup/memory.max"), "max\n").unwrap();
        assert_eq!(
            memory_budget_from(0, &d.join("cgroup"), &d.join("proc")),
            (25165824 * 1024 / 4 * 3, BudgetSource::MachineMemory)
        );
        // cgroup v1 without a limit reports about i64::MAX rounded to pages.
        std::fs::remove_file(d.join("cgroup/memory.max")).unwrap();
        std::fs::write(
            d.join("cgroup/memory/memory.limit_in_bytes"),
            "9223372036854771712\n",
        )
        .unwrap();
        assert_eq!(
            memory_budget_from(0, &d.join("cgroup"), &d.join("proc")).1,
            BudgetSource::MachineMemory
        );
        std::fs::write(
            d.join("cgroup/memory/memory.limit_in_bytes"),
            "4294967296\n",
        )
        .unwrap();
        assert_eq!(
            memory_budget_from(0, &d.join("cgroup"), &d.join("proc")),
            (3 << 30, BudgetSource::CgroupLimit)
        );
    }

    #[test]
    fn nothing_readable_means_no_budget() {
        let d = dir("none");
        assert_eq!(
            memory_budget_from(0, &d.join("cgroup"), &d.join("proc")),
            (u64::MAX, BudgetSource::Unknown)
        );
    }
}
