//! `iogatectl`: look at and drive an iogate gateway over gRPC.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use futures_util::StreamExt;
use iogate_client::{Client, FieldValue, Selection, Update, Value, WriteOutcome};
use serde::Serialize;

#[path = "iogatectl/describe.rs"]
mod describe;
#[path = "iogatectl/format.rs"]
mod format;
#[path = "iogatectl/watch.rs"]
mod watch;

use format::{field_table, print_json, show, split_target};

#[derive(Parser)]
#[command(
    name = "iogatectl",
    version,
    about = "Look at and drive an iogate gateway over gRPC"
)]
struct Cli {
    /// The gateway's gRPC address; both nodes' of an active/standby pair, separated by a
    /// comma (`http://gw-a:50051,http://gw-b:50051`): iogatectl talks to the active.
    #[arg(
        long,
        short,
        env = "IOGATE_SERVER",
        default_value = "http://127.0.0.1:50051"
    )]
    server: String,
    /// Print JSON (one document, or one line per update for `watch`) for scripts.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Devices with their diagnostics.
    Devices,
    /// The gateway in its active/standby pair: node, role, epoch, the active.
    Ha,
    /// Links with their state.
    Links,
    /// Loaded profiles.
    Profiles,
    /// A device's fields (`get DEVICE`) or one field (`get DEVICE.FIELD` or `get %QX0.0`).
    Get { target: String },
    /// Writes a field: `set DEVICE.FIELD VALUE` (or `set %QW2 VALUE`); waits for the outcome.
    Set {
        target: String,
        value: String,
        /// How long to wait for the write's outcome, in milliseconds (0: don't wait).
        #[arg(long, default_value_t = 2000)]
        wait_ms: u64,
    },
    /// Relinquishes an output: `relinquish DEVICE.FIELD` (BACnet: NULL at the field's
    /// priority, so a lower priority or the relinquish default takes over); waits for the
    /// outcome.
    Relinquish {
        target: String,
        /// How long to wait for the write's outcome, in milliseconds (0: don't wait).
        #[arg(long, default_value_t = 2000)]
        wait_ms: u64,
    },
    /// A live table of values; `watch DEVICE...` for some devices only.
    Watch { devices: Vec<String> },
    /// One raw Modbus transaction through the gateway, queued between its polls: mbpoll
    /// through the gateway. `tx rs485 -f 3 -s 1 -a 0 --value-type FLOAT --byte-order
    /// BigEndian`, `tx rs485 -f 6 -s 17 -a 1 --type uint8 3`.
    Tx {
        /// The link.
        link: String,
        /// Function code: 1-4 read, 5, 6, 15, 16 write.
        #[arg(short, long)]
        function: u32,
        /// Slave (device address, network number), 1-255.
        #[arg(short, long)]
        slave: u32,
        /// First coil or register, 0-65535.
        #[arg(short, long, default_value_t = 0)]
        address: u32,
        /// FC01/02: bits to read, 1-32.
        #[arg(long, default_value_t = 0)]
        bit_count: u32,
        /// FC03/04: SIGNED_NUMBER16, SIGNED_NUMBER32, UNSIGNED_NUMBER16, UNSIGNED_NUMBER32, FLOAT.
        #[arg(long, default_value = "")]
        value_type: String,
        /// Reads: the value is divided by this.
        #[arg(long, default_value_t = 0)]
        divisor: u64,
        /// Reads: digits kept after the point (truncated), 0-3.
        #[arg(long)]
        precision: Option<u32>,
        /// LittleEndian, BigEndian, SwapBytes, SwapWords (or Little-endian, Big-endian, Big-endian (2 bytes)).
        #[arg(long, default_value = "")]
        byte_order: String,
        /// Response timeout in ms, 10-60000 (default 1000).
        #[arg(long, default_value_t = 0)]
        timeout_ms: u32,
        /// Writes: uint8, int8, uint16, int16, int32 (an integer), float (IEEE-754); int32/float is IEEE-754 (values are doubles).
        #[arg(long = "type", default_value = "")]
        write_type: String,
        /// Writes: the values.
        #[arg(allow_negative_numbers = true)]
        values: Vec<f64>,
    },
    /// A device (`describe device NAME`) or a profile (`describe profile NAME`).
    Describe {
        #[command(subcommand)]
        what: Describe,
    },
}

#[derive(Subcommand)]
enum Describe {
    Device {
        name: String,
    },
    Profile {
        name: String,
        /// Print only the ST function-block declaration.
        #[arg(long)]
        st: bool,
    },
}

async fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    let urls: Vec<String> = cli
        .server
        .split(',')
        .map(|u| u.trim().to_owned())
        .filter(|u| !u.is_empty())
        .collect();
    let mut client = Client::connect_pair(&urls).await?;
    let json = cli.json;
    match cli.command {
        Command::Devices => devices(&mut client, json).await?,
        Command::Links => links(&mut client, json).await?,
        Command::Ha => {
            let ha = client.ha().await?;
            let active = ha.active_grpc.as_deref().unwrap_or("-");
            if json {
                let fields = [
                    ("node", &ha.node),
                    ("role", &ha.role),
                    ("active", &ha.active_node),
                ];
                let mut doc: serde_json::Map<_, _> = fields
                    .iter()
                    .map(|(k, v)| ((*k).to_owned(), (*v).clone().into()))
                    .collect();
                doc.insert("epoch".into(), ha.epoch.into());
                doc.insert("active_grpc".into(), active.into());
                print_json(&doc)?;
            } else {
                println!(
                    "{} {} epoch {} active {} ({active})",
                    ha.node, ha.role, ha.epoch, ha.active_node
                );
            }
        }
        Command::Profiles => profiles(&mut client, json).await?,
        Command::Get { target } => get(&mut client, &target, json).await?,
        Command::Set {
            target,
            value,
            wait_ms,
        } => return set(&mut client, &target, Some(&value), wait_ms, json).await,
        Command::Relinquish { target, wait_ms } => {
            return set(&mut client, &target, None, wait_ms, json).await;
        }
        Command::Watch { devices } => return watch::watch(&mut client, devices, json).await,
        Command::Tx {
            link,
            function,
            slave,
            address,
            bit_count,
            value_type,
            divisor,
            precision,
            byte_order,
            timeout_ms,
            write_type,
            values,
        } => {
            let request = iogate_client::proto::TransactRequest {
                link,
                function,
                slave,
                address,
                bit_count,
                value_type,
                divisor,
                precision,
                byte_order,
                timeout_ms,
                r#type: write_type,
                values,
            };
            return tx(&mut client, request, json).await;
        }
        Command::Describe { what } => return describe::describe(&mut client, what, json).await,
    }
    Ok(ExitCode::SUCCESS)
}

/// `devices`: a line each, with its diagnostics.
async fn devices(client: &mut Client, json: bool) -> anyhow::Result<()> {
    let devices = client.devices().await?;
    if json {
        print_json(&devices)?;
    } else {
        println!(
            "{:<16} {:<22} {:<10} {:>5} {:>9} {:>5} {:>10} {:>9}",
            "DEVICE", "PROFILE", "LINK", "SLAVE", "CONNECTED", "ERROR", "IO_CYCLES", "LAST_MS"
        );
        for d in devices {
            let diag = d.diagnostics.clone().unwrap_or(iogate_client::Diagnostics {
                device: d.name.clone(),
                connected: false,
                error_code: 0,
                io_cycles: 0,
                last_response_ms: 0.0,
            });
            println!(
                "{:<16} {:<22} {:<10} {:>5} {:>9} {:>5} {:>10} {:>9.3}",
                d.name,
                d.profile,
                d.link.as_deref().unwrap_or("-"),
                d.slave_id.map_or_else(|| "-".to_owned(), |s| s.to_string()),
                diag.connected,
                diag.error_code,
                diag.io_cycles,
                diag.last_response_ms
            );
        }
    }
    Ok(())
}

/// `links`: a line each, with its devices.
async fn links(client: &mut Client, json: bool) -> anyhow::Result<()> {
    let links = client.links().await?;
    if json {
        print_json(&links)?;
    } else {
        println!(
            "{:<16} {:<40} {:>9} {:>5}  DEVICES",
            "LINK", "ENDPOINT", "CONNECTED", "ERROR"
        );
        for l in links {
            println!(
                "{:<16} {:<40} {:>9} {:>5}  {}",
                l.name,
                l.endpoint,
                l.connected,
                l.error_code,
                l.devices.join(", ")
            );
        }
    }
    Ok(())
}

/// `profiles`: a line each.
async fn profiles(client: &mut Client, json: bool) -> anyhow::Result<()> {
    let profiles = client.profiles().await?;
    if json {
        print_json(&profiles)?;
    } else {
        println!(
            "{:<24} {:<12} {:>6}  DESCRIPTION",
            "PROFILE", "PROTOCOL", "FIELDS"
        );
        for p in profiles {
            println!(
                "{:<24} {:<12} {:>6}  {}",
                p.name, p.protocol, p.field_count, p.description
            );
        }
    }
    Ok(())
}

