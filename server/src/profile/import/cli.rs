//! `iogate profile import FILE...`: every file converted first, then one profile written per
//! name. Libraries keep a deprecated template beside its successor under the same device
//! type (wb-mqtt-serial's ONOKOM and Danfoss templates): the current one is written and the
//! deprecated one named as superseded, whatever order the files come in.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::{Converted, Format, import_file};

/// What becomes of one converted file.
#[derive(Debug, PartialEq)]
enum Fate {
    Write,
    /// A deprecated template whose name a current one (this path) takes.
    Superseded(usize),
    /// A second file with the name of this earlier one.
    Taken(usize),
}

/// For each converted file (in order), whether it is written: per profile name the first
/// current file, else the first deprecated one.
fn fates(converted: &[Option<Converted>]) -> Vec<Fate> {
    let mut chosen: HashMap<String, usize> = HashMap::new();
    for (i, c) in converted.iter().enumerate() {
        let Some(c) = c else { continue };
        let key = c.profile.to_ascii_lowercase();
        match chosen.get(&key) {
            None => {
                chosen.insert(key, i);
            }
            Some(&j) => {
                let earlier_deprecated = converted[j].as_ref().is_some_and(|e| e.deprecated);
                if earlier_deprecated && !c.deprecated {
                    chosen.insert(key, i);
                }
            }
        }
    }
    converted
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let Some(c) = c else { return Fate::Write };
            let first = chosen[&c.profile.to_ascii_lowercase()];
            match converted[first].as_ref() {
                _ if first == i => Fate::Write,
                Some(winner) if c.deprecated && !winner.deprecated => Fate::Superseded(first),
                _ => Fate::Taken(first),
            }
        })
        .collect()
}

/// `iogate profile import`: converts every file, writes the profiles into `out` (or prints
/// them), prints the report; the exit code: 0 every file imported (or superseded by a
/// current template), 1 some could not be.
pub fn run(files: &[PathBuf], from: Option<&str>, out: Option<&Path>) -> u8 {
    let from = match from.map(Format::parse).transpose() {
        Ok(from) => from,
        Err(e) => {
            eprintln!("iogate profile import: {e}");
            return crate::EXIT_CONFIG as u8;
        }
    };
    if let Some(dir) = out
        && let Err(e) = std::fs::create_dir_all(dir)
    {
        eprintln!(
            "iogate profile import: cannot create {}: {e}",
            dir.display()
        );
        return 1;
    }
    let mut failed = 0;
    let converted: Vec<Option<Converted>> = files
        .iter()
        .map(|path| match import_file(path, from) {
            Ok(c) => Some(c),
            Err(e) => {
                eprintln!("{e}");
                failed += 1;
                None
            }
        })
        .collect();
    for ((path, c), fate) in files.iter().zip(&converted).zip(fates(&converted)) {
        let Some(c) = c else { continue };
        match fate {
            Fate::Superseded(by) => eprintln!(
                "{}: profile {} is a deprecated template: not written, {} is its current one",
                path.display(),
                c.profile,
                files[by].display()
            ),
            Fate::Taken(by) => {
                eprintln!(
                    "{}: profile {} was imported from {} already: not written (profile names are unique)",
                    path.display(),
                    c.profile,
                    files[by].display()
                );
                failed += 1;
            }
            Fate::Write => {
                if !write(path, c, out) {
                    failed += 1;
                }
            }
        }
    }
    if failed > 0 {
        eprintln!("{failed} of {} files not imported", files.len());
        1
    } else {
        0
    }
}

/// Writes one profile (or prints it) and its report; false when it could not be written.
fn write(path: &Path, c: &Converted, out: Option<&Path>) -> bool {
    let written = match out {
        Some(dir) => {
            let target = dir.join(&c.file_name);
            if let Err(e) = std::fs::write(&target, &c.text) {
                eprintln!("{}: cannot write {}: {e}", path.display(), target.display());
                return false;
            }
            target.display().to_string()
        }
        None => {
            println!("---\n{}", c.text);
            "standard output".to_owned()
        }
    };
    let deprecated = if c.deprecated {
        " (a deprecated template)"
    } else {
        ""
    };
    eprintln!(
        "{}: profile {}{deprecated} ({} fields) to {written}; {} not imported",
        path.display(),
        c.profile,
        c.fields,
        c.unmapped.len()
    );
    for line in &c.unmapped {
        eprintln!("  {line}");
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn converted(profile: &str, deprecated: bool) -> Option<Converted> {
        Some(Converted {
            profile: profile.to_owned(),
            file_name: format!("{}.yaml", profile.to_ascii_lowercase()),
            text: String::new(),
            fields: 1,
            unmapped: Vec::new(),
            deprecated,
        })
    }

    #[test]
    fn a_current_template_wins_over_a_deprecated_one_in_either_order() {
        let list = vec![
            converted("AUX", true),
            converted("AUX", false),
            None,
            converted("CG", false),
            converted("CG", true),
            converted("Old", true),
            converted("Twice", false),
            converted("twice", false),
        ];
        assert_eq!(
            fates(&list),
            vec![
                Fate::Superseded(1),
                Fate::Write,
                Fate::Write,
                Fate::Write,
                Fate::Superseded(3),
                Fate::Write,
                Fate::Write,
                Fate::Taken(6),
            ]
        );
    }
}
