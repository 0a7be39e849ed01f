//! Progress bars on long work (hidden when stderr is not a terminal).

use std::sync::Mutex;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use octoproxy_cpu::BuildProgress;

/// A bar for `total` units of `what`.
pub fn bar(total: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>10} [{bar:40}] {pos}/{len} {msg} ({elapsed})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb.enable_steady_tick(Duration::from_millis(200));
    pb
}

/// Bake progress: one bar per stage.
#[derive(Default)]
pub struct BakeBars {
    current: Mutex<Option<ProgressBar>>,
}

impl BuildProgress for BakeBars {
    fn begin(&self, stage: &'static str, total: u64) {
        if let Ok(mut cur) = self.current.lock() {
            if let Some(pb) = cur.take() {
                pb.finish_and_clear();
            }
            *cur = Some(bar(total, stage));
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(cur) = self.current.lock() {
            if let Some(pb) = cur.as_ref() {
                pb.inc(n);
            }
        }
    }
}

impl BakeBars {
    /// Clears the last bar.
    pub fn finish(&self) {
        if let Ok(mut cur) = self.current.lock() {
            if let Some(pb) = cur.take() {
                pb.finish_and_clear();
            }
        }
    }
}
