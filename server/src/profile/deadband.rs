//! A deadband: a change smaller than it is not reported. A field's profile may say one
//! (`deadband:`), and the MQTT section's `report:` gives the default; both are read here.

use crate::yaml::{Kind, Node, Report};

/// A change smaller than this is not reported.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Deadband {
    #[default]
    None,
    Absolute(f64),
    /// Percent of the last reported value's magnitude.
    Percent(f64),
}

impl Deadband {
    /// Whether `new` is within the band of `old` (numbers only; other values differ when
    /// unequal).
    pub(crate) fn within(
        self,
        old: Option<&crate::codec::Value>,
        new: Option<&crate::codec::Value>,
    ) -> bool {
        match (old, new) {
            (Some(a), Some(b)) if a == b => true,
            (Some(a), Some(b)) => match (a.as_f64(), b.as_f64(), self) {
                (Some(x), Some(y), Deadband::Absolute(d)) => (x - y).abs() < d,
                (Some(x), Some(y), Deadband::Percent(p)) => (x - y).abs() < x.abs() * p / 100.0,
                _ => false,
            },
            (None, None) => true,
            _ => false,
        }
    }
}

/// A deadband as written: a number (absolute) or a percentage (`"5%"`).
pub(crate) fn read_deadband(node: &Node, report: &mut Report, ctx: &str) -> Option<Deadband> {
    let bad = |report: &mut Report, why: &str| {
        report.push(node.line, ctx, why);
        None
    };
    match &node.kind {
        Kind::Int(_) | Kind::Float(_) => {
            let x = node.number(report, ctx)?;
            if x < 0.0 {
                return bad(report, "must not be negative");
            }
            Some(if x == 0.0 {
                Deadband::None
            } else {
                Deadband::Absolute(x)
            })
        }
        _ => {
            let text = node.scalar_text(report, ctx)?;
            let Some(p) = text
                .strip_suffix('%')
                .and_then(|p| p.trim().parse::<f64>().ok())
            else {
                return bad(
                    report,
                    &format!(
                        "`{text}` is not a deadband (write an absolute change, e.g. 0.5, or a percentage, e.g. 2%)"
                    ),
                );
            };
            if !(0.0..=100.0).contains(&p) {
                return bad(report, "a percentage deadband must be 0% to 100%");
            }
            Some(if p == 0.0 {
                Deadband::None
            } else {
                Deadband::Percent(p)
            })
        }
    }
}
