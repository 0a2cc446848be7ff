//! A tissue dragged out on withdrawal: the surface round the shaft follows
//! the withdrawing needle at a fraction of its travel until it is
//! stretched as far as it goes (the kink), then stays while the shaft
//! slides out of it to the let-go. The length of shaft in the tissue
//! shrinks at (1 − ratio) of the travel above the kink and at the full
//! travel below it, so the pull is two straight lines in x that meet
//! there, the lower one reaching zero at the let-go — where real
//! withdrawals reach zero, 1.5–9 mm before the first contact. A straight
//! line from the let-go (ratio 0, or a kink at the top) is the law
//! without it.
//!
//! The search is a grid over the let-go and the kink, each point a least
//! squares fit of the pull on both lines' lengths; sums over the samples
//! above a threshold come from suffix sums over the samples sorted by
//! position, so a point costs a 2×2 solve, not a pass over the samples.

use super::lsq::Lsq;

/// Position, velocity, force of one sample.
pub type Xvf = (f64, f64, f64);

/// Where the dragged surface stopped following the needle, and how fast
/// it followed above that.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Drag {
    /// The needle's position when the surface stopped, m.
    pub kink_x_m: f64,
    /// The surface's travel per metre of the needle's above the kink,
    /// 0 < ratio ≤ [`MOST_FOLLOWED`].
    pub ratio: f64,
}

impl Drag {
    /// The shaft's length in the tissue at `x_m`, the tissue letting go at
    /// `let_go_m`.
    pub fn length_m(&self, x_m: f64, let_go_m: f64) -> f64 {
        (x_m - let_go_m) - self.ratio * (x_m - self.kink_x_m).max(0.0)
    }
}

/// The shaft's length in the tissue of a needle withdrawing at `x_m`,
/// the tissue letting go at `let_go_m`, with `drag` if its surface was
/// dragged part of the way.
pub fn withdrawing_length_m(x_m: f64, let_go_m: f64, drag: Option<Drag>) -> f64 {
    drag.map_or(x_m - let_go_m, |d| d.length_m(x_m, let_go_m))
}

/// The best kinked pull found: the drag, the let-go, the friction per
/// length below the kink (the shaft's own) and the sum of squared
/// residuals over every withdrawing sample (zero predicted past the
/// let-go).
#[derive(Clone, Copy, Debug)]
pub struct Kinked {
    pub drag: Drag,
    pub let_go_m: f64,
    pub n_per_m: f64,
    pub sse: f64,
}

/// Sums over samples at or above a position: count, x, x², f, x·f, f².
#[derive(Clone, Copy, Default)]
struct Sums([f64; 6]);

/// A withdrawal's samples as the search reads them: suffix sums over the
/// samples sorted by position, made once for every law and grid point
/// tried on them.
pub struct Pulls {
    x_sorted: Vec<f64>,
    /// `suffix[k]`: sums over samples k.. in position order.
    suffix: Vec<Sums>,
}

impl Pulls {
    /// The withdrawing samples `out`.
    pub fn of(out: &[Xvf]) -> Self {
        let mut by_x: Vec<(f64, f64)> = out.iter().map(|s| (s.0, s.2)).collect();
        by_x.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut suffix = vec![Sums::default(); by_x.len() + 1];
        for (k, &(x, f)) in by_x.iter().enumerate().rev() {
            let s = suffix[k + 1].0;
            suffix[k] = Sums([
                s[0] + 1.0,
                s[1] + x,
                s[2] + x * x,
                s[3] + f,
                s[4] + x * f,
                s[5] + f * f,
            ]);
        }
        Self {
            x_sorted: by_x.iter().map(|s| s.0).collect(),
            suffix,
        }
    }

    /// Sums over the samples past `x_m`.
    fn past(&self, x_m: f64) -> Sums {
        let k = self.x_sorted.partition_point(|&x| x <= x_m);
        self.suffix[k]
    }

    /// Σf² over every sample.
    fn all_ff(&self) -> f64 {
        self.suffix[0].0[5]
    }

    /// Over the samples past `x_e`: Σa², Σa·f and Σf² of the length
    /// a = x − x_e and the pull f.
    fn line_sums(&self, x_e: f64) -> [f64; 3] {
        let [n, sx, sxx, sf, sxf, sff] = self.past(x_e).0;
        [sxx - 2.0 * x_e * sx + x_e * x_e * n, sxf - x_e * sf, sff]
    }

    /// The pull on the lengths a = x − x_e (past x_e) and b = (x − x_k)⁺
    /// (past x_k > x_e): its least squares fit f ≈ c·a − d·b, and the sum
    /// of squared residuals with the samples at or before x_e read as zero.
    fn fit_at(&self, x_e: f64, x_k: f64) -> Option<([f64; 2], f64)> {
        let [aa, af, sff] = self.line_sums(x_e);
        let [nk, sxk, sxxk, sfk, sxfk, _] = self.past(x_k).0;
        let bb = sxxk - 2.0 * x_k * sxk + x_k * x_k * nk;
        let ab = sxxk - (x_e + x_k) * sxk + x_e * x_k * nk;
        let bf = sxfk - x_k * sfk;
        let lsq = Lsq::from_sums([[aa, -ab], [-ab, bb]], [af, -bf], sff);
        let c = lsq.solve()?;
        Some((c, lsq.sse(&c) + (self.all_ff() - sff)))
    }

