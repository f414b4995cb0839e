//! The benches' CPU-time probe (`benches/support/thread_cpu.rs`) against an independent clock:
//! the kernel's per-thread tick accounting in `/proc/thread-self/stat` (utime + stime, fields
//! 14 and 15, in USER_HZ = 100 ticks per second on Linux: 10 ms resolution).

#[path = "../benches/support/thread_cpu.rs"]
mod thread_cpu;

use std::time::Instant;

/// CPU time the probe must see the busy loop use. Long against the 10 ms tick so that the
/// reference's resolution is ±2 % of it, short enough for CI (one core for 0.6 s).
const BUSY_NS: u64 = 600_000_000;
/// Agreement required between the probe and the tick accounting: two ticks of rounding at
/// each end (4 × 10 ms) plus 20 ms of accounting lag. The old schedstat probe under-counted a
/// running thread by up to one scheduler period per read (3.07 ms of 7.0 ms measured), which
/// a probe that lost time in the same way on every read would show here as a drift.
const AGREE_NS: u64 = 60_000_000;

/// utime + stime of this thread in nanoseconds, from `/proc/thread-self/stat`.
fn tick_cpu_ns() -> u64 {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").expect("Linux /proc");
    // The command name (field 2) is in parentheses and may hold spaces: split after it.
    let rest = &stat[stat.rfind(')').expect("stat has (comm)") + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // rest starts at field 3 (state): utime is field 14, stime field 15.
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    ticks * 10_000_000
}

#[test]
fn probe_counts_a_busy_loop_like_the_kernels_tick_accounting() {
    let (p0, k0, w0) = (thread_cpu::thread_cpu_ns().expect("clock"), tick_cpu_ns(), Instant::now());
    let mut x = 0u64;
    // Spin on the probe itself: many short reads, as the benches do between calls.
    while thread_cpu::thread_cpu_ns().unwrap() - p0 < BUSY_NS {
        for i in 0..10_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
    }
    let (p1, k1, wall) = (thread_cpu::thread_cpu_ns().unwrap(), tick_cpu_ns(), w0.elapsed());
    let (probe, ticks) = (p1 - p0, k1 - k0);
    eprintln!(
        "busy loop: probe {:.1} ms, ticks {:.1} ms, wall {:.1} ms",
        probe as f64 / 1e6,
        ticks as f64 / 1e6,
        wall.as_secs_f64() * 1e3
    );
    assert!(probe.abs_diff(ticks) <= AGREE_NS, "probe {probe} ns vs tick accounting {ticks} ns");
    // A thread cannot run longer than the wall clock (plus one tick of rounding).
    assert!(probe as f64 <= wall.as_secs_f64() * 1e9 + 1e7, "probe {probe} ns > wall {wall:?}");
}
