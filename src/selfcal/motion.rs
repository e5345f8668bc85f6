//! The rigid motion at one sample from the accelerometers alone: specific force at the origin
//! `f`, angular acceleration `alpha` and angular rate `omega` (9 unknowns from N >= 9 outputs), by
//! Gauss-Newton on the model of `selfcal::model`.
//!
//! The outputs are even in `omega` (the centripetal term `W = w w^T - |w|^2 I` is quadratic), so
//! one sample gives the rate only up to its sign. The sign is carried by continuity: within a
//! run of samples, each rate takes the sign closer to the previous rate advanced by the mean
//! angular acceleration over the step, and the run's overall sign is the one for which the rate's
//! increments agree with `alpha dt` ([`orient_run`]).
//!
//! A first guess comes from the linear model with a general 3x3 matrix `A = [alpha x] + W` (12
//! unknowns): `omega` is the eigenvector of the symmetric part of `A` with the largest eigenvalue,
//! and `|omega|^2` minus the mean of the other two.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector3};

use super::model::{SampleMotion, Sensor};

/// One sample's corrected data: outputs, which are used (not clipped), and their weights.
pub struct SampleData<'a> {
    pub outputs: &'a [f64],
    pub used: &'a [bool],
    pub weights: &'a [f64],
}

/// Weighted misfit of a motion.
pub fn cost(sensors: &[Sensor], data: &SampleData, m: &SampleMotion) -> f64 {
    let mut c = 0.0;
    for (j, s) in sensors.iter().enumerate() {
        if data.used[j] {
            let r = data.outputs[j] - s.output(&m.specific_force_m_s2(&s.position_m));
            c += data.weights[j] * r * r;
        }
    }
    c
}

