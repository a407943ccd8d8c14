//! The front-ends over the service layer: REST under `/api/v1`, Server-Sent Events,
//! health, OpenAPI and metrics on the HTTP listener; the gRPC service (with health and
//! reflection) on its own. Each handler parses, calls the service, and maps the answer.

pub(crate) mod convert;
pub(crate) mod front_end;
pub(crate) mod grpc;
pub(crate) mod http;
pub(crate) mod iec104_server;

pub(crate) use http::{error, rest};
pub(crate) mod modbus_serial;
pub(crate) mod modbus_server;
pub(crate) mod mqtt;
pub(crate) mod opcua;

pub(crate) use grpc::serve::serve_grpc;
pub(crate) use http::{ApiDoc, serve_http};
