//! Declaring a device: the rules it obeys, the device of that name if its settings agree,
//! a new one (and its simulator) if there is none.

use super::*;

/// Removes a device declared at run time: it is no longer polled, its simulator stops, and
/// writes still waiting for it fail. A device from the config file stays.
pub(crate) fn remove_device(cache: &Cache, name: &str) -> Result<Arc<Device>, DeclareError> {
    let device = cache.change(|registry: &mut Registry| {
        let device = registry
            .device(name)
            .cloned()
            .ok_or_else(|| DeclareError::NotFound(AccessError::UnknownDevice(quote(name))))?;
        if device.config.line != 0 {
            return Err(DeclareError::FromConfig {
                what: "device",
                name: device.name().to_owned(),
            });
        }
        cache.remove_device(registry, &device, "the device was removed");
        Ok(device)
    })?;
    tracing::info!(device = %device.name(), "device removed");
    Ok(device)
}

/// Where `decl` differs from the device `existing` of the same name. A link or slave id the
/// device does not have yet is no conflict: declaring it binds the device.
fn device_conflicts(
    existing: &Device,
    decl: &DeviceDeclaration,
    profile: &str,
    want: &Binding,
) -> Vec<Conflict> {
    let mut conflicts = Vec::new();
    let (config, have) = (&existing.config, existing.binding());
    if config.profile != profile {
        conflicts.push(Conflict::Profile {
            have: config.profile.clone(),
            want: profile.to_owned(),
        });
    }
    if have.link.is_some() && have.link != want.link {
        conflicts.push(Conflict::Link {
            have: have.link.clone(),
            want: want.link.clone(),
        });
    }
    if have.slave_id.is_some() && have.slave_id != want.slave_id {
        conflicts.push(Conflict::SlaveId {
            have: have.slave_id.unwrap_or(0),
            want: want.slave_id.unwrap_or(0),
        });
    }
    let config = &existing.config;
    if config.refresh_rate != decl.refresh_rate {
        conflicts.push(Conflict::RefreshRate {
            have: config.refresh_rate,
            want: decl.refresh_rate,
        });
    }
    if let Some(want) = decl.timeout.filter(|t| *t != config.timeout) {
        conflicts.push(Conflict::Timeout {
            have: config.timeout,
            want,
        });
    }
    conflicts
}

/// Declares a device: returns the device of that name if its settings agree, creates it
/// otherwise. Its link's task starts polling it at once; a simulated device gets its task.
///
/// A Modbus device declared with no link, or with slave id 0, is accepted and reports
/// error 1 (no link) or 2 (no slave) until it is declared again with them, as the device
/// function blocks of source document 000 do when called before their link is set. (A
/// config file refuses such devices: a file has no "later".)
pub(crate) fn ensure_device(
    cache: &Cache,
    tasks: &Tasks,
    decl: DeviceDeclaration,
) -> Result<Ensured<Device>, DeclareError> {
    valid_name("device", &decl.name)?;
    let profile = cache
        .profile(&decl.profile)
        .map_err(DeclareError::UnknownProfile)?
        .clone();
    let simulated = profile.protocol == Protocol::Simulated;
    let link = (!decl.link.trim().is_empty()).then_some(decl.link.as_str());
    let slave = (decl.slave_id != 0).then_some(u64::from(decl.slave_id));
    let mut broken: Vec<RuleError> = rules::binding(&profile, link, slave)
        .into_iter()
        .filter(|e| !matches!(e, RuleError::NoLink { .. } | RuleError::NoSlave))
        .collect();
    broken.extend(rules::period("refresh_rate", decl.refresh_rate).err());
    if let Some(t) = decl.timeout {
        broken.extend(rules::period("timeout", t).err());
    }
    if !REFRESH_RATES.contains(&decl.refresh_rate) {
        return Err(DeclareError::OutOfBounds(format!(
            "refresh_rate {} ms is outside 1 ms - 1 h",
            decl.refresh_rate.as_millis()
        )));
    }
    if let Some(t) = decl.timeout.filter(|t| !TIMEOUTS.contains(t)) {
        return Err(DeclareError::OutOfBounds(format!(
            "timeout {} ms is outside 10 ms - 10 s (no device may hold its link longer)",
            t.as_millis()
        )));
    }
    if !broken.is_empty() {
        return Err(DeclareError::Rules(broken));
    }
    let ensured = cache.change(|registry: &mut Registry| {
        let declared = Declared {
            decl: &decl,
            profile: &profile,
            simulated,
            link,
            slave,
        };
        declared.ensure(cache, registry)
    })?;
    if ensured.created {
        tracing::info!(device = %ensured.value.name(), "device declared");
        if simulated {
            tasks.spawn_sim(ensured.value.clone());
        }
    }
    Ok(ensured)
}

