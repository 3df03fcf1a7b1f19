//! Animated sequences: frame-number patterns in file names and frame ranges.
//!
//! A pattern names one file per frame. Two spellings are accepted, as in Houdini, Nuke and
//! OpenVDB's own tools: a run of `#` (one digit each, zero-padded: `smoke.####.vdb` names
//! `smoke.0007.vdb` for frame 7) and printf's `%d` / `%0Nd` (`smoke.%04d.vdb`). A name holds
//! at most one frame field, so a name cannot be ambiguous about where the number goes.
//! Negative frames keep their sign in front of the padding (`-007`).

use std::fmt;

/// A file-name pattern with one frame-number field.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePattern {
    prefix: String,
    suffix: String,
    /// Minimum digits (zero-padded); 0 or 1 means no padding.
    width: usize,
}

/// Why a pattern or range was refused (usage errors: exit 2).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameError(pub String);

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for FrameError {}

/// The most frames one `--frames` may name: a bound on the work list, far above any shot.
pub const MAX_FRAMES: usize = 1_000_000;

impl FramePattern {
    /// `Ok(None)` when `s` holds no frame field; an error when it holds more than one or a
    /// malformed `%` field.
    pub fn parse(s: &str) -> Result<Option<Self>, FrameError> {
        let mut fields = Vec::new();
        let b = s.as_bytes();
        let mut i = 0;
        while i < b.len() {
            if b[i] == b'#' {
                let start = i;
                while i < b.len() && b[i] == b'#' {
                    i += 1;
                }
                fields.push((start, i, i - start));
                continue;
            }
            if b[i] == b'%' {
                let start = i;
                let mut j = i + 1;
                while j < b.len() && b[j].is_ascii_digit() {
                    j += 1;
                }
                if j < b.len() && b[j] == b'd' {
                    let digits = &s[i + 1..j];
                    if !digits.is_empty() && !digits.starts_with('0') && digits != "0" {
                        return Err(FrameError(format!(
                            "'{s}': write a padded frame field as %0Nd (e.g. %04d), not %{digits}d"
                        )));
                    }
                    let width = if digits.is_empty() {
                        0
                    } else {
                        digits.parse::<usize>().map_err(|_| {
                            FrameError(format!("'{s}': frame field width is not a number"))
                        })?
                    };
                    if width > 32 {
                        return Err(FrameError(format!(
                            "'{s}': frame field width {width} is more than 32 digits"
                        )));
                    }
                    fields.push((start, j + 1, width));
                    i = j + 1;
                    continue;
                }
            }
            i += 1;
        }
        match fields.as_slice() {
            [] => Ok(None),
            [(a, b, width)] => Ok(Some(FramePattern {
                prefix: s[..*a].to_string(),
                suffix: s[*b..].to_string(),
                width: *width,
            })),
            _ => Err(FrameError(format!(
                "'{s}' holds {} frame fields; a sequence name has exactly one (#### or %04d)",
                fields.len()
            ))),
        }
    }

    /// The file name of `frame`.
    pub fn name(&self, frame: i64) -> String {
        let digits = format!("{:0w$}", frame.unsigned_abs(), w = self.width);
        let sign = if frame < 0 { "-" } else { "" };
        format!("{}{sign}{digits}{}", self.prefix, self.suffix)
    }
}

/// Parses a frame list: `A-B` (inclusive), `A-BxS` (every S-th frame from A), a single frame,
/// or a comma-separated mix of those (`1-10,20,30-40x5`). Frames keep the order given and
/// repeats are dropped. Negative frames are written with a leading minus (`-5--1`).
pub fn parse_frames(s: &str) -> Result<Vec<i64>, FrameError> {
    let bad = |why: &str| FrameError(format!("--frames '{s}': {why}"));
    let mut out: Vec<i64> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for part in s.split(',').map(str::trim) {
        if part.is_empty() {
            return Err(bad("empty item"));
        }
        let (range, step) = match part.split_once('x') {
            Some((r, st)) => (
                r,
                st.trim()
                    .parse::<i64>()
                    .map_err(|_| bad("the step after 'x' must be a whole number"))?,
            ),
            None => (part, 1),
        };
        if step < 1 {
            return Err(bad("the step must be at least 1"));
        }
        // The separator is the first '-' that is not a sign (not at the start, not after '-').
        let sep = range
            .char_indices()
            .skip(1)
            .find(|&(i, c)| c == '-' && range.as_bytes()[i - 1] != b'-')
            .map(|(i, _)| i);
        let num = |t: &str| {
            t.trim()
                .parse::<i64>()
                .map_err(|_| bad(&format!("'{t}' is not a frame number")))
        };
        let (a, b) = match sep {
            Some(i) => (num(&range[..i])?, num(&range[i + 1..])?),
            None => {
                let f = num(range)?;
                (f, f)
            }
        };
        if b < a {
            return Err(bad(&format!("the range {a}-{b} runs backwards")));
        }
        let count = (b - a) / step + 1;
        if count as u128 + out.len() as u128 > MAX_FRAMES as u128 {
            return Err(bad(&format!("more than {MAX_FRAMES} frames")));
        }
        let mut f = a;
        while f <= b {
            if seen.insert(f) {
                out.push(f);
            }
            match f.checked_add(step) {
                Some(n) => f = n,
                None => break,
            }
        }
    }
    Ok(out)
}

