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

    /// Column `k` taken out of the sums: [`Self::solve`] gives it θ 0.
    pub fn leave_out(&mut self, k: usize) {
        for j in 0..self.n {
            self.ata[k * self.n + j] = 0.0;
            self.ata[j * self.n + k] = 0.0;
        }
        self.aty[k] = 0.0;
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
    /// all-zero column (an effect with nothing to act on) gives θ = 0. A
    /// column absent from these samples but for rounding (its sum of
    /// squares under [`ABSENT_SS`]) gets θ = 0 too: its θ would be a
    /// ratio of rounding errors, and the trials it is present in would
    /// be scored with that.
    pub fn solve(&self) -> Vec<f64> {
        let n = self.n;
        let mut m = self.ata.clone();
        let mut b = self.aty.clone();
        for i in 0..n {
            if m[i * n + i] <= ABSENT_SS {
                for k in 0..n {
                    m[i * n + k] = 0.0;
                    m[k * n + i] = 0.0;
                }
                b[i] = 0.0;
            }
        }
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

/// A column's sum of squares at or under which it is absent from the
/// samples summed (in its own units squared: the smallest column that
/// means something, a friction basis v·l at 0.1 mm/s and 1 mm in, sums
/// to 1e-14 a sample; a cutting odds of e^-100 a sample, rounding, to
/// 1e-47). A trial with no puncture has no cutting and no friction
/// ahead: a fold without the one trial that has them would otherwise
/// fit their corrections to rounding (θ of 1e22–1e26) and score that
/// trial with them.
pub const ABSENT_SS: f64 = 1e-30;

/// Relative ridge on the shared columns once the trials' own are taken out.
const RIDGE: f64 = 1e-3;

/// Least squares with some columns free per trial (the trial-to-trial
/// spread of a tissue: each insertion meets its own stiffness, cutting
/// force and friction) and the rest shared: the shared θ from the
/// training trials' sums with each trial's own columns eliminated (its
/// Schur complement), and a trial's own values given the shared ones.
#[derive(Clone, Debug)]
pub struct PerTrial<'a> {
    /// Indices of the columns fitted per trial.
    pub own: &'a [usize],
    /// The first this many columns (the nominal's corrections) get the
    /// ridge; a candidate's own columns never do.
    pub ridged: usize,
    /// Shared columns whose θ the physics signs: fitted under θ ≥ 0,
    /// exactly (the best of the fits leaving out each set of them).
    pub non_negative: &'a [usize],
}

impl PerTrial<'_> {
    fn shared(&self, n: usize) -> Vec<usize> {
        (0..n).filter(|i| !self.own.contains(i)).collect()
    }

    /// The shared θ (full length, the per-trial entries 0) from the
    /// trials' whole-trial sums.
    pub fn solve_shared(&self, trials: &[&Gram]) -> Vec<f64> {
        let n = trials.first().map_or(0, |g| g.n);
        let reduced: Vec<Gram> = trials.iter().map(|g| self.reduced(g)).collect();
        self.fit_reduced(n, &reduced).1
    }

    /// One trial's whole-trial sums over the shared columns with its own
    /// columns taken out (their Schur complement), for
    /// [`Self::fit_reduced`]: a search that fits many sets of the same
    /// trials reduces each trial once.
    pub fn reduced(&self, g: &Gram) -> Gram {
        self.reduce(g, &self.shared(g.n))
    }

    /// The shared θ (full length `n`, the per-trial entries 0) from the
    /// trials' [`Self::reduced`] sums, and the trials' squared error under
    /// it, each with its own columns at their best (the summed reduced
    /// sums' error: what [`Self::for_trial`] leaves, but for the 1e-9
    /// ridge the own columns are solved with).
    pub fn fit_reduced<'g>(
        &self,
        n: usize,
        trials: impl IntoIterator<Item = &'g Gram>,
    ) -> (f64, Vec<f64>) {
        let shared = self.shared(n);
        let mut reduced = Gram::new(shared.len());
        for g in trials {
            reduced.merge(g);
        }
        let mut ridged = reduced.clone();
        // The trials' own columns are near some combination of the
        // shared ones in every trial (the friction scale is nearly the
        // friction basis at the nominal's coefficients): that direction
        // is left to the own columns, not fitted from rounding.
        let s = shared.len();
        for (i, &col) in shared.iter().enumerate() {
            if col < self.ridged {
                ridged.ata[i * s + i] *= 1.0 + RIDGE;
            }
        }
        let signed: Vec<usize> = (0..s)
            .filter(|&k| self.non_negative.contains(&shared[k]))
            .collect();
        let th = non_negative_solve(&ridged, &signed);
        let sse = reduced.sse(&th);
        let mut full = vec![0.0; n];
        for (k, &i) in shared.iter().enumerate() {
            full[i] = th[k];
        }
        (sse, full)
    }

    /// θ for one trial: `shared` with this trial's own columns fitted to
    /// what the shared ones leave of it.
    pub fn for_trial(&self, g: &Gram, shared: &[f64]) -> Vec<f64> {
        let n = g.n;
        let own = self.own;
        let mut sub = Gram::new(own.len());
        for (a, &i) in own.iter().enumerate() {
            for (b, &j) in own.iter().enumerate() {
                sub.ata[a * own.len() + b] = g.ata[i * n + j];
            }
            let explained: f64 = (0..n)
                .filter(|k| !own.contains(k))
                .map(|k| g.ata[i * n + k] * shared[k])
                .sum();
            sub.aty[a] = g.aty[i] - explained;
        }
        let mine = sub.solve();
        let mut theta = shared.to_vec();
        for (a, &i) in own.iter().enumerate() {
            theta[i] = mine[a];
        }
        theta
    }

    /// The shared columns' sums with this trial's own columns taken out:
    /// A_ss − A_so A_oo⁻¹ A_os and b_s − A_so A_oo⁻¹ b_o.
    fn reduce(&self, g: &Gram, shared: &[usize]) -> Gram {
        let n = g.n;
        let own = self.own;
        let m = own.len();
        let mut oo = Gram::new(m);
        for (a, &i) in own.iter().enumerate() {
            for (b, &j) in own.iter().enumerate() {
                oo.ata[a * m + b] = g.ata[i * n + j];
            }
        }
        // A_oo⁻¹ times each shared column's products with the own ones,
        // and times b_o.
        let solve_with = |rhs: Vec<f64>| {
            let mut sys = oo.clone();
            sys.aty = rhs;
            sys.solve()
        };
        let by_shared: Vec<Vec<f64>> = shared
            .iter()
            .map(|&k| solve_with(own.iter().map(|&i| g.ata[i * n + k]).collect()))
            .collect();
        let by_y = solve_with(own.iter().map(|&i| g.aty[i]).collect());
        let s = shared.len();
        let mut r = Gram::new(s);
        for (a, &i) in shared.iter().enumerate() {
            for (b, &j) in shared.iter().enumerate() {
                let taken: f64 = own
                    .iter()
                    .enumerate()
                    .map(|(c, &o)| g.ata[i * n + o] * by_shared[b][c])
                    .sum();
                r.ata[a * s + b] = g.ata[i * n + j] - taken;
            }
            let taken: f64 = own
                .iter()
                .enumerate()
                .map(|(c, &o)| g.ata[i * n + o] * by_y[c])
                .sum();
            r.aty[a] = g.aty[i] - taken;
        }
        let y_taken: f64 = own
            .iter()
            .enumerate()
            .map(|(c, &o)| g.aty[o] * by_y[c])
            .sum();
        r.yy = g.yy - y_taken;
        r.count = g.count;
        r
    }
}

