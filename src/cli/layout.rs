//! `vamos layout`: a Foxglove layout for a profile's scored bags, made from a bag's topics
//! and the detectors the profile runs ([`vamos::pipeline::layout`]).

use anyhow::{Context, Result};
use std::path::PathBuf;
use vamos::config::Settings;
use vamos::episode::McapEpisode;
use vamos::pipeline::layout::{layout_topics, scored_bag_layout};
use vamos::setup::Setup;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The profile the bags are (or will be) scored with.
    #[arg(long)]
    pub profile: PathBuf,
    /// A recorded episode of the robot, or a bag `vamos score --mcap` wrote: its image,
    /// camera-info and joint-state topics are the ones the profile reads.
    pub episode: PathBuf,
    /// Write the layout here (JSON; Foxglove: Layouts, Import from file) instead of stdout.
    #[arg(short, long)]
    pub out: Option<PathBuf>,
}

/// `vamos layout`: prints (or writes) the layout; the topics it shows go to stderr.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    let setup = Setup::load(settings, &args.profile)?;
    let episode = McapEpisode::open(&args.episode, &setup.episode)
        .with_context(|| format!("reading {}", args.episode.display()))?;
    let layout = scored_bag_layout(&episode.info().chosen, &setup.scored_content());
    let text = serde_json::to_string_pretty(&layout)? + "\n";
    match &args.out {
        Some(path) => {
            std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?
        }
        None => print!("{text}"),
    }
    eprintln!(
        "layout for profile {}: topics {}",
        setup.profile.file.name,
        layout_topics(&layout).join(", ")
    );
    Ok(())
}
