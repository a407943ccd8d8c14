//! The ST declarations of the two function blocks a remote runtime uses for raw
//! transactions (implemented in the client crate as `fb::ModbusRead` and
//! `fb::ModbusWrite`), for `iogate fb st`.

/// Both declarations.
pub fn declarations() -> String {
    format!("{READ}\n{WRITE}")
}

const READ: &str = "\
FUNCTION_BLOCK ModbusRead
VAR_INPUT
    IN : BOOL;                    (* main input; a read starts on it per input_edge *)
    server : STRING;              (* the link (RS485 configuration) *)
    input_edge : STRING := 'rising'; (* rising, falling, both, true, false, null, none *)
    functionCode : USINT;         (* 1 coils, 2 discrete inputs, 3 holding, 4 input registers *)
    deviceAddress : USINT;        (* 1-255 *)
    registerAddress : UINT;       (* 0-65535 *)
    bitCount : USINT;             (* functions 1 and 2: 1-32 *)
    valueType : STRING;           (* SIGNED_NUMBER16, SIGNED_NUMBER32, UNSIGNED_NUMBER16, UNSIGNED_NUMBER32, FLOAT *)
    divisor : UDINT := 1;         (* 1-4294967295, no rounding *)
    precision : USINT := 3;       (* 0-3 digits kept, truncated *)
    endianess : STRING;           (* LittleEndian, BigEndian, SwapBytes, SwapWords *)
    refreshInterval : TIME := T#0ms; (* 0: no cyclic reads; the first about 2 s after start *)
    responseTimeout : TIME := T#1s; (* 10 ms - 60 s *)
END_VAR
VAR_OUTPUT
    value : LREAL;                (* the last value read correctly *)
    ok : BOOL;                    (* the last read succeeded *)
    status : STRING;              (* the value, or the error message *)
END_VAR
END_FUNCTION_BLOCK
";

const WRITE: &str = "\
FUNCTION_BLOCK ModbusWrite
VAR_INPUT
    enable : BOOL;                (* TRUE: send, and again every polling period *)
    value0 : LREAL;               (* value0 .. valueX: the values to write *)
    link : STRING;                (* the link (the block's Interface) *)
    pollingPeriod : TIME := T#1s; (* from the start of the previous transaction *)
    timeout : TIME := T#100ms;
    functionCode : USINT;         (* the block's Function: 5, 6, 15, 16 *)
    networkNumber : USINT;        (* the slave, 1-255 *)
    dataAddress : UINT;
    dataType : STRING;            (* the block's Type: uint8, int8, uint16, int16, int32, float, int32/float *)
    byteOrder : STRING;           (* Little-endian, Big-endian, Big-endian (2 bytes) *)
END_VAR
VAR_OUTPUT
    actual : BOOL;                (* the last command got a correct response *)
    state : DINT;                 (* 0 not active, 1 waiting, 2 access, 3 in progress, 4 done, -1 interface unavailable, -2 timeout, -3 unknown error *)
END_VAR
END_FUNCTION_BLOCK
";
