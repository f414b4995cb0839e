//! The depth camera's measured-depth correction (`kfuse calibrate --depth`), a versioned
//! optional part of the rig file (`"depth_correction"`; absent = the depth is taken as exact).
//!
//! # Model (version 1)
//!
//! The sensor's z (metres) at raw depth pixel `(u, v)` is modelled as
//!
//! ```text
//! z_measured = (1 + scale) · z_true + Σ_k c_k · φ_k(u, v)
//! ```
//!
//! with the spatial terms `φ_k` of [`DepthTermKind`] in coordinates normalised over the depth
//! image (centre `(uc, vc) = ((W−1)/2, (H−1)/2)`, pixel centres at integer coordinates):
//! `offset` 1, `x` `(u−uc)/uc`, `y` `(v−vc)/vc`, `radial2` ρ² and `radial4` ρ⁴ with
//! `ρ² = ((u−uc)² + (v−vc)²) / (uc² + vc²)`, i.e. 1 at the image's corner pixels. The
//! correction inverts it exactly: `z_true = (z_measured − Σ c_k φ_k) / (1 + scale)`
//! ([`DepthCorrection::correct`], [`DepthCorrection::correct_image`]).
//!
//! ```json
//! "depth_correction": { "version": 1, "width": 512, "height": 424,
//!   "model": "z_measured = (1 + scale)·z_true + Σ coefficient_m·term(u, v) ...",
//!   "terms": [ {"term": "offset", "value": 0.024, "std": 0.0002}, {"term": "scale", ...} ],
//!   "fit": { ... report of kfuse calibrate --depth ... } }
//! ```
//! Values of `scale` are unitless, all others metres; `std` is 1σ (0 where unknown).

use serde::{Deserialize, Serialize};

use crate::{GeometryError, Image};

/// The newest `depth_correction` version this build writes and reads.
pub const DEPTH_CORRECTION_VERSION: u32 = 1;

/// Largest |scale| accepted: 20 %. A time-of-flight sensor's scale error is a fraction of a
/// per cent; 0.2 and more is a unit mistake (a per-cent value written as a fraction).
pub const MAX_SCALE: f64 = 0.2;
/// Largest |coefficient| of a spatial term accepted, metres: 0.5 m. The Kinect v2's reported
/// errors are 2–5 cm; half a metre is a millimetre value written as metres.
pub const MAX_TERM_M: f64 = 0.5;

const MODEL_TEXT: &str = "z_measured = (1 + scale)·z_true + Σ value·term(u, v); terms over the raw depth image: offset 1, x (u-uc)/uc, y (v-vc)/vc, radial2 ρ², radial4 ρ⁴, ρ² = ((u-uc)² + (v-vc)²)/(uc² + vc²), uc = (W-1)/2, vc = (H-1)/2; scale unitless, other values metres; std 1σ";

/// One term of the model (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthTermKind {
    /// Constant offset, metres.
    Offset,
    /// Relative scale of the true z (unitless).
    Scale,
    /// Linear across the image, metres at the right edge (−value at the left).
    X,
    /// Linear down the image, metres at the bottom edge.
    Y,
    /// ρ², metres at the corners.
    Radial2,
    /// ρ⁴, metres at the corners.
    Radial4,
}

impl DepthTermKind {
    /// The term's name in files and reports.
    pub fn name(self) -> &'static str {
        match self {
            DepthTermKind::Offset => "offset",
            DepthTermKind::Scale => "scale",
            DepthTermKind::X => "x",
            DepthTermKind::Y => "y",
            DepthTermKind::Radial2 => "radial2",
            DepthTermKind::Radial4 => "radial4",
        }
    }

    /// The value's unit ("m" or "" for the scale).
    pub fn unit(self) -> &'static str {
        if self == DepthTermKind::Scale { "" } else { "m" }
    }
}

/// Normalised image coordinates of a `width × height` depth image (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageCoords {
    uc: f64,
    vc: f64,
    r2: f64,
}

impl ImageCoords {
    /// The coordinates of a `width × height` image (each side at least 2).
    pub fn new(width: usize, height: usize) -> Self {
        let (uc, vc) = ((width.max(2) as f64 - 1.0) / 2.0, (height.max(2) as f64 - 1.0) / 2.0);
        Self { uc, vc, r2: uc * uc + vc * vc }
    }

    /// `φ(u, v)` of spatial term `kind` (0 for the scale, which multiplies z instead).
    pub fn term(&self, kind: DepthTermKind, u: f64, v: f64) -> f64 {
        let (du, dv) = (u - self.uc, v - self.vc);
        let rho2 = (du * du + dv * dv) / self.r2;
        match kind {
            DepthTermKind::Offset => 1.0,
            DepthTermKind::Scale => 0.0,
            DepthTermKind::X => du / self.uc,
            DepthTermKind::Y => dv / self.vc,
            DepthTermKind::Radial2 => rho2,
            DepthTermKind::Radial4 => rho2 * rho2,
        }
    }
}

