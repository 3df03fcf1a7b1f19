//! The path tracer's WGSL, with as many brick value bindings as a scene needs.
//!
//! `shaders/render.wgsl` declares sixteen value bindings (`rt_bricks0..15`) and a switch over
//! them (`rt_brick_word`), each between marker comments. A scene whose bricks need more (the
//! full-size production cloud needs 24 bindings of lavapipe's 128 MiB) or that needs fewer
//! (a device that binds only eight storage buffers in a stage) gets the same text with those
//! two regions generated for its count. The generator writes the file's own text for
//! sixteen, which a test checks, so the file stays the shader that runs.

/// The WGSL of the GPU path tracer as the files hold it: the pin sampler followed by
/// `shaders/render.wgsl` (entry point `render_main`), with sixteen value bindings.
pub const RENDER_WGSL: &str = concat!(
    include_str!("../../../shaders/pin.wgsl"),
    include_str!("../../../shaders/render.wgsl")
);

/// The first binding (group 1) of the brick values.
const FIRST_VALUE_BINDING: usize = 7;

/// [`render_wgsl`] with an extension's kernels (a [`super::ShaderKernel`]'s WGSL, defining
/// `rt_kernel_transmittance`) in place of the file's extension region.
pub fn render_wgsl_with(bindings: usize, kernels: &str) -> String {
    replace_region(
        &render_wgsl(bindings),
        "// extension kernels {\n",
        "// } extension kernels\n",
        kernels,
    )
}

/// [`RENDER_WGSL`] with `bindings` brick value bindings (at least one).
pub fn render_wgsl(bindings: usize) -> String {
    let n = bindings.max(1);
    let decls: String = (0..n)
        .map(|k| {
            format!(
                "@group(1) @binding({}) var<storage, read> rt_bricks{k}: array<u32>;\n",
                FIRST_VALUE_BINDING + k
            )
        })
        .collect();
    let mut word = String::from(
        "fn rt_brick_word(a: u32, cap: u32) -> u32 {\n    let k = a / cap;\n    \
         let i = a - k * cap;\n    switch k {\n",
    );
    for k in 0..n {
        let label = if k + 1 == n {
            "default".to_string()
        } else {
            format!("case {k}u")
        };
        word.push_str(&format!(
            "        {label}: {{\n            return rt_bricks{k}[i];\n        }}\n"
        ));
    }
    word.push_str("    }\n}\n");
    let text = replace_region(
        RENDER_WGSL,
        "// value bindings {\n",
        "// } value bindings\n",
        &decls,
    );
    replace_region(&text, "// brick word {\n", "// } brick word\n", &word)
}

/// `text` with what lies between the lines `open` and `close` replaced by `body`.
fn replace_region(text: &str, open: &str, close: &str, body: &str) -> String {
    let start = text.find(open).expect("render.wgsl keeps its markers") + open.len();
    let end = start
        + text[start..]
            .find(close)
            .expect("render.wgsl keeps its markers");
    format!("{}{body}{}", &text[..start], &text[end..])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The file is the generator's text for sixteen bindings, so what runs is what is read.
    #[test]
    fn the_file_is_the_generated_text_for_sixteen() {
        assert_eq!(render_wgsl(16), RENDER_WGSL);
    }

    /// Every count from one to the most the renderer uses declares that many bindings and
    /// validates (naga's WGSL front end and validator, as wgpu runs them).
    #[cfg(feature = "cli")]
    #[test]
    fn every_count_validates() {
        for n in [1, 2, 16, 17, 26, super::super::media::MAX_VALUE_BINDINGS] {
            let text = render_wgsl(n);
            assert_eq!(text.matches("var<storage, read> rt_bricks").count(), n);
            assert!(text.contains(&format!("return rt_bricks{}[i];", n - 1)));
            let module = naga::front::wgsl::parse_str(&text).unwrap_or_else(|e| panic!("{n}: {e}"));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{n}: {e:?}"));
        }
    }
}