/// Newton from `start`, damped (Levenberg-Marquardt) where the full step does not lower the cost;
/// with `omega_fixed` only `f` and `alpha` are solved (then the model is linear and one step is
/// exact). Returns the motion and its cost; [`information`] gives its local normal matrix.
///
/// The rate's block of the normal matrix carries the residual's curvature ([`rate_curvature`])
/// wherever the sum stays positive definite (the Newton block, [`newton_rate_block`]): the outputs
/// are quadratic in the rate, and at a low rate the Gauss-Newton block (which goes as the rate
/// squared) is smaller than that term, so Gauss-Newton steps there are wrong in size. Where the
/// sum has a direction of negative curvature (a saddle: a rate of exactly zero, where the first
/// guess found no centripetal term, is one) a search along it leaves the saddle when that clearly
/// lowers the misfit ([`leave_saddle`]), and otherwise the Gauss-Newton block is kept (a flat
/// array, whose rate is not resolved, stays as it was). The solve stops when the undamped step
/// would lower the cost by less than `1e-8` (a chi^2: about 1e-4 of a sigma).
pub fn solve(sensors: &[Sensor], data: &SampleData, start: SampleMotion, omega_fixed: bool) -> (SampleMotion, f64) {
    let dim = if omega_fixed { 6 } else { 9 };
    let mut m = start;
    let mut c = cost(sensors, data, &m);
    // What does not move with the motion, formed once: the outputs are linear in the specific
    // force and angular acceleration, with coefficients free of the motion, so the normal
    // matrix's block of those six is the same at every iteration; and the rate's second
    // derivative is the same at every motion. Each element is summed as `Matrix::ger` sums it
    // (`(w d_k) d_i`, the accelerometers in order), and only what the solve reads is formed: the
    // lower triangle (Cholesky reads no more) and the rate's whole 3 x 3 block (its eigen-
    // decomposition reads both triangles).
    let mut linear_block = SMatrix::<f64, 9, 9>::zeros();
    let mut second = Vec::with_capacity(if omega_fixed { 0 } else { sensors.len() });
    for (j, s) in sensors.iter().enumerate() {
        if !data.used[j] {
            continue;
        }
        let d = s.d_motion(&m);
        let w = data.weights[j];
        for k in 0..6 {
            let wk = w * d[k];
            for i in k..6 {
                linear_block[(i, k)] += wk * d[i];
            }
        }
        if !omega_fixed {
            second.push(s.d2_rate());
        }
    }
    let mut h = SMatrix::<f64, 9, 9>::zeros();
    let mut mu = 0.0_f64;
    let mut escaped = false;
    for _ in 0..50 {
        h.copy_from(&linear_block);
        let mut g = SVector::<f64, 9>::zeros();
        let mut curvature = Matrix3::zeros();
        let mut used = 0;
        for (j, s) in sensors.iter().enumerate() {
            if !data.used[j] {
                continue;
            }
            let r = data.outputs[j] - s.output(&m.specific_force_m_s2(&s.position_m));
            let d = SVector::<f64, 9>::from(s.d_motion(&m));
            let w = data.weights[j];
            if !omega_fixed {
                // The rate's rows below the diagonal, then the rate block above it.
                for k in 0..9 {
                    let wk = w * d[k];
                    for i in k.max(6)..9 {
                        h[(i, k)] += wk * d[i];
                    }
                }
                for k in 7..9 {
                    let wk = w * d[k];
                    for i in 6..k {
                        h[(i, k)] += wk * d[i];
                    }
                }
                curvature -= second[used] * (w * r);
            }
            g.axpy(w * r, &d, 1.0);
            used += 1;
        }
        if omega_fixed {
            for i in 6..9 {
                h.row_mut(i).fill(0.0);
                h.column_mut(i).fill(0.0);
                h[(i, i)] = 1.0;
                g[i] = 0.0;
            }
        } else {
            let block = h.fixed_view::<3, 3>(6, 6).into_owned();
            let (newton, full) = newton_rate_block(&block, &curvature);
            if let Some(n) = newton {
                h.fixed_view_mut::<3, 3>(6, 6).copy_from(&n);
            } else if !escaped && let Some(better) = leave_saddle(sensors, data, &m, c, &full) {
                (m, c) = better;
                escaped = true;
                continue;
            }
        }
        // A floor on the diagonal keeps the linear unknowns' step defined where the rate's rows
        // vanish.
        let floor = 1e-12 * (0..9).map(|i| h[(i, i)].abs()).fold(0.0, f64::max);
        // Converged when the undamped step's predicted decrease `g^T H^-1 g` is negligible.
        if let Some(chol) = h.cholesky()
            && g.dot(&chol.solve(&g)) <= 1e-8_f64.max(1e-12 * c)
        {
            break;
        }
        let mut accepted = false;
        for _ in 0..16 {
            let mut damped = h;
            for i in 0..9 {
                damped[(i, i)] += floor + mu * h[(i, i)].abs().max(floor);
            }
            if let Some(chol) = damped.cholesky() {
                let step = chol.solve(&g);
                let trial = SampleMotion {
                    f_m_s2: m.f_m_s2 + step.fixed_rows::<3>(0),
                    alpha_rad_s2: m.alpha_rad_s2 + step.fixed_rows::<3>(3),
                    omega_rad_s: m.omega_rad_s + step.fixed_rows::<3>(6),
                };
                let ct = cost(sensors, data, &trial);
                if ct <= c {
                    m = trial;
                    c = ct;
                    accepted = true;
                    mu = if mu > 1e-6 { mu * 0.1 } else { 0.0 };
                    break;
                }
            }
            mu = if mu > 0.0 { mu * 10.0 } else { 1e-4 };
        }
        if !accepted || dim == 6 {
            break;
        }
    }
    (m, c)
}

/// One output's share of the residual's curvature in the rate, `-w r d2_rate` (`weighted_residual`
/// is `w r`). Summed over a sample's used outputs, it is what the Newton matrix of the sample's
/// motion adds to the Gauss-Newton one in the rate's block (the outputs are linear in the specific
/// force and angular acceleration, so the other blocks have none). Summed where the residuals are
/// computed anyway (here and in the joint fit's elimination).
pub fn rate_curvature(sensor: &Sensor, weighted_residual: f64) -> Matrix3<f64> {
    -(sensor.d2_rate() * weighted_residual)
}

