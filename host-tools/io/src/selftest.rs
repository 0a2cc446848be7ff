//! `needle device selftest`: ask the board to test itself and read its
//! answer as a bring-up checklist, a line a check, each with its verdict.

use needle_holder::protocol::SelfTest;

/// One line of the checklist: what was found, and whether it is as it
/// should be (`None`: nothing to judge, information).
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    pub line: String,
    pub ok: Option<bool>,
}

/// Data-ready rates within this share of the configured one pass: the
/// ADS1220's internal oscillator is within ±2 % of its 4.096 MHz over
/// temperature (SBAS501 §7.5), and a second's count is ±1.
const RATE_TOLERANCE: f64 = 0.03;

/// The checklist a self-test answers.
pub fn checks(t: &SelfTest) -> Vec<Check> {
    let mut out = Vec::new();
    let hex = |r: &[u8; 4]| {
        r.iter()
            .map(|b| format!("{b:02x}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    out.push(match t.board.adc_registers {
        Some((read, written)) => Check {
            line: format!(
                "converter registers {} (written {})",
                hex(&read),
                hex(&written)
            ),
            ok: Some(read == written),
        },
        None => Check {
            line: "converter registers not read (a replay board, or a converter that did not start or has stopped: see data-ready)".into(),
            ok: None,
        },
    });
    let expected = t.board.data_ready_expected_per_s;
    out.push(match t.board.data_ready_per_s {
        Some(counted) => Check {
            line: format!("data-ready {counted} a second (configured {expected})"),
            ok: Some(
                (f64::from(counted) - f64::from(expected)).abs()
                    <= RATE_TOLERANCE * f64::from(expected) + 1.0,
            ),
        },
        None => Check {
            line: format!(
                "data-ready not counted (a replay board, or less than two seconds since boot; configured {expected} a second)"
            ),
            ok: None,
        },
    });
    out.push(Check {
        line: match t.board.encoder_count {
            Some(count) => format!("encoder count {count}"),
            None => "encoder not read (the converter is silent)".into(),
        },
        ok: None,
    });
    out.push(Check {
        line: format!(
            "halt line {} ({})",
            if t.halt { "ASSERTED" } else { "released" },
            if t.faults.is_empty() {
                "no fault".to_string()
            } else {
                format!("faults {}", crate::decode::fault_names(t.faults.into()))
            }
        ),
        // Asserted for an assist's stop, with no fault: information.
        ok: if !t.faults.is_empty() {
            Some(false)
        } else if t.halt {
            None
        } else {
            Some(true)
        },
    });
    // Since boot: one glitch at the port's opening is not a failed board.
    out.push(Check {
        line: format!(
            "link since boot: {} receive errors; {} conversions lost",
            t.counters.line_errors, t.counters.conversions_lost
        ),
        ok: None,
    });
    out
}

/// How many of `checks` failed.
pub fn failed(checks: &[Check]) -> usize {
    checks.iter().filter(|c| c.ok == Some(false)).count()
}

/// The checklist as one line (for `needle decode`).
pub fn summary(t: &SelfTest) -> String {
    let checks = checks(t);
    let failed = failed(&checks);
    format!(
        "selftest {}: {}",
        if failed == 0 {
            "passed".to_string()
        } else {
            format!("{failed} checks failed")
        },
        checks
            .iter()
            .map(|c| c.line.as_str())
            .collect::<Vec<_>>()
            .join("; ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_holder::faults::Faults;
    use needle_holder::protocol::{BoardCounters, BoardFindings};

    fn report(read: [u8; 4], counted: u32) -> SelfTest {
        SelfTest {
            board: BoardFindings {
                adc_registers: Some((read, [0x3e, 0xc4, 0x40, 0x00])),
                data_ready_per_s: Some(counted),
                data_ready_expected_per_s: 1000,
                encoder_count: Some(7),
            },
            halt: false,
            faults: Faults::NONE.into(),
            counters: BoardCounters::default(),
        }
    }

    #[test]
    fn a_good_board_passes_and_each_fault_fails_its_own_line() {
        let good = report([0x3e, 0xc4, 0x40, 0x00], 1012);
        assert!(checks(&good).iter().all(|c| c.ok != Some(false)));
        assert!(summary(&good).starts_with("selftest passed"));
        // Registers at their reset values: the converter lost power.
        let reset = report([0; 4], 1000);
        assert_eq!(checks(&reset)[0].ok, Some(false));
        // Half the edges: a 500 SPS converter, or edges merged.
        let slow = report([0x3e, 0xc4, 0x40, 0x00], 500);
        assert_eq!(checks(&slow)[1].ok, Some(false));
        assert!(summary(&slow).starts_with("selftest 1 checks failed"));
    }
}
