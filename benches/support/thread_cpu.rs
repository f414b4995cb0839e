//! CPU time of the calling thread, for the benches' CPU-time probes (shared by
//! `benches/fusion_cpu.rs`, `crates/kinect-usb/benches/decode.rs` and the test
//! `tests/thread_cpu_probe.rs`, which holds it against the kernel's tick accounting).
//!
//! `CLOCK_THREAD_CPUTIME_ID` includes the time the thread has run since it was last scheduled.
//! The earlier probe read `/proc/thread-self/schedstat`, whose run time is only brought up to
//! date at scheduler events: a 7.0 ms busy loop read as 3.07 ms there (issue 17).

/// Nanoseconds this thread has run on a CPU (`clock_gettime(CLOCK_THREAD_CPUTIME_ID)` through
/// nix's safe wrapper), or `None` where the clock is not available.
pub fn thread_cpu_ns() -> Option<u64> {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID).ok()?;
    u64::try_from(t.tv_sec())
        .ok()?
        .checked_mul(1_000_000_000)?
        .checked_add(u64::try_from(t.tv_nsec()).ok()?)
}