/// One fitted term: its value and 1σ.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthTerm {
    /// Which term.
    #[serde(rename = "term")]
    pub kind: DepthTermKind,
    /// Its coefficient (metres; unitless for the scale).
    pub value: f64,
    /// 1σ of the coefficient, same unit (0 = unknown).
    #[serde(default)]
    pub std: f64,
}

/// A depth correction (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthCorrection {
    /// Size of the raw depth images the pixel coordinates refer to.
    pub width: usize,
    /// See `width`.
    pub height: usize,
    /// The terms (each kind at most once; a kind not listed is 0).
    pub terms: Vec<DepthTerm>,
    /// The fit's report as written by `kfuse calibrate --depth` (views, RMS before/after),
    /// kept verbatim; `None` for corrections from other sources.
    pub fit: Option<serde_json::Value>,
}

#[derive(Serialize, Deserialize)]
pub(crate) struct DepthCorrectionFile {
    version: u32,
    width: usize,
    height: usize,
    #[serde(default)]
    model: String,
    terms: Vec<DepthTerm>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fit: Option<serde_json::Value>,
}

impl DepthCorrection {
    /// The value of term `kind` (0 when absent).
    pub fn value(&self, kind: DepthTermKind) -> f64 {
        self.terms.iter().find(|t| t.kind == kind).map_or(0.0, |t| t.value)
    }

    /// The modelled error's non-scale part `Σ c_k φ_k(u, v)` at raw pixel `(u, v)`, metres.
    fn spatial(&self, coords: &ImageCoords, u: f64, v: f64) -> f64 {
        self.terms
            .iter()
            .filter(|t| t.kind != DepthTermKind::Scale)
            .map(|t| t.value * coords.term(t.kind, u, v))
            .sum()
    }

    /// The true z (metres) of measured z `z_m` (metres) at raw depth pixel `(u, v)`.
    pub fn correct(&self, u: f64, v: f64, z_m: f64) -> f64 {
        let c = ImageCoords::new(self.width, self.height);
        (z_m - self.spatial(&c, u, v)) / (1.0 + self.value(DepthTermKind::Scale))
    }

    /// The measured z the model predicts for true z `z_m` (metres) at `(u, v)`: the inverse
    /// of [`DepthCorrection::correct`] (what the simulator's injected error does).
    pub fn distort(&self, u: f64, v: f64, z_m: f64) -> f64 {
        let c = ImageCoords::new(self.width, self.height);
        (1.0 + self.value(DepthTermKind::Scale)) * z_m + self.spatial(&c, u, v)
    }

    /// Corrects every valid sample of a raw depth image in place (`metres_per_unit`: 1 for
    /// metres, 0.001 for millimetres); invalid samples (0, NaN, negative) stay as they are.
    /// Returns how many samples were corrected. Error: the image is not the size the
    /// correction was fitted for (a registered or cropped depth has other pixels).
    ///
    /// This is the one function every path where depth becomes 3D calls (fuse, the viewer,
    /// `capture scene`'s `*_depth_corrected.png`).
    pub fn correct_image(
        &self,
        depth: &mut Image<f32>,
        metres_per_unit: f64,
    ) -> Result<usize, GeometryError> {
        let (w, h) = depth.size();
        if (w, h) != (self.width, self.height) {
            return Err(GeometryError::SizeMismatch {
                what: "depth image to correct with the rig's depth_correction".into(),
                got_w: w,
                got_h: h,
                want_w: self.width,
                want_h: self.height,
            });
        }
        let c = ImageCoords::new(w, h);
        let k = 1.0 + self.value(DepthTermKind::Scale);
        let mut n = 0;
        for y in 0..h {
            for x in 0..w {
                let z = depth.get_mut(x, y);
                if !(*z > 0.0) || !z.is_finite() {
                    continue;
                }
                let zm = f64::from(*z) * metres_per_unit;
                let t = (zm - self.spatial(&c, x as f64, y as f64)) / k;
                *z = (t / metres_per_unit) as f32;
                n += 1;
            }
        }
        Ok(n)
    }

