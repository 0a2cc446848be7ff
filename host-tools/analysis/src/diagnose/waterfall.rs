//! The waterfall: the first effect, then each further one the withheld
//! trials support against what the effects before it left, each judged
//! once the nominal is found again under it.

use super::backfit::{
    backfitting, scored_with_backfit, worse, Backfitted, Backfitting, BACKFIT_ROUNDS,
};
use super::candidates::{Backfit, Candidate, CANDIDATES};
use super::prepare::Prepared;
use super::significance::{improvement, Bar, Consistency, MIN_SHRINK, NOTHING_LEFT_FACTOR};
use super::{score_beside, Fixed, Nominal, Scored};

/// The waterfall from the first effect: each further effect is the
/// candidate of most shrink that is significant against what the effects
/// before it left (with the nominal found again under them), until none
/// is, a backfit undoes a step's gain, a step is not a cause of the gap
/// ([`Bar::a_cause`]), or [`MOST_EFFECTS`] are named. With the steps,
/// the data the last one left and the set still added as columns.
pub(super) fn waterfall(
    (ci, (alone, cleaned, fixed)): (usize, Backfitted<'static>),
    bar: Bar,
    nominal: Nominal,
    progress: &mut dyn FnMut(&str),
) -> Waterfall {
    let mut steps = vec![(ci, alone)];
    let (mut cur, mut fixed) = (cleaned, fixed);
    while steps.len() < MOST_EFFECTS {
        let Some((_, left)) = steps.last() else { break };
        // Within a tenth of the noise floor nothing is left to take.
        if left.rms() <= NOTHING_LEFT_FACTOR * bar.noise_n {
            break;
        }
        progress(&format!("searching for effect {}", steps.len() + 1));
        let beside = Fixed::of(&cur, &fixed);
        let mut next: Vec<(usize, Scored)> = CANDIDATES
            .iter()
            .enumerate()
            .filter(|(cj, _)| steps.iter().all(|(ci, _)| ci != cj))
            .map(|(cj, c)| (cj, score_beside(&cur, &beside, Some(c))))
            .filter(|(_, with)| bar.worthy(left, with))
            .collect();
        next.sort_by(|a, b| a.1.rms().total_cmp(&b.1.rms()));
        let contenders: Vec<Contender> = next
            .iter()
            .map(|(cj, with)| Contender::of(*cj, with))
            .collect();
        let Some((cj, (scored, cleaned, kept))) =
            best_backfitted(&cur, (&fixed, left.rms()), &contenders, nominal, progress)
        else {
            break;
        };
        // A backfit that undoes the step's gain ends the waterfall, and
        // so does a step too small to be a cause of the gap.
        if scored.rms() >= left.rms() || !bar.a_cause(left, &scored) {
            break;
        }
        steps.push((cj, scored));
        (cur, fixed) = (cleaned, kept);
    }
    (steps, cur, fixed)
}

/// The waterfall's steps (each effect and what it left), the data the
/// last one left and the set still added as columns.
pub(super) type Waterfall = (
    Vec<(usize, Scored)>,
    Vec<Prepared>,
    Vec<(&'static Candidate, f64)>,
);

/// A candidate significant for a step: which, its grid value, and the
/// held-out RMS it leaves as columns.
#[derive(Clone, Copy)]
pub(super) struct Contender {
    ci: usize,
    grid_value: f64,
    rms: f64,
}

impl Contender {
    pub(super) fn of(ci: usize, scored: &Scored) -> Self {
        Self {
            ci,
            grid_value: scored.grid_value,
            rms: scored.rms(),
        }
    }
}

/// Least share of what the leading contender takes as columns (in mean
/// square) that tissue motion, a contender beside it, must take as
/// columns to get its round in the tissue's frame; under it, its round
/// is one as columns, and only if it wins that way is it fitted in its
/// frame. A frame round fits every trial's displacement (about a second
/// of a 10-trial diagnosis of 15 000 samples a trial, where a round as
/// columns refits the nominal only), and columns that take so much less
/// than the leader's are the linear part of another effect's residual
/// more than a motion of the tissue. Alone or leading, the motion always
/// gets its frame.
const FRAME_SHARE: f64 = 0.5;

/// Of `contenders` (best first), the one that leaves least beside
/// `fixed` (which left `before_rms`) once the nominal is found again
/// under it: alone, an effect is judged against a nominal that took up
/// part of it, and a rival can look better beside that nominal than the
/// effect itself. The [`BACKFIT_TRIED`] leading ones get one round each,
/// the winner the rest of its backfit from there (the nominal's own rules
/// for what is backfitted, a device's model never, hold for it as for
/// one).
pub(super) fn best_backfitted<'c>(
    data: &[Prepared],
    (fixed, before_rms): (&[(&'c Candidate, f64)], f64),
    contenders: &[Contender],
    nominal: Nominal,
    progress: &mut dyn FnMut(&str),
) -> Option<(usize, Backfitted<'c>)> {
    let with = |c: &Contender| {
        let mut set = fixed.to_vec();
        set.push((&CANDIDATES[c.ci], c.grid_value));
        set
    };
    if let [c] = contenders {
        return Some((
            c.ci,
            scored_with_backfit(data, &with(c), nominal, BACKFIT_ROUNDS),
        ));
    }
    let taken = |c: &Contender| before_rms.powi(2) - c.rms.powi(2);
    let lead_taken = contenders.first().map_or(0.0, taken);
    let may_move = |c: &Contender| {
        CANDIDATES[c.ci].backfit != Backfit::TissueFrame || taken(c) >= FRAME_SHARE * lead_taken
    };
    // Only the best so far is kept: each holds a copy of the data.
    let mut best: Option<(&Contender, Backfitting)> = None;
    for c in contenders.iter().take(BACKFIT_TRIED) {
        progress(&format!(
            "backfitting the nominal under {}",
            CANDIDATES[c.ci].effect
        ));
        let tried = backfitting(data, &with(c), nominal, may_move(c)).more(1);
        if best
            .as_ref()
            .is_none_or(|(_, b)| displaces(&tried.state.0, &b.state.0))
        {
            best = Some((c, tried));
        }
    }
    let (c, winner) = best?;
    let state = winner.more(BACKFIT_ROUNDS).state;
    if may_move(c) {
        return Some((c.ci, state));
    }
    // A motion that won as columns is fitted in its frame after all, and
    // stands where that leaves the withheld trials no worse.
    let framed = scored_with_backfit(data, &with(c), nominal, BACKFIT_ROUNDS);
    Some((
        c.ci,
        if worse(framed.0.rms(), state.0.rms()) {
            state
        } else {
            framed
        },
    ))
}

/// Whether a contender's backfit, `rival`, displaces the best so far
/// (`best`; the first is the leader as columns): it leaves less on the
/// withheld trials, and does so consistently ([`Consistency::holds`]).
/// A refitted nominal gains a few per cent on every candidate by taking
/// up some of the trials' spread, more on some trials than on others; a
/// pooled gain that half the trials do not share is that, not the
/// rival's physics, and the ranking as columns stands.
pub(super) fn displaces(rival: &Scored, best: &Scored) -> bool {
    let (shrink, consistency) = improvement(best, rival);
    shrink > 0.0 && consistency.holds()
}

/// Most effects the waterfall names.
pub(super) const MOST_EFFECTS: usize = 4;

/// Candidates tried with their backfit when none is significant without
/// it: the three of most shrink.
const BACKFIT_TRIED: usize = 3;

/// Of the [`BACKFIT_TRIED`] leading candidates, those significant
/// against the baseline once backfitted, the first (the leader as
/// columns) or a later one that [`displaces`] it.
pub(super) fn backfitted_first<'c>(
    data: &[Prepared],
    baseline: &Scored,
    ranked: &[(usize, Scored, f64, Consistency)],
    nominal: Nominal,
) -> Option<(usize, Backfitted<'c>)> {
    ranked
        .iter()
        .filter(|r| r.2 > 0.0)
        .take(BACKFIT_TRIED)
        .map(|(ci, s, ..)| {
            let fixed = [(&CANDIDATES[*ci], s.grid_value)];
            (
                *ci,
                scored_with_backfit(data, &fixed, nominal, BACKFIT_ROUNDS),
            )
        })
        .filter(|(_, (alone, ..))| {
            let (shrink, consistency) = improvement(baseline, alone);
            shrink >= MIN_SHRINK && consistency.holds()
        })
        .reduce(|best, rival| {
            if displaces(&rival.1 .0, &best.1 .0) {
                rival
            } else {
                best
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::prepare::PHASES;

    /// Held-out mean squares `ms` (N²), one a withheld trial of 1000
    /// samples.
    fn scored(ms: &[f64]) -> Scored {
        Scored {
            per_trial: ms.iter().map(|m| (m * 1000.0, 1000)).collect(),
            by_phase: [(0.0, 0); PHASES.len()],
            per_trial_dwell: Vec::new(),
            grid_value: 0.0,
            theta: Vec::new(),
            fold_theta: Vec::new(),
            trial_theta: Vec::new(),
        }
    }

    /// A rival's backfit that leaves less in all, by a large gain on two
    /// withheld trials and a loss on most others, does not displace the
    /// leader as columns; one that gains on every trial does, and one
    /// that leaves more never does.
    #[test]
    fn a_rival_displaces_the_leader_only_by_a_consistent_gain() {
        let leader = scored(&[2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0]);
        let lumpy = scored(&[0.5, 0.5, 2.1, 2.1, 2.1, 2.1, 2.1, 2.1, 2.1, 2.1]);
        assert!(lumpy.rms() < leader.rms());
        assert!(!displaces(&lumpy, &leader));
        let steady = scored(&[1.9, 1.8, 1.9, 1.8, 1.9, 1.8, 1.9, 1.8, 1.9, 1.8]);
        assert!(displaces(&steady, &leader));
        assert!(!displaces(&leader, &steady));
    }
}
