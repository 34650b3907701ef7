//! libFuzzer entry of the `atlas` target (`hydrometra_fuzz::TARGETS`).
#![no_main]

use hydrometra_fuzz::alloc::PeakTracking;
use libfuzzer_sys::fuzz_target;

#[global_allocator]
static ALLOC: PeakTracking = PeakTracking;

fuzz_target!(|data: &[u8]| {
    // ok: the name is one of hydrometra_fuzz::TARGETS (the corpus test checks the list).
    let target = hydrometra_fuzz::target("atlas").expect("target registered");
    hydrometra_fuzz::run(target, data);
});
