//! `Setup`: a config file (or the built-in demo) with its profiles, checked: what `check`
//! validates, `serve` runs and a reload compares with what runs.

use std::path::{Path, PathBuf};

use crate::config::{self, Config};
use crate::profile::{self, Catalog};
use crate::yaml::{Problems, Report};

/// The config file looked for in the working directory when none is given.
pub(crate) const DEFAULT_CONFIG: &str = "iogate.yaml";

/// A checked configuration with its profiles: what `check` validates and `serve` runs.
#[derive(Debug, Clone)]
pub struct Setup {
    pub config: Config,
    pub catalog: Catalog,
    /// The profiles directory used, if any.
    pub profiles_dir: Option<PathBuf>,
    /// Whether this is the built-in demo.
    pub demo: bool,
    /// The Modbus TCP server's bindings, when it is configured.
    pub map: Option<crate::map::Plan>,
}

/// Listeners moved from the command line (`serve --http ...`), over the config's.
#[derive(Debug, Clone, Default)]
pub struct Listeners {
    pub http: Option<std::net::SocketAddr>,
    pub grpc: Option<std::net::SocketAddr>,
    pub modbus: Option<std::net::SocketAddr>,
    /// The listeners of front-ends' sections, by section (`opcua`).
    pub sections: Vec<(&'static str, std::net::SocketAddr)>,
}

impl Setup {
    /// Moves the listeners the command line names; one for a server the configuration does
    /// not have (`--opcua` with no `opcua:` section) is refused, naming it.
    pub fn move_listeners(&mut self, to: Listeners) -> Result<(), String> {
        let config = &mut self.config;
        if let Some(a) = to.http {
            config.http = a;
        }
        if let Some(a) = to.grpc {
            config.grpc = a;
        }
        if let Some(a) = to.modbus {
            match &mut config.modbus_server {
                Some(server) => server.listen = Some(a),
                None => {
                    return Err("--modbus: the configuration has no modbus_server section".into());
                }
            }
        }
        for (section, a) in to.sections {
            match config.sections.listen_mut(section) {
                Some(listen) => *listen = a,
                None => {
                    return Err(format!(
                        "--{section}: the configuration has no {section} section"
                    ));
                }
            }
        }
        Ok(())
    }

    /// `path` if given; else `iogate.yaml` in the working directory; else the built-in demo.
    pub fn load(path: Option<&Path>) -> Result<Setup, Problems> {
        match path {
            Some(p) => Setup::from_file(p),
            None if Path::new(DEFAULT_CONFIG).is_file() => {
                Setup::from_file(Path::new(DEFAULT_CONFIG))
            }
            None => Setup::demo(),
        }
    }

    pub fn demo() -> Result<Setup, Problems> {
        crate::drivers::register();
        let (mut config, catalog) = crate::demo::load()?;
        let problems = crate::front_ends::read_sections(&mut config);
        if !problems.is_empty() {
            return Err(problems);
        }
        let map = crate::map::plan(&config, &catalog)?;
        Ok(Setup {
            config,
            catalog,
            profiles_dir: None,
            demo: true,
            map,
        })
    }

    /// The demo without its field line: only the simulated devices `sim` and `plant` (what
    /// the tests of simulated devices and the benchmarks start).
    pub fn demo_simulated() -> Result<Setup, Problems> {
        crate::drivers::register();
        let mut setup = Setup::demo()?;
        setup.config.links.clear();
        setup.config.devices.retain(|d| d.link.is_none());
        let kept: Vec<String> = setup
            .config
            .devices
            .iter()
            .map(|d| d.name.clone())
            .collect();
        if let Some(server) = setup.config.modbus_server.as_mut() {
            server.map.retain(|entry| kept.contains(&entry.device));
        }
        setup.map = crate::map::plan(&setup.config, &setup.catalog)?;
        Ok(setup)
    }

