//! Small linear least squares by normal equations (2–8 unknowns, and the
//! tissue-motion fit's steps of at most 36), the only regression the fits
//! need. Written here: pulling a linear-algebra crate in for 3×3 systems
//! would cost more build time than these lines.

/// Accumulates `y ≈ Σ c_k·φ_k` and solves for `c`.
#[derive(Clone, Debug)]
pub struct Lsq<const N: usize> {
    ata: [[f64; N]; N],
    aty: [f64; N],
    yy: f64,
}

impl<const N: usize> Default for Lsq<N> {
    fn default() -> Self {
        Self {
            ata: [[0.0; N]; N],
            aty: [0.0; N],
            yy: 0.0,
        }
    }
}

impl<const N: usize> Lsq<N> {
    /// From sums already made: ΦᵀΦ (symmetric; its upper triangle is
    /// read), Φᵀy, yᵀy.
    pub fn from_sums(ata: [[f64; N]; N], aty: [f64; N], yy: f64) -> Self {
        Self { ata, aty, yy }
    }

    /// One row. Only ΦᵀΦ's upper triangle is summed ([`Self::gram`]
    /// mirrors it), and a zero in `phi` adds nothing: the tissue-motion
    /// fit's rows are half zeros, and this was most of its time.
    pub fn add(&mut self, phi: [f64; N], y: f64) {
        for (i, &p) in phi.iter().enumerate() {
            if p == 0.0 {
                continue;
            }
            for (a, q) in self.ata[i][i..].iter_mut().zip(&phi[i..]) {
                *a += p * q;
            }
            self.aty[i] += p * y;
        }
        self.yy += y * y;
    }

    /// Rows all at once, every term of each summed, zeros too: for finite
    /// rows the same sums as [`Self::add`] (a zero term adds an exact zero
    /// to a sum that starts at +0), on copies held through the loop,
    /// which the compiler keeps out of memory where `add` stores them a
    /// row at a time. For short rows with few zeros.
    pub fn add_all(&mut self, rows: impl Iterator<Item = ([f64; N], f64)>) {
        let (mut ata, mut aty, mut yy) = (self.ata, self.aty, self.yy);
        for (phi, y) in rows {
            for i in 0..N {
                for j in i..N {
                    ata[i][j] += phi[i] * phi[j];
                }
                aty[i] += phi[i] * y;
            }
            yy += y * y;
        }
        (self.ata, self.aty, self.yy) = (ata, aty, yy);
    }

    /// The sums made: ΦᵀΦ (its upper triangle), Φᵀy, yᵀy — for
    /// [`Self::from_sums`] to build a larger system on.
    pub fn sums(&self) -> ([[f64; N]; N], [f64; N], f64) {
        (self.ata, self.aty, self.yy)
    }

    /// ΦᵀΦ, its lower triangle mirrored from the upper.
    fn gram(&self) -> [[f64; N]; N] {
        let mut m = self.ata;
        for (i, row) in m.iter_mut().enumerate() {
            for (j, a) in row.iter_mut().enumerate().take(i) {
                *a = self.ata[j][i];
            }
        }
        m
    }

    /// The coefficients, or `None` when the system is singular.
    pub fn solve(&self) -> Option<[f64; N]> {
        let mut m = self.gram();
        let mut b = self.aty;
        for col in 0..N {
            let pivot = (col..N).max_by(|&a, &c| m[a][col].abs().total_cmp(&m[c][col].abs()))?;
            let scale = m.iter().map(|r| r[col].abs()).fold(0.0, f64::max);
            if m[pivot][col].abs() <= 1e-12 * scale.max(f64::MIN_POSITIVE) {
                return None;
            }
            m.swap(col, pivot);
            b.swap(col, pivot);
            for row in 0..N {
                if row != col {
                    let k = m[row][col] / m[col][col];
                    let pivot_row = m[col];
                    for (mj, pj) in m[row].iter_mut().zip(pivot_row).skip(col) {
                        *mj -= k * pj;
                    }
                    b[row] -= k * b[col];
                }
            }
        }
        Some(std::array::from_fn(|i| b[i] / m[i][i]))
    }

    /// Levenberg–Marquardt's step: the first `free` coefficients solved
    /// with each diagonal term raised by `lambda` times itself (the rest
    /// held at 0), or `None` when singular even so.
    pub fn solve_damped(&self, lambda: f64, free: usize) -> Option<[f64; N]> {
        let mut damped = Self {
            ata: self.gram(),
            ..self.clone()
        };
        for i in 0..N {
            if i < free {
                let d = self.ata[i][i];
                damped.ata[i][i] = d + lambda * d.max(f64::MIN_POSITIVE);
            } else {
                damped.ata[i] = [0.0; N];
                for row in &mut damped.ata {
                    row[i] = 0.0;
                }
                damped.ata[i][i] = 1.0;
                damped.aty[i] = 0.0;
            }
        }
        damped.solve()
    }

