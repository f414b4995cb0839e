//! Host-side lookup tables the shaders index, computed with the CPU twins' formulas so both
//! sides visit the same pixels in the same order.

/// The disc offsets `(dx, dy, dx² + dy²)` with `dx² + dy² <= radius²`, sorted by distance²,
/// then `dy`, then `dx`: the visiting order of H3's nearest fill
/// (`geometry::fusion::disc_offsets`, same formula).
pub fn disc_offsets(radius_px: f32) -> Vec<(i32, i32, i32)> {
    let r = radius_px.max(0.0);
    let k = r.floor() as i32;
    let r2 = r * r;
    let mut offsets = Vec::new();
    for dy in -k..=k {
        for dx in -k..=k {
            let d2 = dx * dx + dy * dy;
            if d2 as f32 <= r2 {
                offsets.push((dx, dy, d2));
            }
        }
    }
    offsets.sort_by_key(|&(dx, dy, d2)| (d2, dy, dx));
    offsets
}

/// Half widths of the coverage disc of H8's hole mask per row offset `dy = 0..=floor(r)`:
/// `floor(sqrt(r² - dy²))` in `f32`, the formula of `geometry::fusion::HoleMasker`.
pub fn hole_half_widths(radius_px: f32) -> Vec<u32> {
    let r = radius_px.max(0.0);
    let k = r.floor() as usize;
    (0..=k).map(|dy| ((r * r - (dy * dy) as f32).max(0.0)).sqrt().floor() as u32).collect()
}
