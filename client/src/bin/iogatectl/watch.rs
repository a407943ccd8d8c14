//! `iogatectl watch`.

use super::*;

/// `watch`: a live table on a terminal, a line per change when piped, JSON lines with
/// `--json`.
pub(crate) async fn watch(
    client: &mut Client,
    devices: Vec<String>,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let selection = Selection {
        devices,
        fields: Vec::new(),
    };
    let mut updates = client.subscribe(&selection, true).await?;
    let live = std::io::stdout().is_terminal() && !json;
    let mut table: BTreeMap<(String, String), FieldValue> = BTreeMap::new();
    let mut diagnostics = BTreeMap::new();
    let mut drawn = Instant::now() - Duration::from_secs(1);
    while let Some(update) = updates.next().await {
        let update = update?;
        if json {
            println!("{}", serde_json::to_string(&update)?);
            continue;
        }
        if !live {
            match &update {
                Update::Value(v) => println!(
                    "{}.{} = {} ({})",
                    v.device,
                    v.field,
                    show(v),
                    v.quality.name()
                ),
                Update::Diagnostics(d) => println!(
                    "{}: connected={} error_code={}",
                    d.device, d.connected, d.error_code
                ),
                Update::Removed {
                    device,
                    field,
                    reason,
                } => match field {
                    Some(f) => println!("{device}.{f} removed: {reason}"),
                    None => println!("{device} removed: {reason}"),
                },
            }
            continue;
        }
        match update {
            Update::Value(v) => {
                table.insert((v.device.clone(), v.field.clone()), v);
            }
            Update::Diagnostics(d) => {
                diagnostics.insert(d.device.clone(), d);
            }
            Update::Removed { device, field, .. } => match field {
                Some(f) => {
                    table.remove(&(device, f));
                }
                None => {
                    table.retain(|(d, _), _| *d != device);
                    diagnostics.remove(&device);
                }
            },
        }
        if drawn.elapsed() >= Duration::from_millis(100) {
            drawn = Instant::now();
            let values: Vec<FieldValue> = table.values().cloned().collect();
            let mut screen = String::from("\x1b[2J\x1b[H");
            for d in diagnostics.values() {
                screen.push_str(&format!(
                    "{}: connected={} error_code={} io_cycles={}\n",
                    d.device, d.connected, d.error_code, d.io_cycles
                ));
            }
            screen.push('\n');
            screen.push_str(&field_table(&values));
            print!("{screen}");
            std::io::stdout().flush()?;
        }
    }
    Ok(ExitCode::SUCCESS)
}
