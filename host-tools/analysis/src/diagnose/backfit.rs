//! Backfitting: the nominal found again under the named effects (their
//! fitted contribution taken out of the measured force, each trial with
//! the effect as fitted without its fold), in rounds until the withheld
//! trials stop gaining; and tissue motion's rounds in the moving tissue's
//! frame.

use std::path::PathBuf;

use anyhow::Result;

use needle_io::trial::Trial;

use super::candidates::{Backfit, Candidate};
use super::crossval::folds;
use super::motion::{self, TissueShift};
use super::prepare::{self, prepare, Prepared};
use super::significance::NOTHING_LEFT_FACTOR;
use super::{
    columns, noise_floor, nominal_params, score, with_fitted, Nominal, Scored, NOMINAL_CORRECTIONS,
};
use crate::fit::predict::NeedleVelocity;
use crate::fit::{fit_trial, fit_trial_at, Falls, TrialFit};

/// The nominal model found again with the named effects' fitted
/// contribution taken out of the measured force: an effect also bends the
/// geometry `needle fit` finds (the contact point of a loading curve with
/// a relaxing branch in it, the peak of a drifting puncture) and the
/// coefficients, which the linear corrections cannot undo. Trial j is
/// cleaned with the effect as fitted without its fold (`fold_theta` of
/// fold j mod k), so no trial's geometry is found with parameters its own
/// samples set. The residual stays measured − model; only the nominal's
/// fit sees the cleaned force.
fn backfit(
    data: &[Prepared],
    set: &[(&Candidate, f64)],
    fold_theta: &[Vec<f64>],
    refit_params: bool,
) -> Result<Vec<Prepared>> {
    let skip = NOMINAL_CORRECTIONS.len();
    let refits: Vec<Refit> = data
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let theta = &fold_theta[j % fold_theta.len()];
            let mut cleaned = p.trial.clone();
            for (c, th) in columns(p, set)[skip..].iter().zip(&theta[skip..]) {
                for (f, e) in cleaned.f_n.iter_mut().zip(c) {
                    *f -= e * th;
                }
            }
            let mut geometry = fit_trial(&cleaned).unwrap_or_else(|_| p.geometry.clone());
            // Where the measured force snapped back to zero is where the
            // tissue let go, whatever an effect added before: the cleaned
            // force past it holds the effect's fit, not the tissue's.
            if p.geometry.let_go_snapped {
                geometry.let_go_x_m = p.geometry.let_go_x_m;
                geometry.let_go_snapped = true;
            }
            // Cleaning changed forces, not positions: the velocity is
            // what it was, and the trial kept is the measured one.
            Refit {
                seen: cleaned,
                geometry,
                velocity: p.velocity.clone(),
                kept: p.trial.clone(),
            }
        })
        .collect();
    nominal_again(data, refits, refit_params)
}

/// One trial as the nominal is found again on it.
struct Refit {
    /// The trial `needle fit`'s code saw: force cleaned, or positions in
    /// the tissue's frame.
    seen: Trial,
    geometry: TrialFit,
    /// The needle's velocity along `seen`.
    velocity: NeedleVelocity,
    /// The trial to prepare against the new nominal: forces as measured,
    /// so the residual stays measured − model.
    kept: Trial,
}

/// The nominal's parameters found again over `refits` (with `needle
/// fit`'s code, or `data`'s own kept when not `refit_params`), ρ over
/// them, and each kept trial prepared against it.
fn nominal_again(
    data: &[Prepared],
    mut refits: Vec<Refit>,
    refit_params: bool,
) -> Result<Vec<Prepared>> {
    let mut params = if refit_params {
        let fits: Vec<_> = data
            .iter()
            .zip(&refits)
            .map(|(p, r)| (PathBuf::from(&p.file), r.geometry.clone()))
            .collect();
        nominal_params(&fits, Vec::new())?
    } else {
        data[0].params
    };
    let triples: Vec<_> = refits
        .iter()
        .map(|r| (&r.seen, &r.geometry, &r.velocity))
        .collect();
    params.relaxation = prepare::fit_relaxation(&triples, &params);
    prepare::relaxed_surfaces(
        &mut refits
            .iter_mut()
            .map(|r| &mut r.geometry)
            .collect::<Vec<_>>(),
        params.relaxation,
    );
    Ok(with_fitted(
        refits
            .into_iter()
            .zip(data)
            .map(|(r, p)| {
                let mut again = prepare(p.file.clone(), r.kept, r.geometry, &params, r.velocity);
                again.keep_protocol_phase(&p.protocol_phase);
                again
            })
            .collect(),
    ))
}

