//! `iogatectl describe`.

use super::*;

/// `describe device NAME` and `describe profile NAME [--st]`.
pub(crate) async fn describe(
    client: &mut Client,
    what: Describe,
    json: bool,
) -> anyhow::Result<ExitCode> {
    match what {
        Describe::Device { name } => {
            let device = client.device(&name).await?;
            if json {
                print_json(&device)?;
            } else {
                println!(
                    "device {} (profile {}, {})",
                    device.name, device.profile, device.protocol
                );
                if let Some(link) = &device.link {
                    println!("link {link}, slave {}", device.slave_id.unwrap_or(0));
                }
                println!(
                    "refresh every {} ms, timeout {} ms",
                    device.refresh_rate_ms, device.timeout_ms
                );
                if let Some(d) = &device.diagnostics {
                    println!(
                        "connected={} error_code={} io_cycles={} last_response_ms={:.3}",
                        d.connected, d.error_code, d.io_cycles, d.last_response_ms
                    );
                }
                println!();
                print!("{}", field_table(&device.fields));
            }
        }
        Describe::Profile { name, st } => {
            let profile = client.profile(&name).await?;
            if st {
                print!("{}", profile.st_declaration);
            } else if json {
                print_json(&profile)?;
            } else {
                println!(
                    "profile {} ({}) {}",
                    profile.name, profile.protocol, profile.description
                );
                println!("\nfunction block layout:");
                for m in &profile.layout {
                    println!(
                        "  {:<10} {:<20} : {:<6} ({})",
                        m.section,
                        m.name,
                        m.ty.map_or("", |t| t.name()),
                        m.role
                    );
                }
                println!("\nfields:");
                for f in &profile.fields {
                    println!(
                        "  {:<24} {:<6} {:<7} {} {}{}",
                        f.name,
                        f.ty.map_or("", |t| t.name()),
                        format!("{:?}", f.direction).to_lowercase(),
                        f.kind,
                        f.address,
                        if f.unit.is_empty() {
                            String::new()
                        } else {
                            format!(" [{}]", f.unit)
                        }
                    );
                }
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
