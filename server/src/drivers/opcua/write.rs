//! A device's outputs written with one Write request: each value in the variant type the
//! server holds it in (checked against that type's range), each outcome the server's status
//! for it; a value the server takes is published before its outcome.

use std::sync::Arc;

use opcua::types::{AttributeId, DataValue, NumericRange, WriteValue};

use super::{Connection, Plan};
use crate::cache::{Device, WriteError};
use crate::drivers::WriteItem;
use crate::drivers::{finish, written};
use crate::link::LinkFault;
use crate::opcua_variant::write_variant;

/// The items that can be sent, each with its write value; the others finished with why.
fn prepare(
    device: &Device,
    plan: &Plan,
    items: Vec<WriteItem>,
) -> (Vec<WriteItem>, Vec<WriteValue>) {
    let mut sent = Vec::new();
    let mut values = Vec::new();
    for item in items {
        let field = device.field(item.field);
        let node = match plan.nodes.get(item.field) {
            Some(Ok(node)) => node.clone(),
            Some(Err(why)) => {
                finish(device, &item, Err(WriteError::Refused(why.clone())), 0);
                continue;
            }
            None => {
                finish(
                    device,
                    &item,
                    Err(WriteError::Refused("no node".to_owned())),
                    0,
                );
                continue;
            }
        };
        let server_type = plan
            .types
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get(item.field)
            .copied()
            .flatten();
        match item
            .value()
            .and_then(|v| write_variant(field.ty, v, server_type))
        {
            Ok(v) => {
                values.push(WriteValue {
                    node_id: node,
                    attribute_id: AttributeId::Value as u32,
                    index_range: NumericRange::None,
                    value: DataValue::value_only(v),
                });
                sent.push(item);
            }
            Err(why) => finish(device, &item, Err(WriteError::Refused(why)), 0),
        }
    }
    (sent, values)
}

/// Writes `items` in requests within the server's limit, finishing each.
pub(super) async fn items(
    conn: &Connection,
    device: &Arc<Device>,
    plan: &Plan,
    items: Vec<WriteItem>,
) -> Result<(), LinkFault> {
    let (all, values) = prepare(device, plan, items);
    let session = &conn.session;
    let answered =
        super::limits::in_requests(conn, super::Service::Write, &values, |v| session.write(v))
            .await;
    for (range, got) in answered {
        let after = range.end;
        let (sent, unsent) = (&all[range], &all[after..]);
        let statuses = match got {
            Ok(s) => s,
            Err(e) => {
                // The connection failed: the latest values are written again once it is
                // back; a refused request is the server's word on each item.
                let fault = conn.fault(&e);
                let why = match &fault {
                    Some(f) => WriteError::LinkDown(f.clone()),
                    None => WriteError::Refused(e.status().to_string()),
                };
                for item in sent {
                    finish(device, item, Err(why.clone()), 1);
                }
                if let Some(f) = fault {
                    // The requests not sent: written again once the link is back.
                    for item in unsent {
                        finish(device, item, Err(WriteError::LinkDown(f.clone())), 0);
                    }
                    return Err(f);
                }
                continue;
            }
        };
        for (n, item) in sent.iter().enumerate() {
            match statuses.get(n) {
                Some(s) if s.is_good() => {
                    written(device, item, 1);
                }
                Some(s) => finish(device, item, Err(WriteError::Refused(s.to_string())), 1),
                None => finish(
                    device,
                    item,
                    Err(WriteError::Refused("no answer for it".to_owned())),
                    1,
                ),
            }
        }
    }
    Ok(())
}
