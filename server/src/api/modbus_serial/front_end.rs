//! The Modbus serial server as one of the front-ends: one task that opens, keeps and
//! closes the ports the located image's configuration names, following each reload
//! itself (a changed port restarted, the others kept), so a reload never restarts it.

use futures_util::future::BoxFuture;
use tokio_util::sync::CancellationToken;

use crate::api::front_end::{Carried, FrontEnd, Prepare, Running, Start, Starting};
use crate::config::Config;
use crate::service::Service;

pub(crate) struct ModbusSerialFrontEnd;

impl FrontEnd for ModbusSerialFrontEnd {
    fn name(&self) -> &'static str {
        "modbus_serial"
    }

    fn restarts(&self, _old: &Config, _new: &Config) -> bool {
        false
    }

    fn prepare<'a>(
        &'a self,
        _prepare: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        Box::pin(std::future::ready(Ok(Some(
            Box::new(SerialStarting) as Box<dyn Starting>
        ))))
    }
}

struct SerialStarting;

impl Starting for SerialStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        let service = start.service;
        let stop = service.tasks().token().child_token();
        service
            .tasks()
            .spawn(super::serve_serial(service.clone(), stop.clone()));
        Box::pin(std::future::ready(Ok(
            Box::new(SerialRunning(stop)) as Box<dyn Running>
        )))
    }
}

/// The serial server's task, and what stops it.
struct SerialRunning(CancellationToken);

impl Running for SerialRunning {
    fn stop(
        self: Box<Self>,
        _service: std::sync::Arc<Service>,
    ) -> BoxFuture<'static, Result<Carried, String>> {
        self.0.cancel();
        Box::pin(std::future::ready(Ok(None)))
    }
}
