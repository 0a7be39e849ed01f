//! What the command-line tests share: running the binary, scratch directories, and the check
//! that an error is one readable line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `octoproxy` with `args` in `dir`.
pub fn octoproxy(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_octoproxy"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("octoproxy runs")
}

/// A fresh directory under the system's temporary one, removed when the test passes (and
/// kept, to look into, when it fails).
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A fresh scratch directory named for the test.
pub fn scratch(name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("octoproxy-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

/// The command failed with one readable line on stderr, `error: ...` holding `needle`, and no
/// panic.
pub fn assert_one_line_error(out: &Output, needle: &str) {
    assert!(!out.status.success(), "expected failure");
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    let last = lines.last().copied().unwrap_or("");
    assert!(last.starts_with("error: "), "stderr: {err}");
    assert!(last.contains(needle), "expected {needle:?} in {last:?}");
    assert!(!err.contains("panicked"), "stderr: {err}");
}
