//! Nominal array geometry: the paper's cube (Hung & Lee 2006, Table 1) or any N >= 6 layout.

use nalgebra::Vector3;

use super::mechanization::{Mechanization, RankError};

/// One single-axis accelerometer of the nominal design.
#[derive(Debug, Clone, PartialEq)]
pub struct Accelerometer {
    /// Nominal position in the body frame, m.
    pub position_m: Vector3<f64>,
    /// Nominal sensitive axis in the body frame, unit length.
    pub axis: Vector3<f64>,
}

/// Why an array description was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ArrayError {
    #[error("an array needs at least 6 accelerometers to sense 6 rigid-body accelerations, got {count}")]
    TooFew { count: usize },
    #[error("accelerometer {index}: {what} is not finite")]
    NonFinite { index: usize, what: &'static str },
    #[error("accelerometer {index}: sensitive axis has zero length")]
    ZeroAxis { index: usize },
    #[error("triad {triad}: {problem}")]
    BadTriad { triad: usize, problem: String },
    #[error(transparent)]
    Degenerate(#[from] RankError),
}

/// A nominal accelerometer array (1-based accelerometer numbers appear only in messages and files).
#[derive(Debug, Clone)]
pub struct Array {
    name: String,
    accelerometers: Vec<Accelerometer>,
    /// Triads of linearly independent axes (0-based indices), used by the paper's misalignment form.
    triads: Vec<[usize; 3]>,
    mechanization: Mechanization,
}

impl Array {
    /// Builds an array from nominal positions (m) and axes (normalised here), checking that it can
    /// sense every rigid-body acceleration.
    ///
    /// ```
    /// use gfcal::array::Array;
    /// let cube = Array::cube(0.1).unwrap();
    /// assert_eq!(cube.len(), 6);
    /// ```
    pub fn new(
        name: impl Into<String>,
        positions_m: &[Vector3<f64>],
        axes: &[Vector3<f64>],
        triads: Vec<[usize; 3]>,
    ) -> Result<Self, ArrayError> {
        assert_eq!(positions_m.len(), axes.len(), "one axis per position");
        let count = positions_m.len();
        if count < 6 {
            return Err(ArrayError::TooFew { count });
        }
        let mut accelerometers = Vec::with_capacity(count);
        for (j, (p, a)) in positions_m.iter().zip(axes).enumerate() {
            let index = j + 1;
            if !p.iter().all(|v| v.is_finite()) {
                return Err(ArrayError::NonFinite { index, what: "position" });
            }
            if !a.iter().all(|v| v.is_finite()) {
                return Err(ArrayError::NonFinite { index, what: "sensitive axis" });
            }
            let norm = a.norm();
            if norm < 1e-12 {
                return Err(ArrayError::ZeroAxis { index });
            }
            accelerometers.push(Accelerometer { position_m: *p, axis: a / norm });
        }
        let mut in_triad = vec![false; count];
        for (t, triad) in triads.iter().enumerate() {
            check_triad(t + 1, triad, &accelerometers)?;
            for &k in triad {
                if std::mem::replace(&mut in_triad[k], true) {
                    return Err(ArrayError::BadTriad {
                        triad: t + 1,
                        problem: format!("accelerometer {} already belongs to another triad", k + 1),
                    });
                }
            }
        }
        let positions: Vec<_> = accelerometers.iter().map(|a| a.position_m).collect();
        let unit_axes: Vec<_> = accelerometers.iter().map(|a| a.axis).collect();
        let mechanization = Mechanization::new(&positions, &unit_axes)?;
        Ok(Self { name: name.into(), accelerometers, triads, mechanization })
    }

    /// The six-accelerometer cube of Chen, Lee & DeBra (1994) as in Hung & Lee (2006), Table 1:
    /// one accelerometer at the centre of each face, distance `rho_m` from the centre, axis along a
    /// face diagonal. Triads A = (1, 4, 6) and B = (2, 3, 5) (paper Sections 3.1-3.2).
    pub fn cube(rho_m: f64) -> Result<Self, ArrayError> {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let p =
            [[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let th =
            [[1.0, 1.0, 0.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, -1.0, 1.0], [-1.0, 0.0, 1.0], [-1.0, 1.0, 0.0]];
        let positions: Vec<_> = p.iter().map(|v| Vector3::from(*v) * rho_m).collect();
        let axes: Vec<_> = th.iter().map(|v| Vector3::from(*v) * s).collect();
        Self::new("cube", &positions, &axes, vec![[0, 3, 5], [1, 2, 4]])
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    pub fn len(&self) -> usize {
        self.accelerometers.len()
    }
    pub fn is_empty(&self) -> bool {
        self.accelerometers.is_empty()
    }
    pub fn accelerometers(&self) -> &[Accelerometer] {
        &self.accelerometers
    }
    pub fn positions_m(&self) -> Vec<Vector3<f64>> {
        self.accelerometers.iter().map(|a| a.position_m).collect()
    }
    pub fn axes(&self) -> Vec<Vector3<f64>> {
        self.accelerometers.iter().map(|a| a.axis).collect()
    }
    /// Triads of linearly independent axes (0-based), empty when the array defines none.
    pub fn triads(&self) -> &[[usize; 3]] {
        &self.triads
    }
    /// The mechanization of the nominal geometry.
    pub fn mechanization(&self) -> &Mechanization {
        &self.mechanization
    }
    /// The triad holding accelerometer `j` (0-based) and its row in that triad.
    pub fn triad_of(&self, j: usize) -> Option<(usize, usize)> {
        self.triads.iter().enumerate().find_map(|(t, tr)| tr.iter().position(|&k| k == j).map(|row| (t, row)))
    }
}

fn check_triad(t: usize, triad: &[usize; 3], accs: &[Accelerometer]) -> Result<(), ArrayError> {
    let bad = |problem: String| ArrayError::BadTriad { triad: t, problem };
    for &k in triad {
        if k >= accs.len() {
            return Err(bad(format!("accelerometer {} does not exist (array has {})", k + 1, accs.len())));
        }
    }
    if triad[0] == triad[1] || triad[0] == triad[2] || triad[1] == triad[2] {
        return Err(bad("an accelerometer appears twice".into()));
    }
    let m = nalgebra::Matrix3::from_columns(&[accs[triad[0]].axis, accs[triad[1]].axis, accs[triad[2]].axis]);
    if m.determinant().abs() < 1e-6 {
        return Err(bad(format!(
            "axes of accelerometers {}, {}, {} are not linearly independent",
            triad[0] + 1,
            triad[1] + 1,
            triad[2] + 1
        )));
    }
    Ok(())
}