/// The Gauss-Newton rate block plus the residual's curvature: `(Some(sum), sum)` where the sum is
/// positive definite (what the solve and the joint fit's elimination use), `(None, sum)` where it
/// is not (both keep the Gauss-Newton block).
pub fn newton_rate_block(
    gauss_newton: &Matrix3<f64>,
    curvature: &Matrix3<f64>,
) -> (Option<Matrix3<f64>>, Matrix3<f64>) {
    let sum = gauss_newton + curvature;
    (sum.cholesky().map(|_| sum), sum)
}

/// The fall of a sample's chi^2 that a move off a saddle must give to be kept ([`leave_saddle`]).
const SADDLE_GAIN: f64 = 25.0;

/// A motion off a saddle of the sample's misfit: where the rate's Newton block has a negative
/// eigenvalue, the rate moved along its eigenvector by the step (of a few tried) that lowers the
/// cost most, the linear unknowns re-solved with it. `None` where the block has no negative
/// curvature or no tried step lowers the cost.
///
/// The tried steps are scored on the misfit's profile along the line ([`LineProfile`]: the
/// linear unknowns eliminated in closed form), and only the best is solved for; where the
/// profile cannot be formed, each step is solved for.
fn leave_saddle(
    sensors: &[Sensor],
    data: &SampleData,
    m: &SampleMotion,
    c: f64,
    block: &Matrix3<f64>,
) -> Option<(SampleMotion, f64)> {
    let eig = block.symmetric_eigen();
    let (k, lam) = eig.eigenvalues.iter().copied().enumerate().min_by(|a, b| a.1.total_cmp(&b.1))?;
    if lam.is_nan() || lam >= 0.0 {
        return None;
    }
    let v = eig.eigenvectors.column(k).into_owned();
    let solved = |t: f64| solve(sensors, data, SampleMotion { omega_rad_s: m.omega_rad_s + v * t, ..*m }, true);
    // Kept only for a clear gain (a chi^2 fall above 25, five sigmas): where the rate is not
    // resolved at all (a flat array) a rate fitted to the noise alone lowers the chi^2 by about
    // its 3 unknowns, and must not be taken for one.
    let steps = SADDLE_STEPS.iter().flat_map(|&t| [t, -t]);
    let Some(profile) = LineProfile::new(sensors, data, m, &v) else {
        let mut best: Option<(SampleMotion, f64)> = None;
        for t in steps {
            let (trial, ct) = solved(t);
            if ct < best.as_ref().map_or(c - SADDLE_GAIN, |b| b.1) {
                best = Some((trial, ct));
            }
        }
        return best;
    };
    let mut best: Option<(f64, f64)> = None;
    for t in steps {
        let ct = profile.cost(t);
        if ct < best.map_or(c - SADDLE_GAIN, |b| b.1) {
            best = Some((t, ct));
        }
    }
    let (trial, ct) = solved(best?.0);
    (ct < c - SADDLE_GAIN).then_some((trial, ct))
}

/// The rate steps (rad/s, each taken both ways) [`leave_saddle`] tries.
const SADDLE_STEPS: [f64; 7] = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0];

/// A sample's misfit along the line `omega + t v` with the specific force and angular
/// acceleration re-solved at every `t`. The outputs are linear in those six unknowns, with
/// coefficients that do not depend on the rate, and quadratic in `t`: the residual is
/// `r - t d1 - t^2 d2` (`d1` the rate's derivative along `v`, `d2 = v^T H v / 2` with `H` the
/// output's second derivative in the rate). With the six unknowns eliminated by least squares
/// the misfit is the quartic `u^T G u`, `u = (1, -t, -t^2)`, `G` the Gram matrix of `(r, d1, d2)`
/// in the weighted metric projected off the unknowns' columns.
struct LineProfile {
    gram: Matrix3<f64>,
}

