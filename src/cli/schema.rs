//! `vamos schema <file>`: the JSON Schema of a file vamos reads (the settings file, a
//! profile file, `camera.json`), made from the Rust types that read it (schemars), with
//! their doc comments as descriptions. Editors validate and complete TOML and JSON with
//! it (e.g. taplo / Even Better TOML: `#:schema ./vamos.schema.json` at the top of the
//! file).

use anyhow::Result;
use schemars::JsonSchema;
use schemars::generate::SchemaSettings;

/// The files.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum SchemaFile {
    /// The settings file (`vamos.toml`, `--config`).
    Settings,
    /// A profile file (`--profile`).
    Profile,
    /// A camera description (`camera.json`).
    Camera,
}

/// Flags of `vamos schema`.
#[derive(clap::Args, Debug)]
pub struct SchemaArgs {
    /// Which file's schema to print (JSON Schema draft 7, to stdout).
    #[arg(value_enum)]
    pub file: SchemaFile,
}

fn schema_of<T: JsonSchema>() -> serde_json::Value {
    SchemaSettings::draft07()
        .into_generator()
        .into_root_schema_for::<T>()
        .to_value()
}

/// The schema of `file`.
pub fn schema(file: SchemaFile) -> serde_json::Value {
    match file {
        SchemaFile::Settings => schema_of::<vamos::config::Settings>(),
        SchemaFile::Profile => schema_of::<vamos::pipeline::ProfileFile>(),
        SchemaFile::Camera => schema_of::<vamos::robot::CameraSpec>(),
    }
}

/// Prints the schema of `args.file`.
pub fn run(args: &SchemaArgs) -> Result<()> {
    println!("{}", serde_json::to_string_pretty(&schema(args.file))?);
    Ok(())
}
