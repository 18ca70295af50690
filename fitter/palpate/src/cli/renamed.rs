//! Flags that were renamed so that one thing has one name (`--clamps`) and a unit that is not SI
//! is in the flag's name (`--gauge-length-mm`, `--adc-dither-counts`). The old spellings are
//! still read (clap aliases); this says, once per run, which new name to use.

/// Warns when the command line spells a flag by its old name `old` (as `--old v` or `--old=v`).
pub fn warn_if_used(old: &str, new: &str) {
    warn_if_in(std::env::args_os(), old, new);
}

fn warn_if_in(args: impl Iterator<Item = std::ffi::OsString>, old: &str, new: &str) {
    let used = args.into_iter().any(|a| {
        a.to_str()
            .is_some_and(|a| a == old || a.strip_prefix(old).is_some_and(|r| r.starts_with('=')))
    });
    if used {
        log::warn!("{old} is the older name of {new}: read as {new}");
    }
}
