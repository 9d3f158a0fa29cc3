//! Peak resident memory of this process (Linux `/proc`; `None` elsewhere).

/// Resets the kernel's peak-RSS mark of this process (`VmHWM`), so that
/// [`peak_rss_mib`] reports the peak of what runs next. Returns whether the reset took effect
/// (Linux ≥ 4.0; elsewhere the peak is the process's since it started).
pub fn reset_peak() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Peak resident set size of this process (`VmHWM`) since it started or since the last
/// [`reset_peak`], MiB; `None` where `/proc/self/status` is not available.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status_field_kib(&status, "VmHWM:").map(|kib| kib / 1024.0)
}

/// The value of `field` (e.g. `VmHWM:`) in a `/proc/<pid>/status` text, kiB.
fn status_field_kib(status: &str, field: &str) -> Option<f64> {
    let line = status.lines().find(|l| l.starts_with(field))?;
    let mut parts = line[field.len()..].split_whitespace();
    let value: f64 = parts.next()?.parse().ok()?;
    match parts.next() {
        Some("kB") | None => Some(value),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_status_field() {
        let s = "Name:\tx\nVmPeak:\t  2048 kB\nVmHWM:\t    1536 kB\nVmRSS:\t 1000 kB\n";
        assert_eq!(status_field_kib(s, "VmHWM:"), Some(1536.0));
        assert_eq!(status_field_kib(s, "VmSwap:"), None);
        assert_eq!(status_field_kib("VmHWM:\t12 MB\n", "VmHWM:"), None);
    }

    #[test]
    fn a_large_allocation_raises_the_peak() {
        let Some(before) = peak_rss_mib() else {
            return; // not Linux: nothing to measure
        };
        let v = vec![1u8; 64 << 20];
        let after = peak_rss_mib().unwrap();
        assert!(v.iter().map(|&b| b as usize).sum::<usize>() == 64 << 20);
        // 64 MiB touched: the peak is at least 60 MiB above zero and not below the earlier one.
        assert!(after >= before && after >= 60.0, "{before} -> {after}");
    }
}