impl LineProfile {
    /// `None` where the six unknowns' normal matrix is not positive definite.
    fn new(sensors: &[Sensor], data: &SampleData, m: &SampleMotion, v: &Vector3<f64>) -> Option<Self> {
        let mut n = SMatrix::<f64, 6, 6>::zeros();
        let mut b = SMatrix::<f64, 6, 3>::zeros();
        let mut e = Matrix3::zeros();
        for (j, s) in sensors.iter().enumerate() {
            if !data.used[j] {
                continue;
            }
            let w = data.weights[j];
            let d = s.d_motion(m);
            let linear = SVector::<f64, 6>::from_column_slice(&d[..6]);
            let rate = Vector3::new(d[6], d[7], d[8]);
            let coefficients = Vector3::new(
                data.outputs[j] - s.output(&m.specific_force_m_s2(&s.position_m)),
                rate.dot(v),
                0.5 * v.dot(&(s.d2_rate() * v)),
            );
            n.ger(w, &linear, &linear, 1.0);
            b.ger(w, &linear, &coefficients, 1.0);
            e.ger(w, &coefficients, &coefficients, 1.0);
        }
        let chol = n.cholesky()?;
        Some(LineProfile { gram: e - b.transpose() * chol.solve(&b) })
    }

    /// The misfit at `omega + t v`, the linear unknowns re-solved.
    fn cost(&self, t: f64) -> f64 {
        let u = Vector3::new(1.0, -t, -t * t);
        u.dot(&(self.gram * u))
    }
}

/// The local normal matrix of a sample's motion (its inverse is the motion's covariance given
/// the sensor parameters): it reads which outputs are `used` and their `weights`, not the outputs.
pub fn information(sensors: &[Sensor], used: &[bool], weights: &[f64], m: &SampleMotion) -> SMatrix<f64, 9, 9> {
    let mut h = SMatrix::<f64, 9, 9>::zeros();
    for (j, s) in sensors.iter().enumerate() {
        if used[j] {
            let d = SVector::<f64, 9>::from(s.d_motion(m));
            h.ger(weights[j], &d, &d, 1.0);
        }
    }
    h
}

/// A first guess of the motion from the linear 12-unknown model (see the module docs).
pub fn linear_guess(sensors: &[Sensor], data: &SampleData) -> SampleMotion {
    let rows: Vec<usize> = (0..sensors.len()).filter(|&j| data.used[j]).collect();
    let mut a = DMatrix::zeros(rows.len(), 12);
    let mut y = DVector::zeros(rows.len());
    for (i, &j) in rows.iter().enumerate() {
        let s = &sensors[j];
        let sw = data.weights[j].sqrt();
        for c in 0..3 {
            a[(i, c)] = s.k * s.axis[c] * sw;
            for d in 0..3 {
                a[(i, 3 + 3 * c + d)] = s.k * s.axis[c] * s.position_m[d] * sw;
            }
        }
        y[i] = (data.outputs[j] - s.k * s.b_m_s2) * sw;
    }
    let Ok(x) = a.svd(true, true).solve(&y, 1e-10) else { return SampleMotion::default() };
    let full = Matrix3::from_row_slice(&x.as_slice()[3..12]);
    let sym = (full + full.transpose()) * 0.5;
    let anti = (full - full.transpose()) * 0.5;
    let eig = sym.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&p, &q| eig.eigenvalues[p].total_cmp(&eig.eigenvalues[q]));
    let w2 = (eig.eigenvalues[order[2]] - 0.5 * (eig.eigenvalues[order[0]] + eig.eigenvalues[order[1]])).max(0.0);
    let dir = eig.eigenvectors.column(order[2]).into_owned();
    SampleMotion {
        f_m_s2: Vector3::new(x[0], x[1], x[2]),
        alpha_rad_s2: Vector3::new(anti[(2, 1)], anti[(0, 2)], anti[(1, 0)]),
        omega_rad_s: dir * w2.sqrt(),
    }
}

