//! 3-D vectors and rotation matrices on plain `[f64; 3]` arrays: the one home of the rotation
//! math that BVH import (forward kinematics), BVH export (solving joint rotations), ground
//! alignment and rendering share.
//!
//! Our own small module rather than glam or nalgebra: every caller holds positions as
//! `[f64; 3]` rows of an ndarray, and needs a dozen functions; a crate would add a conversion
//! at each of those boundaries and a dependency for less code than its glue.
//!
//! Conventions: matrices are row-major and act on column vectors (`apply(r, v) = r · v`);
//! angles are in degrees; rotations are right-handed.

/// A point or direction.
pub type V3 = [f64; 3];
/// A 3×3 matrix, row-major.
pub type M3 = [[f64; 3]; 3];

/// The identity matrix.
pub const IDENTITY: M3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `a + b`.
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `s · a`.
pub fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a · b`.
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
pub fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `|a|`.
pub fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}

/// `a / |a|`; the zero vector stays zero.
pub fn normalize(a: V3) -> V3 {
    let n = norm(a);
    if n > 0.0 {
        scale(a, 1.0 / n)
    } else {
        a
    }
}

/// `a · b`.
pub fn mul(a: &M3, b: &M3) -> M3 {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}

/// `aᵀ` (the inverse of a rotation).
pub fn transpose(a: &M3) -> M3 {
    std::array::from_fn(|r| std::array::from_fn(|c| a[c][r]))
}

/// `a · v`.
pub fn apply(a: &M3, v: V3) -> V3 {
    std::array::from_fn(|r| a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2])
}

/// `det a`.
pub fn determinant(a: &M3) -> f64 {
    dot(a[0], cross(a[1], a[2]))
}

/// Rotation by `deg` degrees about axis 0 (x), 1 (y) or 2 (z).
pub fn axis_rotation(axis: usize, deg: f64) -> M3 {
    let (s, c) = deg.to_radians().sin_cos();
    match axis {
        0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    }
}

/// The smallest rotation taking the direction of `u` to that of `v` (Rodrigues); a half turn
/// about an axis perpendicular to `u` when they are opposite.
pub fn rotation_between(u: V3, v: V3) -> M3 {
    let (u, v) = (normalize(u), normalize(v));
    let k = cross(u, v);
    let s = norm(k);
    let c = dot(u, v);
    if s < 1e-12 {
        if c > 0.0 {
            return IDENTITY;
        }
        let e = if u[0].abs() < 0.6 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let a = normalize(cross(u, e));
        return std::array::from_fn(|r| std::array::from_fn(|col| 2.0 * a[r] * a[col] - IDENTITY[r][col]));
    }
    let kx: M3 = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let kx2 = mul(&kx, &kx);
    let f = (1.0 - c) / (s * s);
    std::array::from_fn(|r| std::array::from_fn(|col| IDENTITY[r][col] + kx[r][col] + f * kx2[r][col]))
}

/// The rotation of a unit quaternion `[w, x, y, z]` (normalized first).
pub fn quaternion_matrix(q: [f64; 4]) -> M3 {
    let n = (q.iter().map(|x| x * x).sum::<f64>()).sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
        [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
        [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Angles `[a, b, c]` in degrees with `r = Rz(a) · Rx(b) · Ry(c)` (BVH's `Zrotation Xrotation
/// Yrotation`); at gimbal lock (`b = ±90°`) `c` is 0.
pub fn euler_zxy(r: &M3) -> [f64; 3] {
    let b = r[2][1].atan2(r[2][0].hypot(r[2][2]));
    let (a, c) = if r[2][0].hypot(r[2][2]) > 1e-9 { ((-r[0][1]).atan2(r[1][1]), (-r[2][0]).atan2(r[2][2])) } else { (r[1][0].atan2(r[0][0]), 0.0) };
    [a.to_degrees(), b.to_degrees(), c.to_degrees()]
}

