//! Where the gateway's servers listen, as bound (a port 0 resolved), so that the overview
//! can say how to reach each of them.

use std::collections::BTreeMap;
use std::net::SocketAddr;

use serde::Serialize;

/// A server of the gateway that listens on a TCP port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Server {
    /// REST, Server-Sent Events, `/metrics` and the web page.
    Http,
    Grpc,
    /// The Modbus TCP server.
    Modbus,
    Opcua,
}

/// One server and how a client reaches it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Listener {
    pub server: Server,
    /// What a client connects to: `http(s)://host:port`, `host:port`, `opc.tcp://host:port/`.
    pub address: String,
}

/// The servers listening now.
#[derive(Debug, Default)]
pub(crate) struct Listening(std::sync::RwLock<BTreeMap<Server, String>>);

impl Listening {
    /// `server` listens at `addr` (`secure`: HTTP over TLS).
    pub(crate) fn set(&self, server: Server, addr: SocketAddr, secure: bool) {
        let address = match server {
            Server::Http if secure => format!("https://{addr}"),
            Server::Http => format!("http://{addr}"),
            Server::Grpc | Server::Modbus => addr.to_string(),
            Server::Opcua => format!("opc.tcp://{addr}/"),
        };
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(server, address);
    }

    /// `server` no longer listens.
    pub(crate) fn remove(&self, server: Server) {
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&server);
    }

    pub(crate) fn list(&self) -> Vec<Listener> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .map(|(server, address)| Listener {
                server: *server,
                address: address.clone(),
            })
            .collect()
    }
}