    /// One Levenberg–Marquardt step on the first `unknowns`: the damping
    /// raised tenfold until `try_delta`'s step (its new state and loss)
    /// lowers `loss`, then lowered tenfold; `None` when no step does by a
    /// damping of 10⁶.
    pub fn damped_step<T>(
        &self,
        unknowns: usize,
        lambda: &mut f64,
        loss: f64,
        mut try_delta: impl FnMut(&[f64; N]) -> (T, f64),
    ) -> Option<(T, f64)> {
        while *lambda < 1e6 {
            let Some(delta) = self.solve_damped(*lambda, unknowns) else {
                *lambda *= 10.0;
                continue;
            };
            let (next, loss_next) = try_delta(&delta);
            if loss_next < loss {
                *lambda = (*lambda / 10.0).max(1e-9);
                return Some((next, loss_next));
            }
            *lambda *= 10.0;
        }
        None
    }

    /// Sum of squared residuals at `c` (from the accumulated sums).
    pub fn sse(&self, c: &[f64; N]) -> f64 {
        let ata = self.gram();
        let mut s = self.yy;
        for i in 0..N {
            s -= 2.0 * c[i] * self.aty[i];
            for j in 0..N {
                s += c[i] * c[j] * ata[i][j];
            }
        }
        s.max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_an_exact_quadratic_and_refuses_a_singular_system() {
        let mut lsq = Lsq::<3>::default();
        for i in 0..20 {
            let x = i as f64 * 0.001;
            lsq.add([1.0, x, x * x], 0.5 - 3.0 * x + 5200.0 * x * x);
        }
        let c = lsq.solve().unwrap();
        assert!(
            (c[0] - 0.5).abs() < 1e-9 && (c[1] + 3.0).abs() < 1e-6 && (c[2] - 5200.0).abs() < 1e-3
        );
        assert!(lsq.sse(&c) < 1e-12);
        let mut flat = Lsq::<2>::default();
        for _ in 0..5 {
            flat.add([1.0, 1.0], 2.0);
        }
        assert!(flat.solve().is_none());
    }

    #[test]
    fn a_damped_step_shrinks_toward_zero_and_holds_the_unfree_at_zero() {
        let mut lsq = Lsq::<3>::default();
        for i in 0..20 {
            let x = i as f64 * 0.1;
            lsq.add([1.0, x, x * x], 2.0 + 0.5 * x - 0.25 * x * x);
        }
        let exact = lsq.solve().unwrap();
        let barely = lsq.solve_damped(1e-12, 3).unwrap();
        assert!((0..3).all(|k| (exact[k] - barely[k]).abs() < 1e-6));
        let heavy = lsq.solve_damped(1e6, 3).unwrap();
        assert!(heavy.iter().all(|c| c.abs() < 1e-3), "{heavy:?}");
        let two = lsq.solve_damped(1e-12, 2).unwrap();
        assert_eq!(two[2], 0.0);
    }

    /// `add_all` is a faster `add`, not another sum: bit for bit the same
    /// normal equations on rows with zeros (of either sign) and negative
    /// terms.
    #[test]
    fn all_rows_at_once_sum_as_one_at_a_time() {
        let rows: Vec<([f64; 4], f64)> = (0..50)
            .map(|k| {
                let x = 0.37 * k as f64 - 4.0;
                let zero_or = |on: bool, v: f64| if on { v } else { 0.0 };
                (
                    [
                        zero_or(k % 3 != 0, x.sin()),
                        zero_or(k % 2 == 0, -x),
                        1.0 / 3.0,
                        if k % 7 == 0 {
                            -0.0
                        } else {
                            zero_or(k % 5 < 2, x * x * 1e-3)
                        },
                    ],
                    (0.3 * x).cos() - 0.1,
                )
            })
            .collect();
        let (mut one, mut all) = (Lsq::<4>::default(), Lsq::<4>::default());
        for &(phi, y) in &rows {
            one.add(phi, y);
        }
        all.add_all(rows.iter().copied());
        let bits = |l: &Lsq<4>| {
            let mut b: Vec<u64> = l.gram().iter().flatten().map(|v| v.to_bits()).collect();
            b.extend(l.aty.iter().map(|v| v.to_bits()));
            b.push(l.yy.to_bits());
            b
        };
        assert_eq!(bits(&one), bits(&all));
    }
}
