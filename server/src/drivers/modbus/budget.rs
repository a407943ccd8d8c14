//! The bus time a link's transactions take at its line settings, and the share of the line
//! its devices' refresh rates demand.

use std::time::Duration;

use super::ReadBatch;
use crate::config::DeviceConfig;
use crate::link::frame::Request;
use crate::link::timing::LineTiming;

/// Bytes of an RTU request and its good response.
pub(crate) fn rtu_sizes(request: &Request) -> (usize, usize) {
    let mut pdu = Vec::new();
    request.encode(&mut pdu);
    (pdu.len() + 3, request.response_len() + 3)
}

/// The bus time of one transaction: both frames, each after the silence and guard time.
pub(crate) fn transaction_time(
    request: &Request,
    timing: &LineTiming,
    guard: Duration,
) -> Duration {
    let (req, resp) = rtu_sizes(request);
    timing.transaction_time(req, resp) + guard * 2
}

/// The bus time one poll cycle of a device needs at `timing`.
pub(crate) fn cycle_time(batches: &[ReadBatch], timing: &LineTiming, guard: Duration) -> Duration {
    batches
        .iter()
        .map(|b| transaction_time(&b.request(), timing, guard))
        .sum()
}

/// The share of a line's time the devices' refresh rates demand (1.0 = all of it).
pub(crate) fn utilisation<'a>(
    devices: impl IntoIterator<Item = (&'a DeviceConfig, &'a [ReadBatch])>,
    timing: &LineTiming,
    guard: Duration,
) -> f64 {
    devices
        .into_iter()
        // A device read back to back (`0ms`) takes what the line has left by design.
        .filter(|(d, _)| !d.refresh_rate.is_zero())
        .map(|(d, batches)| {
            cycle_time(batches, timing, guard).as_secs_f64()
                / d.refresh_rate.as_secs_f64().max(1e-6)
        })
        // Not `sum()`: the sum of no floats is -0.0, and a link with no devices would
        // report a utilisation of -0.0.
        .fold(0.0, |total, u| total + u)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_link_with_no_devices_uses_none_of_the_line_not_minus_zero() {
        let line = crate::config::SerialSettings {
            port: "/dev/ttyUSB0".to_owned(),
            baud: 9600,
            parity: crate::config::Parity::None,
            data_bits: 8,
            stop_bits: 1,
            framing: Default::default(),
        };
        let u = utilisation(
            std::iter::empty::<(&DeviceConfig, &[ReadBatch])>(),
            &LineTiming::new(&line),
            Duration::ZERO,
        );
        assert_eq!(u.to_bits(), 0.0f64.to_bits(), "{u}");
    }
}
