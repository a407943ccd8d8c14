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
    /// Held from a change to its image being saved, so that saves are whole (one writer of
    /// the temporary file at a time) and in the order of the changes (the file never goes
    /// back to an older image).
    saving: Mutex<()>,
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
            saving: Mutex::new(()),
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
        let _saving = self
            .file
            .as_ref()
            .map(|_| self.saving.lock().unwrap_or_else(|e| e.into_inner()));
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

/// `kill -9` at random moments while the memory file is written, 100 times, and writers
/// racing each other: the file always loads, holds one whole change (every register a
/// change set has the same value) and none older than the last one that returned.
#[cfg(test)]
mod crash_tests {
    use std::time::Duration;

    use super::*;

    const CHILD: &str = "IOGATE_MEMORY_CRASH_FILE";

    /// Sets registers 0-63 to n, n + 1, ... (1 after 65535) until killed, telling each `n`
    /// once it returned.
    #[test]
    #[ignore = "run by the crash test in a process of its own"]
    fn a_writer_until_killed() {
        let Ok(file) = std::env::var(CHILD) else {
            return;
        };
        let m = Memory::new(8, 64, Some(PathBuf::from(file))).expect("loads");
        let mut n = m.register(0);
        let until = std::time::Instant::now() + Duration::from_secs(5);
        while std::time::Instant::now() < until {
            // Never 0: a register at 0 is not in the file.
            n = n.checked_add(1).unwrap_or(1);
            let all: Vec<(u16, u16)> = (0..64).map(|a| (a, n)).collect();
            m.set(&[(u16::from(n.is_multiple_of(8)), true)], &all)
                .expect("saves");
            println!("{n}");
        }
    }

    #[test]
    fn a_memory_file_killed_while_written_a_hundred_times_loads_whole() {
        let dir = tempfile::tempdir().expect("a directory");
        let file = dir.path().join("memory.json");
        let mut moments = crate::killed::Moments::new();
        let mut last = None::<u16>;
        for life in 0..100 {
            let lines = crate::killed::run_and_kill(
                "map::memory::crash_tests::a_writer_until_killed",
                (CHILD, &file),
                &mut moments,
                (Duration::from_micros(200), Duration::from_millis(10)),
            );
            for line in lines {
                last = line.trim().parse().ok().or(last);
            }
            let m = Memory::new(8, 64, Some(file.clone()))
                .unwrap_or_else(|e| panic!("life {life}: {e}"));
            let (_, registers) = m.contents();
            let values: Vec<u16> = registers.iter().map(|(_, v)| *v).collect();
            assert!(
                values.len() == 64 && values.windows(2).all(|w| w[0] == w[1]),
                "life {life}: not one whole change: {values:?}"
            );
            if let Some(l) = last {
                // Newer or the same, across the wrap from 65535 to 1.
                assert!(
                    values[0].wrapping_sub(l) < 0x8000,
                    "life {life}: {l} was saved, the file holds {}",
                    values[0]
                );
            }
        }
        assert!(last.is_some_and(|l| l > 100), "the writer wrote: {last:?}");
    }

    /// Writers racing: the file is whole and holds the last change.
    #[test]
    fn racing_writers_leave_the_last_change_whole() {
        let dir = tempfile::tempdir().expect("a directory");
        let file = dir.path().join("memory.json");
        let m = std::sync::Arc::new(Memory::new(8, 64, Some(file.clone())).expect("new"));
        let writers: Vec<_> = (0..4u16)
            .map(|w| {
                let m = m.clone();
                std::thread::spawn(move || {
                    for k in 0..200u16 {
                        let v = w * 1000 + k + 1;
                        let all: Vec<(u16, u16)> = (0..64).map(|a| (a, v)).collect();
                        m.set(&[], &all).expect("saves");
                    }
                })
            })
            .collect();
        for w in writers {
            w.join().expect("a writer");
        }
        let again = Memory::new(8, 64, Some(file)).expect("loads");
        assert_eq!(
            again.contents(),
            m.contents(),
            "the file holds the last change"
        );
    }
}