/// Horn's closed-form absolute orientation: the rotation `R` minimizing `Σ w |R a − b|²` over
/// `(a, b, w)` pairs.
pub fn best_fit_rotation(pairs: &[(V3, V3, f64)]) -> M3 {
    let mut s = [[0.0f64; 3]; 3];
    for (a, b, w) in pairs {
        for (i, row) in s.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v += w * a[i] * b[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let n = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let (vals, vecs) = symmetric_eigen4(n);
    let best = (0..4).max_by(|&a, &b| vals[a].total_cmp(&vals[b])).expect("4 eigenvalues");
    quaternion_matrix(std::array::from_fn(|r| vecs[r][best]))
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 4×4 matrix, cyclic Jacobi.
#[allow(clippy::needless_range_loop)]
fn symmetric_eigen4(mut a: [[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let size: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>().max(1e-300);
    for _ in 0..64 {
        let off: f64 = (0..4).flat_map(|p| (p + 1..4).map(move |q| (p, q))).map(|(p, q)| a[p][q] * a[p][q]).sum();
        if off <= 1e-30 * size {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = if theta >= 0.0 { 1.0 } else { -1.0 } / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
                for k in 0..4 {
                    let (pk, qk) = (a[p][k], a[q][k]);
                    a[p][k] = c * pk - s * qk;
                    a[q][k] = s * pk + c * qk;
                }
                for row in v.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2], a[3][3]], v)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::{rngs::StdRng, Rng, SeedableRng};

    /// Largest entry of `|a − b|`.
    pub(crate) fn max_diff(a: &M3, b: &M3) -> f64 {
        (0..3).flat_map(|r| (0..3).map(move |c| (a[r][c] - b[r][c]).abs())).fold(0.0, f64::max)
    }

    /// `Rz · Rx · Ry` with seeded angles (x within ±90°, so every rotation is reachable).
    pub(crate) fn random_rotation(rng: &mut StdRng) -> M3 {
        let z = axis_rotation(2, rng.gen_range(-180.0..180.0));
        let x = axis_rotation(0, rng.gen_range(-90.0..90.0));
        mul(&mul(&z, &x), &axis_rotation(1, rng.gen_range(-180.0..180.0)))
    }

    #[test]
    fn known_values() {
        // Rz(90°) takes x to y; Rx(90°) takes y to z; Ry(90°) takes z to x.
        let close = |a: V3, b: V3| norm(sub(a, b)) < 1e-15;
        assert!(close(apply(&axis_rotation(2, 90.0), [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]));
        assert!(close(apply(&axis_rotation(0, 90.0), [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]));
        assert!(close(apply(&axis_rotation(1, 90.0), [0.0, 0.0, 1.0]), [1.0, 0.0, 0.0]));
        assert_eq!(cross([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]);
        assert!(close(normalize([3.0, 0.0, 4.0]), [0.6, 0.0, 0.8]));
        assert_eq!(normalize([0.0; 3]), [0.0; 3]);
        // The quaternion (cos 30°, 0, 0, sin 30°) is Rz(60°).
        let h = 30f64.to_radians();
        assert!(max_diff(&quaternion_matrix([h.cos(), 0.0, 0.0, h.sin()]), &axis_rotation(2, 60.0)) < 1e-15);
        assert_eq!(determinant(&IDENTITY), 1.0);
    }

    #[test]
    fn round_trips_and_fits_recover_known_rotations() {
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let r = random_rotation(&mut rng);
            assert!((determinant(&r) - 1.0).abs() < 1e-12);
            assert!(max_diff(&mul(&r, &transpose(&r)), &IDENTITY) < 1e-12);
            let [a, b, c] = euler_zxy(&r);
            assert!(max_diff(&mul(&mul(&axis_rotation(2, a), &axis_rotation(0, b)), &axis_rotation(1, c)), &r) < 1e-9);
            let pairs: Vec<(V3, V3, f64)> = (0..3)
                .map(|_| {
                    let a: V3 = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
                    (a, apply(&r, a), 1.0)
                })
                .collect();
            assert!(max_diff(&best_fit_rotation(&pairs), &r) < 1e-9, "Horn");
            let (u, v) = (pairs[0].0, pairs[1].0);
            assert!(norm(sub(apply(&rotation_between(u, v), normalize(u)), normalize(v))) < 1e-9);
        }
        // Gimbal lock and opposite directions.
        let g = mul(&axis_rotation(2, 30.0), &axis_rotation(0, 90.0));
        let [a, b, c] = euler_zxy(&g);
        assert!(max_diff(&mul(&mul(&axis_rotation(2, a), &axis_rotation(0, b)), &axis_rotation(1, c)), &g) < 1e-9);
        let m = rotation_between([0.0, 0.0, 1.0], [0.0, 0.0, -1.0]);
        assert!(norm(sub(apply(&m, [0.0, 0.0, 1.0]), [0.0, 0.0, -1.0])) < 1e-12);
        assert!((determinant(&m) - 1.0).abs() < 1e-12);
    }
}
