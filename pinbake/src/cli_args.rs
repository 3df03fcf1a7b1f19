//! Command-line plumbing shared by the `pinbake` and `pinrender` binaries (feature `cli`).

use std::process::ExitCode;

/// Installs the binaries' signal handlers first thing in `main`: an interrupt, or a reader
/// that closes standard output early (`pinbake inspect --json | head -c 100`), ends the
/// process quietly and unlinks the partial output file, instead of a panic at the next
/// `println!` (see [`crate::files::signals`]). The binaries write to no other pipe (the VDB
/// worker's parent only reads from its child), so no other write raises SIGPIPE.
pub fn end_quietly_on_closed_stdout() {
    crate::files::signals::install();
}

/// The error of [`outln!`](crate::outln): standard output could not be written.
#[derive(Debug, thiserror::Error)]
#[error("standard output: {0}")]
pub struct StdoutError(pub std::io::Error);

/// `println!` for the binaries' results, returning [`StdoutError`] where `println!` panics:
/// a full disk behind a redirection (`> /dev/full`) or any other write error. (A reader that
/// closed a pipe ends the process by SIGPIPE first: [`end_quietly_on_closed_stdout`].)
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*).map_err($crate::cli_args::StdoutError)
    }};
}

/// Parses the command line; a usage error becomes one line on stderr and exit code 2 (clap's
/// own report spans several lines), while `--help` and `--version` print as usual.
pub fn parse_cli<C: clap::Parser>(
    tool: &str,
    args: Vec<std::ffi::OsString>,
) -> Result<C, ExitCode> {
    use clap::error::ErrorKind;
    match C::try_parse_from(args) {
        Ok(c) => Ok(c),
        Err(e)
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) =>
        {
            let _ = e.print();
            Err(ExitCode::from(if e.use_stderr() { 2 } else { 0 }))
        }
        Err(e) => {
            let text = e.render().to_string();
            let line: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| {
                    !(l.is_empty()
                        || l.starts_with("Usage:")
                        || l.starts_with("For more information"))
                })
                .collect();
            let line = line.join(" ");
            crate::errln!(
                "{tool}: error: {}",
                line.strip_prefix("error: ").unwrap_or(&line)
            );
            Err(ExitCode::from(2))
        }
    }
}

/// The flags that say how to read a volume, shared by `pinbake bake` and `pinrender` through
/// `#[command(flatten)]` so that the two tools accept the same volumes the same way (the input
/// itself is each tool's own argument: a positional INPUT for the baker, `--volume` for the
/// renderer).
#[derive(clap::Args, Debug, Clone)]
pub struct VolumeArgs {
    /// VDB: grid to read (`density#1` picks the second grid named density).
    #[arg(long, help_heading = "OpenVDB input")]
    pub grid: Option<String>,
    /// VDB: read a level set as a fog volume (interior = density 1).
    #[arg(long, help_heading = "OpenVDB input")]
    pub levelset_to_fog: bool,

    /// Raw: voxel counts X,Y,Z (x fastest in the file).
    #[arg(long, value_parser = parse_u32x3, help_heading = "Raw input")]
    pub dims: Option<[u32; 3]>,
    /// Raw: voxel type: u8, u16, f16, f32, f64.
    #[arg(long = "type", help_heading = "Raw input")]
    pub voxel_type: Option<String>,
    /// Raw: byte order of multi-byte types: little (default) or big.
    #[arg(long, help_heading = "Raw input")]
    pub endian: Option<String>,
    /// Raw: world size of a voxel, one value or X,Y,Z, each in [1e-9, 1e9]; the grid occupies
    /// [origin, origin + dims * spacing].
    #[arg(long, value_parser = crate::limits::parse_spacing, help_heading = "Raw input")]
    pub spacing: Option<[f64; 3]>,
    /// Raw: world position of the grid box's minimum corner X,Y,Z, each within +-1e12.
    #[arg(long, value_parser = crate::limits::parse_origin, help_heading = "Raw input")]
    pub origin: Option<[f64; 3]>,
    /// Raw: treat negative values as 0 instead of failing.
    #[arg(long, help_heading = "Raw input")]
    pub clamp_negative: bool,
    /// Raw: treat NaN and infinities as 0 instead of failing.
    #[arg(long, help_heading = "Raw input")]
    pub nan_as_zero: bool,