/// `get DEVICE[.FIELD]` or a located address.
async fn get(client: &mut Client, target: &str, json: bool) -> anyhow::Result<()> {
    let (device, field) = split_target(target);
    let selection = match field {
        Some(f) => Selection::field(device, f),
        None => Selection::device(device),
    };
    let values = client.read(&selection).await?;
    if json {
        match (field, values.as_slice()) {
            (Some(_), [one]) => print_json(one)?,
            _ => print_json(&values)?,
        }
    } else {
        print!("{}", field_table(&values));
    }
    Ok(())
}

/// `set DEVICE.FIELD VALUE` (or a located address): the write and its outcome; a failed
/// write is a failure of the command. No value: `relinquish DEVICE.FIELD`.
async fn set(
    client: &mut Client,
    target: &str,
    value: Option<&str>,
    wait_ms: u64,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let (device, field) = match split_target(target) {
        ("", Some(at)) => {
            let bound = client.get("", at).await?;
            (bound.device, bound.field)
        }
        (device, Some(field)) => (device.to_owned(), field.to_owned()),
        _ => anyhow::bail!("write DEVICE.FIELD or a located address, e.g. sim.DO_0 or %QX0.0"),
    };
    let (device, field) = (device.as_str(), field.as_str());
    let Some(value) = value else {
        let generation = client.relinquish(device, field).await?;
        return outcome(client, device, field, generation, wait_ms, json).await;
    };
    let info = client.device(device).await?;
    let current = info
        .fields
        .iter()
        .find(|f| f.field.eq_ignore_ascii_case(field))
        .ok_or_else(|| anyhow::anyhow!("device {device} has no field `{field}`"))?;
    let ty = client
        .profile(&info.profile)
        .await?
        .fields
        .iter()
        .find(|f| f.name == current.field)
        .and_then(|f| f.ty)
        .ok_or_else(|| anyhow::anyhow!("the profile does not give {field}'s type"))?;
    let value = Value::parse(ty, value)?;
    let generation = client.write(device, &current.field, value).await?;
    outcome(client, device, &current.field, generation, wait_ms, json).await
}

/// Waits for write `generation`'s outcome and prints it; a failed write is a failure of the
/// command.
async fn outcome(
    client: &mut Client,
    device: &str,
    field: &str,
    generation: u64,
    wait_ms: u64,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let status = if wait_ms > 0 {
        client
            .wait_write(generation, Duration::from_millis(wait_ms))
            .await?
    } else {
        client.write_status(generation).await?
    };
    if json {
        print_json(&status)?;
    } else {
        let outcome = match &status.outcome {
            WriteOutcome::Pending => "pending".to_owned(),
            WriteOutcome::Written => "written".to_owned(),
            WriteOutcome::Superseded => "superseded".to_owned(),
            WriteOutcome::Failed(e) => format!("failed: {e}"),
        };
        println!("{device}.{field} write {generation}: {outcome}");
    }
    if matches!(status.outcome, WriteOutcome::Failed(_)) {
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// `tx`: a raw transaction on a link, its request and response; one that did not happen
/// is a failure of the command.
async fn tx(
    client: &mut Client,
    request: iogate_client::proto::TransactRequest,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let outcome = client.transact(request).await?;
    if json {
        print_json(&outcome)?;
    } else {
        let state = match outcome.state {
            4 => "done",
            -1 => "interface unavailable",
            -2 => "response timeout",
            -3 => "error",
            _ => "?",
        };
        match (outcome.value, &outcome.error) {
            (Some(v), _) => println!("value {v}"),
            (None, Some(e)) => println!("error {e}"),
            (None, None) => println!("written"),
        }
        println!(
            "actual {}  state {} ({state})  {:.1} ms",
            outcome.actual, outcome.state, outcome.elapsed_ms
        );
        println!("> {}", outcome.request);
        println!(
            "< {}",
            outcome.response.as_deref().unwrap_or("(no response)")
        );
    }
    if !outcome.actual {
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("iogatectl: cannot start: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(cli)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("iogatectl: {}", describe(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes, each said once: a cause whose words its error already
/// carries (`cannot connect to ...: transport error` over `transport error`) is left out.
fn describe(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}
