//! `pinbake bake --frames`: one bake per frame of a sequence (the patterns and frame lists are
//! [`pinbake::frames`]).

use std::io::Write as _;

use pin_volume::files::{InputSet, MemoryBudget};
use pinbake::frames::{FRAME_LIST_BYTES, FramePattern, parse_frames};

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
        + inputs.len() as u64 * pin_volume::files::INPUT_SET_ENTRY_BYTES
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
