//! The baker's flags as `clap` arguments (feature `cli`): how to read a volume
//! ([`SourceArgs`], shared by `pinbake bake` and `pinrender` so that the two tools accept the
//! same volumes the same way) and the value parsers of the baker's ranges
//! ([`crate::limits`]). The tools' generic kit (output lines, exit codes, size parsers,
//! signals) is the `pin-cli` crate.

use pin_cli::parse::{parse_f64x3, parse_nonneg};

/// `--step`: see [`crate::limits::check_rel_step`].
pub fn parse_step(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    crate::limits::check_rel_step(v)
}

/// `--spacing`: see [`crate::limits::check_spacing`].
pub fn parse_spacing(s: &str) -> Result<[f64; 3], String> {
    crate::limits::check_spacing(parse_f64x3(s)?)
}

/// `--origin`: see [`crate::limits::check_origin`].
pub fn parse_origin(s: &str) -> Result<[f64; 3], String> {
    crate::limits::check_origin(parse_f64x3(s)?)
}

/// `--density-scale`: finite and >= 0 ([`pin_volume::DensityScale`]).
pub fn parse_density_scale(s: &str) -> Result<pin_volume::DensityScale, String> {
    pin_volume::DensityScale::new(parse_nonneg(s)?).map_err(|e| e.to_string())
}

/// `--threads N`: see [`crate::limits::check_threads`].
pub fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    crate::limits::check_threads(n)
}

/// The flags that say how to read a volume, shared by `pinbake bake` and `pinrender` through
/// `#[command(flatten)]` so that the two tools accept the same volumes the same way (the input
/// itself is each tool's own argument: a positional INPUT for the baker, `--volume` for the
/// renderer).
#[derive(clap::Args, Debug, Clone)]
pub struct SourceArgs {
    /// VDB: grid to read (`density#1` picks the second grid named density).
    #[arg(long, help_heading = "OpenVDB input")]
    pub grid: Option<String>,
    /// VDB: read a level set as a fog volume (interior = density 1).
    #[arg(long, help_heading = "OpenVDB input")]
    pub levelset_to_fog: bool,

    /// Raw: voxel counts X,Y,Z (x fastest in the file).
    #[arg(long, value_parser = pin_cli::parse::parse_u32x3, help_heading = "Raw input")]
    pub dims: Option<[u32; 3]>,
    /// Raw: voxel type: u8, u16, f16, f32, f64.
    #[arg(long = "type", help_heading = "Raw input")]
    pub voxel_type: Option<String>,
    /// Raw: byte order of multi-byte types: little (default) or big.
    #[arg(long, help_heading = "Raw input")]
    pub endian: Option<String>,
    /// Raw: world size of a voxel, one value or X,Y,Z, each in [1e-9, 1e9]; the grid occupies
    /// [origin, origin + dims * spacing].
    #[arg(long, value_parser = parse_spacing, help_heading = "Raw input")]
    pub spacing: Option<[f64; 3]>,
    /// Raw: world position of the grid box's minimum corner X,Y,Z, each within +-1e12.
    #[arg(long, value_parser = parse_origin, help_heading = "Raw input")]
    pub origin: Option<[f64; 3]>,
    /// Raw: treat negative values as 0 instead of failing.
    #[arg(long, help_heading = "Raw input")]
    pub clamp_negative: bool,
    /// Raw: treat NaN and infinities as 0 instead of failing.
    #[arg(long, help_heading = "Raw input")]
    pub nan_as_zero: bool,

    /// Multiply every density by this (extinction = density x scale); finite, >= 0.
    #[arg(long, default_value_t = pin_volume::DensityScale::ONE, value_parser = parse_density_scale)]
    pub density_scale: pin_volume::DensityScale,
}

impl Default for SourceArgs {
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
            density_scale: pin_volume::DensityScale::ONE,
        }
    }
}

fn usage(msg: String) -> anyhow::Error {
    anyhow::Error::new(pin_cli::UsageError(msg))
}

impl SourceArgs {
    /// The flags given (differing from their defaults) as command-line words that parse back
    /// to `self`: how another command (`pinrender render`) opens the same input the same way.
    pub fn to_args(&self) -> Vec<String> {
        let v3 = |v: [f64; 3]| format!("{},{},{}", v[0], v[1], v[2]);
        let mut out: Vec<String> = Vec::new();
        // `--name=value`, one word: a value that starts with `-` (a negative origin) would
        // read as a flag after a space.
        let mut flag = |name: &str, value: Option<String>| {
            out.push(match value {
                Some(v) => format!("{name}={v}"),
                None => name.to_string(),
            });
        };
        // Destructured so that a new read flag cannot be left out of the command line.
        let Self {
            grid,
            levelset_to_fog,
            dims,
            voxel_type,
            endian,
            spacing,
            origin,
            clamp_negative,
            nan_as_zero,
            density_scale,
        } = self;
        if let Some(g) = grid {
            flag("--grid", Some(g.clone()));
        }
        if *levelset_to_fog {
            flag("--levelset-to-fog", None);
        }
        if let Some(d) = dims {
            flag("--dims", Some(format!("{},{},{}", d[0], d[1], d[2])));
        }
        if let Some(t) = voxel_type {
            flag("--type", Some(t.clone()));
        }
        if let Some(e) = endian {
            flag("--endian", Some(e.clone()));
        }
        if let Some(s) = spacing {
            flag("--spacing", Some(v3(*s)));
        }
        if let Some(o) = origin {
            flag("--origin", Some(v3(*o)));
        }
        if *clamp_negative {
            flag("--clamp-negative", None);
        }
        if *nan_as_zero {
            flag("--nan-as-zero", None);
        }
        if *density_scale != pin_volume::DensityScale::ONE {
            flag("--density-scale", Some(density_scale.to_string()));
        }
        out
    }

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
            (
                "--density-scale",
                self.density_scale != pin_volume::DensityScale::ONE,
            ),
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
    ) -> anyhow::Result<pin_volume::SourceSpec> {
        use pin_volume::{self as source, ProceduralSpec, RawOptions, SourceSpec};
        let procedural = input.to_str().and_then(|s| s.strip_prefix("procedural:"));
        let kind = source::InputKind::of(input);
        let is_vdb = kind.is_vdb_like();
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
            let spec: ProceduralSpec = rest
                .parse()
                .map_err(|e: source::SourceError| anyhow::anyhow!("{e}"))?;
            return Ok(SourceSpec::Procedural(spec));
        }
        let path = input.to_path_buf();
        // A FIFO, device or directory is refused before anything opens it.
        pin_volume::files::check_input(&path)?;
        if is_vdb {
            #[cfg(feature = "vdb")]
            return Ok(SourceSpec::Vdb(
                path,
                source::VdbOptions {
                    grid: self.grid.clone(),
                    levelset_to_fog: self.levelset_to_fog,
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
            },
        ))
    }
}

