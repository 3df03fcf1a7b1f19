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

/// `text` specialised to the estimator codes `kinds` (a pipeline's primary and secondary):
/// every estimator dispatch (a `switch kind {` line) keeps only the cases that one of `kinds`
/// reaches, the last kept case becoming the switch's `default`.
///
/// Why: the constants `RT_PRIMARY` and `RT_SECONDARY` select the estimators at run time only
/// after the driver has inlined every function into the entry point, so every estimator's
/// walk is inlined and optimised before the dead cases go: on lavapipe most of a pipeline's
/// creation, paid in every process that renders (docs/gpu.md, "What a pipeline compiles"). A kind reaches a case whose labels name it, or the `default` case
/// where no label of the switch names it; for a kind in `kinds` the specialised switch takes
/// the same case, so the pipeline computes what the full text computes.
///
/// The dispatches follow one shape, which `shaders/render.wgsl` states: each case is one
/// block, `case A, B: {` or `default: {`, closed by a `}` at the case's own indentation,
/// optionally preceded by comment lines; labels are `RT_EST_*` constants the text declares.
pub fn specialise(text: &str, kinds: &[u32]) -> String {
    let codes = estimator_codes(text);
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        out.push_str(line);
        i += 1;
        if line.trim() != "switch kind {" {
            continue;
        }
        let case_indent = indent(line) + 4;
        let mut cases = Vec::new();
        while let Some((case, next)) = Case::parse(&lines, i, case_indent, &codes) {
            cases.push(case);
            i = next;
        }
        // Comment lines after the last case are dropped with the cases; the loop pushes the
        // switch's closing line next.
        while lines[i].trim_start().starts_with("//") {
            i += 1;
        }
        let named: Vec<u32> = cases
            .iter()
            .flat_map(|c| c.labels.iter().flatten())
            .copied()
            .collect();
        let reached = |case: &&Case| {
            kinds.iter().any(|k| match &case.labels {
                Some(l) => l.contains(k),
                None => !named.contains(k),
            })
        };
        let kept: Vec<&Case> = cases.iter().filter(reached).collect();
        for (n, case) in kept.iter().enumerate() {
            case.comments.iter().for_each(|l| out.push_str(l));
            if n + 1 == kept.len() {
                out.push_str(&" ".repeat(case_indent));
                out.push_str("default: {\n");
            } else {
                out.push_str(case.lines[0]);
            }
            case.lines[1..].iter().for_each(|l| out.push_str(l));
        }
    }
    out
}

/// One case of an estimator dispatch.
struct Case<'a> {
    /// The comment lines before it.
    comments: &'a [&'a str],
    /// The codes its labels name; `None` for `default`.
    labels: Option<Vec<u32>>,
    /// Its lines, from its head to its closing brace.
    lines: &'a [&'a str],
}

impl<'a> Case<'a> {
    /// The case starting at line `i` (its comments first) and the line after it; `None` at
    /// the switch's closing brace.
    fn parse(
        lines: &'a [&'a str],
        i: usize,
        case_indent: usize,
        codes: &std::collections::HashMap<&str, u32>,
    ) -> Option<(Self, usize)> {
        let mut head = i;
        while lines[head].trim_start().starts_with("//") {
            head += 1;
        }
        let text = lines[head].trim();
        if text == "}" {
            return None;
        }
        assert_eq!(indent(lines[head]), case_indent, "estimator switch: {text}");
        let labels = (text != "default: {").then(|| {
            text.strip_prefix("case ")
                .and_then(|h| h.strip_suffix(": {"))
                .unwrap_or_else(|| panic!("estimator switch: {text}"))
                .split(',')
                .map(|l| {
                    let l = l.trim();
                    *codes
                        .get(l)
                        .unwrap_or_else(|| panic!("undeclared estimator code {l}"))
                })
                .collect()
        });
        let mut end = head + 1;
        while !(lines[end].trim() == "}" && indent(lines[end]) == case_indent) {
            end += 1;
        }
        let case = Case {
            comments: &lines[i..head],
            labels,
            lines: &lines[head..=end],
        };
        Some((case, end + 1))
    }
}

