//! Needle motion of a trial: a list of segments the robot executes, sampled
//! into position, velocity and acceleration.

use std::f64::consts::TAU;

/// One piece of motion.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Segment {
    /// Constant speed to `to_m`.
    Move { to_m: f64, speed_mps: f64 },
    /// Rest.
    Dwell { duration_s: f64 },
    /// x0 + A·sin(2π f t) for `cycles` cycles (a whole or half number, so
    /// it ends where it began, moving at full speed: an abrupt stop).
    Oscillate {
        amplitude_m: f64,
        freq_hz: f64,
        cycles: f64,
    },
}

impl Segment {
    fn duration_s(&self, from_m: f64) -> f64 {
        match *self {
            Segment::Move { to_m, speed_mps } => (to_m - from_m).abs() / speed_mps.max(1e-9),
            Segment::Dwell { duration_s } => duration_s,
            Segment::Oscillate {
                freq_hz, cycles, ..
            } => cycles / freq_hz.max(1e-9),
        }
    }

    /// Position and velocity `t` seconds into the segment.
    fn at(&self, from_m: f64, t: f64) -> (f64, f64) {
        match *self {
            Segment::Move { to_m, speed_mps } => {
                let dir = (to_m - from_m).signum();
                (from_m + dir * speed_mps * t, dir * speed_mps)
            }
            Segment::Dwell { .. } => (from_m, 0.0),
            Segment::Oscillate {
                amplitude_m,
                freq_hz,
                ..
            } => {
                let w = TAU * freq_hz;
                (
                    from_m + amplitude_m * (w * t).sin(),
                    amplitude_m * w * (w * t).cos(),
                )
            }
        }
    }

    fn end(&self, from_m: f64) -> f64 {
        match *self {
            Segment::Move { to_m, .. } => to_m,
            _ => from_m,
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

/// Sample `segments`, starting at `start_m`, at `rate_hz`.
pub fn sample(segments: &[Segment], start_m: f64, rate_hz: f64) -> Sampled {
    let dt = 1.0 / rate_hz;
    let mut starts = Vec::with_capacity(segments.len());
    let (mut t0, mut x0) = (0.0, start_m);
    for seg in segments {
        starts.push((t0, x0));
        t0 += seg.duration_s(x0);
        x0 = seg.end(x0);
    }
    let total_s = t0;
    let mut out = Sampled::default();
    let mut k = 0;
    let n = (total_s * rate_hz).floor() as usize + 1;
    for i in 0..n {
        let t = i as f64 * dt;
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
    out.a_mps2 = (0..n)
        .map(|i| {
            if i == 0 {
                0.0
            } else {
                (out.v_mps[i] - out.v_mps[i - 1]) * rate_hz
            }
        })
        .collect();
    out
}