/// Most rounds of [`backfit`]; it stops sooner once a round changes the
/// held-out RMS by less than [`BACKFIT_TOL`] of it.
pub(super) const BACKFIT_ROUNDS: usize = 8;
const BACKFIT_TOL: f64 = 0.01;
/// Rounds of a backfit in which the newest effect's grid value is found
/// again ([`backfit_rounds`]).
const REGRID_ROUNDS: usize = 2;
/// Most rounds of [`tissue_frame_rounds`]: each fits the displacement of
/// every trial again (from the round before and from a fresh grid), and a
/// trial stuck at the wrong flip of friction gets out once the nominal
/// has improved. From the third round on the held-out RMS wanders by a
/// few per cent about where it settled (seeds 3, 7, 11), and a round
/// worse than the one before ends them; the cap bounds the time (each
/// round about 0.27 s of a 10-trial diagnosis).
const TISSUE_FRAME_ROUNDS: usize = 6;

/// A set scored after backfitting: the score, the data the last round
/// left, and the part of the set still to add as columns.
pub(super) type Backfitted<'c> = (Scored, Vec<Prepared>, Vec<(&'c Candidate, f64)>);

/// `set` scored after backfitting the nominal under it, with the data the
/// last round left and the part of `set` still to be added as columns
/// (tissue motion is in the data's positions once backfitted).
pub(super) fn scored_with_backfit<'c>(
    data: &[Prepared],
    set: &[(&'c Candidate, f64)],
    nominal: Nominal,
    rounds: usize,
) -> Backfitted<'c> {
    backfitting(data, set, nominal, true).more(rounds).state
}

/// A backfit under way: what its rounds so far left, and whether more
/// rounds may change it. The leading contenders get one round each and
/// the winner goes on from its own
/// ([`best_backfitted`](super::waterfall::best_backfitted)).
pub(super) struct Backfitting<'c> {
    pub(super) state: Backfitted<'c>,
    refit_params: bool,
    rounds_done: usize,
    settled: bool,
    /// Tissue motion alone, under way in the tissue's frame: its rounds
    /// are the costliest of any effect (each fits every trial's
    /// displacement), and a contender that does not win needs only one.
    frame: Option<InFrame<'c>>,
}

/// Tissue motion's rounds in the tissue's frame so far, the motion as
/// columns (which stand where the rounds leave the withheld trials
/// worse) and the effects beside it, added as columns in the frame.
struct InFrame<'c> {
    rounds: KeptRounds<FrameRound>,
    columns: Backfitted<'c>,
    forces: Vec<(&'c Candidate, f64)>,
}

impl<'c> InFrame<'c> {
    /// The rounds up to the `most`-th.
    fn upto(self, most: usize, refit_params: bool) -> Self {
        let rounds = tissue_frame_rounds(&self.columns.1, refit_params, self.rounds, most);
        Self { rounds, ..self }
    }

    /// The better of the last round kept (the effects beside the motion
    /// scored in its frame) and the columns, and whether it is the round.
    fn state(&self) -> (Backfitted<'c>, bool) {
        let Some((_, (scored, moved, _))) = &self.rounds.last else {
            return (self.columns.clone(), false);
        };
        let in_frame = if self.forces.is_empty() {
            scored.clone()
        } else {
            score(moved, &self.forces, None)
        };
        if worse(in_frame.rms(), self.columns.0.rms()) {
            (self.columns.clone(), false)
        } else {
            ((in_frame, moved.clone(), self.forces.clone()), true)
        }
    }
}

impl<'c> Backfitting<'c> {
    fn settled(state: Backfitted<'c>) -> Self {
        Self {
            state,
            refit_params: false,
            rounds_done: 0,
            settled: true,
            frame: None,
        }
    }

    /// Rounds of [`backfit`] up to the `upto`-th in all. With tissue
    /// motion, its rounds in the tissue's frame come first, as many
    /// ([`tissue_frame_rounds`]): the effects beside it are backfitted
    /// once they are all made.
    pub(super) fn more(mut self, upto: usize) -> Self {
        if let Some(frame) = self.frame.take() {
            let frame = frame.upto(upto.min(TISSUE_FRAME_ROUNDS), self.refit_params);
            let in_frame;
            (self.state, in_frame) = frame.state();
            if frame.rounds.open(TISSUE_FRAME_ROUNDS) {
                self.frame = Some(frame);
                return self;
            }
            self.settled = !in_frame || frame.forces.is_empty();
        }
        if !self.settled && self.rounds_done < upto {
            let rounds = self.rounds_done..upto;
            self.rounds_done = upto;
            (self.state, self.settled) = backfit_rounds(self.state, self.refit_params, rounds);
        }
        self
    }
}

