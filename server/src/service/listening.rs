//! Where the gateway's servers listen, as bound (a port 0 resolved), so that the overview
//! can say how to reach each of them.

use std::collections::BTreeMap;
use std::net::SocketAddr;

use serde::Serialize;

/// One server and how a client reaches it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Listener {
    /// The server's name: `http` (REST, Server-Sent Events, `/metrics` and the web page),
    /// `grpc`, `modbus` (the Modbus TCP server), `opcua`.
    pub server: String,
    /// What a client connects to: `http(s)://host:port`, `host:port`, `opc.tcp://host:port/`.
    pub address: String,
}

/// The servers listening now.
#[derive(Debug, Default)]
pub(crate) struct Listening(std::sync::RwLock<BTreeMap<&'static str, (SocketAddr, String)>>);

impl Listening {
    /// `server` listens on `addr`: a client reaches it at `address` (each server says its
    /// own form).
    pub(crate) fn set(&self, server: &'static str, addr: SocketAddr, address: String) {
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(server, (addr, address));
    }

    /// Where `server` listens, while it does.
    pub(crate) fn bound(&self, server: &str) -> Option<SocketAddr> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(server)
            .map(|(addr, _)| *addr)
    }

    /// How a client reaches `server`, while it listens.
    pub(crate) fn address(&self, server: &str) -> Option<String> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(server)
            .map(|(_, address)| address.clone())
    }

    /// `server` no longer listens.
    pub(crate) fn remove(&self, server: &str) {
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .remove(server);
    }

    pub(crate) fn list(&self) -> Vec<Listener> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .map(|(server, (_, address))| Listener {
                server: (*server).to_owned(),
                address: address.clone(),
            })
            .collect()
    }
}
