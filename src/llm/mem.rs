//! Where the memory goes: `--log step::llm::mem=debug` prints the process's resident and peak memory
//! (Linux `/proc/self/status`) after each load stage and at the end of `step bench llm`, so that a
//! peak can be put down to a stage rather than guessed. Free when the level is off.

/// Logs resident, peak, anonymous (heap) and file-backed (mmapped) memory after `stage`.
pub fn stage(stage: &str) {
    if !tracing::enabled!(tracing::Level::DEBUG) {
        return;
    }
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else { return };
    let mb = |key: &str| {
        status
            .lines()
            .find(|l| l.starts_with(key))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<f64>().ok())
            .map_or(0.0, |kb| (kb / 1024.0).round())
    };
    tracing::debug!(
        "{stage}: rss {} MB (peak {}), anonymous {} MB, mapped files {} MB, allocated {} MB",
        mb("VmRSS:"),
        mb("VmHWM:"),
        mb("RssAnon:"),
        mb("RssFile:"),
        allocated_mb().map_or("?".to_string(), |m| format!("{m:.1}"))
    );
}

/// Bytes held by live allocations (glibc's count over all arenas): unlike RSS, it drops as soon as
/// something is freed, so a stage's own cost is the difference between two lines.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn allocated_mb() -> Option<f64> {
    // SAFETY: mallinfo2 only reads the allocator's counters.
    let m = unsafe { libc::mallinfo2() };
    Some((m.uordblks + m.hblkhd) as f64 / (1024.0 * 1024.0))
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn allocated_mb() -> Option<f64> {
    None
}

/// Logs the model's own account of its memory (see [`super::model::Transformer::memory`]).
pub fn model(stage: &str, model: &super::model::Transformer) {
    if !tracing::enabled!(tracing::Level::DEBUG) {
        return;
    }
    let (weights, kv, scratch) = model.memory();
    let cfg = model.config();
    let per_position = 2 * cfg.n_layer * cfg.n_head_kv * cfg.head_dim * 4;
    let mb = |b: usize| b as f64 / (1024.0 * 1024.0);
    tracing::debug!(
        "{stage}: weights {:.1} MB, KV cache {:.1} MB ({} positions), scratch {:.1} MB",
        mb(weights),
        mb(kv),
        kv / per_position.max(1),
        mb(scratch)
    );
}