/// [`scored_with_backfit`] before its rounds; tissue motion in `set` is
/// moved into the tissue's frame when `may_move`, else kept as columns.
pub(super) fn backfitting<'c>(
    data: &[Prepared],
    set: &[(&'c Candidate, f64)],
    nominal: Nominal,
    may_move: bool,
) -> Backfitting<'c> {
    if nominal == Nominal::Device {
        return Backfitting::settled((score(data, set, None), data.to_vec(), set.to_vec()));
    }
    let refit_params = nominal == Nominal::Fitted;
    let (moving, forces): (Vec<_>, Vec<_>) = set
        .iter()
        .partition(|(c, _)| c.backfit == Backfit::TissueFrame);
    // Moving the trials into a displacement fitted wrong (to another
    // effect's residual) can leave them worse than the motion as
    // columns: the better of the two on the withheld trials stands, and
    // a moved trial that no longer fits leaves the motion as columns.
    let columns = (score(data, set, None), data.to_vec(), set.to_vec());
    let frame = (may_move && !moving.is_empty()).then(|| InFrame {
        rounds: KeptRounds::new(),
        columns: columns.clone(),
        forces: forces.into_iter().copied().collect(),
    });
    Backfitting {
        state: columns,
        refit_params,
        rounds_done: 0,
        settled: false,
        frame,
    }
}

/// Up to `rounds` more rounds of [`backfit`] from `state`, each kept only
/// if it leaves the withheld trials no worse, until a round changes the
/// held-out RMS by less than [`BACKFIT_TOL`] or leaves it within
/// [`NOTHING_LEFT_FACTOR`] noise floors, where nothing is left for an
/// effect to take (a relaxing branch's rounds creep 1.5–2 % a round
/// there, a tenth of a second each on ten trials of 15 000 samples). The newest effect's shape
/// (its grid value) is found again in the first
/// [`REGRID_ROUNDS`] under the nominal found again: chosen against a
/// nominal that took up part of it (a relaxing branch's withdrawal offset
/// as a longer friction length), it would keep that nominal where it was.
/// Later rounds move the nominal by little and keep it. True once no
/// further round would change what it returns.
fn backfit_rounds<'c>(
    (mut scored, mut current, mut forces): Backfitted<'c>,
    refit_params: bool,
    rounds: std::ops::Range<usize>,
) -> (Backfitted<'c>, bool) {
    let nothing_left_n = NOTHING_LEFT_FACTOR * noise_floor(&current);
    for round in rounds {
        let Ok(again) = backfit(&current, &forces, &scored.fold_theta, refit_params) else {
            return ((scored, current, forces), true);
        };
        let regrid = round < REGRID_ROUNDS && !forces.is_empty();
        let next = match forces.split_last() {
            Some(((newest, _), before)) if regrid => score(&again, before, Some(newest)),
            _ => score(&again, &forces, None),
        };
        // A round that makes the withheld trials worse is not kept: the
        // refitted nominal took up what the effect should have.
        if worse(next.rms(), scored.rms()) {
            return ((scored, current, forces), true);
        }
        if let Some(last) = forces.last_mut().filter(|_| regrid) {
            last.1 = next.grid_value;
        }
        let change = (next.rms() - scored.rms()).abs();
        let done = change < BACKFIT_TOL * scored.rms() || next.rms() <= nothing_left_n;
        (scored, current) = (next, again);
        if done {
            return ((scored, current, forces), true);
        }
    }
    ((scored, current, forces), false)
}

/// A round of [`tissue_frame_rounds`]: the nominal found again in the
/// tissue's frame, the data moved into it and the displacements.
type FrameRound = (Scored, Vec<Prepared>, Vec<TissueShift>);

