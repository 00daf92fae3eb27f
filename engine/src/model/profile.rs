//! Where a training step's time goes: wall time and matrix-product work (multiply-adds of the
//! gemms) per custom op and per phase of the step, collected only while enabled (`socdiff bench
//! train --profile`, `bench sample`). Disabled, a timer or a product count costs one atomic load.
//!
//! Ops run on rayon's workers, so nested times overlap: a phase (`step: forward`) holds the ops
//! it called, and the ops of one phase may sum to more than the phase when they run in parallel
//! (they do not here: candle calls custom ops one after another, each op parallel inside).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

static ENABLED: AtomicBool = AtomicBool::new(false);
static TOTALS: Mutex<BTreeMap<&'static str, OpTotal>> = Mutex::new(BTreeMap::new());
static MULTIPLY_ADDS: AtomicU64 = AtomicU64::new(0);

/// What one op or phase took while collecting.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpTotal {
    /// Its name (`step: …` for a phase).
    pub name: &'static str,
    /// Wall seconds, summed over its calls.
    pub seconds: f64,
    /// How often it ran.
    pub calls: u64,
    /// Multiply-adds of the matrix products run during its calls ([`count_products`]).
    pub multiply_adds: u64,
}

/// Starts collecting (and clears what was collected).
pub fn enable() {
    TOTALS.lock().expect("profile lock").clear();
    MULTIPLY_ADDS.store(0, Ordering::SeqCst);
    ENABLED.store(true, Ordering::SeqCst);
}

/// Counts the `m·n·k` multiply-adds of an `m × k` by `k × n` product (when collecting).
pub fn count_products(m: usize, n: usize, k: usize) {
    if ENABLED.load(Ordering::Relaxed) {
        MULTIPLY_ADDS.fetch_add((m * n * k) as u64, Ordering::Relaxed);
    }
}

/// Multiply-adds counted since [`enable`], over every thread.
pub fn multiply_adds() -> u64 {
    MULTIPLY_ADDS.load(Ordering::SeqCst)
}

/// Whether collecting is on.
pub fn enabled() -> bool {
    ENABLED.load(Ordering::SeqCst)
}

/// Stops collecting and returns the totals per op and phase, by name.
pub fn take() -> Vec<OpTotal> {
    // Under the lock: a timer still running on another thread cannot add to the totals after
    // they are taken.
    let mut totals = TOTALS.lock().expect("profile lock");
    ENABLED.store(false, Ordering::SeqCst);
    std::mem::take(&mut *totals).into_values().collect()
}

/// Adds its lifetime, and the products counted during it, to `name`'s total when collecting.
/// The count is the process's: right for ops, which candle runs one after another (each
/// parallel inside), and for phases, which hold their ops.
pub struct Timer {
    name: &'static str,
    start: Option<(Instant, u64)>,
}

impl Timer {
    /// A timer for `name` (idle when profiling is off).
    pub fn start(name: &'static str) -> Self {
        Self { name, start: ENABLED.load(Ordering::Relaxed).then(|| (Instant::now(), MULTIPLY_ADDS.load(Ordering::Relaxed))) }
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        if let Some((t, products)) = self.start {
            let mut totals = TOTALS.lock().expect("profile lock");
            // Started while collecting, ending after `take`: not counted.
            if !ENABLED.load(Ordering::SeqCst) {
                return;
            }
            let e = totals.entry(self.name).or_insert(OpTotal { name: self.name, ..Default::default() });
            e.seconds += t.elapsed().as_secs_f64();
            e.calls += 1;
            e.multiply_adds += MULTIPLY_ADDS.load(Ordering::Relaxed).saturating_sub(products);
        }
    }
}

/// What a benchmarked block used of the process (Linux `/proc`; unknown elsewhere).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Usage {
    /// CPU seconds of all threads (user + system) during the block.
    pub cpu_seconds: f64,
    /// Peak resident set (`VmHWM`) in bytes, if known.
    pub peak_rss_bytes: Option<u64>,
    /// Whether the peak was reset at the start (else it is the whole process's peak).
    pub peak_is_the_blocks: bool,
}

