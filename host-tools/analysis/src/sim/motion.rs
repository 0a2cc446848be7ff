//! Needle motion of a trial: a list of segments the robot executes, sampled
//! into position, velocity and acceleration.

use std::f64::consts::TAU;

/// One piece of motion.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Segment {
    /// To `to_m` at `speed_mps`, reached and shed at `accel_mps2` (a
    /// trapezoid, or a triangle where the move is too short to reach
    /// it); 0: the speed changes at once.
    Move {
        to_m: f64,
        speed_mps: f64,
        #[serde(skip_serializing_if = "at_once")]
        accel_mps2: f64,
    },
    /// Rest.
    Dwell { duration_s: f64 },
    /// x0 + A·sin(2π f t) for `cycles` cycles (a whole or half number, so
    /// it ends where it began, moving at full speed: an abrupt stop); or,
    /// `from_rest` (a drive that ramps its speed), x0 − A·(1 − cos 2π f t),
    /// starting and ending at rest (a whole number of cycles where it
    /// began).
    Oscillate {
        amplitude_m: f64,
        freq_hz: f64,
        cycles: f64,
        #[serde(skip_serializing_if = "std::ops::Not::not")]
        from_rest: bool,
    },
}

fn at_once(accel_mps2: &f64) -> bool {
    *accel_mps2 <= 0.0
}

/// A move of `distance_m` at `speed_mps` whose speed changes at
/// `accel_mps2`: the speed it reaches and how long it takes to, s (0 for
/// a speed reached at once).
fn ramp(distance_m: f64, speed_mps: f64, accel_mps2: f64) -> (f64, f64) {
    if accel_mps2 <= 0.0 {
        return (speed_mps, 0.0);
    }
    let top_mps = speed_mps.min((accel_mps2 * distance_m).sqrt());
    (top_mps, top_mps / accel_mps2)
}

impl Segment {
    fn duration_s(&self, from_m: f64) -> f64 {
        match *self {
            Segment::Move {
                to_m,
                speed_mps,
                accel_mps2,
            } => {
                let d = (to_m - from_m).abs();
                let (top_mps, ramp_s) = ramp(d, speed_mps, accel_mps2);
                d / top_mps.max(1e-9) + ramp_s
            }
            Segment::Dwell { duration_s } => duration_s,
            Segment::Oscillate {
                freq_hz, cycles, ..
            } => cycles / freq_hz.max(1e-9),
        }
    }

    /// Position and velocity `t` seconds into the segment.
    fn at(&self, from_m: f64, t: f64) -> (f64, f64) {
        match *self {
            Segment::Move {
                to_m,
                speed_mps,
                accel_mps2,
            } => {
                let (dir, d) = ((to_m - from_m).signum(), (to_m - from_m).abs());
                let (top_mps, ramp_s) = ramp(d, speed_mps, accel_mps2);
                let end_s = self.duration_s(from_m);
                let (s, v) = if t < ramp_s {
                    (0.5 * accel_mps2 * t * t, accel_mps2 * t)
                } else if t <= end_s - ramp_s {
                    (0.5 * top_mps * ramp_s + top_mps * (t - ramp_s), top_mps)
                } else {
                    let left_s = (end_s - t).max(0.0);
                    (d - 0.5 * accel_mps2 * left_s * left_s, accel_mps2 * left_s)
                };
                (from_m + dir * s, dir * v)
            }
            Segment::Dwell { .. } => (from_m, 0.0),
            Segment::Oscillate {
                amplitude_m,
                freq_hz,
                from_rest,
                ..
            } => {
                let w = TAU * freq_hz;
                if from_rest {
                    (
                        from_m - amplitude_m * (1.0 - (w * t).cos()),
                        -amplitude_m * w * (w * t).sin(),
                    )
                } else {
                    (
                        from_m + amplitude_m * (w * t).sin(),
                        amplitude_m * w * (w * t).cos(),
                    )
                }
            }
        }
    }

    fn end(&self, from_m: f64) -> f64 {
        match *self {
            Segment::Move { to_m, .. } => to_m,
            Segment::Oscillate { .. } => self.at(from_m, self.duration_s(from_m)).0,
            Segment::Dwell { .. } => from_m,
        }
    }
}

/// The sampled motion: time, position, velocity, acceleration, and which
/// segment each sample belongs to.
#[derive(Clone, Debug, Default)]
pub struct Sampled {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub v_mps: Vec<f64>,
    pub a_mps2: Vec<f64>,
    pub segment: Vec<usize>,
}

/// Start time and position of each segment, and the total duration, s.
fn starts(segments: &[Segment], start_m: f64) -> (Vec<(f64, f64)>, f64) {
    let mut starts = Vec::with_capacity(segments.len());
    let (mut t0, mut x0) = (0.0, start_m);
    for seg in segments {
        starts.push((t0, x0));
        t0 += seg.duration_s(x0);
        x0 = seg.end(x0);
    }
    (starts, t0)
}

/// How long `segments` take from `start_m`, s.
pub fn duration_s(segments: &[Segment], start_m: f64) -> f64 {
    starts(segments, start_m).1
}

/// Sample `segments`, starting at `start_m`, at `rate_hz`.
pub fn sample(segments: &[Segment], start_m: f64, rate_hz: f64) -> Sampled {
    let n = (duration_s(segments, start_m) * rate_hz).floor() as usize + 1;
    let times: Vec<f64> = (0..n).map(|i| i as f64 / rate_hz).collect();
    sample_at(segments, start_m, &times)
}

/// Sample `segments` at the given increasing times (a real rig's clock
/// jitters and drops samples).
pub fn sample_at(segments: &[Segment], start_m: f64, times_s: &[f64]) -> Sampled {
    let (starts, _) = starts(segments, start_m);
    let mut out = Sampled::default();
    let mut k = 0;
    for &t in times_s {
        while k + 1 < segments.len() && t >= starts[k + 1].0 {
            k += 1;
        }
        let (ts, xs) = starts[k];
        let (x, v) = segments[k].at(xs, t - ts);
        out.t_s.push(t);
        out.x_m.push(x);
        out.v_mps.push(v);
        out.segment.push(k);
    }
    // Acceleration by differences of the commanded velocity: a step change
    // of speed shows as a one-sample pulse, as a real drive's would be short.
    out.a_mps2 = (0..times_s.len())
        .map(|i| {
            if i == 0 {
                0.0
            } else {
                (out.v_mps[i] - out.v_mps[i - 1]) / (times_s[i] - times_s[i - 1])
            }
        })
        .collect();
    out
}
