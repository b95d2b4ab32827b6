//! A 2D pose graph optimised by sparse Gauss-Newton (Grisetti et al., "A
//! tutorial on graph-based SLAM", 2010): nodes are poses `(x, y, θ)`, edges
//! relative-pose measurements with an information matrix; each iteration
//! solves the normal equations `H·Δ = −b` with the sparse Cholesky
//! factorisation of `nalgebra-sparse` (the first node held fixed). Loop
//! closure edges may carry a Huber kernel (iteratively reweighted), so one
//! wrong closure pulls with a bounded force.

use nalgebra::{Isometry2, Matrix3, Vector2, Vector3};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

/// One relative-pose measurement: node `to` seen from node `from`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// Index of the reference node.
    pub from: usize,
    /// Index of the measured node.
    pub to: usize,
    /// Measured `X_from⁻¹ · X_to`.
    pub measurement: Isometry2<f64>,
    /// Information (inverse covariance) of `(x, y, θ)` of the measurement.
    pub information: Matrix3<f64>,
    /// Huber threshold on the Mahalanobis distance, `None` for a plain square.
    pub huber: Option<f64>,
}

/// Why an optimisation stopped without a result.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseGraphError {
    /// An edge names a node that does not exist.
    #[error("edge {from} -> {to} names a node beyond the {nodes} nodes")]
    BadEdge {
        /// Reference node.
        from: usize,
        /// Measured node.
        to: usize,
        /// Nodes in the graph.
        nodes: usize,
    },
    /// The normal equations are not positive definite (a node without edges).
    #[error("the normal equations are not positive definite (non-finite measurements?)")]
    NotPositiveDefinite,
}

/// Result of [`optimise`].
#[derive(Debug, Clone, PartialEq)]
pub struct Optimised {
    /// The optimised poses.
    pub poses: Vec<Isometry2<f64>>,
    /// Gauss-Newton iterations run.
    pub iterations: usize,
    /// Weighted squared error before.
    pub initial_chi2: f64,
    /// Weighted squared error after.
    pub final_chi2: f64,
}

fn v(p: &Isometry2<f64>) -> Vector3<f64> {
    Vector3::new(p.translation.x, p.translation.y, p.rotation.angle())
}

fn wrap(a: f64) -> f64 {
    let t = (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI);
    t - std::f64::consts::PI
}

fn rot(t: f64) -> nalgebra::Matrix2<f64> {
    let (s, c) = t.sin_cos();
    nalgebra::Matrix2::new(c, -s, s, c)
}

/// Error of `e` at poses `xi`, `xj` and its Jacobians with respect to them.
fn linearise(
    xi: &Vector3<f64>,
    xj: &Vector3<f64>,
    z: &Isometry2<f64>,
) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
    let ri = rot(xi.z);
    let rz = rot(z.rotation.angle());
    let dt = Vector2::new(xj.x - xi.x, xj.y - xi.y);
    let et = rz.transpose() * (ri.transpose() * dt - z.translation.vector);
    let e = Vector3::new(et.x, et.y, wrap(xj.z - xi.z - z.rotation.angle()));
    let (s, c) = xi.z.sin_cos();
    // d(Ri^T)/dθ
    let dri_t = nalgebra::Matrix2::new(-s, c, -c, -s);
    let a_t = -(rz.transpose() * ri.transpose());
    let a_th = rz.transpose() * dri_t * dt;
    let mut a = Matrix3::zeros();
    a.fixed_view_mut::<2, 2>(0, 0).copy_from(&a_t);
    a[(0, 2)] = a_th.x;
    a[(1, 2)] = a_th.y;
    a[(2, 2)] = -1.0;
    let mut b = Matrix3::zeros();
    b.fixed_view_mut::<2, 2>(0, 0)
        .copy_from(&(rz.transpose() * ri.transpose()));
    b[(2, 2)] = 1.0;
    (e, a, b)
}

/// Huber weight of a residual with Mahalanobis distance `sqrt(chi2)`.
fn weight(chi2: f64, huber: Option<f64>) -> f64 {
    match huber {
        Some(k) if chi2 > k * k => k / chi2.sqrt(),
        _ => 1.0,
    }
}

/// Total weighted squared error of `edges` at `x`.
fn chi2(x: &[Vector3<f64>], edges: &[Edge]) -> f64 {
    edges
        .iter()
        .map(|e| {
            let (r, _, _) = linearise(&x[e.from], &x[e.to], &e.measurement);
            let c = (r.transpose() * e.information * r)[0];
            match e.huber {
                Some(k) if c > k * k => 2.0 * k * c.sqrt() - k * k,
                _ => c,
            }
        })
        .sum()
}

