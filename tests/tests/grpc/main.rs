//! The gRPC API through the client crate, against a gateway on loopback port 0.

mod services;
mod values_and_declarations;

use std::time::Duration;

use futures_util::StreamExt;
use iogate_client::{
    Client, DeviceDeclaration, Error, IecType, Quality, Selection, SerialLink, Update, Value,
    WriteOutcome,
};
use reqwest::Method;
use tonic::Code;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
use iogate_tests::{TestGateway, eventually};

async fn demo() -> (TestGateway, Client) {
    let gw = TestGateway::demo().await.expect("demo");
    let client = gw.client().await.expect("client");
    (gw, client)
}

fn code(result: Result<impl std::fmt::Debug, Error>) -> (Code, String) {
    match result {
        Err(Error::Status { code, message }) => (code, message),
        other => panic!("expected a status, got {other:?}"),
    }
}

/// Sends bytes as they are and answers the bytes received: a client that is not well behaved.
#[derive(Clone, Copy, Default)]
struct RawCodec;

impl tonic::codec::Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawCodec;
    type Decoder = RawCodec;

    fn encoder(&mut self) -> RawCodec {
        RawCodec
    }

    fn decoder(&mut self) -> RawCodec {
        RawCodec
    }
}

impl tonic::codec::Encoder for RawCodec {
    type Item = Vec<u8>;
    type Error = tonic::Status;

    fn encode(
        &mut self,
        item: Vec<u8>,
        dst: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), tonic::Status> {
        bytes::BufMut::put_slice(dst, &item);
        Ok(())
    }
}

impl tonic::codec::Decoder for RawCodec {
    type Item = Vec<u8>;
    type Error = tonic::Status;

    fn decode(
        &mut self,
        src: &mut tonic::codec::DecodeBuf<'_>,
    ) -> Result<Option<Vec<u8>>, tonic::Status> {
        let mut bytes = vec![0; bytes::Buf::remaining(src)];
        bytes::Buf::copy_to_slice(src, &mut bytes);
        Ok(Some(bytes))
    }
}