/// Flips rate signs along a run of consecutive samples so that each rate is the one closer to
/// its prediction, then flips the whole run if its rate increments disagree with the angular
/// accelerations.
///
/// The prediction is the last *strong* rate (at least half the run's median rate) advanced by the
/// angular accelerations since (trapezoid rule). The angular acceleration is seen linearly (the
/// tangential terms) and is accurate at any rate, while the rate's direction is poorly resolved
/// where the rate is low (the centripetal terms go as its square): chaining each sample to its
/// neighbour let one noisy low-rate sample flip the rest of the run, bridging low-rate stretches
/// with the accelerations does not.
pub fn orient_run(t_s: &[f64], motion: &mut [SampleMotion]) {
    if motion.is_empty() {
        return;
    }
    let mut norms: Vec<f64> = motion.iter().map(|m| m.omega_rad_s.norm()).collect();
    norms.sort_by(f64::total_cmp);
    let strong = 0.5 * norms[norms.len() / 2];
    let mut anchor = motion[0].omega_rad_s;
    for i in 1..motion.len() {
        anchor += (motion[i - 1].alpha_rad_s2 + motion[i].alpha_rad_s2) * (0.5 * (t_s[i] - t_s[i - 1]));
        let w = motion[i].omega_rad_s;
        if (w - anchor).norm_squared() > (-w - anchor).norm_squared() {
            motion[i].omega_rad_s = -w;
        }
        if w.norm() >= strong {
            anchor = motion[i].omega_rad_s;
        }
    }
    let mut agreement = 0.0;
    for i in 1..motion.len() {
        let dt = t_s[i] - t_s[i - 1];
        let dw = motion[i].omega_rad_s - motion[i - 1].omega_rad_s;
        agreement += dw.dot(&(motion[i - 1].alpha_rad_s2 + motion[i].alpha_rad_s2)) * (0.5 * dt);
    }
    if agreement < 0.0 {
        for m in motion.iter_mut() {
            m.omega_rad_s = -m.omega_rad_s;
        }
    }
}

/// A diagonal of a sample's motion information below this share of its largest is a direction
/// the sample does not observe. The rate's at a rate that collapsed to zero: a simulated sample's
/// fitted rate reached 1e-161 rad/s, whose diagonal (about 1e-322) scaled the rest by 1e161 and
/// gave the Schur complement infinities (`selfcal::fit`'s covariance then failed as singular).
pub const UNOBSERVED_DIAGONAL: f64 = f64::EPSILON * f64::EPSILON;

/// Which of a sample's motion directions its information observes: a diagonal above
/// [`UNOBSERVED_DIAGONAL`] of the largest.
pub fn observed(hll: &SMatrix<f64, 9, 9>) -> [bool; 9] {
    let largest = hll.diagonal().max();
    std::array::from_fn(|k| hll[(k, k)] > UNOBSERVED_DIAGONAL * largest)
}

