use geometry::synth;
#[test]
fn timing() {
    let t = std::time::Instant::now();
    let f = synth::render(&synth::kinect_preset(false));
    eprintln!("kinect render {:?}", t.elapsed());
    let nan = f.depth.data().iter().filter(|v| v.is_nan()).count();
    let dis = f.true_disocclusion.data().iter().filter(|&&v| v).count();
    let seen = f.true_seen_by_depth.data().iter().filter(|&&v| v).count();
    eprintln!("nan depth {nan}, disoccluded {dis}, seen {seen}");
    let t = std::time::Instant::now();
    let f = synth::render(&synth::course_preset());
    eprintln!("course render {:?}", t.elapsed());
    let dis = f.true_disocclusion.data().iter().filter(|&&v| v).count();
    eprintln!("course disoccluded {dis}");
}
#[test]
fn dump() {
    let f = synth::render(&synth::kinect_preset(false));
    let c = &f.color;
    let mut img = image::RgbImage::new(c.width() as u32, c.height() as u32);
    for (i, p) in c.data().iter().enumerate() { img.put_pixel((i % c.width()) as u32, (i / c.width()) as u32, image::Rgb(*p)); }
    for (i, &d) in f.true_disocclusion.data().iter().enumerate() { if d { img.put_pixel((i % c.width()) as u32, (i / c.width()) as u32, image::Rgb([255,0,255])); } }
    img.save("/tmp/k_color.png").unwrap();
    let d = &f.depth;
    let mut g = image::GrayImage::new(d.width() as u32, d.height() as u32);
    for (i, &z) in d.data().iter().enumerate() { let v = if z.is_nan() {0} else {(255.0 - (z - 1.5) * 80.0).clamp(1.0,255.0) as u8}; g.put_pixel((i % d.width()) as u32, (i / d.width()) as u32, image::Luma([v])); }
    g.save("/tmp/k_depth.png").unwrap();
    let f = synth::render(&synth::course_preset());
    let c = &f.color;
    let mut img = image::RgbImage::new(c.width() as u32, c.height() as u32);
    for (i, p) in c.data().iter().enumerate() { img.put_pixel((i % c.width()) as u32, (i / c.width()) as u32, image::Rgb(*p)); }
    for (i, &d) in f.true_disocclusion.data().iter().enumerate() { if d { img.put_pixel((i % c.width()) as u32, (i / c.width()) as u32, image::Rgb([255,0,255])); } }
    img.save("/tmp/c_color.png").unwrap();
    let d = &f.depth;
    let mut g = image::GrayImage::new(d.width() as u32, d.height() as u32);
    for (i, &z) in d.data().iter().enumerate() { let v = if z.is_nan() {0} else {(255.0 - (z - 9.0) * 20.0).clamp(1.0,255.0) as u8}; g.put_pixel((i % d.width()) as u32, (i / d.width()) as u32, image::Luma([v])); }
    g.save("/tmp/c_depth.png").unwrap();
}