/// A device declaration that obeys the rules, as the registry takes it.
struct Declared<'a> {
    decl: &'a DeviceDeclaration,
    profile: &'a Arc<crate::profile::Profile>,
    simulated: bool,
    link: Option<&'a str>,
    slave: Option<u64>,
}

impl Declared<'_> {
    /// The device of that name if its settings agree (bound to its link and slave id when
    /// it had none), else a new one.
    fn ensure(
        &self,
        cache: &Cache,
        registry: &mut Registry,
    ) -> Result<Ensured<Device>, DeclareError> {
        let link = match self.link {
            None => None,
            Some(link) => Some(link_named(registry, link)?),
        };
        let slave_id = self.slave.and_then(|id| rules::slave_id(id).ok());
        let want = Binding {
            link: link.clone(),
            slave_id,
            at: Vec::new(),
        };
        if let Some(other) = registry
            .devices
            .iter()
            .find(|d| d.name() != self.decl.name && d.name().eq_ignore_ascii_case(&self.decl.name))
        {
            return Err(DeclareError::NameClash {
                what: "device",
                name: self.decl.name.clone(),
                other: other.name().to_owned(),
            });
        }
        if let Some(existing) = registry.device(&self.decl.name).cloned() {
            return self.agreed(cache, registry, &existing, want);
        }
        if registry
            .devices
            .iter()
            .filter(|d| d.config.line == 0)
            .count()
            >= MAX_DECLARED_DEVICES
        {
            return Err(DeclareError::TooMany("devices", MAX_DECLARED_DEVICES));
        }
        let config = DeviceConfig {
            name: self.decl.name.clone(),
            profile: self.profile.name.clone(),
            link,
            slave_id,
            refresh_rate: self.decl.refresh_rate,
            timeout: self.decl.timeout.unwrap_or(rules::DEFAULT_TIMEOUT),
            retries: rules::DEFAULT_RETRIES,
            max_batch: rules::MAX_READ_REGISTERS,
            max_gap: 0,
            write_mode: crate::config::WriteMode::default(),
            rewrite_outputs: None,
            on_client_loss: None,
            at: Vec::new(),
            line: 0,
        };
        let device = cache.insert_device(registry, config, self.profile.clone());
        Ok(Ensured {
            value: device,
            created: true,
        })
    }

    /// The device of that name, when the declaration agrees with it; bound to the link and
    /// slave id declared when it had none.
    fn agreed(
        &self,
        cache: &Cache,
        registry: &mut Registry,
        existing: &Arc<Device>,
        want: Binding,
    ) -> Result<Ensured<Device>, DeclareError> {
        let conflicts = device_conflicts(existing, self.decl, &self.profile.name, &want);
        if !conflicts.is_empty() {
            return Err(DeclareError::DeviceConflict {
                device: self.decl.name.clone(),
                conflicts,
            });
        }
        let have = existing.binding();
        if !self.simulated && have != want && (have.link.is_none() || have.slave_id.is_none()) {
            let bound = Binding {
                link: have.link.or(want.link),
                slave_id: have.slave_id.or(want.slave_id),
                at: have.at,
            };
            tracing::info!(device = %self.decl.name, link = ?bound.link, slave = ?bound.slave_id, "device bound");
            cache.bind_device(registry, existing, bound);
        }
        Ok(Ensured {
            value: existing.clone(),
            created: false,
        })
    }
}

/// The name of the link `link` names: by its name, or by its serial port.
fn link_named(registry: &Registry, link: &str) -> Result<String, DeclareError> {
    let found = registry.link(link).or_else(|| {
        registry
            .links
            .iter()
            .find(|l| matches!(&l.config().transport, Transport::Serial(s) if s.port == link))
    });
    let found = found.ok_or_else(|| DeclareError::UnknownLink(crate::text::quote(link)))?;
    Ok(found.name().to_owned())
}
