use pin_scene::{IDENTITY, Trs, compose_trs, load, load_bound};

use crate::{folder, write};

#[test]
fn a_whole_scene_reads_in_order_with_paths_resolved() {
    let dir = folder();
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    std::fs::write(dir.path().join("sub/b.pin"), b"").unwrap();
    let p = write(
        dir.path(),
        r#"{
          "assets": {
            "z": {"pins": "sub/b.pin"},
            "a": {"volume": "a.vdb", "pins": "a.pin", "density_scale": 2.5, "grid": "density"},
            "p": {"volume": "procedural:cosine:seed=5"}
          },
          "instances": [
            {"asset": "a"},
            {"asset": "z", "transform": [2,0,0,1, 0,2,0,2, 0,0,2,3]},
            {"asset": "a", "transform": {"translate": [1,2,3], "rotate_deg": [0,90,0], "scale": 2}},
            {"asset": "a", "transform": {"scale": [1,2,3]}}
          ],
          "camera": {"origin": [0,0,-5], "target": [0,0,0], "fov": 30},
          "sun": {"direction": [0,1,0], "radiance": 4},
          "env_radiance": 0.2, "albedo": 0.8, "g": -0.3, "max_bounces": 4
        }"#,
    );
    let s = load(&p, None).unwrap();
    let names: Vec<_> = s.assets.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["z", "a", "p"], "document order, not name order");
    assert_eq!(
        s.assets[0].pins.as_deref(),
        Some(dir.path().join("sub/b.pin").as_path())
    );
    assert_eq!(s.assets[0].volume, None);
    assert_eq!(
        s.assets[1].volume.as_deref(),
        Some(dir.path().join("a.vdb").as_path())
    );
    assert_eq!(s.assets[1].density_scale, Some(2.5));
    assert_eq!(s.assets[1].grid.as_deref(), Some("density"));
    assert_eq!(s.assets[1].json_path("volume"), "assets.a.volume");
    let asset: Vec<u32> = s.instances.iter().map(|i| i.asset).collect();
    assert_eq!(asset, [1, 0, 1, 1]);
    assert_eq!(s.instances[0].local_to_world, IDENTITY);
    assert_eq!(
        s.instances[1].local_to_world,
        [2.0, 0.0, 0.0, 1.0, 0.0, 2.0, 0.0, 2.0, 0.0, 0.0, 2.0, 3.0]
    );
    let trs = Trs {
        translate: [1.0, 2.0, 3.0],
        rotate_deg: [0.0, 90.0, 0.0],
        scale: [2.0; 3],
    };
    assert_eq!(s.instances[2].local_to_world, compose_trs(&trs));
    let m = s.instances[3].local_to_world;
    assert_eq!([m[0], m[5], m[10]], [1.0, 2.0, 3.0]);
    assert_eq!(s.uses(), [1, 3, 0]);
    assert_eq!(
        s.assets[2].volume.as_deref(),
        Some(std::path::Path::new("procedural:cosine:seed=5")),
        "a procedural volume is no file"
    );
    assert_eq!(s.camera.origin, Some([0.0, 0.0, -5.0]));
    assert_eq!(s.camera.fov, Some(30.0));
    assert_eq!(s.sun.direction, Some([0.0, 1.0, 0.0]));
    assert_eq!(s.sun.radiance, Some(4.0));
    assert_eq!(
        (s.env_radiance, s.albedo, s.g, s.max_bounces),
        (Some(0.2), Some(0.8), Some(-0.3), Some(4))
    );
}

#[test]
fn optional_values_stay_unset_for_the_flags_to_fill() {
    let dir = folder();
    let p = write(
        dir.path(),
        r#"{"assets": {"a": {"pins": "a.pin"}}, "instances": [{"asset": "a"}]}"#,
    );
    let s = load(&p, None).unwrap();
    assert_eq!(s.camera, pin_scene::Camera::default());
    assert_eq!(s.sun, pin_scene::Sun::default());
    assert_eq!(
        (s.env_radiance, s.albedo, s.g, s.max_bounces),
        (None, None, None, None)
    );
}

/// Ten thousand instances of three assets, as a cloudscape generator writes them.
fn many(n: usize) -> String {
    let mut t = String::from(
        r#"{"assets": {"a": {"pins": "a.pin"}, "b": {"volume": "a.vdb"}, "c": {"pins": "a.pin"}}, "instances": ["#,
    );
    for i in 0..n {
        if i > 0 {
            t.push(',');
        }
        let f = i as f64;
        t.push_str(&format!(
            r#"{{"asset": "{}", "transform": {{"translate": [{}, {}, {}], "rotate_deg": [{}, {}, {}], "scale": [{}, 1.5, 0.75]}}}}"#,
            ["a", "b", "c"][i % 3],
            f * 3.0,
            (f * 0.37).sin() * 100.0,
            -f,
            f % 360.0,
            (f * 7.0) % 360.0,
            (f * 13.0) % 360.0,
            1.0 + (i % 5) as f64 * 0.25
        ));
    }
    t.push_str("]}");
    t
}

#[test]
fn ten_thousand_instances_load_within_their_bound() {
    let dir = folder();
    let text = many(10_000);
    let p = write(dir.path(), &text);
    let s = load(&p, Some(load_bound(text.len() as u64))).unwrap();
    assert_eq!(s.instances.len(), 10_000);
    assert_eq!(s.uses(), [3334, 3333, 3333]);
    // The bound is what a memory budget is checked against: one byte less is refused.
    let short = load_bound(text.len() as u64) - 1;
    let e = load(&p, Some(short)).unwrap_err().to_string();
    assert!(e.contains("more than --max-memory"), "{e}");
}

#[test]
fn the_bound_grows_with_the_file_and_stops_at_the_caps() {
    assert!(load_bound(1_000) < load_bound(1_000_000));
    let top = load_bound(pin_scene::MAX_SCENE_BYTES);
    assert!(top < 1 << 30, "{top}");
}

/// Relative asset paths resolve beside the scene's path as given: through a symlink to the
/// scene, beside the link, not beside its target (docs/scene.md).
#[test]
fn relative_paths_resolve_beside_a_symlink_not_its_target() {
    let target = folder();
    let p = write(
        target.path(),
        r#"{"assets": {"a": {"volume": "a.vdb"}}, "instances": [{"asset": "a"}]}"#,
    );
    let elsewhere = tempfile::tempdir().unwrap();
    let link = elsewhere.path().join("link.json");
    std::os::unix::fs::symlink(&p, &link).unwrap();
    // Beside the link there is no a.vdb yet: refused, naming the path as resolved there.
    let e = pin_scene::load(&link, None).unwrap_err().to_string();
    assert!(
        e.contains("assets.a.volume") && e.contains(&elsewhere.path().display().to_string()),
        "{e}"
    );
    std::fs::write(elsewhere.path().join("a.vdb"), b"").unwrap();
    let s = pin_scene::load(&link, None).unwrap();
    assert_eq!(
        s.assets[0].volume.as_deref(),
        Some(elsewhere.path().join("a.vdb").as_path())
    );
}
