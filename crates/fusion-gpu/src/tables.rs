//! Host-side lookup tables the shaders index, computed with the CPU twins' formulas so both
//! sides visit the same pixels in the same order. (H3's disc offsets come from
//! `geometry::fusion::disc_offsets` itself.)

/// Half widths of the coverage disc of H8's hole mask per row offset `dy = 0..=floor(r)`:
/// `floor(sqrt(r² - dy²))` in `f32`, the formula of `geometry::fusion::HoleMasker`
/// (private there, so repeated here; `hole_mask_matches_cpu` in the parity tests would catch a
/// drift).
pub fn hole_half_widths(radius_px: f32) -> Vec<u32> {
    let r = radius_px.max(0.0);
    let k = r.floor() as usize;
    (0..=k).map(|dy| ((r * r - (dy * dy) as f32).max(0.0)).sqrt().floor() as u32).collect()
}
