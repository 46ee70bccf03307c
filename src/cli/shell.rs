//! `vamos completions <shell>` and `vamos man`: shell completion scripts (clap_complete)
//! and roff man pages (clap_mangen), both made from the same clap definition the binary
//! parses with, so they cannot drift from the flags.

use anyhow::{Context, Result, bail};
use std::io::Write;
use std::path::PathBuf;

/// Flags of `vamos completions`.
#[derive(clap::Args, Debug)]
pub struct CompletionsArgs {
    /// The shell to write a completion script for (to stdout). bash: save as
    /// `/usr/share/bash-completion/completions/vamos`; zsh: `_vamos` on `$fpath`; fish:
    /// `~/.config/fish/completions/vamos.fish`.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

/// Flags of `vamos man`.
#[derive(clap::Args, Debug)]
pub struct ManArgs {
    /// Write `vamos.1` and one `vamos-<command>.1` per sub-command, nested ones too
    /// (`vamos-profile-init.1`), into this existing folder (e.g. `/usr/local/share/man/man1`) instead of printing `vamos.1` to stdout.
    #[arg(long)]
    pub dir: Option<PathBuf>,
}

/// Writes the completion script of `cmd` for `args.shell` to `out`.
pub fn completions(mut cmd: clap::Command, args: &CompletionsArgs, out: &mut dyn Write) {
    let name = cmd.get_name().to_string();
    clap_complete::generate(args.shell, &mut cmd, name, out);
}

/// Writes the man page(s) of `cmd`: `vamos.1` to `out`, or every page into `args.dir`.
/// Returns the files written (none when printing).
pub fn man(cmd: clap::Command, args: &ManArgs, out: &mut dyn Write) -> Result<Vec<PathBuf>> {
    let Some(dir) = &args.dir else {
        clap_mangen::Man::new(cmd).render(out)?;
        return Ok(Vec::new());
    };
    if !dir.is_dir() {
        bail!("{} is not an existing folder", dir.display());
    }
    let mut written = Vec::new();
    let mut page = |cmd: clap::Command, title: String| -> Result<()> {
        let path = dir.join(format!("{title}.1"));
        let mut buf = Vec::new();
        clap_mangen::Man::new(cmd).title(title).render(&mut buf)?;
        std::fs::write(&path, buf).with_context(|| format!("cannot write {}", path.display()))?;
        written.push(path);
        Ok(())
    };
    let mut cmd = cmd;
    cmd.build();
    let name = cmd.get_name().to_string();
    // Every command at every depth; a page's title names the full command
    // (`vamos-score`, `vamos-profile-init`).
    let mut queue: Vec<(clap::Command, String)> = vec![(cmd, name)];
    while let Some((cmd, title)) = queue.pop() {
        for sub in cmd.get_subcommands().filter(|s| s.get_name() != "help") {
            queue.push((sub.clone(), format!("{title}-{}", sub.get_name())));
        }
        page(cmd, title)?;
    }
    written.sort();
    Ok(written)
}
