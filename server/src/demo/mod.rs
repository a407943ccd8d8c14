//! The built-in demo: simulated devices, and every shipped profile to browse, compiled into
//! the binary so that `iogate serve` works anywhere with nothing configured.

pub(crate) mod field;
pub(crate) mod motion;

use crate::config::{self, Config};
use crate::profile::{self, Catalog};
use crate::yaml::Problems;

/// The demo configuration (`examples/demo.yaml`).
pub(crate) const CONFIG: (&str, &str) = (
    "examples/demo.yaml",
    include_str!("../../../examples/demo.yaml"),
);

/// The shipped profiles (`profiles/`).
pub(crate) const PROFILES: &[(&str, &str)] = &[
    (
        "profiles/energy_meter_sdm630.yaml",
        include_str!("../../../profiles/energy_meter_sdm630.yaml"),
    ),
    (
        "profiles/generic_io_module.yaml",
        include_str!("../../../profiles/generic_io_module.yaml"),
    ),
    (
        "profiles/sim_io.yaml",
        include_str!("../../../profiles/sim_io.yaml"),
    ),
    (
        "profiles/sim_plant.yaml",
        include_str!("../../../profiles/sim_plant.yaml"),
    ),
    (
        "profiles/vfd.yaml",
        include_str!("../../../profiles/vfd.yaml"),
    ),
    (
        "profiles/waveshare_analog_input.yaml",
        include_str!("../../../profiles/waveshare_analog_input.yaml"),
    ),
    (
        "profiles/waveshare_io_8ch.yaml",
        include_str!("../../../profiles/waveshare_io_8ch.yaml"),
    ),
    (
        "profiles/waveshare_relay_8ch.yaml",
        include_str!("../../../profiles/waveshare_relay_8ch.yaml"),
    ),
];

/// The demo's config and profiles.
pub(crate) fn load() -> Result<(Config, Catalog), Problems> {
    let config = config::parse(CONFIG.0, CONFIG.1)?;
    let catalog = Catalog::new(profile::load_files(PROFILES.iter().copied())?);
    config::check_devices(&config, &catalog)?;
    Ok((config, catalog))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_loads() {
        let (config, catalog) = load().expect("demo is valid");
        assert!(!config.devices.is_empty());
        assert_eq!(catalog.len(), PROFILES.len());
    }

    #[test]
    fn every_shipped_profile_is_embedded() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles");
        let mut on_disk: Vec<String> = std::fs::read_dir(&dir)
            .expect("profiles dir")
            .filter_map(Result::ok)
            .map(|e| format!("profiles/{}", e.file_name().to_string_lossy()))
            .collect();
        on_disk.sort();
        let embedded: Vec<String> = PROFILES.iter().map(|(n, _)| n.to_string()).collect();
        assert_eq!(embedded, on_disk);
    }
}