    /// Multiply every density by this (extinction = density x scale); finite, >= 0.
    #[arg(long, default_value_t = 1.0, value_parser = crate::limits::parse_density_scale)]
    pub density_scale: f64,
}

impl Default for VolumeArgs {
    /// No flags given (what clap produces for an empty command line).
    fn default() -> Self {
        Self {
            grid: None,
            levelset_to_fog: false,
            dims: None,
            voxel_type: None,
            endian: None,
            spacing: None,
            origin: None,
            clamp_negative: false,
            nan_as_zero: false,
            density_scale: 1.0,
        }
    }
}

/// `N` or `X,Y,Z` (also `XxYxZ`) counts, each at least 1.
pub fn parse_u32x3(s: &str) -> Result<[u32; 3], String> {
    let v: Vec<u32> = s
        .split([',', 'x'])
        .map(|p| p.trim().parse::<u32>().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, _>>()?;
    let out = match v.as_slice() {
        [n] => [*n; 3],
        [x, y, z] => [*x, *y, *z],
        _ => return Err("expected N or X,Y,Z".into()),
    };
    if out.contains(&0) {
        return Err("every count must be at least 1".into());
    }
    Ok(out)
}

fn usage(msg: String) -> anyhow::Error {
    anyhow::Error::new(crate::files::UsageError(msg))
}

impl VolumeArgs {
    /// The flags given (differing from their defaults), by name: what a command that reads
    /// no volume this time refuses.
    pub fn given(&self) -> Vec<&'static str> {
        [
            ("--grid", self.grid.is_some()),
            ("--levelset-to-fog", self.levelset_to_fog),
            ("--dims", self.dims.is_some()),
            ("--type", self.voxel_type.is_some()),
            ("--endian", self.endian.is_some()),
            ("--spacing", self.spacing.is_some()),
            ("--origin", self.origin.is_some()),
            ("--clamp-negative", self.clamp_negative),
            ("--nan-as-zero", self.nan_as_zero),
            ("--density-scale", self.density_scale != 1.0),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect()
    }

    /// What `input` (a path or `procedural:SPEC`) names, read with these flags. Flags meant for
    /// another kind of input are usage errors ("`--dims` does not apply to a procedural
    /// {noun}"): ignoring them would read something other than what the user asked for. A
    /// path must name a regular file. `worker_exe` is the executable that serves
    /// `__vdb-worker` (the calling binary itself), run only when a VDB is opened.
    pub fn source_spec(
        &self,
        input: &std::path::Path,
        noun: &str,
        worker_exe: impl FnOnce() -> anyhow::Result<std::path::PathBuf>,
    ) -> anyhow::Result<crate::source::SourceSpec> {
        use crate::source::{self, ProceduralSpec, RawOptions, SourceSpec};
        let procedural = input.to_str().and_then(|s| s.strip_prefix("procedural:"));
        let kind = source::InputKind::of(input);
        let is_vdb = kind == source::InputKind::Vdb;
        let given = source::GivenSourceOptions {
            dims: self.dims.is_some(),
            voxel_type: self.voxel_type.is_some(),
            endian: self.endian.is_some(),
            spacing: self.spacing.is_some(),
            origin: self.origin.is_some(),
            clamp_negative: self.clamp_negative,
            nan_as_zero: self.nan_as_zero,
            grid: self.grid.is_some(),
            levelset_to_fog: self.levelset_to_fog,
        };
        if let Some(name) = kind.first_inapplicable(&given) {
            // The flag's spelling: `voxel_type` is `--type`, the rest as named.
            let flag = match name {
                "voxel_type" => "--type".to_string(),
                n => format!("--{}", n.replace('_', "-")),
            };
            return Err(usage(format!(
                "{flag} does not apply to {} {noun} ({})",
                kind.article_name(),
                input.display()
            )));
        }
        if let Some(rest) = procedural {
            let mut spec: ProceduralSpec = rest
                .parse()
                .map_err(|e: source::SourceError| anyhow::anyhow!("{e}"))?;
            spec.density *= self.density_scale;
            return Ok(SourceSpec::Procedural(spec));
        }
        let path = input.to_path_buf();
        // A FIFO, device or directory is refused before anything opens it.
        crate::files::check_input(&path)?;
        if is_vdb {
            #[cfg(feature = "vdb")]
            return Ok(SourceSpec::Vdb(
                path,
                source::VdbOptions {
                    grid: self.grid.clone(),
                    levelset_to_fog: self.levelset_to_fog,
                    density_scale: self.density_scale,
                    worker_exe: worker_exe()?,
                    ..source::VdbOptions::default()
                },
            ));
            #[cfg(not(feature = "vdb"))]
            {
                let _ = worker_exe;
                return Ok(SourceSpec::Vdb(path));
            }
        }
        let voxel_type = match self.voxel_type.as_deref() {
            None => None,
            Some(t) => Some(source::RawType::parse(t).ok_or_else(|| {
                usage(format!("--type '{t}' is not one of u8, u16, f16, f32, f64"))
            })?),
        };
        let endian = match self
            .endian
            .as_deref()
            .unwrap_or("little")
            .to_ascii_lowercase()
            .as_str()
        {
            "little" | "le" => source::Endian::Little,
            "big" | "be" => source::Endian::Big,
            other => return Err(usage(format!("--endian '{other}' is not little or big"))),
        };
        Ok(SourceSpec::Raw(
            path,
            RawOptions {
                dims: self.dims,
                voxel_type,
                endian,
                spacing: self.spacing.unwrap_or([1.0; 3]),
                origin: self.origin.unwrap_or([0.0; 3]),
                clamp_negative: self.clamp_negative,
                nan_as_zero: self.nan_as_zero,
                density_scale: self.density_scale,
            },
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::source::SourceSpec;

    fn no_worker() -> anyhow::Result<std::path::PathBuf> {
        anyhow::bail!("no worker in this test")
    }

    #[test]
    fn counts_reject_zero_and_accept_both_separators() {
        assert_eq!(parse_u32x3("4").unwrap(), [4; 3]);
        assert_eq!(parse_u32x3("2,3,4").unwrap(), [2, 3, 4]);
        assert_eq!(parse_u32x3("2x3x4").unwrap(), [2, 3, 4]);
        assert!(parse_u32x3("0").is_err());
        assert!(parse_u32x3("2,0,4").is_err());
        assert!(parse_u32x3("2,3").is_err());
    }

    #[test]
    fn flags_of_another_kind_of_input_are_usage_errors_naming_the_noun() {
        let a = VolumeArgs {
            dims: Some([4; 3]),
            ..VolumeArgs::default()
        };
        let e = a
            .source_spec("procedural:box".as_ref(), "volume", no_worker)
            .unwrap_err();
        assert!(e.downcast_ref::<crate::files::UsageError>().is_some());
        assert!(
            e.to_string()
                .starts_with("--dims does not apply to a procedural volume"),
            "{e}"
        );
        let a = VolumeArgs {
            grid: Some("density".into()),
            ..VolumeArgs::default()
        };
        let e = a
            .source_spec("x.raw".as_ref(), "input", no_worker)
            .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("--grid does not apply to a raw input"),
            "{e}"
        );
    }

    #[test]
    fn procedural_density_takes_the_scale() {
        let a = VolumeArgs {
            density_scale: 2.5,
            ..VolumeArgs::default()
        };
        let plain = VolumeArgs::default();
        let get = |a: &VolumeArgs| match a
            .source_spec("procedural:box".as_ref(), "input", no_worker)
            .unwrap()
        {
            SourceSpec::Procedural(p) => p.density,
            _ => panic!("not procedural"),
        };
        assert_eq!(get(&a), 2.5 * get(&plain));
        assert_eq!(a.given(), ["--density-scale"]);
        assert!(plain.given().is_empty());
    }
}
