//! File input and output. Every write goes to a temporary file in the destination directory and
//! is renamed into place, so a reader never sees a partial file and a failed write leaves any
//! previous file untouched.

mod exr_io;
mod png;
pub mod text;

pub use exr_io::{
    ExrChannels, check_exr_size, decode_exr_channels, encode_env_exr, encode_exr_channels, read_exr_channels,
    write_env_exr, write_exr_channels,
};
pub use png::{
    SheetLabels, contact_sheet, normal_to_u8, write_contact_sheet, write_labelled_contact_sheet, write_png_preview,
};

use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Runs `write` on a temporary path next to `path`, then renames it to `path`.
pub fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create directory {}", dir.display()))?;
    let name = path
        .file_name()
        .with_context(|| format!("{} is not a file path", path.display()))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    let tmp: PathBuf = dir.join(tmp_name);
    let result = write(&tmp).and_then(|()| {
        std::fs::rename(&tmp, path).with_context(|| format!("cannot move {} to {}", tmp.display(), path.display()))
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_writes_keep_the_previous_file_and_leave_no_temporary() {
        let dir = std::env::temp_dir().join(format!("matedit-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("x.txt");
        write_atomically(&p, |t| Ok(std::fs::write(t, "old")?)).unwrap();
        let r = write_atomically(&p, |t| {
            std::fs::write(t, "partial")?;
            anyhow::bail!("disk full")
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    }
}
