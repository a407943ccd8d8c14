//! Writing a profile an import made from a live device (an OPC UA server, a Logix
//! controller): loaded back before it is written, then one file in the output directory or
//! standard output, with a line saying how much was and was not mapped.

use std::path::Path;

/// A profile made from `source`: its name and YAML, its field count, and how many of the
/// source's `things` (variables, tags) were not mapped.
pub(crate) struct Made<'a> {
    pub(crate) source: &'a str,
    pub(crate) name: &'a str,
    pub(crate) text: String,
    pub(crate) fields: usize,
    pub(crate) skipped: usize,
    pub(crate) things: &'static str,
}

/// Writes it; the exit code: 0 written, 1 not (nothing mapped, or it does not load).
pub(crate) fn emit(made: &Made, out: Option<&Path>) -> u8 {
    let Made {
        source,
        name,
        text,
        fields,
        skipped,
        things,
    } = made;
    if *fields == 0 {
        eprintln!(
            "iogate profile import: nothing of {source} could be mapped ({skipped} {things} skipped)"
        );
        return 1;
    }
    if let Err(problems) = crate::profile::load_str(&format!("{name}.yaml"), text) {
        eprintln!("iogate profile import: the profile made does not load:\n{problems}");
        return 1;
    }
    match out {
        Some(dir) => {
            let target = dir.join(format!("{name}.yaml"));
            if let Err(e) =
                std::fs::create_dir_all(dir).and_then(|()| std::fs::write(&target, text))
            {
                eprintln!(
                    "iogate profile import: cannot write {}: {e}",
                    target.display()
                );
                return 1;
            }
            eprintln!(
                "{source}: profile {name} written to {} ({fields} fields, {skipped} {things} not mapped)",
                target.display(),
            );
        }
        None => {
            println!("---\n{text}");
            eprintln!("{source}: profile {name} ({fields} fields, {skipped} {things} not mapped)");
        }
    }
    0
}

/// Runs a live import (`import`, its exit code) on a runtime of its own: the command line
/// has none.
pub(crate) fn on_runtime(import: impl std::future::Future<Output = u8>) -> u8 {
    on_runtime_with(async { Ok(import.await) }).unwrap_or_else(|e| {
        eprintln!("iogate profile import: {e}");
        1
    })
}

/// Runs a command's work on a runtime of its own: its result, or why there is no runtime.
pub(crate) fn on_runtime_with<T>(
    work: impl std::future::Future<Output = Result<T, String>>,
) -> Result<T, String> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?
        .block_on(work)
}
