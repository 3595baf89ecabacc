//! Staging: outputs all together or not at all, on any file system.
use super::*;

fn fresh(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("matedit-staging-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn hidden_left(parent: &Path) -> Vec<String> {
    std::fs::read_dir(parent)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| n.starts_with('.'))
        .collect()
}

#[test]
fn outputs_appear_all_together_or_not_at_all() {
    let parent = fresh("all");
    // A failure on the way (the stage dropped unpublished): nothing in `out`, no stage left.
    let out = parent.join("out");
    {
        let stage = Staging::new(&out).unwrap();
        std::fs::write(stage.path().join("edited.png"), b"x").unwrap();
    }
    assert!(!out.exists());
    assert!(hidden_left(&parent).is_empty());
    // Published into a folder that does not exist: every file, one rename.
    let stage = Staging::new(&out).unwrap();
    for f in ["edited.png", "report.json"] {
        std::fs::write(stage.path().join(f), f).unwrap();
    }
    stage.publish().unwrap();
    assert_eq!(std::fs::read_to_string(out.join("report.json")).unwrap(), "report.json");
    assert!(hidden_left(&parent).is_empty());
    // Into a folder holding a user's file and an older edit: replaced, the user's file kept.
    std::fs::write(out.join("notes.txt"), b"mine").unwrap();
    let stage = Staging::new(&out).unwrap();
    for f in ["edited.png", "report.json"] {
        std::fs::write(stage.path().join(f), format!("new {f}")).unwrap();
    }
    stage.publish().unwrap();
    assert_eq!(
        std::fs::read_to_string(out.join("edited.png")).unwrap(),
        "new edited.png"
    );
    assert_eq!(std::fs::read_to_string(out.join("notes.txt")).unwrap(), "mine");
    assert!(hidden_left(&parent).is_empty());
    assert!(hidden_left(&out).is_empty(), "the stage inside the folder is gone");
    // A relative output folder without a parent component works too.
    assert!(Staging::new(Path::new("")).is_err());
    std::fs::remove_dir_all(&parent).unwrap();
}

/// A folder on another file system than the temporary folder: `/dev/shm` (a tmpfs) where
/// it is one, for the cross-device moves.
fn other_file_system() -> Option<PathBuf> {
    use std::os::unix::fs::MetadataExt;
    let shm = Path::new("/dev/shm");
    let dev = |p: &Path| std::fs::metadata(p).ok().map(|m| m.dev());
    (dev(shm).is_some() && dev(shm) != dev(&std::env::temp_dir())).then(|| shm.to_path_buf())
}

#[test]
fn outputs_reach_a_folder_on_another_file_system() {
    let Some(other) = other_file_system() else {
        eprintln!("skipped: no second file system (/dev/shm) beside the temporary folder");
        return;
    };
    // A file moved across: copied under a hidden name, renamed, the source removed.
    let here = fresh("xdev");
    let (from, to) = (
        here.join("a.png"),
        other.join(format!("matedit-xdev-{}.png", std::process::id())),
    );
    std::fs::write(&from, b"pixels").unwrap();
    assert_eq!(
        std::fs::rename(&from, &to).unwrap_err().kind(),
        std::io::ErrorKind::CrossesDevices,
        "the test needs two file systems"
    );
    move_file(&from, &to).unwrap();
    assert_eq!(std::fs::read(&to).unwrap(), b"pixels");
    assert!(!from.exists());
    std::fs::remove_file(&to).unwrap();
    // An output folder that exists there (as a mount point does): staged inside it.
    let out = other.join(format!("matedit-xdev-out-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let stage = Staging::new(&out).unwrap();
    std::fs::write(stage.path().join("report.json"), b"{}").unwrap();
    stage.publish().unwrap();
    assert_eq!(std::fs::read(out.join("report.json")).unwrap(), b"{}");
    assert!(hidden_left(&out).is_empty());
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&here).unwrap();
}
