//! Where the gateway's servers listen, as bound (a port 0 resolved), so that the overview
//! can say how to reach each of them.

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

/// The servers listening now, in the order they first listened (a server that stops and
/// listens again keeps its place).
#[derive(Debug, Default)]
pub(crate) struct Listening(std::sync::RwLock<Vec<(&'static str, Option<Bound>)>>);

/// Where a server is bound, and how a client reaches it.
type Bound = (SocketAddr, String);

impl Listening {
    /// `server` listens on `addr`: a client reaches it at `address` (each server says its
    /// own form).
    pub(crate) fn set(&self, server: &'static str, addr: SocketAddr, address: String) {
        let mut servers = self.0.write().unwrap_or_else(|e| e.into_inner());
        match servers.iter_mut().find(|(name, _)| *name == server) {
            Some((_, at)) => *at = Some((addr, address)),
            None => servers.push((server, Some((addr, address)))),
        }
    }

    /// Where `server` listens, while it does.
    pub(crate) fn bound(&self, server: &str) -> Option<SocketAddr> {
        self.find(server).map(|(addr, _)| addr)
    }

    /// How a client reaches `server`, while it listens.
    pub(crate) fn address(&self, server: &str) -> Option<String> {
        self.find(server).map(|(_, address)| address)
    }

    /// `server` no longer listens.
    pub(crate) fn remove(&self, server: &str) {
        let mut servers = self.0.write().unwrap_or_else(|e| e.into_inner());
        if let Some((_, at)) = servers.iter_mut().find(|(name, _)| *name == server) {
            *at = None;
        }
    }

    fn find(&self, server: &str) -> Option<Bound> {
        let servers = self.0.read().unwrap_or_else(|e| e.into_inner());
        let (_, at) = servers.iter().find(|(name, _)| *name == server)?;
        at.clone()
    }

    pub(crate) fn list(&self) -> Vec<Listener> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .filter_map(|(server, at)| {
                at.as_ref().map(|(_, address)| Listener {
                    server: (*server).to_owned(),
                    address: address.clone(),
                })
            })
            .collect()
    }
}