/// Least squares with the θ of the `signed` columns held ≥ 0: the plain
/// solve where it keeps them so, else the best of the solves with each
/// subset of them left out (θ 0) that keeps the rest ≥ 0 — exact, and
/// cheap for the one or two such columns a candidate has (a
/// Lawson–Hanson active set would do for many).
fn non_negative_solve(g: &Gram, signed: &[usize]) -> Vec<f64> {
    let feasible = |th: &Vec<f64>| signed.iter().all(|&k| th[k] >= 0.0);
    let th = g.solve();
    if feasible(&th) {
        return th;
    }
    (1..1usize << signed.len())
        .map(|left_out| {
            let mut sub = g.clone();
            for (bit, &k) in signed.iter().enumerate() {
                if left_out & (1 << bit) != 0 {
                    sub.leave_out(k);
                }
            }
            sub.solve()
        })
        .filter(feasible)
        .min_by(|a, b| g.sse(a).total_cmp(&g.sse(b)))
        .unwrap_or_else(|| vec![0.0; g.n])
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

    /// A column that is rounding on these samples (a cutting odds of
    /// e^-100) has no θ to find: 0, not the ratio of two rounding errors,
    /// which would score a trial where the column is present.
    #[test]
    fn a_column_of_rounding_gets_no_coefficient() {
        let mut g = Gram::new(2);
        for i in 0..100 {
            let sign = if i % 3 == 0 { 1.0 } else { -1.0 };
            g.add(&[1.0, 1e-25 * sign], 2.0 + 0.01 * sign);
        }
        let th = g.solve();
        assert_eq!(th[1], 0.0, "{th:?}");
        assert!((th[0] - 2.0).abs() < 0.01, "{th:?}");
    }

    /// Three trials of y = 2x + c_j (c_j their own offsets 1, −4, 7): the
    /// slope is shared and found, each trial's offset is its own.
    #[test]
    fn a_column_free_per_trial_takes_each_trials_own_value() {
        let offsets = [1.0, -4.0, 7.0];
        let grams: Vec<Gram> = offsets
            .iter()
            .map(|c| {
                let mut g = Gram::new(2);
                for i in 0..50 {
                    let x = i as f64 * 0.2;
                    g.add(&[x, 1.0], 2.0 * x + c);
                }
                g
            })
            .collect();
        let per = PerTrial {
            own: &[1],
            ridged: 0,
            non_negative: &[],
        };
        let refs: Vec<&Gram> = grams.iter().collect();
        let shared = per.solve_shared(&refs);
        assert!((shared[0] - 2.0).abs() < 1e-6, "{shared:?}");
        for (g, c) in grams.iter().zip(offsets) {
            let th = per.for_trial(g, &shared);
            assert!((th[1] - c).abs() < 1e-6, "{th:?}");
            assert!(g.sse(&th) < 1e-8);
        }
        // Shared alone, the offsets' spread is left in the error.
        let mut all = Gram::new(2);
        grams.iter().for_each(|g| all.merge(g));
        let pooled = all.solve();
        assert!(grams.iter().map(|g| g.sse(&pooled)).sum::<f64>() > 1.0);
    }

    /// A signed column the data want negative is left out and the others
    /// fitted without it: y = 1 + 2x − 0.5z has z's θ 0 and the line
    /// refitted to what z's part leaves; unsigned, z's θ is −0.5.
    #[test]
    fn a_signed_column_fitted_negative_is_left_out() {
        let trials: Vec<Gram> = (0..3)
            .map(|t| {
                let mut g = Gram::new(3);
                for i in 0..50 {
                    let (x, z) = (f64::from(i) * 0.1, f64::from((i * 7 + t) % 11));
                    g.add(&[1.0, x, z], 1.0 + 2.0 * x - 0.5 * z);
                }
                g
            })
            .collect();
        let refs: Vec<&Gram> = trials.iter().collect();
        let fit = |signed: &[usize]| {
            let per = PerTrial {
                own: &[],
                ridged: 0,
                non_negative: signed,
            };
            per.solve_shared(&refs)
        };
        assert!((fit(&[])[2] + 0.5).abs() < 1e-6);
        let signed = fit(&[2]);
        assert_eq!(signed[2], 0.0);
        let mut without_z = Gram::new(2);
        for g in &trials {
            for i in 0..2 {
                for j in 0..2 {
                    without_z.ata[i * 2 + j] += g.ata[i * 3 + j];
                }
                without_z.aty[i] += g.aty[i];
            }
        }
        let line = without_z.solve();
        assert!((signed[0] - line[0]).abs() < 1e-6 && (signed[1] - line[1]).abs() < 1e-6);
        // A signed column fitted positive stays.
        assert!((fit(&[1])[1] - 2.0).abs() < 1e-6);
        // Both signed and the data wanting both negative: neither alone
        // left out keeps the other ≥ 0, so both go, and the constant
        // is the mean.
        let falling: Vec<Gram> = (0..3)
            .map(|t| {
                let mut g = Gram::new(3);
                for i in 0..50 {
                    let (x, z) = (f64::from(i) * 0.1, f64::from((i * 7 + t) % 11));
                    g.add(&[1.0, x, z], 1.0 - 2.0 * x - 0.5 * z);
                }
                g
            })
            .collect();
        let per = PerTrial {
            own: &[],
            ridged: 0,
            non_negative: &[1, 2],
        };
        let both = per.solve_shared(&falling.iter().collect::<Vec<_>>());
        let (sum_y, count) = falling
            .iter()
            .fold((0.0, 0.0), |(s, c), g| (s + g.aty[0], c + g.ata[0]));
        assert_eq!((both[1], both[2]), (0.0, 0.0), "{both:?}");
        assert!((both[0] - sum_y / count).abs() < 1e-6, "{both:?}");
    }

    /// The trials reduced once and summed give the shared θ of
    /// `solve_shared` and, as their error, what each trial's own columns
    /// at their best leave of it (a search's fold fits use the one for
    /// the other): noisy trials, two shared columns, one of them ridged.
    #[test]
    fn reduced_sums_fit_and_score_as_the_trials_do() {
        let grams: Vec<Gram> = [(1.0, 0.3), (-4.0, 0.5), (7.0, -0.2)]
            .iter()
            .map(|&(c, tilt)| {
                let mut g = Gram::new(3);
                for i in 0..60 {
                    let x = i as f64 * 0.2;
                    let wobble = ((i * 7919) % 13) as f64 / 13.0 - 0.5;
                    g.add(
                        &[1.0, x, x * x * 0.1],
                        c + 2.0 * x + tilt * x * x * 0.1 + wobble,
                    );
                }
                g
            })
            .collect();
        let per = PerTrial {
            own: &[0],
            ridged: 2,
            non_negative: &[],
        };
        let refs: Vec<&Gram> = grams.iter().collect();
        let shared = per.solve_shared(&refs);
        let sse: f64 = grams
            .iter()
            .map(|g| g.sse(&per.for_trial(g, &shared)))
            .sum();
        let reduced: Vec<Gram> = grams.iter().map(|g| per.reduced(g)).collect();
        let (reduced_sse, reduced_shared) = per.fit_reduced(3, &reduced);
        for (a, b) in shared.iter().zip(&reduced_shared) {
            assert!(
                (a - b).abs() < 1e-12,
                "{shared:?} against {reduced_shared:?}"
            );
        }
        assert!(sse > 1.0, "{sse}");
        // Equal but for the 1e-9 ridge the own columns are solved with.
        assert!(
            (reduced_sse - sse).abs() < 1e-7 * sse,
            "{reduced_sse} against {sse}"
        );
    }
}
