//! The per-token path allocates nothing on the Rust side: a counting allocator (per
//! thread, so other tests do not interfere) sees no allocation while sampling and
//! evaluating one token at a time. llama.cpp's own C allocations are not counted here.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ferrosa::backend::BackendKind;
use ferrosa::decode::{Sampler, SamplerConfig};

pub struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
    /// The largest single allocation (or reallocation) asked for on this thread.
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    ALLOCS.with(|c| c.set(c.get() + 1));
    LARGEST.with(|l| l.set(l.get().max(size)));
}

// SAFETY: forwards to the system allocator; the counter is a thread-local Cell.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn allocations() -> u64 {
    ALLOCS.with(Cell::get)
}

/// `f`'s result and the largest single allocation it asked for on this thread (what a
/// parser allocated on a peer's word: bounded-memory property tests).
pub fn largest_allocation<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let before = LARGEST.with(|l| l.replace(0));
    let out = f();
    let largest = LARGEST.with(|l| l.replace(before.max(l.get())));
    (out, largest)
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn llama_token_loop_allocates_nothing() {
    let mut m = crate::util::load("smollm2-135m", BackendKind::Llama, 512);
    let prompt = m.tokenize("The robot reported", false).unwrap();
    let cfg = SamplerConfig {
        temperature: 0.8,
        top_k: 40,
        top_p: 0.9,
        seed: 1,
    };
    let mut sampler = Sampler::new(cfg, m.vocab().len());
    let mut tok = sampler.sample(m.forward(0, &prompt).unwrap()).unwrap();
    let before = allocations();
    for pos in prompt.len()..prompt.len() + 32 {
        let logits = m.forward(pos, &[tok]).unwrap();
        tok = sampler.sample(logits).unwrap();
    }
    assert_eq!(allocations() - before, 0, "allocations in 32 token steps");
}
