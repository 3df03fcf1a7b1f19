//! A private X server per test (Xvfb), the binaries in a runtime directory of their own, and
//! small bakes (each baked once per test binary).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use pin_format::Metadata;
use pin_volume::{DensitySource, ProceduralSpec, SourceIdentity};

pub const PINVIEW: &str = env!("CARGO_BIN_EXE_pinview");
pub const COSINE: &str = "procedural:cosine:seed=5,freq=4,density=6";

/// `pinrender` from the same target directory (built by `cargo test --workspace`).
pub fn pinrender() -> PathBuf {
    let dir = Path::new(PINVIEW).parent().unwrap();
    let bin = dir.join("pinrender");
    assert!(
        bin.exists(),
        "{} is missing: build it with `cargo build --release -p pinrender --all-features` \
         (cargo test --workspace builds it)",
        bin.display()
    );
    bin
}

/// An Xvfb server on a display of its own, stopped when dropped.
pub struct Display {
    child: Child,
    number: u32,
    pub name: String,
}

impl Drop for Display {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        // A killed server leaves its lock and socket behind; they are this test's own.
        let _ = std::fs::remove_file(format!("/tmp/.X{}-lock", self.number));
        let _ = std::fs::remove_file(format!("/tmp/.X11-unix/X{}", self.number));
    }
}

/// Whether a missing X server must fail the test rather than skip it: on CI (`CI` set), the
/// window tests are the point of the job.
fn must_run() -> bool {
    std::env::var_os("CI").is_some_and(|v| !v.is_empty() && v != "0" && v != "false")
}

