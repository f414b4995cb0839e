//! Zhang's linear initialisation: plane-to-image homographies, closed-form intrinsics and
//! per-view poses (distortion ignored; Levenberg–Marquardt refines everything afterwards).

use geometry::{Intrinsics, RigidTransform};
use nalgebra::{DMatrix, Matrix3, Rotation3, Vector2, Vector3};

/// Homography `H` with `pixel ~ H · (X, Y, 1)` from ≥ 4 plane points by the normalised DLT.
pub fn homography(plane: &[Vector2<f64>], pixels: &[Vector2<f64>]) -> Option<Matrix3<f64>> {
    let n = plane.len();
    if n < 4 || pixels.len() != n {
        return None;
    }
    let norm = |pts: &[Vector2<f64>]| {
        let mean = pts.iter().fold(Vector2::zeros(), |a, p| a + p) / pts.len() as f64;
        let spread = pts.iter().map(|p| (p - mean).norm()).sum::<f64>() / pts.len() as f64;
        let s = if spread > 0.0 { std::f64::consts::SQRT_2 / spread } else { 1.0 };
        Matrix3::new(s, 0.0, -s * mean.x, 0.0, s, -s * mean.y, 0.0, 0.0, 1.0)
    };
    let ta = norm(plane);
    let tb = norm(pixels);
    let mut a = DMatrix::zeros(2 * n, 9);
    for i in 0..n {
        let p = ta * Vector3::new(plane[i].x, plane[i].y, 1.0);
        let q = tb * Vector3::new(pixels[i].x, pixels[i].y, 1.0);
        let (x, y, u, v) = (p.x, p.y, q.x, q.y);
        let r0 = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u];
        let r1 = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v];
        for j in 0..9 {
            a[(2 * i, j)] = r0[j];
            a[(2 * i + 1, j)] = r1[j];
        }
    }
    // Smallest right singular vector via the 9x9 normal matrix (well conditioned after
    // normalisation).
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let (imin, _) = eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = eig.eigenvectors.column(imin);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let hfull = tb.try_inverse()? * hn * ta;
    let s = hfull[(2, 2)];
    if s.abs() < 1e-300 {
        return None;
    }
    let out = hfull / s;
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// Zhang's closed-form intrinsics (zero skew) from ≥ 2 homographies. The homographies are
/// first conditioned by the image size. `None` when the system gives no valid camera.
pub fn zhang_intrinsics(hs: &[Matrix3<f64>], width: usize, height: usize) -> Option<Intrinsics> {
    let s = width.max(height) as f64;
    let (c0x, c0y) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let nrm = Matrix3::new(1.0 / s, 0.0, -c0x / s, 0.0, 1.0 / s, -c0y / s, 0.0, 0.0, 1.0);
    let v = |h: &Matrix3<f64>, i: usize, j: usize| {
        [
            h[(0, i)] * h[(0, j)],
            h[(0, i)] * h[(1, j)] + h[(1, i)] * h[(0, j)],
            h[(1, i)] * h[(1, j)],
            h[(2, i)] * h[(0, j)] + h[(0, i)] * h[(2, j)],
            h[(2, i)] * h[(1, j)] + h[(1, i)] * h[(2, j)],
            h[(2, i)] * h[(2, j)],
        ]
    };
    let mut rows: Vec<[f64; 6]> = Vec::new();
    for h in hs {
        let h = nrm * h;
        let h = h / h.column(0).norm().max(h.column(1).norm());
        let v12 = v(&h, 0, 1);
        let v11 = v(&h, 0, 0);
        let v22 = v(&h, 1, 1);
        rows.push(v12);
        rows.push(std::array::from_fn(|k| v11[k] - v22[k]));
    }
    // Zero skew: B12 = 0.
    rows.push([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    let m = DMatrix::from_fn(rows.len(), 6, |i, j| rows[i][j]);
    let eig = (m.transpose() * &m).symmetric_eigen();
    let (imin, _) = eig.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let mut b = eig.eigenvectors.column(imin).clone_owned();
    if b[0] < 0.0 {
        b = -b;
    }
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if den <= 0.0 || b11 <= 0.0 {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    if lambda / b11 <= 0.0 {
        return None;
    }
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let u0 = -b13 * alpha * alpha / lambda;
    // Back to pixels: K = nrm⁻¹ · K_n.
    let k = Intrinsics::new(alpha * s, beta * s, u0 * s + c0x, v0 * s + c0y);
    let plausible = k.fx.is_finite()
        && k.fy.is_finite()
        && (k.cx - c0x).abs() < 0.25 * width as f64
        && (k.cy - c0y).abs() < 0.25 * height as f64
        && (k.fx / k.fy - 1.0).abs() < 0.2;
    plausible.then_some(k)
}

/// OpenCV-style focal lengths with the principal point held at `(cx, cy)`: two linear
/// equations per homography in `1/fx²`, `1/fy²`. `None` when they give no positive solution.
pub fn focal_with_principal_point(hs: &[Matrix3<f64>], cx: f64, cy: f64) -> Option<(f64, f64)> {
    let t = Matrix3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    let mut ata = nalgebra::Matrix2::zeros();
    let mut atb = Vector2::zeros();
    for h in hs {
        let h = t * h;
        let (h1, h2) = (h.column(0).into_owned(), h.column(1).into_owned());
        let sc = 1.0 / h1.norm().max(h2.norm());
        let (h1, h2) = (h1 * sc, h2 * sc);
        let eqs = [
            (Vector2::new(h1.x * h2.x, h1.y * h2.y), -h1.z * h2.z),
            (
                Vector2::new(h1.x * h1.x - h2.x * h2.x, h1.y * h1.y - h2.y * h2.y),
                -(h1.z * h1.z - h2.z * h2.z),
            ),
        ];
        for (a, b) in eqs {
            ata += a * a.transpose();
            atb += a * b;
        }
    }
    let sol = ata.try_inverse()? * atb;
    if sol.x <= 0.0 || sol.y <= 0.0 {
        return None;
    }
    Some((1.0 / sol.x.sqrt(), 1.0 / sol.y.sqrt()))
}

/// Board pose from a homography and intrinsics: `camera_from_board` (board plane z = 0).
pub fn pose_from_homography(h: &Matrix3<f64>, k: &Intrinsics) -> Option<RigidTransform> {
    let m = k.matrix().try_inverse()? * h;
    let (m1, m2, m3) =
        (m.column(0).into_owned(), m.column(1).into_owned(), m.column(2).into_owned());
    let mut lambda = 2.0 / (m1.norm() + m2.norm());
    if m3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = m1 * lambda;
    let r2 = m2 * lambda;
    let r3 = r1.cross(&r2);
    let r = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = r.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut rot = u * vt;
    if rot.determinant() < 0.0 {
        rot = -rot;
    }
    let t = m3 * lambda;
    t.iter()
        .all(|v| v.is_finite())
        .then(|| RigidTransform::new(Rotation3::from_matrix_unchecked(rot), t))
}

/// Tilt of a board pose: angle between the board normal and the optical axis, degrees.
pub fn tilt_deg(camera_from_board: &RigidTransform) -> f64 {
    let n: Vector3<f64> = camera_from_board.rotation * Vector3::z();
    n.z.abs().clamp(-1.0, 1.0).acos().to_degrees()
}
