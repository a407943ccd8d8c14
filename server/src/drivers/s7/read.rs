//! A device's read: its jobs sent as the PLC takes them, each span's bytes put together from
//! its pieces' answers, each field decoded from them (or given its span's error); a merged
//! range past its block's end makes its fields be read alone from then on.

use std::sync::Arc;

use tokio::time::Instant;

use super::conn::Answers;
use super::plan::{Span, read_plan};
use super::szl::Mode;
use super::{IN_STOP, Plan, Plc, fault, lost, pdu, value};
use crate::cache::{Device, FieldError};
use crate::drivers::Read;
use crate::link::LinkFault;

/// Why a span has no bytes: the error its fields get, and the item's return code.
type Failed = (String, Option<u8>);

/// Plans the device's jobs for the PDU the PLC granted and the link's gap, telling each
/// field that has no place why.
pub(super) fn replan(device: &Device, plan: &mut Plan, (pdu, gap): (u16, u32)) {
    plan.reads = read_plan(&plan.places, pdu, &plan.alone, gap);
    plan.pdu = pdu;
    plan.gap = gap;
    for (idx, p) in plan.places.iter().enumerate() {
        if let Err(why) = p {
            device.publish(idx, Err(FieldError::Device(why.clone())));
        }
    }
}

/// A span's bytes from its pieces' answers, in order.
fn span_bytes(span: &Span, answers: &Answers) -> Result<Vec<u8>, Failed> {
    let mut bytes = Vec::new();
    for &(job, item) in &span.pieces {
        match answers
            .get(job)
            .map(|a| a.as_ref().map(|items| items.get(item)))
        {
            Some(Ok(Some(Ok(piece)))) => bytes.extend_from_slice(piece),
            Some(Ok(Some(Err(code)))) => {
                return Err((pdu::item_error(*code).to_owned(), Some(*code)));
            }
            Some(Err(refused)) => return Err((refused.to_string(), None)),
            _ => return Err(("the PLC's answer has no such item".to_owned(), None)),
        }
    }
    Ok(bytes)
}

/// Publishes a span's fields (stale with `doubt` where the PLC vouches for them only in
/// part).
fn publish_span(
    device: &Device,
    plan: &Plan,
    span: &Span,
    bytes: &Result<Vec<u8>, Failed>,
    doubt: Option<&FieldError>,
    now: crate::cache::Stamp,
) {
    for &(idx, offset) in &span.fields {
        let Some(Ok(place)) = plan.places.get(idx) else {
            continue;
        };
        let value = match bytes {
            Ok(bytes) => {
                let at = usize::try_from(offset).unwrap_or(usize::MAX);
                let mine = bytes.get(at..).unwrap_or_default();
                value::decode(place.form, place.stored, mine)
                    .and_then(|raw| device.field(idx).value_of_raw(raw))
                    .map_err(FieldError::Device)
            }
            Err((why, _)) => Err(FieldError::Device(why.clone())),
        };
        device.publish_from(idx, value, doubt.cloned(), None, now);
    }
}

pub(super) async fn read(
    plc: &mut Plc,
    device: &Arc<Device>,
    plan: &mut Plan,
) -> Result<Read, LinkFault> {
    if (plan.pdu, plan.gap) != (plc.conn.pdu, plc.gap) {
        replan(device, plan, (plc.conn.pdu, plc.gap));
    }
    if !plc.identified
        && let Err(e) = plc.identify().await
    {
        fault(e)?;
    }
    let started = Instant::now();
    if started >= plc.next_mode
        && let Err(e) = plc.read_mode().await
    {
        fault(e)?;
    }
    let doubt = (plc.mode == Some(Mode::Stop)).then(|| FieldError::Device(IN_STOP.into()));
    let jobs: Vec<&[pdu::Item]> = plan.reads.jobs.iter().map(Vec::as_slice).collect();
    let (progress, timeout) = (plc.progress.clone(), plc.timeout);
    let answered = plc
        .conn
        .read_jobs(&jobs, || progress.started(Instant::now() + timeout))
        .await;
    plc.progress.ended();
    let answers = answered.map_err(lost)?;
    for refused in answers.iter().filter_map(|a| a.as_ref().err()) {
        plc.tell_refused(&refused.to_string());
    }
    let now = crate::cache::Stamp::now();
    let mut split = Vec::new();
    for span in &plan.reads.spans {
        let bytes = span_bytes(span, &answers);
        publish_span(device, plan, span, &bytes, doubt.as_ref(), now);
        if span.fields.len() > 1
            && matches!(bytes, Err((_, Some(code))) if code == pdu::OUT_OF_RANGE)
        {
            split.extend(span.fields.iter().map(|&(idx, _)| idx));
        }
    }
    if !split.is_empty() {
        // A range past the end of its block: its fields are read alone from now on, so
        // that those within it are read.
        plan.alone.extend(split);
        plan.pdu = 0;
    }
    Ok(Read::Answered(started.elapsed()))
}
