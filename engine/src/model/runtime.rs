//! Process-wide CPU settings for training and sampling: the worker pool, candle's own thread
//! pools, and how the C allocator keeps freed activation buffers.
//!
//! A training step allocates and frees its activations and gradients in blocks of megabytes
//! (peak 0.5 GB at H = 128, 16 × 3 × 256). glibc serves such blocks with `mmap` and returns them with `munmap`, so
//! every step faulted its memory back in page by page (about 34,000 faults per step at H = 128,
//! 16 × 3 × 256, with TLB shoot-downs on every core). And candle runs its element-wise ops on
//! a second, spinning thread pool beside rayon's, so on a small machine the two pools took
//! turns on the same cores. [`tune_process`] fixes both; `socdiff` calls it first thing.
//!
//! Every custom op splits its work over rayon's pool. Called from a thread outside the pool,
//! each op hands its job to the workers and sleeps until they finish: two futex round trips per
//! op, thousands per step, and with one worker an idle caller beside it. [`start_workers`] makes
//! the calling thread one of the workers instead, so an op starts on it at once (and with one
//! thread runs inline); `socdiff` starts the pool so.

/// Threads the training and sampling kernels run on (rayon's global pool: `RAYON_NUM_THREADS`
/// or one per CPU).
pub fn worker_threads() -> usize {
    rayon::current_num_threads()
}

/// Starts the global worker pool that training, sampling and the metrics run on, with
/// `threads` workers (`None`: `RAYON_NUM_THREADS`, else one per CPU), the calling thread being
/// one of them (it must live as long as the process, as `main` does). Call it before any
/// parallel work; afterwards the pool is fixed: asking again for the count it has is fine, for
/// another an error.
pub fn start_workers(threads: Option<usize>) -> crate::Result<()> {
    if threads == Some(0) {
        crate::bail!("worker threads: need at least 1");
    }
    let built = rayon::ThreadPoolBuilder::new().num_threads(threads.unwrap_or(0)).use_current_thread().build_global();
    match (built, threads) {
        (Ok(()), _) | (Err(_), None) => Ok(()),
        (Err(_), Some(n)) if n == rayon::current_num_threads() => Ok(()),
        (Err(e), Some(n)) => Err(crate::Error::invalid(format!("worker threads: cannot set {n}: {e} (the pool is already running)"))),
    }
}

/// [`start_workers`] with `threads` workers.
pub fn set_worker_threads(threads: usize) -> crate::Result<()> {
    start_workers(Some(threads))
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
    elementwise_on_caller();
    keep_freed_memory_mapped();
}

/// The first half of [`tune_process`]: candle's element-wise ops on the calling thread (unless
/// `CANDLE_NUM_THREADS` is set). Call before any thread is spawned or any tensor made.
pub fn elementwise_on_caller() {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // Before any thread exists (the caller's contract), so no concurrent reader.
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
}

/// The second half of [`tune_process`]: with glibc, freed blocks up to 1 GiB stay mapped. Not
/// for a process whose memory is someone else's (the Python module leaves it out).
pub fn keep_freed_memory_mapped() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; both values are in range.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}