/// Optimises `poses` under `edges` by at most `max_iterations` Gauss-Newton
/// steps, holding the first pose fixed; stops early when the largest update
/// is below 1e-6 (m or rad).
pub fn optimise(
    poses: &[Isometry2<f64>],
    edges: &[Edge],
    max_iterations: usize,
) -> Result<Optimised, PoseGraphError> {
    let n = poses.len();
    if let Some(e) = edges.iter().find(|e| e.from >= n || e.to >= n) {
        return Err(PoseGraphError::BadEdge {
            from: e.from,
            to: e.to,
            nodes: n,
        });
    }
    let mut x: Vec<Vector3<f64>> = poses.iter().map(v).collect();
    let initial_chi2 = chi2(&x, edges);
    let mut iterations = 0;
    while iterations < max_iterations && n > 1 {
        iterations += 1;
        let mut coo = CooMatrix::new(3 * n, 3 * n);
        let mut b = nalgebra::DVector::<f64>::zeros(3 * n);
        // The first node is held by a stiff prior; a tiny damping on every
        // variable keeps a node without edges (where it stays) from making the
        // system singular.
        for k in 0..3 * n {
            coo.push(k, k, if k < 3 { 1e9 } else { 1e-6 });
        }
        for e in edges {
            let (r, a, bj) = linearise(&x[e.from], &x[e.to], &e.measurement);
            let c = (r.transpose() * e.information * r)[0];
            let omega = e.information * weight(c, e.huber);
            let blocks = [(e.from, a), (e.to, bj)];
            for (p, jp) in &blocks {
                let g = jp.transpose() * omega * r;
                for k in 0..3 {
                    b[3 * p + k] += g[k];
                }
                for (q, jq) in &blocks {
                    let h = jp.transpose() * omega * jq;
                    for r in 0..3 {
                        for c in 0..3 {
                            coo.push(3 * p + r, 3 * q + c, h[(r, c)]);
                        }
                    }
                }
            }
        }
        let h = CscMatrix::from(&coo);
        let chol = CscCholesky::factor(&h).map_err(|_| PoseGraphError::NotPositiveDefinite)?;
        let dx = chol.solve(&(-b));
        let mut largest = 0f64;
        for (i, xi) in x.iter_mut().enumerate() {
            let d = Vector3::new(dx[3 * i], dx[3 * i + 1], dx[3 * i + 2]);
            largest = largest.max(d.amax());
            *xi += d;
            xi.z = wrap(xi.z);
        }
        if !largest.is_finite() {
            return Err(PoseGraphError::NotPositiveDefinite);
        }
        if largest < 1e-6 {
            break;
        }
    }
    let final_chi2 = chi2(&x, edges);
    Ok(Optimised {
        poses: x
            .iter()
            .map(|p| Isometry2::new(Vector2::new(p.x, p.y), p.z))
            .collect(),
        iterations,
        initial_chi2,
        final_chi2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edge(from: usize, to: usize, z: Isometry2<f64>, info: f64) -> Edge {
        Edge {
            from,
            to,
            measurement: z,
            information: Matrix3::from_diagonal_element(info),
            huber: None,
        }
    }

    /// A square loop driven with biased odometry; one closure edge back to
    /// the start pulls the last pose home.
    #[test]
    fn loop_closure_fixes_a_drifted_square() {
        let step = Isometry2::new(Vector2::new(1.0, 0.0), 0.0);
        let turn = Isometry2::new(Vector2::new(1.0, 0.0), std::f64::consts::FRAC_PI_2);
        let mut truth = vec![Isometry2::identity()];
        for k in 1..=16 {
            let m = if k % 4 == 0 { turn } else { step };
            truth.push(truth[k - 1] * m);
        }
        // Odometry: each step 5% long and turned 2 degrees more.
        let bias = Isometry2::new(Vector2::new(0.05, 0.0), 2f64.to_radians());
        let mut poses = vec![Isometry2::identity()];
        let mut edges = Vec::new();
        for k in 1..truth.len() {
            let z = truth[k - 1].inverse() * truth[k] * bias;
            poses.push(poses[k - 1] * z);
            edges.push(edge(k - 1, k, z, 100.0));
        }
        let before = (truth[16].inverse() * poses[16]).translation.vector.norm();
        edges.push(edge(0, 16, truth[0].inverse() * truth[16], 1e4));
        let o = optimise(&poses, &edges, 20).expect("optimise");
        let after = (truth[16].inverse() * o.poses[16])
            .translation
            .vector
            .norm();
        assert!(before > 1.0, "drift {before}");
        assert!(after < 0.05, "after {after}, before {before}");
        assert!(o.final_chi2 < o.initial_chi2);
        assert!(
            o.poses[0].translation.vector.norm() < 1e-6,
            "first node fixed"
        );
    }

    #[test]
    fn bad_edges_are_errors() {
        let poses = vec![Isometry2::identity(); 2];
        let e = optimise(&poses, &[edge(0, 5, Isometry2::identity(), 1.0)], 5);
        assert!(matches!(e, Err(PoseGraphError::BadEdge { to: 5, .. })));
        // A node without edges stays where it is; no error, no panic.
        let mut poses = vec![Isometry2::identity(); 3];
        poses[2] = Isometry2::new(Vector2::new(4.0, 1.0), 0.5);
        let o = optimise(&poses, &[edge(0, 1, Isometry2::identity(), 1.0)], 5).expect("ok");
        assert!((o.poses[2].translation.vector - Vector2::new(4.0, 1.0)).norm() < 1e-9);
    }

    /// The Jacobians agree with finite differences.
    #[test]
    fn jacobians_match_finite_differences() {
        let xi = Vector3::new(0.3, -0.2, 0.7);
        let xj = Vector3::new(1.1, 0.4, -0.4);
        let z = Isometry2::new(Vector2::new(0.5, 0.2), 0.3);
        let (e0, a, b) = linearise(&xi, &xj, &z);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let (ea, _, _) = linearise(&(xi + d), &xj, &z);
            let (eb, _, _) = linearise(&xi, &(xj + d), &z);
            for r in 0..3 {
                assert!(((ea[r] - e0[r]) / h - a[(r, k)]).abs() < 1e-5, "A {r} {k}");
                assert!(((eb[r] - e0[r]) / h - b[(r, k)]).abs() < 1e-5, "B {r} {k}");
            }
        }
    }
}
