//! `m1cs run` as a general master's front end: `--record` patterns for any outputs, the CSV
//! written as the run goes, a run stopped by a signal (the rows until then kept, the temporary
//! folders removed, exit status 130), and `m1cs system`'s connection count.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn fmu_dir() -> String {
    std::env::var("M1CS_FMU_DIR")
        .unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/target/fmu").to_string())
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("m1cs-cli-record-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The header and the numeric rows of a CSV file.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    (header, rows)
}

/// Patterns select outputs of any component (an array by base name, `*` and `?` globs, a
/// pattern matching a default column adds nothing twice); the CSV holds exactly the metrics and
/// those columns, every row; the figures' mirror displacement is not in it; `--no-plots` draws
/// nothing. A pattern that matches nothing, or a String, is an error naming it.
#[test]
fn record_patterns_select_any_outputs() {
    let dir = scratch("patterns");
    let out = dir.to_string_lossy().into_owned();
    let fmus = fmu_dir();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "run",
            "--layout",
            "keck",
            "--duration",
            "0.1",
            "--fmu-dir",
            &fmus,
            "--out",
            &out,
            "--json",
        ];
        args.extend_from_slice(extra);
        Command::new(env!("CARGO_BIN_EXE_m1cs"))
            .args(&args)
            .output()
            .unwrap()
    };
    let o = run(&[
        "--record",
        "mirror.z[1?]",
        "--record",
        "*.pssn",
        "--record",
        "controller.u_cmd",
        "--record",
        "sensors.y[3]",
        "--no-plots",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (header, rows) = read_csv(&dir.join("closed_loop.csv"));
    let mut expected: Vec<String> = [
        "time",
        "optics.rms_surface",
        "optics.focus_mode",
        "optics.rms_surface_without_focus",
        "optics.pssn",
    ]
    .map(String::from)
    .to_vec();
    expected.extend((10..20).map(|k| format!("mirror.z[{k}]")));
    expected.extend((1..=108).map(|k| format!("controller.u_cmd[{k}]")));
    expected.push("sensors.y[3]".into());
    assert_eq!(header, expected);
    assert_eq!(rows.len(), 101);
    assert!(rows.iter().all(|r| r.len() == expected.len()));
    // The recorded displacement moves with the wind; the controller's command too, closed loop.
    assert!(rows.iter().any(|r| r[5] != 0.0));
    assert!(rows.iter().any(|r| r[15] != 0.0));
    assert!(
        !dir.join("rms_surface.png").exists(),
        "--no-plots drew a figure"
    );
    // Without --record the CSV has the metrics only (the displacement is kept for the figures,
    // not written), and the figures are drawn.
    let o = run(&[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (header, _) = read_csv(&dir.join("closed_loop.csv"));
    assert_eq!(header.len(), 5, "{header:?}");
    assert!(dir.join("rms_surface.png").is_file());
    for (pattern, says) in [
        ("mirror.nosuch*", "matches no output"),
        ("nosuch.z", "no component named nosuch"),
        ("*.nosuch", "matches no output"),
        ("rmssurface", "expected component.signal"),
    ] {
        let o = run(&["--record", pattern]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(says),
            "{pattern}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Starts a 600 s Keck run of `m1cs run` (no figures) with `extra` arguments, results in `out`
/// and `TMPDIR` at `tmp`; once `file` holds `bytes` (set-up done, the loop running) sends
/// `signal` and returns the output. Checks the FMUs were unpacked under `tmp` meanwhile.
fn interrupt(
    extra: &[&str],
    out: &Path,
    tmp: &Path,
    file: &Path,
    bytes: u64,
    signal: libc::c_int,
) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .args(["run", "--layout", "keck", "--duration", "600", "--no-plots"])
        .args(["--fmu-dir", &fmu_dir(), "--json", "--out"])
        .arg(out)
        .args(extra)
        .env("TMPDIR", tmp)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while std::fs::metadata(file).map_or(0, |m| m.len()) < bytes {
        assert!(
            t0.elapsed().as_secs() < 120,
            "no rows after 120 s: {:?}",
            child.try_wait()
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert!(
        std::fs::read_dir(tmp).unwrap().count() > 0,
        "the FMUs are unpacked under TMPDIR"
    );
    // SAFETY: kill with a valid pid and signal.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, signal) }, 0);
    child.wait_with_output().unwrap()
}

/// SIGINT on a running `m1cs run`: the loop stops at the next step, the CSV holds the rows up
/// to then (consecutive, complete), the summary says where it stopped, the FMUs' temporary
/// folders are gone, and the exit status is 130. The same for SIGTERM.
#[test]
fn a_signal_stops_the_run_and_keeps_its_rows() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        let dir = scratch(&format!("signal-{signal}"));
        let tmp = dir.join("tmp");
        std::fs::create_dir_all(&tmp).unwrap();
        let out = dir.join("results");
        let csv = out.join("open_loop.csv");
        let o = interrupt(&[], &out, &tmp, &csv, 200_000, signal);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(130), "{err}");
        assert!(err.contains("stopped by a signal at t ="), "{err}");
        let (header, rows) = read_csv(&csv);
        assert_eq!(header.len(), 5);
        assert!(rows.len() > 100, "{} rows", rows.len());
        for (k, r) in rows.iter().enumerate() {
            assert_eq!(r.len(), 5, "row {k}");
            assert!(
                (r[0] - k as f64 * 1e-3).abs() < 1e-9,
                "row {k}: t = {}",
                r[0]
            );
        }
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let stopped = v["runs"][0]["interrupted_at_s"].as_f64().unwrap();
        assert!(
            (stopped - rows.last().unwrap()[0]).abs() < 1e-9,
            "{stopped}"
        );
        // The closed-loop run after it did not start.
        assert_eq!(v["runs"].as_array().unwrap().len(), 1);
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert!(left.is_empty(), "temporary folders left: {left:?}");
        std::fs::remove_dir_all(&dir).ok();
    }
}

/// `m1cs system` counts the scalar connections it writes, next to the signal connections.
#[test]
fn system_reports_scalar_connections() {
    let dir = scratch("system");
    let ssp = dir.join("keck.ssp");
    let o = Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .args(["system", "--layout", "keck", "--fmu-dir", &fmu_dir(), "-o"])
        .arg(&ssp)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // wind -> mirror (108), controller -> mirror (108), mirror -> sensors (108), sensors ->
    // controller (168), mirror -> optics (108).
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("5 signal connections = 600 scalar connections"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `m1cs run --ssp` honours the file's step, rates and stop time; `--step`, `--duration` and
/// `--uniform` override them, each with a note (the rates keep their periods when the step
/// changes); an error about a file inside the archive names it as `X.ssp: resources/...`,
/// not the temporary folder it was unpacked to.
#[test]
fn ssp_overrides_say_so_and_errors_name_the_archive() {
    let dir = scratch("ssp");
    let ssp = dir.join("keck.ssp");
    let out = dir.join("results");
    let fmus = fmu_dir();
    let o = Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .args([
            "system",
            "--layout",
            "keck",
            "--duration",
            "0.1",
            "--fmu-dir",
            &fmus,
        ])
        .arg("-o")
        .arg(&ssp)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = |extra: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_m1cs"))
            .arg("run")
            .arg("--ssp")
            .arg(&ssp)
            .arg("--out")
            .arg(&out)
            .args(["--json", "--no-plots"])
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        (o.status.success(), err)
    };
    let (ok, err) = run(&[]);
    assert!(ok && !err.contains("note:"), "{err}");
    assert_eq!(read_csv(&out.join("system.csv")).1.len(), 101);
    let (ok, err) = run(&["--step", "4e-4", "--duration", "0.05"]);
    assert!(ok, "{err}");
    assert!(
        err.contains("--step 0.0004 overrides the step of")
            && err.contains(
                "the slower components keep their periods: wind every 25, controller every 125"
            ),
        "{err}"
    );
    assert!(
        err.contains("stop time 0.05 s overrides that of") && err.contains("(0.1 s)"),
        "{err}"
    );
    let (_, rows) = read_csv(&out.join("system.csv"));
    assert_eq!(rows.len(), 126);
    assert!((rows[125][0] - 0.05).abs() < 1e-12);
    let (ok, err) = run(&["--uniform"]);
    assert!(
        ok && err.contains("--uniform steps every component"),
        "{err}"
    );
    let (ok, err) = run(&["--step", "3e-4"]);
    assert!(!ok && err.contains("not a whole number"), "{err}");
    let (ok, err) = run(&["--stop-time", "0.0105"]);
    assert!(!ok && err.contains("whole number of steps"), "{err}");
    assert!(
        !out.join("system.csv").exists(),
        "a run that failed in its set-up left a results file"
    );
    // A broken FMU inside the archive.
    let broken = dir.join("broken.ssp");
    {
        let mut src = zip::ZipArchive::new(std::fs::File::open(&ssp).unwrap()).unwrap();
        let mut dst = zip::ZipWriter::new(std::fs::File::create(&broken).unwrap());
        let opts = zip::write::SimpleFileOptions::default();
        for k in 0..src.len() {
            let mut f = src.by_index(k).unwrap();
            let name = f.name().unwrap().to_string();
            let mut bytes = Vec::new();
            std::io::Read::read_to_end(&mut f, &mut bytes).unwrap();
            if name.ends_with("edge_sensors.fmu") {
                bytes = b"not a zip archive".to_vec();
            }
            dst.start_file(name, opts).unwrap();
            std::io::Write::write_all(&mut dst, &bytes).unwrap();
        }
        dst.finish().unwrap();
    }
    let unpacked = dir.join("tmp");
    std::fs::create_dir_all(&unpacked).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .arg("run")
        .arg("--ssp")
        .arg(&broken)
        .arg("--out")
        .arg(&out)
        .env("TMPDIR", &unpacked)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains(&format!("{}: resources/edge_sensors.fmu", broken.display())),
        "{err}"
    );
    assert!(
        !err.contains(&*unpacked.to_string_lossy()),
        "names the temporary folder: {err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `--format npy` writes the same rows as the CSV, as one float64 array (rows x columns, C
/// order) with its column names beside it.
#[test]
fn npy_results_hold_the_csv_rows() {
    let dir = scratch("npy");
    let fmus = fmu_dir();
    let run = |format: &str| {
        let out = dir.join(format);
        let o = Command::new(env!("CARGO_BIN_EXE_m1cs"))
            .args([
                "run",
                "--layout",
                "keck",
                "--duration",
                "0.05",
                "--no-plots",
            ])
            .args([
                "--record",
                "mirror.z",
                "--fmu-dir",
                &fmus,
                "--format",
                format,
            ])
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        out
    };
    let (header, rows) = read_csv(&run("csv").join("closed_loop.csv"));
    let out = run("npy");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("closed_loop.npy.json")).unwrap())
            .unwrap();
    let names: Vec<String> = meta["columns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap().to_string())
        .collect();
    assert_eq!(names, header);
    assert_eq!(header.len(), 5 + 108);
    assert_eq!(meta["rows"], rows.len());
    let bytes = std::fs::read(out.join("closed_loop.npy")).unwrap();
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    assert_eq!(npy.shape(), &[rows.len() as u64, header.len() as u64]);
    let values: Vec<f64> = npy.into_vec().unwrap();
    for (k, row) in rows.iter().enumerate() {
        // The CSV's text is the shortest representation that reads back the same float.
        assert_eq!(
            &values[k * header.len()..(k + 1) * header.len()],
            &row[..],
            "row {k}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// `--format npy` stopped by a signal: the array's header says the rows written (the header
/// announced the whole run), the values are whole rows, and the `.json` says the same.
#[test]
fn a_signal_leaves_a_whole_npy_array() {
    let dir = scratch("npy-signal");
    let (out, tmp) = (dir.join("results"), dir.join("tmp"));
    std::fs::create_dir_all(&tmp).unwrap();
    let npy = out.join("open_loop.npy");
    let args = ["--format", "npy", "--record", "mirror.z"];
    let o = interrupt(&args, &out, &tmp, &npy, 2_000_000, libc::SIGINT);
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("open_loop.npy.json")).unwrap())
            .unwrap();
    let rows = meta["rows"].as_u64().unwrap();
    let cols = meta["columns"].as_array().unwrap().len() as u64;
    assert_eq!(cols, 5 + 108);
    assert!(rows > 100, "{rows} rows");
    let bytes = std::fs::read(&npy).unwrap();
    let file = npyz::NpyFile::new(&bytes[..]).unwrap();
    assert_eq!(file.shape(), &[rows, cols]);
    let values: Vec<f64> = file.into_vec().unwrap();
    assert_eq!(values.len() as u64, rows * cols);
    for k in 0..rows as usize {
        let t = values[k * cols as usize];
        assert!((t - k as f64 * 1e-3).abs() < 1e-9, "row {k}: t = {t}");
    }
    assert!(values.iter().all(|v| v.is_finite()));
    std::fs::remove_dir_all(&dir).ok();
}
