//! Where a training step's time goes: wall time per custom op and per phase of the step, collected
//! only while enabled (`socdiff bench train --profile`). Disabled, a timer costs one atomic load.
//!
//! Ops run on rayon's workers, so nested times overlap: a phase (`step: forward`) holds the ops
//! it called, and the ops of one phase may sum to more than the phase when they run in parallel
//! (they do not here: candle calls custom ops one after another, each op parallel inside).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Instant;

static ENABLED: AtomicBool = AtomicBool::new(false);
static TOTALS: Mutex<BTreeMap<&'static str, (f64, u64)>> = Mutex::new(BTreeMap::new());

/// Starts collecting (and clears what was collected).
pub fn enable() {
    TOTALS.lock().expect("profile lock").clear();
    ENABLED.store(true, Ordering::SeqCst);
}

/// Stops collecting and returns `(name, seconds, calls)` per op and phase, by name.
pub fn take() -> Vec<(&'static str, f64, u64)> {
    // Under the lock: a timer still running on another thread cannot add to the totals after
    // they are taken.
    let mut totals = TOTALS.lock().expect("profile lock");
    ENABLED.store(false, Ordering::SeqCst);
    std::mem::take(&mut *totals).into_iter().map(|(k, (s, n))| (k, s, n)).collect()
}

/// Adds its lifetime to `name`'s total when collecting.
pub struct Timer {
    name: &'static str,
    start: Option<Instant>,
}

impl Timer {
    /// A timer for `name` (idle when profiling is off).
    pub fn start(name: &'static str) -> Self {
        Self { name, start: ENABLED.load(Ordering::Relaxed).then(Instant::now) }
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        if let Some(t) = self.start {
            let mut totals = TOTALS.lock().expect("profile lock");
            // Started while collecting, ending after `take`: not counted.
            if !ENABLED.load(Ordering::SeqCst) {
                return;
            }
            let e = totals.entry(self.name).or_insert((0.0, 0));
            e.0 += t.elapsed().as_secs_f64();
            e.1 += 1;
        }
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
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let got = take();
        drop(Timer::start("test: after"));
        let op = got.iter().find(|(n, _, _)| *n == "test: op").expect("timed");
        assert_eq!(op.2, 3);
        assert!(op.1 >= 0.006, "{got:?}");
        assert!(got.iter().all(|(n, _, _)| *n != "test: before"));
        assert!(take().is_empty(), "nothing after take");
    }
}