    /// Loads a config file, then its profiles, then checks the devices against both.
    /// Every problem of every file is reported: what could not be read is left out of the
    /// checks that follow, and the rest is still checked.
    pub fn from_file(path: &Path) -> Result<Setup, Problems> {
        crate::drivers::register();
        let (config, mut problems) = Config::load_partial(path);
        let Some(config) = config else {
            return Err(problems);
        };
        let base = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        match Setup::from_config(config, base) {
            Ok(setup) if problems.is_empty() => return Ok(setup),
            Ok(_) => {}
            Err(more) => problems.extend(more),
        }
        // File by file, in line order, as an editor shows them.
        problems
            .0
            .sort_by(|a, b| (&a.file, a.line).cmp(&(&b.file, b.line)));
        Err(problems)
    }

    /// The IEC 104 outstation's points, one line each (`IOA ASDU device.field`), and the
    /// fields it does not serve; its map file read from `base`. `None` without one.
    pub fn iec104_map(&self, base: &Path) -> Option<Result<PointList, Vec<String>>> {
        let plan = crate::api::iec104_server::plan(&self.config, &self.catalog, base)?;
        Some(plan.map(|table| PointList {
            lines: table.render(),
            skipped: table.skipped.clone(),
        }))
    }

    /// What `check` and `serve` print without stopping anything: every profile field that
    /// relies on the default `word_count` of 1 although its type is wider, and every map
    /// binding that cannot show every value of its field (a TIME at `%MD`), every link
    /// setting that turns a check off.
    pub fn warnings(&self) -> Vec<crate::yaml::Problem> {
        let profiles = self.catalog.iter().flat_map(|p| p.width_warnings());
        let map = self.map.iter().flat_map(|m| m.warnings.iter().cloned());
        let links = crate::drivers::link_warnings(&self.config);
        profiles.chain(map).chain(links).collect()
    }

    /// Loads the profiles for `config` (its `profiles` directory, else `profiles/` in
    /// `base` or up to six parents) and checks its devices, security, standing transactions
    /// and Modbus map: every problem of every stage at once.
    pub fn from_config(mut config: Config, base: &Path) -> Result<Setup, Problems> {
        let mut problems = crate::front_ends::read_sections(&mut config);
        config.sections.resolve(base);
        let dir = profile::find_dir(config.profiles.as_deref(), base);
        let catalog = match &dir {
            Some(dir) => {
                let (catalog, more) = profile::load_catalog_partial(dir);
                problems.extend(more);
                catalog
            }
            None if config.devices.is_empty() => Catalog::default(),
            None => {
                // Reported once; every other check still runs (a wrong link is no less wrong
                // for a missing directory), the profiles' own ones aside.
                let mut report = Report::new(&config.source);
                report.push(
                    config.lines.profiles.max(1),
                    "profiles",
                    format!(
                        "no profiles directory found in {} or its {} parents; set `profiles:`",
                        base.display(),
                        profile::PARENT_SEARCH_DEPTH
                    ),
                );
                problems.extend(report.into_problems());
                Catalog::missing(config.devices.iter().map(|d| d.profile.clone()))
            }
        };
        let checks = [
            config::check_devices(&config, &catalog).err(),
            config::check_security(&config).err(),
            crate::transaction::check_standing(&config).err(),
        ];
        problems.extend_all(checks.into_iter().flatten());
        problems.extend(crate::front_ends::check_files(&config, &catalog, base));
        problems.extend(crate::drivers::check_links(&config));
        problems.extend(crate::ha::check(&config, base));
        let map = if dir.is_none() && !config.devices.is_empty() {
            None // the map's fields are the profiles' (checked once they load)
        } else {
            crate::map::plan(&config, &catalog).unwrap_or_else(|more| {
                problems.extend(more);
                None
            })
        };
        if !problems.is_empty() {
            return Err(problems);
        }
        Ok(Setup {
            config,
            catalog,
            profiles_dir: dir,
            demo: false,
            map,
        })
    }
}

/// A front end's points as `map` prints them: one line each, and the fields it leaves out.
pub struct PointList {
    pub lines: String,
    pub skipped: Vec<String>,
}
