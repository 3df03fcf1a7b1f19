//! Animated sequences: frame-number patterns in file names and frame ranges.
//!
//! A pattern names one file per frame. Two spellings are accepted, as in Houdini, Nuke and
//! OpenVDB's own tools: a run of `#` (one digit each, zero-padded: `smoke.####.vdb` names
//! `smoke.0007.vdb` for frame 7) and printf's `%d` / `%0Nd` (`smoke.%04d.vdb`). A name holds
//! at most one frame field, so a name cannot be ambiguous about where the number goes.
//! Negative frames keep their sign in front of the padding (`-007`).

use pin_volume::files::MemoryBudget;
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

    /// The frame whose file name is `name` ([`FramePattern::name`]'s inverse), `None` when
    /// `name` is no frame's: a sequence's reader lists the files of a folder with it.
    pub fn frame_of(&self, name: &str) -> Option<i64> {
        let middle = name
            .strip_prefix(&self.prefix)?
            .strip_suffix(&self.suffix)?;
        let digits = middle.strip_prefix('-').unwrap_or(middle);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        let frame: i64 = middle.parse().ok()?;
        (self.name(frame) == name).then_some(frame)
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
    fn a_name_gives_back_its_frame() {
        for pattern in ["sim.####.pin", "sim.%04d.pin", "sim.%d.pin"] {
            let p = FramePattern::parse(pattern).unwrap().unwrap();
            for frame in [-12, -1, 0, 7, 12345] {
                assert_eq!(p.frame_of(&p.name(frame)), Some(frame), "{pattern} {frame}");
            }
        }
        let p = FramePattern::parse("sim.####.pin").unwrap().unwrap();
        // Not this pattern's spelling of any frame: too few digits, no digits, a sign
        // without them, -0, another suffix.
        for name in [
            "sim.7.pin",
            "sim..pin",
            "sim.-.pin",
            "sim.-0000.pin",
            "sim.0007.vdb",
            "sim.00x7.pin",
        ] {
            assert_eq!(p.frame_of(name), None, "{name}");
        }
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
