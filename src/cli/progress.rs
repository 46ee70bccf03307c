//! Progress of the long CLI runs (`vamos score`, `calibrate`, `eval` with its ablation
//! variants, `export-dataset`): `indicatif` bars on stderr, one bar per run counting its
//! episodes and, beneath it, one bar per episode in flight counting the images read.
//!
//! Bars are drawn only when stderr is a terminal and `--no-progress` is not given. Without
//! bars (a log file, CI, a pipe) each finished episode is one `[n/total] ...` line on
//! stderr, as before; with bars that line is printed above them. Episodes scored in
//! parallel (rayon) each hold their own bar; the run bar is shared and thread safe.

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Whether and where progress is drawn; cheap to clone (the bars share one renderer).
#[derive(Clone, Default)]
pub struct Progress {
    multi: Option<MultiProgress>,
}

impl Progress {
    /// Bars on stderr when it is a terminal and `no_progress` is false; otherwise lines.
    pub fn new(no_progress: bool) -> Self {
        let draw = !no_progress && std::io::stderr().is_terminal();
        Self {
            multi: draw.then(|| MultiProgress::with_draw_target(ProgressDrawTarget::stderr())),
        }
    }

    /// A run over `episodes` episodes, labelled `label` (e.g. `scoring`, `ablation masked`).
    pub fn run(&self, label: &str, episodes: usize) -> RunProgress {
        let bar = self.multi.as_ref().map(|m| {
            let bar = m.add(ProgressBar::new(episodes as u64));
            bar.set_style(style(
                "{prefix:.bold} [{elapsed_precise}] {wide_bar} {pos}/{len} episodes",
            ));
            bar.set_prefix(label.to_string());
            bar.tick();
            bar
        });
        RunProgress {
            multi: self.multi.clone(),
            bar,
            total: episodes,
            done: AtomicUsize::new(0),
        }
    }
}

/// The bar style of `template`, or the default one if the template is refused (it is a
/// constant, so only a programming error could make it fail; progress is never fatal).
fn style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar())
}

/// One run: its episode counter and the bars of the episodes in flight.
pub struct RunProgress {
    multi: Option<MultiProgress>,
    bar: Option<ProgressBar>,
    total: usize,
    done: AtomicUsize,
}

impl RunProgress {
    /// A bar for one episode of `images` images (from its summary), counting images read.
    pub fn episode(&self, name: &str, images: u64) -> EpisodeProgress {
        EpisodeProgress(self.multi.as_ref().map(|m| {
            let bar = m.add(ProgressBar::new(images));
            bar.set_style(style(
                "  {prefix} {wide_bar} {pos}/{len} frames ({per_sec}, eta {eta})",
            ));
            bar.set_prefix(name.to_string());
            bar
        }))
    }

    /// Counts one finished episode and reports it: `[n/total] line` above the bars, or on
    /// stderr when there are none.
    pub fn finished(&self, line: &str) {
        let n = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        let text = format!("[{n}/{}] {line}", self.total);
        match (&self.multi, &self.bar) {
            (Some(m), Some(bar)) => {
                bar.inc(1);
                // A failed write of a progress line is no reason to fail the run.
                if m.println(&text).is_err() {
                    eprintln!("{text}");
                }
            }
            _ => eprintln!("{text}"),
        }
    }
}

impl Drop for RunProgress {
    fn drop(&mut self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// The bar of one episode; cleared when dropped.
pub struct EpisodeProgress(Option<ProgressBar>);

impl EpisodeProgress {
    /// `images` images of the episode have been read.
    pub fn set(&self, images: u64) {
        if let Some(bar) = &self.0 {
            bar.set_position(images);
        }
    }
}

impl Drop for EpisodeProgress {
    fn drop(&mut self) {
        if let Some(bar) = &self.0 {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_progress_counts_finished_episodes_without_bars() {
        let p = Progress::new(true);
        assert!(p.multi.is_none(), "--no-progress draws nothing");
        let run = p.run("scoring", 3);
        let ep = run.episode("a", 10);
        ep.set(4);
        assert!(ep.0.is_none());
        run.finished("a: 4 frames scored");
        run.finished("b: 0 frames scored");
        assert_eq!(run.done.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn drawn_bars_track_episodes_and_frames() {
        // A hidden draw target: the bars exist and count, nothing reaches the terminal.
        let p = Progress {
            multi: Some(MultiProgress::with_draw_target(ProgressDrawTarget::hidden())),
        };
        let run = p.run("eval", 2);
        let ep = run.episode("a", 10);
        ep.set(7);
        assert_eq!(
            ep.0.as_ref().map(|b| (b.position(), b.length())),
            Some((7, Some(10)))
        );
        run.finished("a: 7 frames scored");
        assert_eq!(run.bar.as_ref().map(|b| b.position()), Some(1));
        drop(ep);
    }
}
