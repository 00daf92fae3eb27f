//! What a training step holds in memory: the live heap bytes (allocated and not yet freed, as
//! counted by a global allocator around the system one) at their peak during `bench train`'s
//! steps, beside what the weights, EMA and Adam moments alone take. Unlike the peak RSS that
//! `socdiff bench train` prints, this does not count memory the allocator keeps for reuse, so it
//! shows what a change to the network's stored activations saves.
//!
//! ```sh
//! cargo run --release --example step_memory -- [HIDDEN ...]   # default 128 256; 2 threads
//! ```

use socdiff::model::{DenoiserConfig, Placement};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded to the system allocator unchanged; only sizes are counted.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let now = LIVE.fetch_add(layout.size(), Relaxed) + layout.size();
        PEAK.fetch_max(now, Relaxed);
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Relaxed);
        System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn main() {
    let widths: Vec<usize> = std::env::args().skip(1).map(|a| a.parse().expect("widths are numbers")).collect();
    let widths = if widths.is_empty() { vec![128, 256] } else { widths };
    socdiff::model::runtime::tune_process();
    socdiff::model::runtime::set_worker_threads(2).expect("worker threads");
    println!("training step 16 × 3 × 256 frames (δ = 61), aggregator mean, 2 threads");
    println!("{:>6} {:>10} {:>16} {:>16}", "hidden", "params", "state MB", "live peak MB");
    for hidden in widths {
        // the network of `socdiff bench train` (19 joints: δ = 61)
        let model = DenoiserConfig { feature_dims: socdiff::features::feature_dim(19), hidden, social_dim: hidden, ..Default::default() };
        let before = LIVE.load(Relaxed);
        PEAK.store(before, Relaxed);
        let timing = socdiff::train::time_train_steps(&model, 16, 3, 256, 2, &Placement::cpu()).expect("training steps");
        // weights, EMA copy and Adam's two moments: four f32 values per parameter
        let state = 4 * 4 * timing.params;
        println!("{hidden:>6} {:>10} {:>16.1} {:>16.1}", timing.params, state as f64 / 1e6, (PEAK.load(Relaxed) - before) as f64 / 1e6);
    }
}
