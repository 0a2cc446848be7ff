//! Linear fits of candidate terms to the residual, scored on withheld
//! trials (k-fold by trial, never by sample).
//!
//! Each candidate adds `Σ θ_k φ_k` to the nominal model; φ are its columns
//! (from its physics, with one nonlinear parameter on a grid), θ its
//! linear parameters. Per trial and phase we keep the Gram sums (ΦᵀΦ, Φᵀr,
//! rᵀr), so fitting on any set of trials and scoring any other is a sum and
//! a small solve. Written here: a dense solve of ≤ 6 unknowns does not
//! justify a linear-algebra crate.

/// Gram sums of columns φ and the residual r over some samples.
#[derive(Clone, Debug, PartialEq)]
pub struct Gram {
    pub n: usize,
    pub ata: Vec<f64>,
    pub aty: Vec<f64>,
    pub yy: f64,
    pub count: usize,
}

impl Gram {
    pub fn new(n: usize) -> Self {
        Self {
            n,
            ata: vec![0.0; n * n],
            aty: vec![0.0; n],
            yy: 0.0,
            count: 0,
        }
    }

    pub fn add(&mut self, phi: &[f64], y: f64) {
        for i in 0..self.n {
            for j in 0..self.n {
                self.ata[i * self.n + j] += phi[i] * phi[j];
            }
            self.aty[i] += phi[i] * y;
        }
        self.yy += y * y;
        self.count += 1;
    }

    /// The same sums with `extra` columns appended, their sums zero.
    pub fn with_columns(&self, extra: usize) -> Gram {
        let n = self.n + extra;
        let mut g = Gram::new(n);
        for i in 0..self.n {
            g.ata[i * n..i * n + self.n].copy_from_slice(&self.ata[i * self.n..(i + 1) * self.n]);
        }
        g.aty[..self.n].copy_from_slice(&self.aty);
        g.yy = self.yy;
        g.count = self.count;
        g
    }

    pub fn merge(&mut self, other: &Gram) {
        for (a, b) in self.ata.iter_mut().zip(&other.ata) {
            *a += b;
        }
        for (a, b) in self.aty.iter_mut().zip(&other.aty) {
            *a += b;
        }
        self.yy += other.yy;
        self.count += other.count;
    }

    /// Squared error of r − Φθ.
    pub fn sse(&self, theta: &[f64]) -> f64 {
        let n = self.n;
        let mut quad = 0.0;
        for i in 0..n {
            for j in 0..n {
                quad += theta[i] * self.ata[i * n + j] * theta[j];
            }
        }
        let lin: f64 = theta.iter().zip(&self.aty).map(|(t, a)| t * a).sum();
        (self.yy - 2.0 * lin + quad).max(0.0)
    }

    /// Least-squares θ, with a ridge of 1e-9 of the diagonal's scale so an
    /// all-zero column (an effect with nothing to act on) gives θ = 0.
    pub fn solve(&self) -> Vec<f64> {
        let n = self.n;
        let mut m = self.ata.clone();
        let mut b = self.aty.clone();
        for i in 0..n {
            m[i * n + i] += 1e-9 * m[i * n + i].abs() + 1e-300;
        }
        for col in 0..n {
            let pivot = (col..n)
                .max_by(|&a, &c| m[a * n + col].abs().total_cmp(&m[c * n + col].abs()))
                .unwrap_or(col);
            for k in 0..n {
                m.swap(col * n + k, pivot * n + k);
            }
            b.swap(col, pivot);
            let p = m[col * n + col];
            if p.abs() < 1e-300 {
                continue;
            }
            for r in 0..n {
                if r != col {
                    let f = m[r * n + col] / p;
                    for k in 0..n {
                        m[r * n + k] -= f * m[col * n + k];
                    }
                    b[r] -= f * b[col];
                }
            }
        }
        (0..n)
            .map(|i| {
                let p = m[i * n + i];
                if p.abs() < 1e-300 {
                    0.0
                } else {
                    b[i] / p
                }
            })
            .collect()
    }
}

/// Folds: trial `j` is withheld in fold `j % k`.
pub fn folds(trials: usize) -> usize {
    trials.clamp(2, 5)
}

/// Paired t statistic of per-trial improvements (baseline − candidate
/// held-out mean squares): large and positive when the candidate helps on
/// nearly every withheld trial, not just on a few.
pub fn paired_t(improvements: &[f64]) -> f64 {
    let n = improvements.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let mean = improvements.iter().sum::<f64>() / n;
    let var = improvements.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0);
    if var <= 0.0 {
        return if mean > 0.0 { f64::INFINITY } else { 0.0 };
    }
    mean / (var / n).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_linear_coefficients_and_zero_for_an_empty_column() {
        let mut g = Gram::new(3);
        for i in 0..100 {
            let x = i as f64 * 0.1;
            g.add(&[x, 1.0, 0.0], 2.0 * x - 3.0);
        }
        let th = g.solve();
        assert!((th[0] - 2.0).abs() < 1e-6 && (th[1] + 3.0).abs() < 1e-6 && th[2] == 0.0);
        assert!(g.sse(&th) < 1e-8);
        assert!((g.sse(&[0.0; 3]) - g.yy).abs() < 1e-9);
    }
}
