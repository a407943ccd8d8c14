//! Gateway memory: the coils and holding registers no field is bound to. Masters write and
//! read them back (a SCADA's own flags and setpoints); with `memory_file` they are kept
//! across restarts, the file replaced atomically (written beside it, then renamed) on
//! every change.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

/// The memory image: one bool per coil, one word per holding register.
#[derive(Debug)]
pub(crate) struct Memory {
    inner: Mutex<Image>,
    file: Option<PathBuf>,
}

#[derive(Debug, Clone, Default)]
struct Image {
    coils: Vec<bool>,
    registers: Vec<u16>,
}

/// What the file holds: the set coils and the non-zero registers, by address.
#[derive(Debug, Default, Serialize, Deserialize)]
struct Saved {
    coils: Vec<u16>,
    registers: BTreeMap<u16, u16>,
}

/// Why memory could not be kept.
#[derive(Debug, thiserror::Error)]
pub(crate) enum MemoryError {
    #[error("cannot read the memory file {path}: {reason}")]
    Read { path: String, reason: String },
    #[error("cannot write the memory file {path}: {reason}")]
    Write { path: String, reason: String },
}

impl Memory {
    /// Memory for `coils` coils and `registers` holding registers, loaded from `file` when
    /// it exists.
    pub(crate) fn new(
        coils: usize,
        registers: usize,
        file: Option<PathBuf>,
    ) -> Result<Self, MemoryError> {
        let mut image = Image {
            coils: vec![false; coils],
            registers: vec![0; registers],
        };
        if let Some(path) = file.as_deref().filter(|p| p.exists()) {
            let read = |reason: String| MemoryError::Read {
                path: path.display().to_string(),
                reason,
            };
            let text = std::fs::read_to_string(path).map_err(|e| read(e.to_string()))?;
            let saved: Saved = serde_json::from_str(&text).map_err(|e| read(e.to_string()))?;
            for c in saved.coils {
                if let Some(slot) = image.coils.get_mut(usize::from(c)) {
                    *slot = true;
                }
            }
            for (a, v) in saved.registers {
                if let Some(slot) = image.registers.get_mut(usize::from(a)) {
                    *slot = v;
                }
            }
        }
        Ok(Memory {
            inner: Mutex::new(image),
            file,
        })
    }

    /// Memory for a reloaded configuration (`coils`, `registers`, `file`), holding what this
    /// one holds: loaded from `file` when that exists (it is saved on every write), else a
    /// copy of this image, cut or padded with zeros to the new size.
    pub(crate) fn carried(
        &self,
        coils: usize,
        registers: usize,
        file: Option<PathBuf>,
    ) -> Result<Memory, MemoryError> {
        let from_file = file.as_deref().is_some_and(|p| p.exists());
        let next = Memory::new(coils, registers, file)?;
        if !from_file {
            let old = self.lock().clone();
            let mut image = next.lock();
            for (slot, v) in image.coils.iter_mut().zip(old.coils) {
                *slot = v;
            }
            for (slot, v) in image.registers.iter_mut().zip(old.registers) {
                *slot = v;
            }
        }
        Ok(next)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Image> {
        // Updates are whole assignments; a poisoned lock still holds a consistent image.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Appends the `count` registers from `address` to `out` (0 past the end), under one
    /// lock.
    pub(crate) fn registers_into(&self, address: u16, count: u16, out: &mut Vec<u16>) {
        let image = self.lock();
        let start = usize::from(address);
        out.extend(
            (start..start + usize::from(count))
                .map(|a| image.registers.get(a).copied().unwrap_or(0)),
        );
    }

    /// Appends the `count` coils from `address` to `out` (false past the end), under one
    /// lock.
    pub(crate) fn coils_into(&self, address: u16, count: u16, out: &mut Vec<bool>) {
        let image = self.lock();
        let start = usize::from(address);
        out.extend(
            (start..start + usize::from(count))
                .map(|a| image.coils.get(a).copied().unwrap_or(false)),
        );
    }

    pub(crate) fn register(&self, address: u16) -> u16 {
        self.lock()
            .registers
            .get(usize::from(address))
            .copied()
            .unwrap_or(0)
    }

    /// Sets coils and registers at once, and saves the image if it is kept in a file.
    pub(crate) fn set(
        &self,
        coils: &[(u16, bool)],
        registers: &[(u16, u16)],
    ) -> Result<(), MemoryError> {
        let snapshot = {
            let mut image = self.lock();
            for &(a, v) in coils {
                if let Some(slot) = image.coils.get_mut(usize::from(a)) {
                    *slot = v;
                }
            }
            for &(a, v) in registers {
                if let Some(slot) = image.registers.get_mut(usize::from(a)) {
                    *slot = v;
                }
            }
            self.file.as_ref().map(|_| image.clone())
        };
        match (&self.file, snapshot) {
            (Some(path), Some(image)) => save(path, &image),
            _ => Ok(()),
        }
    }

    /// The set coils and the non-zero registers, by address.
    pub(crate) fn contents(&self) -> (Vec<u16>, Vec<(u16, u16)>) {
        let image = self.lock();
        (
            (0..image.coils.len())
                .filter(|&a| image.coils[a])
                .map(|a| a as u16)
                .collect(),
            image
                .registers
                .iter()
                .enumerate()
                .filter(|(_, v)| **v != 0)
                .map(|(a, v)| (a as u16, *v))
                .collect(),
        )
    }
}

fn save(path: &Path, image: &Image) -> Result<(), MemoryError> {
    let saved = Saved {
        coils: (0..image.coils.len())
            .filter(|&a| image.coils[a])
            .map(|a| a as u16)
            .collect(),
        registers: image
            .registers
            .iter()
            .enumerate()
            .filter(|(_, v)| **v != 0)
            .map(|(a, v)| (a as u16, *v))
            .collect(),
    };
    let write = |reason: String| MemoryError::Write {
        path: path.display().to_string(),
        reason,
    };
    let text = serde_json::to_string(&saved).map_err(|e| write(e.to_string()))?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text).map_err(|e| write(e.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|e| write(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_survives_a_restart_through_its_file() {
        let dir = std::env::temp_dir().join(format!("iogate-memory-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let file = dir.join("memory.json");
        let _ = std::fs::remove_file(&file);
        let m = Memory::new(16, 100, Some(file.clone())).expect("new");
        m.set(&[(3, true)], &[(42, 0xBEEF), (7, 1)]).expect("set");
        drop(m);
        let again = Memory::new(16, 100, Some(file.clone())).expect("load");
        let mut coils = Vec::new();
        again.coils_into(3, 2, &mut coils);
        assert_eq!(coils, vec![true, false]);
        assert_eq!(again.register(42), 0xBEEF);
        assert_eq!(again.contents().1, vec![(7, 1), (42, 0xBEEF)]);
        std::fs::write(&file, "not json").expect("corrupt");
        assert!(matches!(
            Memory::new(16, 100, Some(file)),
            Err(MemoryError::Read { .. })
        ));
    }
}