    /// Checks the version-independent invariants: finite values within [`MAX_SCALE`] /
    /// [`MAX_TERM_M`], each kind once, a size of at least 2×2.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let bad =
            |m: String| Err(GeometryError::InvalidParameter(format!("depth_correction: {m}")));
        if self.width < 2 || self.height < 2 {
            return bad(format!("image size {}x{} is too small", self.width, self.height));
        }
        for (i, t) in self.terms.iter().enumerate() {
            if self.terms[..i].iter().any(|o| o.kind == t.kind) {
                return bad(format!("term '{}' is listed twice", t.kind.name()));
            }
            let limit = if t.kind == DepthTermKind::Scale { MAX_SCALE } else { MAX_TERM_M };
            if !(t.value.abs() <= limit) || !t.std.is_finite() {
                return bad(format!(
                    "term '{}' = {} is not finite or above {limit}{} (values are metres, the scale a fraction)",
                    t.kind.name(),
                    crate::num_fmt::num(t.value),
                    t.kind.unit()
                ));
            }
        }
        Ok(())
    }

    pub(crate) fn to_file(&self) -> DepthCorrectionFile {
        DepthCorrectionFile {
            version: DEPTH_CORRECTION_VERSION,
            width: self.width,
            height: self.height,
            model: MODEL_TEXT.into(),
            terms: self.terms.clone(),
            fit: self.fit.clone(),
        }
    }

    pub(crate) fn from_file(f: DepthCorrectionFile) -> Result<Self, String> {
        if f.version > DEPTH_CORRECTION_VERSION {
            return Err(format!(
                "depth_correction version {} is newer than this kfuse understands ({DEPTH_CORRECTION_VERSION}); upgrade kfuse",
                f.version
            ));
        }
        let c = DepthCorrection { width: f.width, height: f.height, terms: f.terms, fit: f.fit };
        c.validate().map_err(|e| e.to_string())?;
        Ok(c)
    }

    /// One line per term with its unit and 1σ (for `kfuse rig show` and the CLI).
    pub fn describe(&self) -> Vec<String> {
        self.terms
            .iter()
            .map(|t| {
                if t.kind == DepthTermKind::Scale {
                    format!("scale {:+.4} % ± {:.4} % (1σ)", 100.0 * t.value, 100.0 * t.std)
                } else {
                    format!(
                        "{} {:+.2} mm ± {:.2} mm (1σ)",
                        t.kind.name(),
                        1e3 * t.value,
                        1e3 * t.std
                    )
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> DepthCorrection {
        let t = |kind, value| DepthTerm { kind, value, std: 0.0 };
        DepthCorrection {
            width: 512,
            height: 424,
            terms: vec![
                t(DepthTermKind::Offset, 0.024),
                t(DepthTermKind::Scale, 0.005),
                t(DepthTermKind::Radial2, 0.010),
            ],
            fit: None,
        }
    }

    /// The normalised coordinates are 0 at the centre and ρ² = 1 at the four corner pixels.
    #[test]
    fn terms_are_normalised_to_the_image() {
        let c = ImageCoords::new(512, 424);
        assert_eq!(c.term(DepthTermKind::Radial2, 255.5, 211.5), 0.0);
        for (u, v) in [(0.0, 0.0), (511.0, 0.0), (0.0, 423.0), (511.0, 423.0)] {
            assert!((c.term(DepthTermKind::Radial2, u, v) - 1.0).abs() < 1e-12);
            assert!((c.term(DepthTermKind::X, u, v).abs() - 1.0).abs() < 1e-12);
        }
    }

    /// correct ∘ distort is the identity (1e-12 m), and the model's numbers: at the centre
    /// and 1 m, measured = 1.005 + 0.024 m; at a corner 10 mm more.
    #[test]
    fn correct_inverts_distort() {
        let m = model();
        assert!((m.distort(255.5, 211.5, 1.0) - 1.029).abs() < 1e-12);
        assert!((m.distort(0.0, 0.0, 1.0) - 1.039).abs() < 1e-12);
        for (u, v, z) in [(0.0, 0.0, 0.7), (300.0, 17.0, 2.5), (511.0, 423.0, 4.0)] {
            assert!((m.correct(u, v, m.distort(u, v, z)) - z).abs() < 1e-12);
        }
        let mut img = Image::from_fn(512, 424, |x, _| if x == 3 { 0.0 } else { 1029.0 });
        *img.get_mut(4, 0) = f32::NAN;
        let n = m.correct_image(&mut img, 1e-3).unwrap();
        assert_eq!(n, 512 * 424 - 424 - 1);
        assert_eq!(*img.get(3, 7), 0.0);
        assert!(img.get(4, 0).is_nan());
        // Pixel (256, 212) is half a pixel from the centre: ρ² ≈ 2e-6, 0.02 µm of radial.
        assert!((img.get(256, 212) - 1000.0).abs() < 1e-3, "{}", img.get(256, 212));
        let mut small = Image::filled(4, 4, 1.0f32);
        assert!(m.correct_image(&mut small, 1.0).is_err());
    }

    #[test]
    fn implausible_values_are_refused() {
        let mut m = model();
        m.terms[1].value = 0.5;
        assert!(m.validate().unwrap_err().to_string().contains("scale"));
        let mut m = model();
        m.terms[0].value = 24.0;
        assert!(m.validate().unwrap_err().to_string().contains("offset"));
        let mut m = model();
        m.terms.push(m.terms[0]);
        assert!(m.validate().unwrap_err().to_string().contains("twice"));
        let mut f = model().to_file();
        f.version = 2;
        assert!(DepthCorrection::from_file(f).unwrap_err().contains("upgrade"));
    }
}
