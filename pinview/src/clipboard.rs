//! "copy command": the batch command line of the view shown, at the passes its accumulation
//! holds, put on the system clipboard and printed on stdout (where a clipboard is not at
//! hand). The clipboard is egui-winit's with its `clipboard` feature: arboard on X11 (a
//! thread of its own serves the selection while the window lives), smithay-clipboard on
//! Wayland through the window's own connection; without that feature egui keeps the text in
//! the process and nothing reaches other programs.

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
    let command = view.command_line(medium.input_flag(), &medium.path, spp);
    ctx.copy_text(command.clone());
    // A closed stdout costs the terminal copy only.
    let _ = pin_cli::outln!("{command}");
    Ok(command)
}
