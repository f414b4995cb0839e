//! CPU fusion benchmarks on a Kinect-size frame (512×424 depth → 1920×1080 colour), rendered
//! by `geometry::synth::kinect_preset`.
//!
//! * `register+holes/single`: exact z-buffered registration (H1+H2+H7 fused, marking the
//!   occupancy bits as it goes) plus the H8 hole mask as a `bool` image, one thread, through a
//!   `geometry::fusion::Registration` workspace reused from frame to frame (what a streaming
//!   user does: buffers and per-pixel constants are made once, no allocation per frame). The
//!   number to compare with OpenCV's `cv2.rgbd.registerDepth` and Open3D's
//!   `project_to_depth_image` (`benches/peers/register_peers.py`). Goal: <= 2 ms.
//! * `register+holes/single_bits`: the same with the mask left as bits (no `bool` image).
//! * `register+holes/rayon`: `Registration::register_parallel` (projection in parallel, then
//!   one band of colour rows per thread, no atomics) and `hole_mask_parallel` (bit mask on
//!   one thread, the `bool` image written in parallel).
//! * `register+holes/rayon_into`: the same registering into a z-buffer of the caller's
//!   (`register_parallel_into`, what Python's `Registration.register(out=)` runs on the CPU):
//!   every colour row is cleared whole, as a buffer holding anything needs.
//! * `register+holes/legacy_*`: the previous entry points (`register_depth_marking` +
//!   `HoleMasker`, and the atomic-min `register_depth_parallel` + a z-buffer scan), kept for
//!   comparison.
//! * `run_h7_h8mask/*`: H7 + H8's mask as `geometry::fusion::run` computes them on one frame:
//!   `staged_before` (z-buffer from H2's samples, then a mask scan; `run` before issue 11) and
//!   `registration_now` (a fresh `Registration`, what `run` and `kfuse fuse` use now).
//! * `stage/*`: every stage of `geometry::fusion::run` on its own, and `run` itself.
//! * `memory/fill_outputs`: the memory floor of `register+holes/single` on this machine: one
//!   thread fills a colour-sized `f32` z-buffer (8.3 MB) with the empty marker and a `bool`
//!   mask (2.1 MB) with `false`, the bytes the registration must write per frame, as `memset`
//!   writes them. `register+holes/single` over this is the ratio BENCHMARKS.md states (issue
//!   47: registration <= 1 ms, or shown to be at the memory bandwidth).
//!
//! `KFUSE_WRITE_PEER_FRAME=1 cargo bench --bench fusion_cpu` also writes the frame for the
//! peers script to `$CARGO_TARGET_DIR/peer-frame/` (default `target/peer-frame/`):
//! `depth.png` (16-bit, millimetres, 0 = no sample), `color.png`, `rig.json`.

use std::hint::black_box;
use std::path::PathBuf;
use std::sync::atomic::AtomicU32;

use criterion::{Criterion, criterion_group, criterion_main};
use geometry::fusion::{self, FusionOptions, HoleMasker, Registration};
use geometry::synth;

fn peer_frame_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target"));
    target.join("peer-frame")
}

