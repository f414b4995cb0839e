//! Decoding one raw frame (`frames/scene.raw` of the shared vectors), for both decoder
//! precisions (and for Fast, both kernel widths): filters on (bilateral + edge-aware) on one thread and on a two-thread rayon pool,
//! and filters off on one thread. Goals (issue 4): ≤ 10 ms single-threaded, ≤ 6 ms on two cores.

use criterion::{Criterion, criterion_group, criterion_main};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DecoderPrecision, DepthDecoder, Kernels};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::PIXELS;
use kinect_usb::testdata::{read_bytes, read_f32, vectors_dir};

#[path = "../../../benches/support/thread_cpu.rs"]
mod thread_cpu;
use thread_cpu::thread_cpu_ns;

/// With `DECODE_CPU_PROBE=N` set: before the criterion runs, the least CPU time of the calling
/// thread and the least wall-clock time of N decodes per configuration. On a machine shared
/// with other work, criterion's wall-clock figures include time the threads waited for a core;
/// the calling thread's CPU time does not (with two threads it only counts the caller's share).
/// `DECODE_CPU_PROBE_ONLY=SUBSTRING` limits it to the matching configurations (e.g. for
/// `valgrind --tool=callgrind`).
fn cpu_probe(dec: &mut DepthDecoder, raw: &[u8], depth: &mut [f32], ir: &mut [f32], name: &str) {
    let Some(n) = std::env::var("DECODE_CPU_PROBE").ok().and_then(|v| v.parse::<usize>().ok())
    else {
        return;
    };
    if std::env::var("DECODE_CPU_PROBE_ONLY").is_ok_and(|only| !name.contains(&only)) {
        return;
    }
    let (mut best, mut best_wall) = (u64::MAX, f64::MAX);
    for _ in 0..n {
        let wall = std::time::Instant::now();
        let (Some(t0), _, Some(t1)) =
            (thread_cpu_ns(), dec.decode(raw, depth, ir).unwrap(), thread_cpu_ns())
        else {
            return;
        };
        best = best.min(t1 - t0);
        best_wall = best_wall.min(wall.elapsed().as_secs_f64());
    }
    eprintln!(
        "cpu probe {name}: {:.2} ms thread CPU time per frame, {:.2} ms wall (least of {n} each)",
        best as f64 / 1e6,
        best_wall * 1e3
    );
}

fn bench(c: &mut Criterion) {
    let Some(dir) = vectors_dir() else {
        eprintln!("SKIP decode bench: shared data not found");
        return;
    };
    let p0 =
        P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin")).unwrap())
            .unwrap();
    let xz = XzTables::from_vecs(
        read_f32(&dir.join("tables/xtable.f32")).unwrap(),
        read_f32(&dir.join("tables/ztable.f32")).unwrap(),
    )
    .unwrap();
    let raw = read_bytes(&dir.join("frames/scene.raw")).unwrap();
    let mut depth = vec![0f32; PIXELS];
    let mut ir = vec![0f32; PIXELS];
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let mut g = c.benchmark_group("decode_frame");
    // "fast": the default decoder (AVX2 kernels where the CPU has them); "fast_portable": the
    // four-lane kernels every x86-64 CPU runs.
    let configurations = [
        ("fast", DecoderPrecision::Fast, Kernels::detect()),
        ("fast_portable", DecoderPrecision::Fast, Kernels::Portable),
        ("exact", DecoderPrecision::Exact, Kernels::Portable),
    ];
    eprintln!("decode bench: default kernels on this CPU: {:?}", Kernels::detect());
    for (name, precision, kernels) in configurations {
        let single = DecoderConfig { parallel: false, ..DecoderConfig::default() };
        let mut dec = DepthDecoder::new(DecoderParams::default(), single, &xz, &p0)
            .unwrap()
            .with_precision(precision)
            .with_kernels(kernels);
        cpu_probe(&mut dec, &raw, &mut depth, &mut ir, &format!("{name}/filters_on_1_thread"));
        dec.config.parallel = true;
        pool.install(|| {
            cpu_probe(&mut dec, &raw, &mut depth, &mut ir, &format!("{name}/filters_on_2_threads"))
        });
        dec.config = DecoderConfig {
            bilateral: false,
            edge_aware: false,
            parallel: false,
            ..DecoderConfig::default()
        };
        cpu_probe(&mut dec, &raw, &mut depth, &mut ir, &format!("{name}/filters_off_1_thread"));
        dec.config = single;
        g.bench_function(format!("{name}/filters_on_1_thread"), |b| {
            b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap())
        });
        dec.config.parallel = true;
        g.bench_function(format!("{name}/filters_on_2_threads"), |b| {
            pool.install(|| b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap()))
        });
        dec.config = DecoderConfig {
            bilateral: false,
            edge_aware: false,
            parallel: false,
            ..DecoderConfig::default()
        };
        g.bench_function(format!("{name}/filters_off_1_thread"), |b| {
            b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