/// Starts Xvfb, or returns `None` (after printing why) where it is not installed outside CI.
pub fn display() -> Option<Display> {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    if Command::new("Xvfb")
        .arg("-help")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_err()
    {
        let why = "Xvfb is not installed (Debian package `xvfb`); the window tests need it";
        assert!(!must_run(), "{why}");
        eprintln!("SKIPPED: {why}");
        return None;
    }
    for _ in 0..64 {
        let n = 100 + (std::process::id() % 256) * 64 + NEXT.fetch_add(1, Ordering::Relaxed) % 64;
        if Path::new(&format!("/tmp/.X{n}-lock")).exists() {
            continue;
        }
        let mut child = Command::new("Xvfb")
            .args([
                format!(":{n}").as_str(),
                "-screen",
                "0",
                "1600x1200x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("starting Xvfb");
        let socket = format!("/tmp/.X11-unix/X{n}");
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(10) {
            if Path::new(&socket).exists() {
                return Some(Display {
                    child,
                    number: n,
                    name: format!(":{n}"),
                });
            }
            if let Ok(Some(_)) = child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = child.kill();
        let _ = child.wait();
    }
    panic!("could not start Xvfb on any display");
}

/// `program` with a valid runtime directory and no Wayland display. The shader caches are the
/// environment's, as for every other test binary and the main job: Mesa's (`~/.cache`, or
/// `MESA_SHADER_CACHE_DIR`: lavapipe's LLVM compiles) and the pipeline cache's. An estimator
/// the main job or an earlier test compiled is not compiled again. On lavapipe each process
/// rasterises and dispatches on its own thread (`LP_NUM_THREADS=0`): the tests run several
/// processes at once on the cores, and lavapipe's thread pool cost this binary 9% more CPU
/// (213 s against 194 s for the whole binary, docs/viewer.md); the bits are the same.
pub fn command(program: impl AsRef<std::ffi::OsStr>) -> Command {
    let mut cmd = Command::new(program);
    cmd.env("LP_NUM_THREADS", "0")
        .env_remove("MESA_SHADER_CACHE_DISABLE")
        .env_remove("WAYLAND_DISPLAY")
        .env("XDG_RUNTIME_DIR", runtime_dir())
        .stdin(Stdio::null());
    cmd
}

/// pinview on `display` (none: without any display), with [`command`]'s environment.
pub fn viewer_command(display: Option<&Display>) -> Command {
    let mut cmd = command(PINVIEW);
    match display {
        Some(d) => cmd.env("DISPLAY", &d.name),
        None => cmd.env_remove("DISPLAY"),
    };
    cmd
}

/// Runs pinview on `display` (none: without any display) with `args`.
pub fn pinview(display: Option<&Display>, args: &[&str]) -> Output {
    viewer_command(display)
        .args(args)
        .output()
        .expect("running pinview")
}

/// A private, valid XDG runtime directory: without one Mesa's Vulkan loader prints a warning
/// line per start, which the one-line failure checks would count.
pub fn runtime_dir() -> PathBuf {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("pinview-xdg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        dir
    })
    .clone()
}

/// [`pinview`] that must end within `limit`: killed and failed when it does not.
pub fn pinview_within(display: Option<&Display>, args: &[&str], limit: Duration) -> Output {
    let mut child = viewer_command(display)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running pinview");
    let drain = |r: Option<Box<dyn std::io::Read + Send>>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            if let Some(mut r) = r {
                let _ = r.read_to_end(&mut buf);
            }
            buf
        })
    };
    let stdout = drain(child.stdout.take().map(|r| Box::new(r) as _));
    let stderr = drain(child.stderr.take().map(|r| Box::new(r) as _));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("waiting for pinview") {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            let err = stderr.join().unwrap_or_default();
            panic!(
                "pinview {} did not end within {} s: {}",
                args.join(" "),
                limit.as_secs(),
                String::from_utf8_lossy(&err)
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    Output {
        status,
        stdout: stdout.join().unwrap_or_default(),
        stderr: stderr.join().unwrap_or_default(),
    }
}

pub fn pinrender_render(args: &[&str]) -> Output {
    command(pinrender())
        .arg("render")
        .args(args)
        .output()
        .expect("running pinrender")
}

pub fn ok(out: &Output, what: &str) {
    assert!(
        out.status.success(),
        "{what} failed ({:?}): {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Writes the cosine field times `scale` (8^3 cells), with `embed` density voxels per axis,
/// baked as [`bake_bytes`] bakes it, to `dir/name`. Each such bake is made once per test
/// binary (about 1.5 s of CPU each) and its bytes written for every test that asks.
pub fn bake(dir: &Path, name: &str, scale: f64, embed: Option<u32>) -> PathBuf {
    type Bakes = Mutex<HashMap<(u64, Option<u32>), Arc<OnceLock<Vec<u8>>>>>;
    static BAKES: OnceLock<Bakes> = OnceLock::new();
    let slot = BAKES
        .get_or_init(Bakes::default)
        .lock()
        .unwrap()
        .entry((scale.to_bits(), embed))
        .or_default()
        .clone();
    let bytes = slot.get_or_init(|| bake_bytes(scale, embed));
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// The pin file of the cosine field times `scale`, baked (fixed seed, so the same bytes every
/// time).
fn bake_bytes(scale: f64, embed: Option<u32>) -> Vec<u8> {
    let mut p: ProceduralSpec = COSINE["procedural:".len()..].parse().unwrap();
    p.density *= scale;
    let src: Box<dyn DensitySource> = p.build(pin_volume::DensityScale::ONE).unwrap();
    let opts = pinbake::BakeOptions {
        cells: [8; 3],
        density_scale: scale,
        embed_density: embed.map(|n| pinbake::EmbedDensity::Dense([n; 3])),
        majorant: embed.map(|_| [8; 3]),
        metadata: Metadata {
            extra: SourceIdentity::of(src.as_ref(), scale).to_extra(),
            ..Metadata::default()
        },
        ..pinbake::BakeOptions::default()
    };
    let (grid, _) = pinbake::bake(src.as_ref(), &opts, &|_| {}).unwrap();
    grid.to_bytes().unwrap()
}

/// The camera of the renders here: in front of the unit box.
pub const VIEW: [&str; 8] = [
    "--camera-origin",
    "0.5,0.6,2.6",
    "--camera-target",
    "0.5,0.5,0.5",
    "--width",
    "48",
    "--height",
    "40",
];

/// Runs the `pinrender render` command a viewer's JSON line gives (`command`), writing its
/// EXR to `out`, and returns that EXR's bits.
pub fn render_command(command: &str, out: &Path) -> Vec<u32> {
    let words: Vec<&str> = command.split_whitespace().collect();
    assert_eq!(&words[..2], ["pinrender", "render"], "{command}");
    let mut args: Vec<&str> = words[2..].to_vec();
    let at = args.iter().position(|w| *w == "--out").expect("--out");
    args[at + 1] = s(out);
    ok(&pinrender_render(&args), command);
    exr_bits(out)
}

/// An EXR's float bits.
pub fn exr_bits(path: &Path) -> Vec<u32> {
    let im = pinrender::render::Image::read_exr(path).unwrap();
    im.rgb.iter().flat_map(|p| p.map(f32::to_bits)).collect()
}

/// A PNG's 8-bit RGB (or RGBA reduced to RGB) and its size.
pub fn png_rgb(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let rgb = buf[..info.buffer_size()]
        .chunks_exact(channels)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    (info.width, info.height, rgb)
}

pub fn json(out: &Output) -> serde_json::Value {
    let s = String::from_utf8_lossy(&out.stdout);
    let line = s.lines().last().unwrap_or_default();
    serde_json::from_str(line).unwrap_or_else(|e| panic!("not one JSON object ({e}): {s}"))
}

/// Writes `text` to `dir/name` (an events script, a scene) and returns the path.
pub fn write_file(dir: &Path, name: &str, text: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Whether the viewer times passes with timestamp queries on the adapter it opens
/// (`pinrt::gpu::GpuContext::new`'s, found by name): the adapter offers them and is not a CPU.
pub fn adapter_has_timestamps() -> bool {
    let ctx = pinrt::gpu::GpuContext::new().expect("a wgpu adapter");
    pollster::block_on(async {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
        instance
            .enumerate_adapters(wgpu::Backends::all())
            .await
            .into_iter()
            .find(|a| {
                let i = a.get_info();
                i.name == ctx.adapter_info.name && i.backend == ctx.adapter_info.backend
            })
            .map(|a| {
                // The viewer asks a CPU adapter for none (its stamps are not pass times).
                a.features().contains(wgpu::Features::TIMESTAMP_QUERY)
                    && a.get_info().device_type != wgpu::DeviceType::Cpu
            })
            .expect("the adapter GpuContext::new opened")
    })
}
