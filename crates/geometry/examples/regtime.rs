use geometry::fusion::{self, FusionOptions, HoleMasker, Registration};
use geometry::synth;
use std::hint::black_box;
fn cpu_ns() -> u64 { std::fs::read_to_string("/proc/thread-self/schedstat").unwrap().split_whitespace().next().unwrap().parse().unwrap() }
fn t(name: &str, iters: u32, mut f: impl FnMut()) {
    f();
    let mut best = f64::MAX; let mut tot = 0.0;
    for _ in 0..iters { let a = cpu_ns(); f(); let d = (cpu_ns() - a) as f64 / 1e6; best = best.min(d); tot += d; }
    eprintln!("{name:40} min {best:.3} ms  mean {:.3} ms (cpu)", tot / iters as f64);
}
fn main() {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
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
    let mut reg = Registration::new(rig, frame.depth_kind, &options);
    let mut mask2 = vec![false; cw * ch];
    let it = 100;
    let words = masker.words_per_row();
    let n0 = fusion::register_depth_marking(frame.depth.data(), &rays, &proj, &mut zbuffer, masker.occupancy_mut(), words);
    let h0 = masker.compute_from_occupancy(&mut mask);
    let n1 = reg.register(&frame.depth).unwrap();
    let h1 = reg.hole_mask(&mut mask2);
    if (n0, h0) != (n1, h1) { eprintln!("MISMATCH counts"); }
    assert!(zbuffer.iter().zip(reg.zbuffer()).all(|(a, b)| a.to_bits() == b.to_bits()));
    if mask != mask2 { eprintln!("MISMATCH mask"); }
    let n2 = reg.register_parallel(&frame.depth).unwrap();
    assert_eq!(n0, n2);
    assert!(zbuffer.iter().zip(reg.zbuffer()).all(|(a, b)| a.to_bits() == b.to_bits()));
    for _ in 0..2 {
    t("old register+holes", it, || { let n = fusion::register_depth_marking(frame.depth.data(), &rays, &proj, &mut zbuffer, masker.occupancy_mut(), words); black_box((n, masker.compute_from_occupancy(&mut mask))); });
    t("old register_marking", it, || { black_box(fusion::register_depth_marking(frame.depth.data(), &rays, &proj, &mut zbuffer, masker.occupancy_mut(), words)); });
    t("old hole mask", it, || { black_box(masker.compute_from_occupancy(&mut mask)); });
    t("memset 8MB", it, || { zbuffer.fill(f32::from_bits(u32::MAX)); black_box(&zbuffer); });
    t("new register+holes", it, || { let n = reg.register(&frame.depth).unwrap(); black_box((n, reg.hole_mask(&mut mask2))); });
    t("new register+hole bits", it, || { let n = reg.register(&frame.depth).unwrap(); black_box((n, reg.hole_bits().0)); });
    t("new register", it, || { black_box(reg.register(&frame.depth).unwrap()); });
    t("new hole mask", it, || { black_box(reg.hole_mask(&mut mask2)); });
    let w0 = std::time::Instant::now();
    for _ in 0..it { let n = reg.register_parallel(&frame.depth).unwrap(); black_box((n, reg.hole_mask_parallel(&mut mask2))); }
    eprintln!("new parallel register+holes wall {:.3} ms", w0.elapsed().as_secs_f64()*1e3/it as f64);
    }
}