/// The nominal found again in the tissue's frame: the tissue's
/// displacement fitted per trial under the current nominal (cross-fitted,
/// [`motion::fit_shifts`]), the positions moved into its frame, `needle
/// fit`'s code run on them, in rounds kept as [`KeptRounds`] keeps them,
/// from `rounds` up to the `most`-th.
fn tissue_frame_rounds(
    data: &[Prepared],
    refit_params: bool,
    rounds: KeptRounds<FrameRound>,
    most: usize,
) -> KeptRounds<FrameRound> {
    if !rounds.open(most) {
        return rounds;
    }
    let k = folds(data.len());
    // The displacement is fitted at the search rate, applied at the full
    // one. (Finding the nominal at the search rate too, and only the last
    // round at the full one, left 0.56 N of a 0.15 N gap at 100 Hz.)
    let searched: Vec<Prepared> = data
        .iter()
        .map(|p| p.at_sudden_fall().for_search().clone())
        .collect();
    // The first round from the nominal as the trials' sudden falls have
    // it: a loading curve that runs on past a sag is not cut track.
    let first_params = if refit_params {
        let fits: Vec<_> = data
            .iter()
            .map(|p| (PathBuf::from(&p.file), p.at_sudden_fall().geometry.clone()))
            .collect();
        nominal_params(&fits, Vec::new()).map_or(data[0].params, |mut params| {
            params.relaxation = data[0].params.relaxation;
            params
        })
    } else {
        data[0].params
    };
    let round = |last: Option<&FrameRound>| {
        // Each round from the nominal and displacements the last one kept.
        let (params, start) = match last {
            Some((_, prepared, shifts)) => (prepared[0].params, Some(&shifts[..])),
            None => (first_params, None),
        };
        let found = motion::fit_shifts(&searched, &params, k, start);
        let prepared = moved_into(data, &found, refit_params)?;
        let scored = score(&prepared, &[], None);
        Some((scored.rms(), (scored, prepared, found)))
    };
    rounds.upto(most, round)
}

/// Rounds of an iteration judged on withheld trials, as
/// [`backfit_rounds`] judges its own ([`Self::upto`]), which may stop and
/// go on later from where they stopped: the leading contenders for an
/// effect get a round each, the winner the rest
/// ([`best_backfitted`](super::waterfall::best_backfitted)).
/// The choice among rounds is made on the withheld trials that then
/// score it: the figure is the best of several, mildly optimistic.
struct KeptRounds<T> {
    /// The last round kept, with its held-out RMS.
    last: Option<(f64, T)>,
    /// Rounds asked for so far.
    asked: usize,
    /// No round after them is to be made.
    ended: bool,
}

impl<T> KeptRounds<T> {
    fn new() -> Self {
        Self {
            last: None,
            asked: 0,
            ended: false,
        }
    }

    /// Rounds up to the `most`-th in all: `round` makes the next from
    /// the last one kept (`None` before the first) and gives its held-out
    /// RMS, or `None` when it cannot be made. A round that cannot be
    /// made, or leaves the RMS worse or not a number, is not kept and
    /// ends the rounds; one that changes it by less than [`BACKFIT_TOL`]
    /// of it is kept and ends them.
    fn upto(mut self, most: usize, mut round: impl FnMut(Option<&T>) -> Option<(f64, T)>) -> Self {
        while !self.ended && self.asked < most {
            self.asked += 1;
            let Some((rms, next)) = round(self.last.as_ref().map(|l| &l.1)) else {
                self.ended = true;
                break;
            };
            let before = self.last.as_ref().map(|l| l.0);
            // Before the first round, anything but a number is worse.
            if worse(rms, before.unwrap_or(f64::INFINITY)) {
                self.ended = true;
                break;
            }
            self.ended = before.is_some_and(|b| b - rms < BACKFIT_TOL * b);
            self.last = Some((rms, next));
        }
        self
    }

    /// Whether more rounds up to `most` would be made.
    fn open(&self, most: usize) -> bool {
        !self.ended && self.asked < most
    }
}

/// Whether a round's held-out RMS `next` is worse than `before`, the
/// rule of [`backfit_rounds`] and [`KeptRounds`]: higher, or not a
/// number where `before` is one (a number is never worse than NaN).
pub(super) fn worse(next: f64, before: f64) -> bool {
    next > before || (next.is_nan() && !before.is_nan())
}

/// Each trial moved into the tissue's frame by its `shifts`, and the
/// nominal found again there. `None` when a moved trial no longer fits.
fn moved_into(
    data: &[Prepared],
    shifts: &[TissueShift],
    refit_params: bool,
) -> Option<Vec<Prepared>> {
    let refits: Vec<Refit> = data
        .iter()
        .zip(shifts)
        .map(|(p, s)| {
            let moved = s.apply(&p.trial);
            // The puncture at the sudden fall, as the displacement was
            // searched: where a breath's phase is known only roughly
            // before the puncture, the moved loading curve still sags. A
            // trial with no sudden fall (a wall that rolls over) keeps
            // its fall, as `Prepared::at_sudden_fall` does.
            let geometry = fit_trial_at(&moved, Falls::Sudden)
                .or_else(|_| fit_trial(&moved))
                .ok()?;
            Some(Refit {
                kept: moved.clone(),
                seen: moved,
                geometry,
                velocity: s.velocity_in_tissue(&p.velocity, &p.trial.t_s),
            })
        })
        .collect::<Option<_>>()?;
    nominal_again(data, refits, refit_params).ok()
}