/// Inverse of one sample's motion information (the 9 x 9 normal matrix, [`information`]), or its pseudo-inverse when some motion direction
/// is not observed (a column whose diagonal is zero or below [`UNOBSERVED_DIAGONAL`] of the
/// largest, or an eigenvalue below `1e-12` of the largest after scaling by the diagonal).
pub fn information_inverse(hll: &SMatrix<f64, 9, 9>) -> SMatrix<f64, 9, 9> {
    let seen = observed(hll);
    let d = SVector::<f64, 9>::from_fn(|k, _| if seen[k] { 1.0 / hll[(k, k)].sqrt() } else { 0.0 });
    // `D X D` for the diagonal `D`, element by element: `(d_i x_ij) d_j`, the value the two
    // matrix products give (their other terms are exact zeros), without the products.
    let both_sides = |x: &SMatrix<f64, 9, 9>| SMatrix::<f64, 9, 9>::from_fn(|i, j| d[i] * x[(i, j)] * d[j]);
    let scaled = both_sides(hll);
    let full = d.iter().all(|&v| v > 0.0);
    if full && let Some(chol) = scaled.cholesky() {
        let l = chol.l();
        let diag_min = l.diagonal().iter().fold(f64::INFINITY, |a, &b| a.min(b * b));
        if diag_min > 1e-12 {
            return both_sides(&chol.inverse());
        }
    }
    let dm = SMatrix::<f64, 9, 9>::from_diagonal(&d);
    let eig = scaled.symmetric_eigen();
    let max = eig.eigenvalues.iter().fold(0.0_f64, |a, &b| a.max(b));
    let mut inv = SMatrix::<f64, 9, 9>::zeros();
    for (k, &lam) in eig.eigenvalues.iter().enumerate() {
        if lam > 1e-12 * max {
            let v = eig.eigenvectors.column(k);
            inv += v * v.transpose() / lam;
        }
    }
    dm * inv * dm
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eight packages of three axes at the corners of a 20 x 20 x 2 mm board (the MIMU4444's
    /// shape), unit scale factors, no biases.
    fn board() -> Vec<Sensor> {
        let mut out = Vec::new();
        for &(x, y, z) in &[(1.0, 1.0, 1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0), (1.0, -1.0, -1.0)] {
            for side in [1.0, -1.0] {
                let position_m = Vector3::new(0.01 * x * side, 0.01 * y, 0.001 * z * side);
                for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
                    out.push(Sensor { k: 1.0, b_m_s2: 0.0, axis, daxis: [Vector3::zeros(); 2], position_m });
                }
            }
        }
        out
    }

    /// The rate's second derivative of an output against central differences of its first
    /// derivative (`d_motion`'s rate part), at a few rates.
    #[test]
    fn the_rate_curvature_matches_central_differences() {
        let sensors = board();
        for w in [Vector3::new(3.0, -2.0, 5.0), Vector3::new(0.0, 0.0, 0.0), Vector3::new(-20.0, 7.0, 1.0)] {
            let m = SampleMotion {
                f_m_s2: Vector3::new(1.0, 2.0, 9.0),
                alpha_rad_s2: Vector3::new(50.0, -30.0, 10.0),
                omega_rad_s: w,
            };
            for s in &sensors {
                let exact = s.d2_rate();
                for e in 0..3 {
                    let h = 1e-4;
                    let mut up = m;
                    up.omega_rad_s[e] += h;
                    let mut down = m;
                    down.omega_rad_s[e] -= h;
                    let (du, dd) = (s.d_motion(&up), s.d_motion(&down));
                    for c in 0..3 {
                        let fd = (du[6 + c] - dd[6 + c]) / (2.0 * h);
                        assert!((fd - exact[(c, e)]).abs() < 1e-9, "{fd} vs {}", exact[(c, e)]);
                    }
                }
            }
        }
    }

    /// The misfit's profile along a rate line against the solve of the linear unknowns at each
    /// point (the misfit itself, evaluated from the model's outputs), on outputs off any rigid
    /// motion, in both directions and out to the farthest step tried.
    #[test]
    fn the_line_profile_is_the_misfit_with_the_linear_unknowns_resolved() {
        let sensors = board();
        let outputs: Vec<f64> = (0..sensors.len()).map(|j| 3.0 * ((j as f64) * 1.7).sin() + 9.0).collect();
        let used: Vec<bool> = (0..sensors.len()).map(|j| j != 5).collect();
        let weights: Vec<f64> = (0..sensors.len()).map(|j| 1e3 * (1.0 + 0.1 * j as f64)).collect();
        let data = SampleData { outputs: &outputs, used: &used, weights: &weights };
        let m = SampleMotion {
            f_m_s2: Vector3::new(1.0, -2.0, 9.0),
            alpha_rad_s2: Vector3::new(40.0, 10.0, -25.0),
            omega_rad_s: Vector3::new(2.0, -1.0, 3.0),
        };
        let v = Vector3::new(0.3, -0.8, 0.5).normalize();
        let profile = LineProfile::new(&sensors, &data, &m, &v).expect("resolved");
        for t in [0.0, 0.5, -2.0, 7.5, -32.0] {
            let start = SampleMotion { omega_rad_s: m.omega_rad_s + v * t, ..m };
            let (_, solved) = solve(&sensors, &data, start, true);
            let read = profile.cost(t);
            assert!((read - solved).abs() <= 1e-9 * solved, "t = {t}: profile {read} vs solve {solved}");
        }
    }

    /// A sample started at exactly zero rate (where the linear first guess finds no centripetal
    /// term) is at a saddle of its misfit: the rate's gradient vanishes there, so Gauss-Newton
    /// alone never leaves it. The solve finds the true motion (the rate up to its sign, which the
    /// outputs do not carry) from noise-free outputs, to the solve's stopping rule (a chi^2
    /// decrease below 1e-8: here about 1e-5 of the rate's sigma).
    #[test]
    fn a_sample_started_at_zero_rate_leaves_the_saddle() {
        let sensors = board();
        let truth = SampleMotion {
            f_m_s2: Vector3::new(2.0, -1.0, 9.5),
            alpha_rad_s2: Vector3::new(120.0, -80.0, 40.0),
            omega_rad_s: Vector3::new(4.0, -3.0, 6.0),
        };
        let outputs: Vec<f64> = sensors.iter().map(|s| s.output(&truth.specific_force_m_s2(&s.position_m))).collect();
        let used = vec![true; sensors.len()];
        let weights = vec![1.0 / 0.04_f64.powi(2); sensors.len()];
        let data = SampleData { outputs: &outputs, used: &used, weights: &weights };
        let start = SampleMotion { omega_rad_s: Vector3::zeros(), ..truth };
        let (m, c) = solve(&sensors, &data, start, false);
        let w_err = (m.omega_rad_s - truth.omega_rad_s).norm().min((m.omega_rad_s + truth.omega_rad_s).norm());
        assert!(w_err < 1e-4, "rate {:?}, cost {c}", m.omega_rad_s);
        assert!((m.alpha_rad_s2 - truth.alpha_rad_s2).norm() < 1e-3, "{:?}", m.alpha_rad_s2);
        assert!((m.f_m_s2 - truth.f_m_s2).norm() < 1e-5, "{:?}", m.f_m_s2);
        assert!(c < 1e-8, "{c}");
    }

    /// A rate collapsed to (almost) zero leaves the rate unobserved: the pseudo-inverse is finite
    /// and is, on the specific force and angular acceleration, the inverse of their own block (at
    /// exactly zero rate the rate's columns vanish, so the two blocks are uncoupled). At 1e-161
    /// rad/s (a rate seen in a simulated calibration) the rate's diagonal is about 1e-322 and,
    /// taken as observed, scaled the rest by 1e161 into infinities.
    #[test]
    fn a_rate_collapsed_to_zero_is_an_unobserved_direction() {
        let sensors = board();
        let used = vec![true; sensors.len()];
        let weights = vec![1.0 / 0.04_f64.powi(2); sensors.len()];
        let at = |w: f64| SampleMotion {
            f_m_s2: Vector3::new(2.0, -1.0, 9.5),
            alpha_rad_s2: Vector3::new(120.0, -80.0, 40.0),
            omega_rad_s: Vector3::new(2.5, -5.5, 6.8) * w,
        };
        let zero = information(&sensors, &used, &weights, &at(0.0));
        let exact = zero.fixed_view::<6, 6>(0, 0).into_owned().try_inverse().expect("f and alpha are observed");
        let inv = information_inverse(&information(&sensors, &used, &weights, &at(1e-161)));
        assert!(inv.iter().all(|v| v.is_finite()));
        let block = inv.fixed_view::<6, 6>(0, 0).into_owned();
        assert!((block - exact).norm() <= 1e-9 * exact.norm(), "{block} against {exact}");
        assert!(inv.fixed_view::<3, 9>(6, 0).norm() == 0.0);
    }
}