/// `pinbake bake INPUT --frames F -o OUTPUT`: one deterministic bake per frame, each written
/// atomically to its own file. A frame that fails is reported on stderr (one line naming the
/// frame and its file) and the rest go on; the exit code is 1 if any frame failed. With
/// `--json`, one object on stdout: `{"frames": [{"frame", "input", "output", "ok", "summary"
/// | "error"}], "ok": N, "failed": N}`. Frames combine with `--tile`: each frame bakes the
/// same tile.
pub fn run_sequence(args: super::BakeArgs) -> anyhow::Result<std::process::ExitCode> {
    let Some(spec) = args.frames.as_deref() else {
        super::usage!("--frames is missing");
    };
    let frames = match parse_frames(spec) {
        Ok(f) => f,
        Err(e) => super::usage!("{e}"),
    };
    let Some(in_str) = args.input.to_str() else {
        super::usage!(
            "{}: a sequence input pattern must be UTF-8",
            args.input.display()
        );
    };
    let input = match FramePattern::parse(in_str) {
        Ok(Some(p)) => p,
        Ok(None) => {
            super::usage!("{in_str}: with --frames the input needs a frame field (#### or %04d)")
        }
        Err(e) => super::usage!("{e}"),
    };
    let Some(out_str) = args.output.to_str() else {
        super::usage!(
            "{}: a sequence output pattern must be UTF-8",
            args.output.display()
        );
    };
    let output = match FramePattern::parse(out_str) {
        Ok(Some(p)) => p,
        Ok(None) => super::usage!(
            "{out_str}: with --frames the output needs a frame field (#### or %04d), or every \
             frame would overwrite one file"
        ),
        Err(e) => super::usage!("{e}"),
    };
    let mut results = Vec::with_capacity(frames.len());
    let mut failed = 0usize;
    for &frame in &frames {
        let mut one = args.clone();
        one.frames = None;
        one.input = input.name(frame).into();
        one.output = output.name(frame).into();
        match super::bake::bake_one(&one) {
            Ok(summary) => results.push(serde_json::json!({
                "frame": frame,
                "input": one.input.display().to_string(),
                "output": one.output.display().to_string(),
                "ok": true,
                "summary": summary,
            })),
            // A flag that does not fit the input fits no frame: stop with the usage error.
            Err(e) if e.downcast_ref::<pinbake::files::UsageError>().is_some() => return Err(e),
            Err(e) => {
                failed += 1;
                let msg = pinbake::files::error_line(e.as_ref());
                pinbake::errln!("pinbake: error: frame {frame}: {msg}");
                results.push(serde_json::json!({
                    "frame": frame,
                    "input": one.input.display().to_string(),
                    "output": one.output.display().to_string(),
                    "ok": false,
                    "error": msg,
                }));
            }
        }
    }
    let ok = frames.len() - failed;
    if args.json {
        pinbake::outln!(
            "{}",
            serde_json::json!({ "frames": results, "ok": ok, "failed": failed })
        )?;
    } else {
        pinbake::errln!(
            "baked {ok} of {} frames of {}{}",
            frames.len(),
            args.input.display(),
            if failed > 0 {
                format!(", {failed} failed")
            } else {
                String::new()
            }
        );
    }
    Ok(std::process::ExitCode::from(u8::from(failed > 0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_and_printf_fields() {
        let p = FramePattern::parse("smoke.####.vdb").unwrap().unwrap();
        assert_eq!(p.name(7), "smoke.0007.vdb");
        assert_eq!(p.name(12345), "smoke.12345.vdb");
        assert_eq!(p.name(-7), "smoke.-0007.vdb");
        let p = FramePattern::parse("out/s_%04d.pin").unwrap().unwrap();
        assert_eq!(p.name(42), "out/s_0042.pin");
        let p = FramePattern::parse("f%d.raw").unwrap().unwrap();
        assert_eq!(p.name(3), "f3.raw");
        let p = FramePattern::parse("a#b").unwrap().unwrap();
        assert_eq!(p.name(5), "a5b");
        assert_eq!(FramePattern::parse("smoke.vdb").unwrap(), None);
        // A percent sign that is not a frame field is part of the name.
        assert_eq!(FramePattern::parse("100%_dense.vdb").unwrap(), None);
    }

    #[test]
    fn ambiguous_patterns_are_refused() {
        assert!(FramePattern::parse("a.##.b.##.vdb").is_err());
        assert!(FramePattern::parse("a.%04d.####.vdb").is_err());
        assert!(FramePattern::parse("a.%4d.vdb").is_err());
        assert!(FramePattern::parse("a.%099d.vdb").is_err());
    }

    #[test]
    fn frame_lists() {
        assert_eq!(parse_frames("1-5").unwrap(), vec![1, 2, 3, 4, 5]);
        assert_eq!(parse_frames("1-10x3").unwrap(), vec![1, 4, 7, 10]);
        assert_eq!(parse_frames("3,1,2-4").unwrap(), vec![3, 1, 2, 4]);
        assert_eq!(parse_frames("-2-1").unwrap(), vec![-2, -1, 0, 1]);
        assert_eq!(parse_frames("-5--3").unwrap(), vec![-5, -4, -3]);
        assert_eq!(parse_frames("7").unwrap(), vec![7]);
        for bad in ["", "5-1", "1-3x0", "a-b", "1,,2", "0-2000000", "1-2x-1"] {
            assert!(parse_frames(bad).is_err(), "{bad}");
        }
        assert_eq!(
            parse_frames("9223372036854775806-9223372036854775807").unwrap(),
            vec![i64::MAX - 1, i64::MAX]
        );
    }
}