/// The held-out RMS of the nominal found again in the tissue's frame
/// with the tissue's displacement given rather than fitted (a tracker's,
/// or a simulation's truth): how much of what tissue motion leaves is the
/// fitted displacement's error. `None` when a moved trial no longer fits.
pub fn heldout_rms_with_displacement(data: &[Prepared], shifts: &[TissueShift]) -> Option<f64> {
    let moved = moved_into(data, shifts, true)?;
    Some(score(&moved, &[], None).rms())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rounds [`KeptRounds`] asks for and the one it keeps, for rounds
    /// whose held-out RMS are `rms` in turn (`None`: cannot be made),
    /// asked for up to each of `stops` in turn and then to the last.
    fn run_in_stages(rms: &[Option<f64>], stops: &[usize]) -> (usize, Option<usize>) {
        let mut asked = 0usize;
        let mut rounds = KeptRounds::new();
        for &most in stops.iter().chain([&TISSUE_FRAME_ROUNDS]) {
            rounds = rounds.upto(most, |last: Option<&usize>| {
                // Made from the round before: in these tests every round
                // before the last asked is kept.
                assert_eq!(last.copied(), asked.checked_sub(1));
                asked += 1;
                rms.get(asked - 1)
                    .copied()
                    .flatten()
                    .map(|r| (r, asked - 1))
            });
        }
        assert_eq!(asked, rounds.asked);
        (asked, rounds.last.map(|l| l.1))
    }

    fn run(rms: &[Option<f64>]) -> (usize, Option<usize>) {
        run_in_stages(rms, &[])
    }

    /// A contender's one round, then the winner's rest, make the rounds
    /// all at once would, each once.
    #[test]
    fn rounds_stopped_and_gone_on_with_are_the_rounds_made_at_once() {
        let by_half: Vec<_> = (0..10).map(|k| Some(0.5f64.powi(k))).collect();
        let cases: [&[Option<f64>]; 4] = [
            &by_half,
            &[Some(10.0), Some(5.0), Some(6.0), Some(1.0)],
            &[Some(10.0), None, Some(1.0)],
            &[None, Some(1.0)],
        ];
        for rms in cases {
            for stops in [&[1][..], &[1, 1, 2], &[0, 3]] {
                assert_eq!(run_in_stages(rms, stops), run(rms), "{rms:?} {stops:?}");
            }
        }
    }

    #[test]
    fn a_round_that_leaves_the_withheld_trials_worse_is_not_kept_and_ends_them() {
        assert_eq!(
            run(&[Some(10.0), Some(5.0), Some(6.0), Some(1.0)]),
            (3, Some(1))
        );
    }

    #[test]
    fn a_round_that_cannot_be_made_or_is_not_a_number_ends_them() {
        assert_eq!(run(&[Some(10.0), None, Some(1.0)]), (2, Some(0)));
        assert_eq!(run(&[Some(10.0), Some(f64::NAN), Some(1.0)]), (2, Some(0)));
        assert_eq!(run(&[None, Some(1.0)]), (1, None));
        // Not even a first round that is not a number.
        assert_eq!(run(&[Some(f64::NAN), Some(5.0)]), (1, None));
    }

    #[test]
    fn not_a_number_is_worse_than_any_number_and_no_number_is_worse_than_it() {
        assert!(worse(6.0, 5.0) && !worse(5.0, 5.0) && !worse(4.0, 5.0));
        assert!(worse(f64::NAN, 5.0));
        assert!(!worse(5.0, f64::NAN) && !worse(f64::NAN, f64::NAN));
    }

    #[test]
    fn a_round_that_barely_changes_the_rms_is_kept_and_ends_them() {
        let by_half: Vec<_> = (0..10).map(|k| Some(0.5f64.powi(k))).collect();
        assert_eq!(
            run(&by_half),
            (TISSUE_FRAME_ROUNDS, Some(TISSUE_FRAME_ROUNDS - 1))
        );
        assert_eq!(
            run(&[Some(10.0), Some(5.0), Some(4.99), Some(1.0)]),
            (3, Some(2))
        );
    }
}