/// The estimator codes `text` declares: `const RT_EST_NAME: u32 = Nu;`.
fn estimator_codes(text: &str) -> std::collections::HashMap<&str, u32> {
    text.lines()
        .filter_map(|l| {
            let rest = l.strip_prefix("const ")?;
            let (name, value) = rest.split_once(": u32 = ")?;
            let value = value.strip_suffix("u;")?.parse().ok()?;
            name.starts_with("RT_EST_").then_some((name, value))
        })
        .collect()
}

fn indent(line: &str) -> usize {
    line.len() - line.trim_start_matches(' ').len()
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

    /// The case heads of every estimator dispatch in `text`, switch by switch.
    fn dispatch_heads(text: &str) -> Vec<Vec<String>> {
        let codes = estimator_codes(text);
        let lines: Vec<&str> = text.split_inclusive('\n').collect();
        let mut out = Vec::new();
        for (i, line) in lines.iter().enumerate() {
            if line.trim() != "switch kind {" {
                continue;
            }
            let mut heads = Vec::new();
            let mut at = i + 1;
            while let Some((case, next)) = Case::parse(&lines, at, indent(line) + 4, &codes) {
                heads.push(case.lines[0].trim().to_string());
                at = next;
            }
            out.push(heads);
        }
        out
    }

    /// With every code (the renderer's and a kernel's) the text is unchanged: the
    /// specialisation only removes cases.
    #[test]
    fn every_code_keeps_the_whole_text() {
        assert_eq!(specialise(RENDER_WGSL, &[0, 1, 2, 3, 6, 9]), RENDER_WGSL);
        // Three dispatches: a medium's transmittance, its distance, and the paired walk.
        assert_eq!(dispatch_heads(RENDER_WGSL).len(), 3);
    }

    /// Each estimator pair keeps the cases that reach it and nothing else, the last as the
    /// default, and the text still validates.
    #[cfg(feature = "cli")]
    #[test]
    fn each_pair_keeps_its_own_cases() {
        let march = "case RT_EST_MARCH: {";
        let pins = "case RT_EST_PINS: {";
        let ratio = "case RT_EST_RATIO: {";
        let tracked = "case RT_EST_DELTA, RT_EST_RATIO, RT_EST_RESIDUAL: {";
        let paired = "case RT_EST_RATIO, RT_EST_RESIDUAL: {";
        let default = "default: {";
        let cases = |kinds: &[u32]| dispatch_heads(&specialise(RENDER_WGSL, kinds));
        // Pins alone: one case per dispatch, and the paired walk's is the never-reached
        // default.
        assert_eq!(cases(&[3, 3]), vec![vec![default]; 3]);
        // PinMS: ratio tracking and pins; its pairs are ratio tracking's.
        assert_eq!(
            cases(&[2, 3]),
            vec![
                vec![ratio, default],
                vec![pins, default],
                vec![paired, default]
            ]
        );
        assert_eq!(cases(&[0, 0]), vec![vec![default]; 3]);
        // The whole text's dispatches, for comparison.
        assert_eq!(dispatch_heads(RENDER_WGSL)[1][0], march);
        assert_eq!(dispatch_heads(RENDER_WGSL)[1][2], tracked);
        assert_eq!(dispatch_heads(RENDER_WGSL)[2][0], paired);
        for pair in [[0, 0], [1, 1], [2, 2], [3, 3], [2, 3], [6, 6], [9, 9]] {
            let text = specialise(&render_wgsl(2), &pair);
            let module = naga::front::wgsl::parse_str(&text)
                .unwrap_or_else(|e| panic!("{pair:?}: {}", e.emit_to_string(&text)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{pair:?}: {e:?}"));
        }
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
