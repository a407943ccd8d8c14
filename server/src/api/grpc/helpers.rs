//! What the gRPC calls share: protobuf to and from the service's types, and the service's
//! own methods on `GrpcApi`.

use super::*;

/// A transaction's value as JSON: a double is a float (so `int32/float` writes it as
/// IEEE-754; the integer types take it when it is whole). Not finite: null, refused.
pub(super) fn json_number(n: f64) -> serde_json::Value {
    serde_json::Number::from_f64(n).map_or(serde_json::Value::Null, Into::into)
}

/// The link and parameters of a transaction request.
pub(super) fn transaction_spec(r: pb::TransactRequest) -> (String, TransactionSpec) {
    let text = |s: String| (!s.is_empty()).then_some(s);
    let spec = TransactionSpec {
        function: Some(r.function.into()),
        slave: Some(r.slave.into()),
        address: Some(r.address.into()),
        bit_count: (r.bit_count > 0).then_some(r.bit_count.into()),
        value_type: text(r.value_type),
        divisor: (r.divisor > 0).then(|| i64::try_from(r.divisor).unwrap_or(i64::MAX)),
        precision: r.precision.map(i64::from),
        byte_order: text(r.byte_order),
        timeout_ms: (r.timeout_ms > 0).then_some(r.timeout_ms.into()),
        write_type: text(r.r#type),
        values: (!r.values.is_empty()).then(|| r.values.into_iter().map(json_number).collect()),
    };
    (r.link, spec)
}

pub(super) fn transact_response(o: &crate::transaction::Outcome) -> pb::TransactResponse {
    pb::TransactResponse {
        actual: o.actual,
        state: o.state,
        value: o.value,
        error: o.error.unwrap_or_default().to_owned(),
        request: o.request.clone(),
        response: o.response.clone().unwrap_or_default(),
        elapsed_ms: o.elapsed_ms,
    }
}

pub(super) fn transaction_status(
    s: &crate::service::Standing,
    st: &crate::service::StandingStatus,
) -> pb::TransactionStatus {
    pb::TransactionStatus {
        name: s.name.clone(),
        link: s.link.clone(),
        kind: if s.is_write { "write" } else { "read" }.to_owned(),
        enabled: st.enabled,
        period_ms: u32::try_from(s.period.as_millis()).unwrap_or(u32::MAX),
        last: st.last.as_ref().map(transact_response),
        runs: st.runs,
        failures: st.failures,
        updated: st.updated.map(prost_types::Timestamp::from),
        state: st.state(),
    }
}

pub(super) fn ack(a: Accepted) -> pb::WriteAck {
    pb::WriteAck {
        device: a.device,
        field: a.field,
        generation: a.generation,
    }
}

impl GrpcApi {
    pub(crate) fn new(service: Arc<Service>) -> Self {
        GrpcApi { service }
    }

    /// The server for this service.
    pub(crate) fn server(service: Arc<Service>) -> GatewayRoutes {
        let api = Arc::new(GrpcApi::new(service));
        GatewayRoutes {
            generated: GatewayServer::from_arc(api.clone())
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            api,
        }
    }

    /// `Subscribe`: the selection's current values, then each change, as encoded `Update`s;
    /// a field's change is encoded once for all its subscribers (the slot's [`GRPC_FORM`]).
    pub(super) fn subscribe_encoded(
        &self,
        r: pb::SubscribeRequest,
        client: Option<std::net::IpAddr>,
    ) -> Result<EncodedStream, Status> {
        self.service.accepting().map_err(status)?;
        let selection = self.select(&r.devices, &r.fields)?;
        let changes = self
            .service
            .subscribe_for(selection, r.diagnostics, client)
            .map_err(status)?;
        let viewer = self.service.clone();
        let updates = changes.map(move |change| {
            Ok(match change {
                Change::Value {
                    device,
                    idx,
                    sample,
                    forms,
                } => forms.get_or_make(GRPC_FORM, || {
                    encoded(pb::update::Kind::Value(to_pb::field_value(
                        &viewer.field_view(&device, idx, &sample),
                    )))
                }),
                Change::Diagnostics {
                    device,
                    diagnostics,
                } => encoded(pb::update::Kind::Diagnostics(to_pb::diagnostics(
                    &device,
                    &diagnostics,
                ))),
                Change::Removed {
                    device,
                    field,
                    reason,
                } => encoded(pb::update::Kind::Removed(pb::Removed {
                    device,
                    field: field.unwrap_or_default(),
                    reason: reason.to_owned(),
                })),
            })
        });
        if !r.transactions {
            return Ok(Box::pin(updates));
        }
        let transactions = self.service.transaction_changes().map(|(s, st)| {
            Ok(encoded(pb::update::Kind::Transaction(transaction_status(
                &s, &st,
            ))))
        });
        Ok(Box::pin(futures_util::stream::select(
            updates,
            transactions,
        )))
    }

    pub(super) fn select(
        &self,
        devices: &[String],
        fields: &[pb::FieldRef],
    ) -> Result<crate::service::Selection, Status> {
        let pairs: Vec<(&str, &str)> = fields
            .iter()
            .map(|f| (f.device.as_str(), f.field.as_str()))
            .collect();
        self.service.select(devices, &pairs).map_err(status)
    }

    /// Converts and checks one write; nothing is written.
    pub(super) fn prepare(service: &Service, w: &pb::FieldWrite) -> Result<Prepared, ServiceError> {
        if w.relinquish {
            return service.prepare_relinquish_named(&w.device, &w.field, w.value.is_some());
        }
        service.prepare_named(&w.device, &w.field, |ty| match &w.value {
            Some(v) => Value::from_pb_as(ty, v),
            None => Err(ValueError::Missing { ty }),
        })
    }
}