/// `--dirs`: `octahedral:N` (or `oct:N`) or `polar:PHIxTHETA`, within the format's limits.
pub fn parse_dirs(s: &str) -> Result<pin_format::Directions, String> {
    let (kind, res) = s
        .split_once(':')
        .ok_or("expected polar:PHIxTHETA or octahedral:N")?;
    let d = match kind {
        "polar" => {
            let (a, b) = res
                .split_once('x')
                .ok_or("polar needs PHIxTHETA, e.g. 16x4")?;
            pin_format::Directions::Polar {
                n_phi: a.parse().map_err(|e| format!("'{a}': {e}"))?,
                n_theta: b.parse().map_err(|e| format!("'{b}': {e}"))?,
            }
        }
        "octahedral" | "oct" => pin_format::Directions::Octahedral {
            n: res.parse().map_err(|e| format!("'{res}': {e}"))?,
        },
        other => return Err(format!("unknown parametrisation '{other}'")),
    };
    let (k, r) = d.to_desc();
    pin_format::Directions::from_desc(k, r).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::SourceSpec;

    fn no_worker() -> anyhow::Result<std::path::PathBuf> {
        anyhow::bail!("no worker in this test")
    }

    #[test]
    fn the_read_flags_as_words_parse_back_to_the_same_flags() {
        #[derive(clap::Parser)]
        struct Cmd {
            #[command(flatten)]
            read: SourceArgs,
        }
        let parse = |words: &[&str]| {
            use clap::Parser;
            Cmd::try_parse_from(std::iter::once("cmd").chain(words.iter().copied()))
                .unwrap()
                .read
        };
        let given = parse(&[
            "--grid",
            "density#1",
            "--levelset-to-fog",
            "--dims",
            "4,5,6",
            "--type",
            "u16",
            "--endian",
            "big",
            "--spacing",
            "0.1,0.25,3",
            "--origin=-1,0.5,2",
            "--clamp-negative",
            "--nan-as-zero",
            "--density-scale",
            "2.5",
        ]);
        let words = given.to_args();
        let again = parse(&words.iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(format!("{given:?}"), format!("{again:?}"));
        assert_eq!(words.len(), 10, "{words:?}");
        assert!(
            words.contains(&"--origin=-1,0.5,2".to_string()),
            "{words:?}"
        );
        // Defaults give no words.
        assert!(SourceArgs::default().to_args().is_empty());
    }

    #[test]
    fn the_bakers_ranges_as_parsers() {
        assert!(parse_step("0").is_err());
        assert!(parse_step("nan").is_err());
        assert_eq!(parse_step("0.01"), Ok(0.01));
        assert!(parse_density_scale("-1").is_err());
        assert!(parse_spacing("1e153").unwrap_err().contains("1e153"));
        assert_eq!(parse_origin("1,2,3"), Ok([1.0, 2.0, 3.0]));
        assert!(parse_threads("0").is_err());
        assert_eq!(parse_threads(" 1"), Ok(1));
    }

    #[test]
    fn flags_of_another_kind_of_input_are_usage_errors_naming_the_noun() {
        let a = SourceArgs {
            dims: Some([4; 3]),
            ..SourceArgs::default()
        };
        let e = a
            .source_spec("procedural:box".as_ref(), "volume", no_worker)
            .unwrap_err();
        assert!(e.downcast_ref::<pin_cli::UsageError>().is_some());
        assert!(
            e.to_string()
                .starts_with("--dims does not apply to a procedural volume"),
            "{e}"
        );
        let a = SourceArgs {
            grid: Some("density".into()),
            ..SourceArgs::default()
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
        use pin_volume::{DensityScale, open_source};
        let a = SourceArgs {
            density_scale: DensityScale::new(2.5).unwrap(),
            ..SourceArgs::default()
        };
        let plain = SourceArgs::default();
        let at_centre = |a: &SourceArgs| {
            let spec = a
                .source_spec("procedural:box".as_ref(), "input", no_worker)
                .unwrap();
            assert!(matches!(spec, SourceSpec::Procedural(_)));
            open_source(&spec, a.density_scale)
                .unwrap()
                .extinction(glam::DVec3::splat(0.5))
        };
        assert_eq!(at_centre(&a), 2.5 * at_centre(&plain));
        assert_eq!(a.given(), ["--density-scale"]);
        assert!(plain.given().is_empty());
    }
}