fn png_bytes<P: image::PixelWithColorType>(img: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> Vec<u8>
where
    P::Subpixel: image::Primitive,
    [P::Subpixel]: image::EncodableLayout,
{
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .expect("PNG encoding of an in-memory image");
    bytes
}

fn write_peer_frame(setup: &synth::SynthSetup, frame: &synth::SynthFrame) {
    let dir = peer_frame_dir();
    std::fs::create_dir_all(&dir).expect("create the peer-frame folder");
    let (dw, dh) = frame.depth.size();
    let depth_mm =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(dw as u32, dh as u32, |x, y| {
            let z = *frame.depth.get(x as usize, y as usize);
            image::Luma([if z.is_finite() {
                (z * 1000.0).round().clamp(0.0, 65535.0) as u16
            } else {
                0
            }])
        });
    let (cw, ch) = frame.color.size();
    let color = image::RgbImage::from_fn(cw as u32, ch as u32, |x, y| {
        image::Rgb(*frame.color.get(x as usize, y as usize))
    });
    let atomic = kfuse_io::atomic::write_bytes_atomic;
    atomic(&dir.join("depth.png"), &png_bytes(&depth_mm)).expect("write depth.png");
    atomic(&dir.join("color.png"), &png_bytes(&color)).expect("write color.png");
    atomic(&dir.join("rig.json"), setup.rig.to_json().as_bytes()).expect("write rig.json");
    eprintln!("peer frame written to {}", dir.display());
}

#[path = "support/thread_cpu.rs"]
mod thread_cpu;
use thread_cpu::thread_cpu_ns;

/// CPU time per call of `f` over `iters` calls: on a machine shared with other jobs the
/// wall-clock figures of criterion include time spent waiting for a core; this does not.
fn report_cpu_time(name: &str, iters: u32, mut f: impl FnMut()) {
    f();
    let (Some(t0), w0) = (thread_cpu_ns(), std::time::Instant::now()) else { return };
    for _ in 0..iters {
        f();
    }
    let Some(t1) = thread_cpu_ns() else { return };
    let wall = w0.elapsed().as_secs_f64() * 1e3 / iters as f64;
    eprintln!(
        "cpu-time {name}: {:.3} ms per call on one core ({wall:.3} ms wall)",
        (t1 - t0) as f64 / 1e6 / iters as f64
    );
}

fn benches(c: &mut Criterion) {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
    if std::env::var_os("KFUSE_WRITE_PEER_FRAME").is_some() {
        write_peer_frame(&setup, &frame);
    }
    let rig = &setup.rig;
    let options = FusionOptions::default();
    let proj = fusion::ColorProjection::from_rig(rig);
    let rays = fusion::depth_ray_table(&rig.depth, frame.depth_kind);
    let (cw, ch) = (rig.color.width, rig.color.height);
    let radius = fusion::coverage_radius_px(rig, &options);
    let grow = fusion::hole_grow_px(rig, &options);
    let mut zbuffer = vec![0f32; cw * ch];
    let mut mask = vec![false; cw * ch];
    let mut masker = HoleMasker::new(cw, ch, radius, grow);
    let atomic: Vec<AtomicU32> = (0..cw * ch).map(|_| AtomicU32::new(0)).collect();

    let mut reg =
        Registration::new(rig, frame.depth_kind, &options).expect("the preset rig is valid");

    report_cpu_time("register+holes/single", 200, || {
        let n = reg.register(&frame.depth).expect("the preset's depth matches its rig");
        black_box((n, reg.hole_mask(&mut mask)));
    });
    report_cpu_time("register+holes/single_bits", 200, || {
        let n = reg.register(&frame.depth).expect("the preset's depth matches its rig");
        black_box((n, reg.hole_bits().0));
    });
    report_cpu_time("stage/register_single", 200, || {
        black_box(reg.register(&frame.depth).expect("the preset's depth matches its rig"));
    });
    report_cpu_time("stage/hole_mask_from_occupancy", 200, || {
        black_box(reg.hole_mask(&mut mask));
    });
    report_cpu_time("register+holes/legacy_single", 200, || {
        let words = masker.words_per_row();
        let n = fusion::register_depth_marking(
            frame.depth.data(),
            &rays,
            &proj,
            &mut zbuffer,
            masker.occupancy_mut(),
            words,
        );
        black_box((n, masker.compute_from_occupancy(&mut mask)));
    });
    if std::env::var_os("KFUSE_CPU_TIME_ONLY").is_some() {
        return;
    }
    let mut g = c.benchmark_group("register+holes");
    g.bench_function("single", |b| {
        b.iter(|| {
            let n =
                reg.register(black_box(&frame.depth)).expect("the preset's depth matches its rig");
            black_box((n, reg.hole_mask(&mut mask)))
        })
    });
    g.bench_function("single_bits", |b| {
        b.iter(|| {
            let n =
                reg.register(black_box(&frame.depth)).expect("the preset's depth matches its rig");
            black_box((n, reg.hole_bits().0))
        })
    });
    g.bench_function("rayon", |b| {
        b.iter(|| {
            let n = reg
                .register_parallel(black_box(&frame.depth))
                .expect("the preset's depth matches its rig");
            black_box((n, reg.hole_mask_parallel(&mut mask)))
        })
    });
    let mut lent = vec![0f32; cw * ch];
    g.bench_function("rayon_into", |b| {
        b.iter(|| {
            let n = reg
                .register_parallel_into(black_box(&frame.depth), &mut lent)
                .expect("the preset's depth matches its rig");
            black_box((n, reg.hole_mask_parallel(&mut mask)))
        })
    });
    g.bench_function("legacy_single", |b| {
        b.iter(|| {
            let words = masker.words_per_row();
            let n = fusion::register_depth_marking(
                black_box(frame.depth.data()),
                &rays,
                &proj,
                &mut zbuffer,
                masker.occupancy_mut(),
                words,
            );
            let holes = masker.compute_from_occupancy(&mut mask);
            black_box((n, holes))
        })
    });
    g.bench_function("legacy_rayon", |b| {
        b.iter(|| {
            let n = fusion::register_depth_parallel(
                black_box(frame.depth.data()),
                &rays,
                rig.depth.width,
                &proj,
                &atomic,
            );
            fusion::atomic_zbuffer_to_image(&atomic, &mut zbuffer);
            let holes = masker.compute(&zbuffer, &mut mask);
            black_box((n, holes))
        })
    });
    g.finish();

    // The memory floor: the registration's outputs written once, as memset writes them.
    let mut g = c.benchmark_group("memory");
    g.bench_function("fill_outputs", |b| {
        b.iter(|| {
            black_box(&mut zbuffer[..]).fill(fusion::ZBUFFER_EMPTY);
            black_box(&mut mask[..]).fill(false);
            black_box((&zbuffer, &mask));
        })
    });
    g.finish();

    // What `geometry::fusion::run` does for H7 + H8's mask on one frame: before issue 11 the
    // staged functions on H2's samples, now a fresh `Registration` (the CPU engine).
    let samples0 =
        fusion::project_cloud(&fusion::backproject_cloud(&frame.depth, &rays).0.points, &proj);
    let mut g = c.benchmark_group("run_h7_h8mask");
    g.sample_size(30);
    g.bench_function("staged_before", |b| {
        b.iter(|| {
            let zb = fusion::zbuffer_from_samples(black_box(&samples0), proj.width, proj.height);
            let mask = fusion::hole_mask(&zb, radius, grow);
            black_box((zb, mask))
        })
    });
    g.bench_function("registration_now", |b| {
        b.iter(|| {
            let mut reg = Registration::from_parts(proj, &rays, rig.depth.width, radius, grow)
                .expect("radii within bounds");
            reg.register_parallel(black_box(&frame.depth)).expect("sizes match");
            let mut mask = geometry::Image::filled(cw, ch, false);
            reg.hole_mask_parallel(mask.data_mut());
            black_box((reg.into_zbuffer(), mask))
        })
    });
    g.finish();

    let zb_image = fusion::zbuffer_from_samples(
        &fusion::project_cloud(&fusion::backproject_cloud(&frame.depth, &rays).0.points, &proj),
        proj.width,
        proj.height,
    );
    let mut g = c.benchmark_group("stage");
    g.sample_size(20);
    g.bench_function("register_single", |b| {
        b.iter(|| fusion::register_depth(black_box(frame.depth.data()), &rays, &proj, &mut zbuffer))
    });
    g.bench_function("hole_mask_single", |b| {
        b.iter(|| masker.compute(black_box(zb_image.data()), &mut mask))
    });
    g.bench_function("h1_backproject", |b| {
        b.iter(|| fusion::backproject_cloud(black_box(&frame.depth), &rays))
    });
    let (cloud, _) = fusion::backproject_cloud(&frame.depth, &rays);
    g.bench_function("h2_project", |b| {
        b.iter(|| fusion::project_cloud(black_box(&cloud.points), &proj))
    });
    let samples = fusion::project_cloud(&cloud.points, &proj);
    g.bench_function("h7_zbuffer_from_samples", |b| {
        b.iter(|| fusion::zbuffer_from_samples(black_box(&samples), proj.width, proj.height))
    });
    g.bench_function("h3_nearest_fill", |b| {
        b.iter(|| fusion::nearest_fill(black_box(&zb_image), radius, options.depth_jump))
    });
    let spacing = fusion::sample_spacing_px(rig);
    g.bench_function("h3_linear", |b| {
        b.iter(|| {
            fusion::linear_resample(
                black_box(&samples),
                &zb_image,
                options.linear_max_edge_factor * spacing,
                options.depth_jump,
            )
        })
    });
    let nearest = fusion::nearest_fill(&zb_image, radius, options.depth_jump);
    g.bench_function("h6_color_on_depth", |b| {
        b.iter(|| {
            fusion::color_on_depth(
                black_box(&frame.depth),
                &rays,
                &proj,
                &frame.color,
                Some(&nearest),
                options.color_occlusion_tolerance,
            )
        })
    });
    g.bench_function("h8_plane_fit", |b| {
        b.iter(|| fusion::fit_plane_ransac(black_box(&nearest), &rig.color, &options.plane))
    });
    let mesh = fusion::mesh_from_depth(&nearest, &rig.color, &frame.color, options.mesh_step);
    g.bench_function("h4_mesh", |b| {
        b.iter(|| {
            fusion::mesh_from_depth(
                black_box(&nearest),
                &rig.color,
                &frame.color,
                options.mesh_step,
            )
        })
    });
    g.bench_function("h5_stretched_faces", |b| {
        b.iter(|| fusion::remove_stretched_faces(black_box(&mesh), options.stretch_ratio))
    });
    // The default H4/H5: the mesh on the depth samples, the sample-scale rule.
    let (cloud, cloud_pixels) = fusion::backproject_cloud(&frame.depth, &rays);
    let (h6, h6_valid) = fusion::color_on_depth(
        &frame.depth,
        &rays,
        &proj,
        &frame.color,
        Some(&nearest),
        options.color_occlusion_tolerance,
    );
    let grid_mesh = |pts: &[[f32; 3]]| {
        fusion::mesh_on_depth_grid(
            rig.depth.width,
            rig.depth.height,
            pts,
            &cloud_pixels,
            &samples,
            &rig.color_from_depth,
            frame.color.size(),
            &h6,
            &h6_valid,
        )
        .0
    };
    g.bench_function("h4_mesh_depth_grid", |b| b.iter(|| grid_mesh(black_box(&cloud.points))));
    let depth_grid = grid_mesh(&cloud.points);
    let test = fusion::stretch_test(rig, &options);
    g.bench_function("h5_sample_scale", |b| {
        b.iter(|| fusion::remove_edge_faces(black_box(&depth_grid), &test))
    });
    g.sample_size(10);
    g.bench_function("run_all", |b| {
        b.iter(|| {
            fusion::run(rig, black_box(&frame.depth), frame.depth_kind, &frame.color, &options)
                .map(|o| o.summary)
        })
    });
    g.finish();
}

criterion_group!(fusion_cpu, benches);
criterion_main!(fusion_cpu);
