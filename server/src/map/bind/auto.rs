//! `auto: true`: every field no map entry binds gets the next free location of its kind;
//! after a reload, each keeps the location it had (masters polling it read the same field),
//! the locations of fields gone stay empty, and new fields take the next free ones.

use std::collections::{HashMap, HashSet};

use super::*;

/// The kind of location `auto` gives a field, if any. TIME is 64-bit milliseconds (source
/// document 000), so it goes to `%ML`, where every value fits.
fn auto_kind(ty: IecType, one_register: bool, writable: bool) -> Option<(Area, Size)> {
    let io = if writable { Area::Output } else { Area::Input };
    [
        (io, Size::Bit),
        (io, Size::Word),
        (Area::Memory, Size::Double),
        (Area::Memory, Size::Long),
    ]
    .into_iter()
    .filter(|(_, size)| !(ty == IecType::Time && *size == Size::Double))
    .find(|(_, size)| Repr::of(ty, *size, one_register).is_some())
}

impl Resolver<'_> {
    /// `auto: true`: every field no entry binds, at the next free location of its kind;
    /// after a reload (`previous`, the map served), first at the location it had, then the
    /// locations of fields gone kept empty, then the new fields.
    pub(super) fn auto(&mut self, previous: Option<&Plan>) {
        let mapped: HashSet<(String, String)> = self
            .bindings
            .iter()
            .map(|b| (b.device.clone(), b.name.to_ascii_lowercase()))
            .collect();
        let had: HashMap<(String, String), Location> = previous
            .iter()
            .flat_map(|p| &p.bindings)
            .filter(|b| b.auto)
            .map(|b| ((b.device.clone(), b.name.to_ascii_lowercase()), b.at))
            .collect();
        let mut fresh = Vec::new();
        let (config, catalog) = (self.config, self.catalog);
        for device in &config.devices {
            let Some(profile) = catalog.get(&device.profile) else {
                continue;
            };
            for (idx, f) in profile.fields.iter().enumerate() {
                let key = (device.name.clone(), f.name.to_ascii_lowercase());
                if mapped.contains(&key) {
                    continue;
                }
                let kept = had
                    .get(&key)
                    .is_some_and(|at| self.auto_at(&device.name, profile, idx, *at));
                if !kept {
                    fresh.push((device, profile, idx));
                }
            }
        }
        self.reserve(previous);
        let mut cursors: HashMap<(Area, Size), u32> = HashMap::new();
        for (device, profile, idx) in fresh {
            self.auto_field(&device.name, profile, idx, &mut cursors);
        }
    }

    /// Binds field `idx` of `device` where `auto` had it, if it is still of that kind and
    /// the place is free.
    fn auto_at(&mut self, device: &str, profile: &Profile, idx: usize, at: Location) -> bool {
        let f = &profile.fields[idx];
        let one = one_register(profile, idx);
        let writable = f.direction.is_writable();
        if auto_kind(f.ty, one, writable) != Some((at.area, at.size)) {
            return false;
        }
        let Ok(slot) = self.space.slot(&at) else {
            return false;
        };
        let Ok((repr, writable)) = fit(&at, f.ty, one, writable, false) else {
            return false;
        };
        if claim(&mut self.taken, slot, at).is_err() {
            return false;
        }
        self.bind_auto(device, profile, idx, (at, slot), (repr, writable));
        true
    }

    /// Records field `idx` of `device` bound by `auto` at a location it claimed.
    fn bind_auto(
        &mut self,
        device: &str,
        profile: &Profile,
        idx: usize,
        (at, slot): (Location, Slot),
        (repr, writable): (Repr, bool),
    ) {
        let f = &profile.fields[idx];
        self.bindings.push(Binding {
            at,
            slot,
            device: device.to_owned(),
            target: Target::Field(idx),
            name: f.name.clone(),
            ty: f.ty,
            repr,
            writable,
            auto: true,
        });
    }

    /// Keeps empty the locations `previous` gave by `auto` (or kept empty) that no field
    /// holds now.
    fn reserve(&mut self, previous: Option<&Plan>) {
        let Some(previous) = previous else { return };
        let gone = previous
            .bindings
            .iter()
            .filter(|b| b.auto)
            .map(|b| (b.at, format!("{}.{}", b.device, b.name)))
            .chain(previous.reserved.iter().cloned());
        for (at, held) in gone {
            let Ok(slot) = self.space.slot(&at) else {
                continue;
            };
            if claim(&mut self.taken, slot, at).is_ok() {
                self.reserved.push((at, held));
            }
        }
    }

    fn auto_field(
        &mut self,
        device: &str,
        profile: &Profile,
        idx: usize,
        cursors: &mut HashMap<(Area, Size), u32>,
    ) {
        let f = &profile.fields[idx];
        let one = one_register(profile, idx);
        let writable = f.direction.is_writable();
        let Some((area, size)) = auto_kind(f.ty, one, writable) else {
            self.unbound.push(format!("{device}.{} ({})", f.name, f.ty));
            return;
        };
        let cursor = cursors.entry((area, size)).or_insert(0);
        let (space, taken) = (&self.space, &mut self.taken);
        let free = space
            .locations(area, size)
            .skip(*cursor as usize)
            .enumerate()
            .find_map(|(k, at)| {
                let slot = space.slot(&at).ok()?;
                claim(taken, slot, at).ok().map(|()| (k, at, slot))
            });
        let Some((k, at, slot)) = free else {
            self.unbound.push(format!("{device}.{} ({})", f.name, f.ty));
            return;
        };
        *cursor += k as u32 + 1;
        let Ok(fits) = fit(&at, f.ty, one, writable, false) else {
            return;
        };
        self.bind_auto(device, profile, idx, (at, slot), fits);
    }
}
