//! `vamos export-dataset` end to end: image folders in, `.npy` shards and a manifest out,
//! with the values the flow of a known camera motion must give.

use std::path::Path;
use std::process::Command;
use vamos::pipeline::dataset::{DatasetManifest, read_npy_f32};
use vamos::vision::GrayImage;
use vamos::vision::synthetic::Texture;

/// `count` frames of a texture drifting by (dx, dy) px per frame at 160x120.
fn write_episode(dir: &Path, count: usize, (dx, dy): (f64, f64), seed: u64, csv: bool) {
    std::fs::create_dir_all(dir).unwrap();
    let tex = Texture::random(seed);
    let mut index = String::from("file,stamp_ns\n");
    for k in 0..count {
        let img = GrayImage::from_fn(160, 120, |x, y| {
            tex.eval(x as f64 - dx * k as f64, y as f64 - dy * k as f64) as f32
        });
        let name = format!("img{k:03}.png");
        img.save_png(&dir.join(&name)).unwrap();
        index.push_str(&format!("{name},{}\n", 1_000 + 33_000_000 * k as i64));
    }
    if csv {
        std::fs::write(dir.join("frames.csv"), index).unwrap();
    }
}

fn export(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vamos"))
        .arg("export-dataset")
        .args(args)
        .env_remove("VAMOS_CONFIG")
        .env("VAMOS_PIPELINE__FRAMES__WIDTH", "160")
        .env("VAMOS_PIPELINE__FRAMES__HEIGHT", "120")
        .output()
        .unwrap()
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64
}

#[test]
fn plain_and_registered_exports() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("ep_a"), dir.path().join("ep_b"));
    write_episode(&a, 6, (1.0, -0.5), 1, true);
    write_episode(&b, 5, (1.0, -0.5), 2, false);
    let out = dir.path().join("ds");
    let run = export(&[
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--stride",
        "2",
        "--preset",
        "realtime",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let m: DatasetManifest =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m.format_version, 1);
    assert_eq!(m.processing.stride, 2);
    assert_eq!(m.processing.width, 160);
    assert_eq!(m.episodes.len(), 2);
    // Episode a: images 0, 2, 4 processed -> flows ending at 2 and 4, stamps from the CSV.
    let ea = &m.episodes[0];
    assert_eq!(ea.name, "ep_a");
    let idx: Vec<_> = ea.frames.iter().map(|f| (f.index, f.stamp_ns)).collect();
    assert_eq!(idx, [(2, 66_001_000), (4, 132_001_000)]);
    // Episode b (no CSV, 10 fps): images 0, 2, 4.
    let eb = &m.episodes[1];
    assert_eq!(eb.frames.len(), 2);
    assert_eq!(eb.frames[1].stamp_ns, 400_000_000);
    let (shape, data) = read_npy_f32(&out.join(&ea.file)).unwrap();
    assert_eq!(shape, [2, 2, 64, 64]);
    // 2 px per processed frame at 160 px wide = 8 px at 640: 8 / 15 * 0.5 = 0.267;
    // -1 px -> -0.133.
    let n = 64 * 64;
    for row in data.chunks(2 * n) {
        assert!(
            (mean(&row[..n]) - 0.2667).abs() < 0.02,
            "{}",
            mean(&row[..n])
        );
        assert!(
            (mean(&row[n..]) + 0.1333).abs() < 0.02,
            "{}",
            mean(&row[n..])
        );
    }

    // The registered variant removes the camera motion: about zero flow.
    let out_r = dir.path().join("ds_r");
    let run = export(&[
        a.to_str().unwrap(),
        "-o",
        out_r.to_str().unwrap(),
        "--stride",
        "2",
        "--preset",
        "realtime",
        "--variant",
        "registered",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let (_, data) = read_npy_f32(&out_r.join("ep_a.npy")).unwrap();
    for row in data.chunks(2 * n) {
        assert!(mean(&row[..n]).abs() < 0.01 && mean(&row[n..]).abs() < 0.01);
    }
}

#[test]
fn bad_input_is_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let ep = dir.path().join("ep");
    write_episode(&ep, 3, (1.0, 0.0), 3, true);
    let out = dir.path().join("ds");
    let o = out.to_str().unwrap();
    let e = ep.to_str().unwrap();
    let cases: [(&[&str], &str); 4] = [
        (
            &[e, "-o", o, "--variant", "masked"],
            "needs the robot's body mask",
        ),
        (&[e, "-o", o, "--variant", "fancy"], "unknown flow variant"),
        (&[e, "-o", o, "--stride", "0"], "--stride"),
        (&["/nonexistent/episode", "-o", o], "cannot read"),
    ];
    for (args, needle) in cases {
        let run = export(args);
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && err.contains(needle),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"));
    }
    // A corrupt image names the file.
    std::fs::write(ep.join("img001.png"), b"not a png").unwrap();
    let run = export(&[e, "-o", o]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("img001.png"), "{err}");
    assert!(
        !out.join("manifest.json").exists(),
        "no manifest for a failed export"
    );
}

/// The masked variant renders the panda's body mask from `joints.csv` for every frame and
/// zeroes the flow there (REFERENCE.md section 3): the masked rows hold a block of exact
/// zeros where the arm is, the plain rows do not.
#[test]
fn masked_export_renders_the_body_from_joint_states() {
    let dir = tempfile::tempdir().unwrap();
    let ep = dir.path().join("ep");
    write_episode(&ep, 4, (1.0, 0.5), 5, true);
    // Joint states at 50 Hz around the image stamps (1 us + k * 33 ms).
    let mut csv = String::from("stamp_ns,panda_joint1,panda_joint2,panda_joint4,panda_joint6\n");
    for i in 0..10 {
        let t = i as i64 * 20_000_000;
        csv.push_str(&format!("{t},{},-0.3,-2.0,1.8\n", 0.01 * i as f64));
    }
    std::fs::write(ep.join("joints.csv"), csv).unwrap();
    let camera = dir.path().join("camera.json");
    std::fs::write(
        &camera,
        r#"{"frame": "panda_link0", "convention": "body", "width": 320, "height": 240,
            "hfov_deg": 70, "offset_xyz": [1.6, 0.0, 0.6], "offset_rpy": [0.0, 0.2, 3.141592653589793]}"#,
    )
    .unwrap();
    let robot = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/robot/franka_panda");
    let zeros = |variant: &str| -> usize {
        let out = dir.path().join(variant);
        let run = export(&[
            ep.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--preset",
            "realtime",
            "--variant",
            variant,
            "--robot",
            robot.to_str().unwrap(),
            "--camera",
            camera.to_str().unwrap(),
        ]);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let (shape, data) = read_npy_f32(&out.join("ep.npy")).unwrap();
        assert_eq!(shape, [3, 2, 64, 64]);
        data.iter().filter(|&&v| v == 0.0).count()
    };
    let masked = zeros("masked");
    let plain = zeros("plain");
    // The arm covers ~4 % of the image: ~160 of 4096 input pixels, 2 channels, 3 rows.
    assert!(masked > 3 * 2 * 100, "masked zeros {masked}");
    assert!(plain < 30, "plain zeros {plain}");
    // Without joints.csv the masked export names the missing file.
    std::fs::remove_file(ep.join("joints.csv")).unwrap();
    let run = export(&[
        ep.to_str().unwrap(),
        "-o",
        dir.path().join("x").to_str().unwrap(),
        "--variant",
        "masked",
        "--robot",
        robot.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("joints.csv"), "{err}");
}
