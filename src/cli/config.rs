//! `vamos config`: the effective settings (defaults + file + environment) as TOML.

use anyhow::Result;
use vamos::config::Settings;

/// Prints the settings.
pub fn run(settings: &Settings) -> Result<()> {
    print!("{}", toml::to_string_pretty(settings)?);
    Ok(())
}
