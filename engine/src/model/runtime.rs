//! Process-wide CPU settings for training and sampling: the worker pool, candle's own thread
//! pools, and how the C allocator keeps freed activation buffers.
//!
//! A training step allocates and frees its activations and gradients in blocks of megabytes
//! (peak 0.5 GB at H = 128, 16 × 3 × 256). glibc serves such blocks with `mmap` and returns them with `munmap`, so
//! every step faulted its memory back in page by page (about 34,000 faults per step at H = 128,
//! 16 × 3 × 256, with TLB shoot-downs on every core). And candle runs its element-wise ops on
//! a second, spinning thread pool beside rayon's, so on a small machine the two pools took
//! turns on the same cores. [`tune_process`] fixes both; `socdiff` calls it first thing.

/// Threads the training and sampling kernels run on (rayon's global pool: `RAYON_NUM_THREADS`
/// or one per CPU).
pub fn worker_threads() -> usize {
    rayon::current_num_threads()
}

/// Sizes the global worker pool that training, sampling and the metrics run on; call it before
/// any parallel work of the process (afterwards the pool is fixed and this is an error).
pub fn set_worker_threads(threads: usize) -> crate::Result<()> {
    if threads == 0 {
        crate::bail!("worker threads: need at least 1");
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .map_err(|e| crate::Error::invalid(format!("worker threads: cannot set {threads}: {e} (the pool is already running)")))
}

/// Process settings for CPU work; call once at the start of `main`, before any thread is
/// spawned or any tensor made:
/// - candle's element-wise ops run on the calling thread (`CANDLE_NUM_THREADS=1`, unless the
///   variable is set): the heavy work is in the custom ops, which use rayon's pool, and a
///   second pool of spinning threads only competed with it;
/// - with glibc, blocks up to 1 GiB come from the heap and freed memory stays mapped
///   (`M_MMAP_THRESHOLD`, `M_TRIM_THRESHOLD`), so the next step reuses it without page faults.
///   The peak resident memory is unchanged; memory a step freed is not returned to the system
///   until the process ends.
pub fn tune_process() {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // Before any thread exists (the caller's contract), so no concurrent reader.
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; both values are in range.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}