    /// The best straight pull from a let-go on `let_go_grid` (the law with
    /// no kink): `(let_go_m, n_per_m, sse)`, zero read past the let-go.
    pub fn straight(&self, let_go_grid: impl Iterator<Item = f64>) -> Option<(f64, f64, f64)> {
        let all_ff = self.all_ff();
        let_go_grid
            .filter_map(|x_e| {
                let [aa, af, sff] = self.line_sums(x_e);
                (aa > 0.0).then(|| {
                    let c = af / aa;
                    (x_e, c, sff - c * af + (all_ff - sff))
                })
            })
            .filter(|s| s.1 < 0.0)
            .min_by(|a, b| a.2.total_cmp(&b.2))
    }

    /// The best kinked pull with the let-go on `let_go_grid`: a pull
    /// (friction per length below zero), the surface following slower
    /// than the needle (0 < ratio ≤ [`MOST_FOLLOWED`]), the kink inside
    /// the withdrawal. `None` when no point of the grid holds one.
    pub fn kinked(&self, let_go_grid: impl Iterator<Item = f64>) -> Option<Kinked> {
        let top_m = *self.x_sorted.last()?;
        let mut best: Option<Kinked> = None;
        for x_e in let_go_grid.filter(|&x| x < top_m) {
            for k in 1..KINKS {
                let x_k = x_e + (top_m - x_e) * k as f64 / KINKS as f64;
                let Some(([c, d], sse)) = self.fit_at(x_e, x_k) else {
                    continue;
                };
                let ratio = d / c;
                if c >= 0.0 || !(0.0..=MOST_FOLLOWED).contains(&ratio) || ratio == 0.0 {
                    continue;
                }
                if best.is_none_or(|b| sse < b.sse) {
                    best = Some(Kinked {
                        drag: Drag {
                            kink_x_m: x_k,
                            ratio,
                        },
                        let_go_m: x_e,
                        n_per_m: c,
                        sse,
                    });
                }
            }
        }
        best
    }
}

/// The most of the needle's travel a dragged surface follows: one that
/// keeps up with it is stuck to it, a tent (the diagnosis's stick) whose
/// pull is its stretch, not the shaft's friction.
pub const MOST_FOLLOWED: f64 = 0.75;

/// Kinks tried between the let-go and the top of the withdrawal, as
/// fractions of that span.
const KINKS: usize = 24;

#[cfg(test)]
mod tests {
    use super::*;

    /// A pull that follows the law exactly, sampled along a withdrawal.
    fn withdrawal(pull: impl Fn(f64) -> f64) -> Vec<Xvf> {
        (0..3000)
            .map(|k| {
                let x = 0.040 - 0.035 * k as f64 / 3000.0;
                (x, -0.002, pull(x))
            })
            .collect()
    }

    #[test]
    fn the_kink_and_the_ratio_are_found_where_the_surface_stopped() {
        let drag = Drag {
            kink_x_m: 0.022,
            ratio: 0.3,
        };
        let out = withdrawal(|x| -60.0 * drag.length_m(x, 0.008).max(0.0));
        let grid = (0..=400).map(|k| 0.004 + 0.016 * k as f64 / 400.0);
        let found = Pulls::of(&out).kinked(grid).expect("a kink");
        assert!((found.let_go_m - 0.008).abs() < 1e-4, "{found:?}");
        assert!((found.drag.kink_x_m - 0.022).abs() < 0.0015, "{found:?}");
        assert!((found.drag.ratio - 0.3).abs() < 0.05, "{found:?}");
        assert!((found.n_per_m + 60.0).abs() < 3.0, "{found:?}");
    }

    #[test]
    fn the_suffix_sums_give_the_sums_a_pass_over_the_samples_gives() {
        let out = withdrawal(|x| -50.0 * (x - 0.01).max(0.0) + 0.01 * (x * 900.0).sin());
        let pulls = Pulls::of(&out);
        let (x_e, x_k) = (0.012, 0.03);
        let mut direct = Lsq::<2>::default();
        let mut outside = 0.0;
        for &(x, _, f) in &out {
            if x > x_e {
                direct.add([x - x_e, -(x - x_k).max(0.0)], f);
            } else {
                outside += f * f;
            }
        }
        let c = direct.solve().unwrap();
        let (c_fast, sse_fast) = pulls.fit_at(x_e, x_k).unwrap();
        assert!((c[0] - c_fast[0]).abs() < 1e-6 * c[0].abs().max(1.0));
        assert!((c[1] - c_fast[1]).abs() < 1e-6 * c[1].abs().max(1.0));
        let sse = direct.sse(&c) + outside;
        assert!(
            (sse - sse_fast).abs() < 1e-9 + 1e-6 * sse,
            "{sse} {sse_fast}"
        );
    }
}
