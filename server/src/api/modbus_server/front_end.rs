//! The Modbus TCP server as one of the front-ends: `modbus_server.listen` bound when
//! prepared, served again when it moves, stopped when it goes. The memory it serves is the
//! service's located image, which a reload rebuilds under it.

use futures_util::future::BoxFuture;

use crate::api::front_end::{FrontEnd, Listen, Prepare, Running, Start, Starting};
use crate::config::Config;
use crate::service::Service;

pub(crate) struct ModbusTcpFrontEnd;

/// Where `config`'s Modbus TCP server listens, when it has one.
fn listen(config: &Config) -> Option<std::net::SocketAddr> {
    config.modbus_server.as_ref().and_then(|s| s.listen)
}

impl FrontEnd for ModbusTcpFrontEnd {
    fn name(&self) -> &'static str {
        "modbus"
    }

    fn listener(&self) -> Option<&'static str> {
        Some("modbus")
    }

    fn banner(&self, service: &Service) -> Vec<String> {
        service
            .listening
            .bound("modbus")
            .map(|addr| format!("Modbus TCP: {addr} (iogate map prints the located addresses)"))
            .into_iter()
            .collect()
    }

    fn restarts(&self, old: &Config, new: &Config) -> bool {
        listen(old) != listen(new)
    }

    fn prepare<'a>(
        &'a self,
        prepare: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        Box::pin(async move {
            let Some(to) = listen(prepare.config) else {
                return Ok(None);
            };
            let was = prepare.old.and_then(listen);
            let listen =
                Listen::prepare(prepare, to, was, "modbus_server.listen", "--modbus").await?;
            Ok(Some(
                Box::new(ModbusTcpStarting(listen)) as Box<dyn Starting>
            ))
        })
    }
}

struct ModbusTcpStarting(Listen);

impl Starting for ModbusTcpStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        Box::pin(async move {
            let service = start.service;
            let serving = service.clone();
            let serve = move |listener, stop| super::serve_modbus(listener, serving, stop);
            let key = "modbus_server.listen";
            (*self)
                .0
                .serve(key, "modbus", &service, |addr| addr.to_string(), serve)
                .await
        })
    }
}
