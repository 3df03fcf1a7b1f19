//! Animated sequences: frame-number patterns in file names and frame ranges.
//!
//! A pattern names one file per frame. Two spellings are accepted, as in Houdini, Nuke and
//! OpenVDB's own tools: a run of `#` (one digit each, zero-padded: `smoke.####.vdb` names
//! `smoke.0007.vdb` for frame 7) and printf's `%d` / `%0Nd` (`smoke.%04d.vdb`). A name holds
//! at most one frame field, so a name cannot be ambiguous about where the number goes.
//! Negative frames keep their sign in front of the padding (`-007`).

use std::fmt;
use std::io::Write as _;

use pinbake::files::{InputSet, MemoryBudget};

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

/// The widest frame field: `%0Nd` and a run of `#` both stop at 32 digits (an i64 has 19).
pub const MAX_FIELD_WIDTH: usize = 32;

impl FramePattern {
    /// `Ok(None)` when `s` holds no frame field; an error when it holds more than one or a
    /// malformed `%` field. `%%` is a literal `%`, as in printf (`100%%_%04d.vdb` names
    /// `100%_0007.vdb`); a `%` not followed by `d`, digits and `d`, or `%` is itself.
    pub fn parse(s: &str) -> Result<Option<Self>, FrameError> {
        // The literal text before the field, the field, and the literal text after it.
        let mut literal = [String::new(), String::new()];
        let mut width = None;
        let mut fields = 0usize;
        let b = s.as_bytes();
        let mut i = 0;
        let mut lit_start = 0;
        let flush = |literal: &mut [String; 2], part: usize, text: &str| {
            literal[part.min(1)].push_str(text);
        };
        while i < b.len() {
            if b[i] == b'#' {
                flush(&mut literal, fields, &s[lit_start..i]);
                let start = i;
                while i < b.len() && b[i] == b'#' {
                    i += 1;
                }
                let w = i - start;
                if w > MAX_FIELD_WIDTH {
                    return Err(FrameError(format!(
                        "'{s}': frame field width {w} is more than {MAX_FIELD_WIDTH} digits"
                    )));
                }
                fields += 1;
                width = Some(w);
                lit_start = i;
                continue;
            }
            if b[i] == b'%' && b.get(i + 1) == Some(&b'%') {
                flush(&mut literal, fields, &s[lit_start..i + 1]);
                i += 2;
                lit_start = i;
                continue;
            }
            if b[i] == b'%' {
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
                    let w = if digits.is_empty() {
                        0
                    } else {
                        digits.parse::<usize>().unwrap_or(usize::MAX)
                    };
                    if w > MAX_FIELD_WIDTH {
                        return Err(FrameError(format!(
                            "'{s}': frame field width {digits} is more than {MAX_FIELD_WIDTH} digits"
                        )));
                    }
                    flush(&mut literal, fields, &s[lit_start..i]);
                    fields += 1;
                    width = Some(w);
                    i = j + 1;
                    lit_start = i;
                    continue;
                }
            }
            i += 1;
        }
        flush(&mut literal, fields, &s[lit_start..]);
        match (fields, width) {
            (0, _) | (_, None) => Ok(None),
            (1, Some(width)) => {
                let [prefix, suffix] = literal;
                Ok(Some(FramePattern {
                    prefix,
                    suffix,
                    width,
                }))
            }
            (n, _) => Err(FrameError(format!(
                "'{s}' holds {n} frame fields; a sequence name has exactly one (#### or %04d)"
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

/// Bytes of memory per listed frame while a sequence runs: the frame number, its slot in
/// the set that drops repeats, and whether its input exists.
pub const FRAME_LIST_BYTES: u64 = 48;

/// Parses a frame list: `A-B` (inclusive), `A-BxS` (every S-th frame from A), a single frame,
/// or a comma-separated mix of those (`1-10,20,30-40x5`). Frames keep the order given and
/// repeats are dropped. Negative frames are written with a leading minus (`-5--1`).
///
/// The list is counted before it is built (in 128-bit arithmetic: `A-B` may span all of
/// i64): more than [`MAX_FRAMES`], or more than `budget` holds at [`FRAME_LIST_BYTES`] a
/// frame, is refused, and the list is allocated fallibly.
pub fn parse_frames(s: &str, budget: &MemoryBudget) -> Result<Vec<i64>, FrameError> {
    let bad = |why: &str| FrameError(format!("--frames '{s}': {why}"));
    let mut ranges: Vec<(i64, i64, i64)> = Vec::new();
    let mut count: u128 = 0;
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
        count += (i128::from(b) - i128::from(a)) as u128 / step as u128 + 1;
        if count > MAX_FRAMES as u128 {
            return Err(bad(&format!("more than {MAX_FRAMES} frames")));
        }
        ranges
            .try_reserve(1)
            .map_err(|_| bad("out of memory for the list"))?;
        ranges.push((a, b, step));
    }
    // `count` is at most MAX_FRAMES here.
    let need = count as u64 * FRAME_LIST_BYTES;
    if need > budget.limit {
        return Err(bad(&format!(
            "{count} frames need {need} bytes, more than the memory budget of {} bytes \
             (--max-memory)",
            budget.limit
        )));
    }
    let alloc = |_| bad(&format!("{count} frames: out of memory for the list"));
    let mut out: Vec<i64> = Vec::new();
    out.try_reserve_exact(count as usize).map_err(alloc)?;
    let mut seen = std::collections::HashSet::new();
    seen.try_reserve(count as usize).map_err(alloc)?;
    for (a, b, step) in ranges {
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
/// frame and its file; a run of frames whose inputs are all missing is one line) and the
/// rest go on; the exit code is 1 if any frame failed. With `--json`, one object on stdout:
/// `{"frames": [{"frame", "input", "output", "ok", "summary" | "error"}], "ok": N,
/// "failed": N}`, streamed frame by frame so that its memory does not grow with the list.
/// Frames combine with `--tile`: each frame bakes the same tile.
///
/// No frame's output may be any frame's input: every input of the list is identified
/// before the first bake, and each output is checked against all of them.
pub fn run_sequence(args: super::BakeArgs) -> anyhow::Result<std::process::ExitCode> {
    let Some(spec) = args.frames.as_deref() else {
        super::usage!("--frames is missing");
    };
    let budget = MemoryBudget::new(args.max_memory);
    let frames = match parse_frames(spec, &budget) {
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
    let frame_args = |frame: i64| {
        let mut one = args.clone();
        one.frames = None;
        one.input = input.name(frame).into();
        one.output = output.name(frame).into();
        one
    };
    // A flag that does not fit the input fits no frame: a usage error, before any output.
    if let Some(&first) = frames.first() {
        match super::bake::check_usage(&frame_args(first)) {
            Err(e) if e.downcast_ref::<pin_cli::UsageError>().is_some() => return Err(e),
            _ => {}
        }
    }
    // Every input of the sequence, identified once (the output rule), and which exist.
    let mut inputs = InputSet::default();
    let mut present: Vec<bool> = Vec::new();
    present
        .try_reserve_exact(frames.len())
        .map_err(|_| anyhow::anyhow!("{} frames: out of memory", frames.len()))?;
    let mut name_bytes = 0u64;
    for &frame in &frames {
        let name = input.name(frame);
        let exists = inputs.add(std::path::Path::new(&name))?;
        if exists {
            name_bytes += name.len() as u64;
        }
        present.push(exists);
    }
    let overhead = frames.len() as u64 * FRAME_LIST_BYTES
        + inputs.len() as u64 * pinbake::files::INPUT_SET_ENTRY_BYTES
        + name_bytes;
    budget.check("the sequence's frame list and inputs", overhead)?;
    // Each frame's bake gets what the sequence's own lists leave.
    let frame_budget = budget.limit - overhead;

    let mut json = args.json.then(JsonStream::start);
    let mut failed = 0usize;
    let mut missing_run: Option<(i64, i64, usize, String)> = None;
    let flush_missing = |run: &mut Option<(i64, i64, usize, String)>| {
        if let Some((first, last, n, name)) = run.take() {
            if n == 1 {
                pin_cli::errln!("pinbake: error: frame {first}: {name}: no such file");
            } else {
                pin_cli::errln!(
                    "pinbake: error: frames {first} to {last} ({n} frames of the list): no such \
                     input file ({name} and {} more)",
                    n - 1
                );
            }
        }
    };
    for (&frame, &exists) in frames.iter().zip(&present) {
        let mut one = frame_args(frame);
        one.max_memory = Some(frame_budget);
        let result = if exists {
            flush_missing(&mut missing_run);
            super::bake::bake_one(&one, &inputs).map_err(|e| pin_cli::error_line(e.as_ref()))
        } else {
            let name = one.input.display().to_string();
            match &mut missing_run {
                Some((_, last, n, _)) => {
                    *last = frame;
                    *n += 1;
                }
                None => missing_run = Some((frame, frame, 1, name.clone())),
            }
            Err(format!("{name}: no such file"))
        };
        if let Err(msg) = &result {
            failed += 1;
            if exists {
                pin_cli::errln!("pinbake: error: frame {frame}: {msg}");
            }
        }
        if let Some(j) = &mut json {
            j.frame(frame, &one, result)?;
        }
    }
    flush_missing(&mut missing_run);
    let ok = frames.len() - failed;
    match json {
        Some(j) => j.finish(ok, failed)?,
        None => pin_cli::errln!(
            "baked {ok} of {} frames of {}{}",
            frames.len(),
            args.input.display(),
            if failed > 0 {
                format!(", {failed} failed")
            } else {
                String::new()
            }
        ),
    }
    Ok(std::process::ExitCode::from(u8::from(failed > 0)))
}

/// The `--json` object of a sequence, written to stdout one frame at a time.
struct JsonStream {
    first: bool,
}

impl JsonStream {
    fn start() -> Self {
        Self { first: true }
    }

    fn frame(
        &mut self,
        frame: i64,
        one: &super::BakeArgs,
        result: Result<serde_json::Value, String>,
    ) -> anyhow::Result<()> {
        let mut v = serde_json::json!({
            "frame": frame,
            "input": one.input.display().to_string(),
            "output": one.output.display().to_string(),
            "ok": result.is_ok(),
        });
        match result {
            Ok(summary) => v["summary"] = summary,
            Err(msg) => v["error"] = serde_json::json!(msg),
        }
        let lead = if std::mem::take(&mut self.first) {
            "{\"frames\": ["
        } else {
            ","
        };
        write!(std::io::stdout().lock(), "{lead}{v}").map_err(pin_cli::StdoutError)?;
        Ok(())
    }

    fn finish(self, ok: usize, failed: usize) -> anyhow::Result<()> {
        let lead = if self.first { "{\"frames\": [" } else { "" };
        pin_cli::outln!("{lead}], \"ok\": {ok}, \"failed\": {failed}}}")?;
        Ok(())
    }
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
        assert!(FramePattern::parse(&"#".repeat(33)).is_err());
        assert!(FramePattern::parse(&"#".repeat(32)).unwrap().is_some());
    }

    #[test]
    fn a_doubled_percent_is_a_literal_percent() {
        assert_eq!(FramePattern::parse("a%%d.vdb").unwrap(), None);
        let p = FramePattern::parse("100%%_%04d.vdb").unwrap().unwrap();
        assert_eq!(p.name(7), "100%_0007.vdb");
        let p = FramePattern::parse("%%%d%%.raw").unwrap().unwrap();
        assert_eq!(p.name(3), "%3%.raw");
    }

    fn budget() -> MemoryBudget {
        MemoryBudget { limit: 1 << 30 }
    }

    #[test]
    fn frame_lists() {
        assert_eq!(parse_frames("1-5", &budget()).unwrap(), vec![1, 2, 3, 4, 5]);
        assert_eq!(
            parse_frames("1-10x3", &budget()).unwrap(),
            vec![1, 4, 7, 10]
        );
        assert_eq!(
            parse_frames("3,1,2-4", &budget()).unwrap(),
            vec![3, 1, 2, 4]
        );
        assert_eq!(parse_frames("-2-1", &budget()).unwrap(), vec![-2, -1, 0, 1]);
        assert_eq!(parse_frames("-5--3", &budget()).unwrap(), vec![-5, -4, -3]);
        assert_eq!(parse_frames("7", &budget()).unwrap(), vec![7]);
        for bad in ["", "5-1", "1-3x0", "a-b", "1,,2", "0-2000000", "1-2x-1"] {
            assert!(parse_frames(bad, &budget()).is_err(), "{bad}");
        }
        // Spans whose length overflows an i64 are counted, not wrapped.
        assert!(parse_frames("-9223372036854775808-9223372036854775807", &budget()).is_err());
        assert!(parse_frames("1-1000", &MemoryBudget { limit: 1000 }).is_err());
        assert_eq!(
            parse_frames("9223372036854775806-9223372036854775807", &budget()).unwrap(),
            vec![i64::MAX - 1, i64::MAX]
        );
    }
}
