//! A global allocator that measures the peak of the bytes a thread holds, so a target can assert
//! that a reader's memory stays within a budget proportional to its input (no length field in a
//! corrupt file may make it reserve gigabytes). A fuzz binary or test installs it with
//! `#[global_allocator] static ALLOC: PeakTracking = PeakTracking;`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The system allocator plus a per-thread count of live bytes and their peak.
pub struct PeakTracking;

thread_local! {
    // Const-initialised cells without destructors: safe to touch from inside the allocator.
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
    static INSTALLED: Cell<bool> = const { Cell::new(false) };
}

fn account(delta: isize) {
    let _ = LIVE.try_with(|live| {
        let now = live.get().saturating_add(delta);
        live.set(now);
        let _ = PEAK.try_with(|peak| peak.set(peak.get().max(now)));
        let _ = INSTALLED.try_with(|i| i.set(true));
    });
}

// SAFETY: every call is forwarded to `System` unchanged; the bookkeeping touches only
// thread-local cells, which never allocate.
unsafe impl GlobalAlloc for PeakTracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            account(layout.size() as isize);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(layout);
        if !p.is_null() {
            account(layout.size() as isize);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        account(-(layout.size() as isize));
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            account(new_size as isize - layout.size() as isize);
        }
        p
    }
}

/// Runs `f` and returns its result with the largest number of bytes this thread held at once
/// during it beyond what it held before (0 when [`PeakTracking`] is not the global allocator).
pub fn peak_during<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let base = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(base));
    let r = f();
    let peak = PEAK.with(Cell::get);
    (r, (peak - base).max(0) as usize)
}

/// Whether [`PeakTracking`] has seen an allocation on this thread (it is installed).
pub fn installed() -> bool {
    drop(std::hint::black_box(vec![0u8; 1]));
    INSTALLED.with(Cell::get)
}