/// Measures a block's [`Usage`]: created before it (resetting the peak RSS), read after.
pub struct UsageMeter {
    cpu0: f64,
    reset: bool,
}

impl UsageMeter {
    /// Starts measuring: resets the peak RSS to the current RSS (Linux ≥ 4.0, best effort).
    pub fn start() -> Self {
        let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
        Self { cpu0: cpu_seconds(), reset }
    }

    /// The usage since [`UsageMeter::start`].
    pub fn read(&self) -> Usage {
        Usage { cpu_seconds: cpu_seconds() - self.cpu0, peak_rss_bytes: status_bytes("VmHWM"), peak_is_the_blocks: self.reset }
    }
}

impl Usage {
    /// The peak RSS as `1.23 GB`, with `*` when it is the whole process's peak, `?` unknown.
    pub fn peak_gb(&self) -> String {
        self.peak_rss_bytes.map_or("?".into(), |b| format!("{:.2} GB{}", b as f64 / 1e9, if self.peak_is_the_blocks { "" } else { "*" }))
    }
}

/// A `/proc/self/status` field in bytes, e.g. `VmHWM`.
fn status_bytes(field: &str) -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with(field))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU seconds (user + system, all threads) of this process so far (0 where unknown).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    // Fields after the parenthesized command name; utime and stime are the 12th and 13th.
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// The 1-minute load average, to print beside timings (`?` where unknown).
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg").ok().and_then(|s| s.split_whitespace().next().map(str::to_string)).unwrap_or_else(|| "?".into())
}

/// Median, minimum and maximum of timings (NaN for none).
pub fn median_and_range(seconds: &[f64]) -> (f64, f64, f64) {
    let mut s = seconds.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => (f64::NAN, f64::NAN, f64::NAN),
        n => (s[n / 2], s[0], s[n - 1]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timers_count_only_while_enabled() {
        drop(Timer::start("test: before"));
        enable();
        for _ in 0..3 {
            let _t = Timer::start("test: op");
            count_products(2, 3, 4);
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        count_products(1, 1, 5);
        // At least: tests running beside this one may count their products too.
        assert!(multiply_adds() >= 3 * 24 + 5);
        let got = take();
        drop(Timer::start("test: after"));
        let counted = multiply_adds();
        count_products(7, 7, 7);
        assert_eq!(multiply_adds(), counted, "nothing counted after take");
        let op = got.iter().find(|o| o.name == "test: op").expect("timed");
        assert_eq!(op.calls, 3);
        assert!(op.multiply_adds >= 3 * 24, "{got:?}");
        assert!(op.seconds >= 0.006, "{got:?}");
        assert!(got.iter().all(|o| o.name != "test: before"));
        assert!(take().is_empty(), "nothing after take");
    }

    #[test]
    fn usage_counts_the_blocks_cpu_and_memory() {
        let meter = UsageMeter::start();
        let v: Vec<u8> = vec![1; 64 << 20];
        let t = std::time::Instant::now();
        let mut x = 0u64;
        while t.elapsed().as_millis() < 300 {
            x = x.wrapping_add(std::hint::black_box(v[x as usize % v.len()] as u64));
        }
        let u = meter.read();
        std::hint::black_box((x, &v));
        if cfg!(target_os = "linux") {
            // 0.3 s of one busy thread, counted in 10 ms ticks; 64 MiB touched.
            assert!(u.cpu_seconds >= 0.2, "{u:?}");
            assert!(u.peak_rss_bytes.unwrap() >= 64 << 20, "{u:?}");
            assert!(load_average().parse::<f64>().is_ok());
        }
        assert_eq!(median_and_range(&[3.0, 1.0, 2.0]), (2.0, 1.0, 3.0));
        assert!(median_and_range(&[]).0.is_nan());
    }
}
