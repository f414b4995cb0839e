//! Decoding one raw frame (bilateral + edge-aware filters on), single-threaded and with two
//! threads. Goals: ≤ 10 ms single-threaded, ≤ 6 ms on two cores.

use criterion::{Criterion, criterion_group, criterion_main};
use kinect_usb::decoder::{DecoderConfig, DecoderParams, DepthDecoder};
use kinect_usb::params::{P0Tables, XzTables};
use kinect_usb::raw::PIXELS;
use kinect_usb::testdata::{read_bytes, read_f32, vectors_dir};

fn bench(c: &mut Criterion) {
    let Some(dir) = vectors_dir() else {
        eprintln!("SKIP decode bench: shared data not found");
        return;
    };
    let p0 = P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin")).unwrap()).unwrap();
    let xz = XzTables::from_vecs(
        read_f32(&dir.join("tables/xtable.f32")).unwrap(),
        read_f32(&dir.join("tables/ztable.f32")).unwrap(),
    )
    .unwrap();
    let raw = read_bytes(&dir.join("frames/scene.raw")).unwrap();
    let mut depth = vec![0f32; PIXELS];
    let mut ir = vec![0f32; PIXELS];
    let mut g = c.benchmark_group("decode_frame");
    let single = DecoderConfig { parallel: false, ..DecoderConfig::default() };
    let mut dec = DepthDecoder::new(DecoderParams::default(), single, &xz, &p0).unwrap();
    g.bench_function("filters_on_1_thread", |b| b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap()));
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    dec.config.parallel = true;
    g.bench_function("filters_on_2_threads", |b| {
        pool.install(|| b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap()))
    });
    dec.config = DecoderConfig { bilateral: false, edge_aware: false, parallel: false };
    g.bench_function("filters_off_1_thread", |b| b.iter(|| dec.decode(&raw, &mut depth, &mut ir).unwrap()));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
