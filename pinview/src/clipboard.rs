//! "copy command": the batch command line of the view shown, at the passes its accumulation
//! holds, put on the system clipboard and printed on stdout (where a clipboard is not at
//! hand).
//!
//! The clipboard is arboard's X11 one (text only): a thread of arboard's serves the CLIPBOARD
//! selection for as long as a `Clipboard` lives, so one is kept for the process's life. The
//! window is X11 only; on a Wayland desktop it runs under XWayland, which hands the selection
//! to Wayland clients. egui-winit's own clipboard feature was not taken: it brings arboard's
//! image stack and a native Wayland backend (docs/decisions.md, D5).

use std::sync::Mutex;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::GpuSession;

use crate::open::Medium;
use crate::view::View;

/// The command line that renders `view` of `medium` in batch at the passes `session` holds
/// once a pass in progress is finished (what `save EXR` writes and what `--spp` renders),
/// copied to the clipboard through `ctx` and printed on stdout.
pub fn copy_command(
    ctx: &egui::Context,
    session: Option<&mut GpuSession>,
    view: &View,
    medium: &Medium,
) -> Result<String> {
    let spp = match session {
        Some(s) if s.next_row() != 0 => s
            .add_passes(0)
            .map(|()| s.passes())
            .map_err(|e| anyhow!("{e}"))?,
        Some(s) => s.passes(),
        None => 0,
    };
    let command = view.command_line(medium, spp);
    // A closed stdout costs the terminal copy only.
    let _ = pin_cli::outln!("{command}");
    // egui's own clipboard (a paste inside the window), and the system's.
    ctx.copy_text(command.clone());
    system_copy(&command)?;
    Ok(command)
}

/// The process's system clipboard, opened at the first copy and kept: dropping it would end
/// the thread that serves the selection to other programs.
static SYSTEM: Mutex<Option<arboard::Clipboard>> = Mutex::new(None);

/// Puts `text` on the system clipboard.
fn system_copy(text: &str) -> Result<()> {
    let mut held = SYSTEM.lock().unwrap_or_else(|p| p.into_inner());
    if held.is_none() {
        *held = Some(arboard::Clipboard::new().map_err(|e| {
            anyhow!("the clipboard is not available ({e}); the command is on stdout")
        })?);
    }
    let clipboard = held.as_mut().expect("opened above");
    clipboard
        .set_text(text)
        .map_err(|e| anyhow!("could not copy to the clipboard ({e}); the command is on stdout"))
}
