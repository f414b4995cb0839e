//! `benches/render_tables.py` (the results and tables of `benches/run_all.sh`): the tables and
//! ratios it renders from a fixture results file, the criterion files it collects, and its
//! refusals. Skips visibly where `python3` is missing (the script needs only its standard
//! library).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    manifest_dir()
}

fn fixture(name: &str) -> PathBuf {
    root().join("tests/fixtures/bench_tables").join(name)
}

/// `python3 benches/render_tables.py ARGS`, or `None` (after recording the skip) without python3.
fn render_tables(test: &str, args: &[&std::ffi::OsStr]) -> Option<Output> {
    let out =
        Command::new("python3").arg(root().join("benches/render_tables.py")).args(args).output();
    match out {
        Ok(out) => Some(out),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            test_skip::skip(test, "python3 not found");
            None
        }
        Err(e) => panic!("running python3: {e}"),
    }
}

fn render(test: &str, results: &Path, doc: &Path, out: &Path) -> Option<Output> {
    render_tables(
        test,
        &[
            "render".as_ref(),
            results.as_os_str(),
            doc.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ],
    )
}

/// The table row whose first cell starts with `label`, split into its cells.
fn row<'a>(doc: &'a str, label: &str) -> Vec<&'a str> {
    let line = doc
        .lines()
        .find(|l| l.starts_with(&format!("| {label}")))
        .unwrap_or_else(|| panic!("no row '{label}' in:\n{doc}"));
    line.trim_matches('|').split(" | ").map(str::trim).collect()
}

#[test]
fn fixture_tables_show_medians_ratios_and_the_runs_load() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("doc.md");
    let Some(run) = render(
        "fixture_tables_show_medians_ratios_and_the_runs_load",
        &fixture("results.json"),
        &fixture("doc.md"),
        &out,
    ) else {
        return;
    };
    assert!(run.status.success(), "render failed: {}", String::from_utf8_lossy(&run.stderr));
    let doc = std::fs::read_to_string(&out).unwrap();

    // Ratios to the peer of the same run: 1.64 / 72.1 = 0.02275, 1.64 / 40.1 = 0.04090,
    // 1.30 / 72.1 = 0.01803; the rayon row's median keeps three figures (1.30, not 1.3).
    // Against the memset of the registration's outputs (issue 47): 1.64 / 0.82 = 2.00; only
    // the one-thread rows have that column. The Python column is for the Python rows only.
    assert_eq!(
        row(&doc, "kfuse `register+holes/single` ")[1..],
        ["1.64 ms", "1.62 ms – 1.66 ms", "0.023×", "0.041×", "2.00×", "—"]
    );
    assert_eq!(
        row(&doc, "kfuse `register+holes/rayon`")[1..],
        ["1.30 ms", "1.25 ms – 1.35 ms", "0.018×", "0.032×", "—", "—"]
    );
    assert_eq!(row(&doc, "memset of the same outputs")[1], "820 µs");
    // kfuse from Python against the peers and the Rust bench of the same run: 1.43 / 72.1 =
    // 0.01983, 1.43 / 40.1 = 0.03566, 1.43 / 1.30 = 1.100 (the call's overhead, 10 %).
    assert_eq!(
        row(&doc, "kfuse from Python `Registration.register`")[1..],
        ["1.43 ms", "min 1.38 ms; process CPU 2.60 ms", "0.020×", "0.036×", "—", "1.10×"]
    );
    assert_eq!(row(&doc, "kfuse from Python, the same with `out=`")[1], "no result");
    // A bench id the run lacks is said, not invented.
    assert_eq!(row(&doc, "kfuse `register+holes/single_bits`")[1], "no result");
    // Decoder: 7.69 / 72.5 = 0.1061 against the recorded libfreenect2 figure (marked †),
    // 7.69 / 22.3 = 0.3448 against Exact of this run; filters off has no libfreenect2 ratio.
    assert_eq!(
        row(&doc, "kfuse Fast (default kernels), filters on, 1 thread")[3..],
        ["0.106× †", "0.345×"]
    );
    // 3.90 / 12.3 = 0.3171.
    assert_eq!(row(&doc, "kfuse Fast, filters off, 1 thread")[3..], ["—", "0.317×"]);
    assert!(
        row(&doc, "libfreenect2 `CpuDepthPacketProcessor`")[0]
            .contains("recorded 2026-12-01, not this run")
    );
    // Paired table: 5.30 / 0.600 = 8.83; a failed bench is named with its status.
    assert_eq!(
        row(&doc, "detection, 512×424 IR")[1..],
        ["5.30 ms (5.20 ms – 5.40 ms)", "600 µs (min 500 µs; process CPU 800 µs)", "8.83×"]
    );
    assert_eq!(row(&doc, "detection, 1920×1080 colour")[1], "failed: exit 101");
    assert_eq!(row(&doc, "end to end `run`")[1..], ["not run", "not run", "—"]);

    // Every table's header names the machine, the date, the commit and the load.
    let header = "Run 2026-12-01 23:00 → 23:20 UTC · commit `0123456789` + uncommitted changes · \
                  Fixture CPU @ 1 GHz, 2 cores, 23 GiB · load (1/5/15 min) 9.50/8.00/7.00 at start, \
                  10.25/8.50/7.25 at end; **not idle**";
    assert_eq!(doc.matches(header).count(), 6, "one header per section:\n{doc}");
    // Text outside the markers is kept, stale text inside them is gone.
    for kept in [
        "Prose before the first section stays as it is.",
        "Prose between sections stays too.",
        "The last line stays.",
    ] {
        assert!(doc.contains(kept), "lost '{kept}'");
    }
    assert!(!doc.contains("stale"), "a stale table survived:\n{doc}");
    // The generic listing of one bench target: every id, sorted.
    let listing: Vec<&str> = doc.lines().filter(|l| l.starts_with("| `decode_frame/")).collect();
    assert_eq!(listing.len(), 4);
    assert_eq!(
        listing[0],
        "| `decode_frame/exact/filters_off_1_thread` | 12.3 ms | 12.2 ms – 12.4 ms |"
    );
    assert_eq!(
        listing[1],
        "| `decode_frame/exact/filters_on_1_thread` | 22.3 ms | 22.0 ms – 22.6 ms |"
    );

    // Rendering is idempotent: the regenerated document renders to itself.
    let again = dir.path().join("again.md");
    let run = render(
        "fixture_tables_show_medians_ratios_and_the_runs_load",
        &fixture("results.json"),
        &out,
        &again,
    )
    .unwrap();
    assert!(run.status.success());
    assert_eq!(std::fs::read_to_string(&again).unwrap(), doc);
}

#[test]
fn a_bad_marker_is_one_line_naming_the_file_and_nothing_is_written() {
    let test = "a_bad_marker_is_one_line_naming_the_file_and_nothing_is_written";
    let dir = tempfile::tempdir().unwrap();
    for (text, says) in [
        (
            "a\n<!-- run_all:begin no_such_table -->\n<!-- run_all:end no_such_table -->\n",
            "doc.md:2: unknown table 'no_such_table'",
        ),
        (
            "a\n\n<!-- run_all:begin decode -->\nb\n",
            "doc.md:3: section 'decode' has no 'run_all:end decode' marker",
        ),
        (
            "<!-- run_all:end decode -->\n",
            "doc.md:1: 'run_all:end decode' without its begin marker",
        ),
        (
            "<!-- run_all:begin run -->\n<!-- run_all:end decode -->\n",
            "doc.md:2: '<!-- run_all:end decode -->' inside section 'run'",
        ),
    ] {
        let doc = dir.path().join("doc.md");
        std::fs::write(&doc, text).unwrap();
        let Some(run) = render_tables(
            test,
            &["render".as_ref(), fixture("results.json").as_os_str(), doc.as_os_str()],
        ) else {
            return;
        };
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "accepted {text:?}");
        assert!(stderr.contains(says), "for {text:?} said: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");
        assert_eq!(std::fs::read_to_string(&doc).unwrap(), text, "the document was changed");
    }
}

/// `collect` reads criterion's `new/estimates.json` medians and intervals, the bench logs and
/// the peers' JSON, and falls back to the recorded libfreenect2 row.
#[test]
fn collect_reads_criterion_estimates_logs_and_peers() {
    let test = "collect_reads_criterion_estimates_logs_and_peers";
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let crit = d.join("criterion/kinect-usb/decode/decode_frame/fast_filters_on_1_thread/new");
    std::fs::create_dir_all(&crit).unwrap();
    std::fs::write(
        crit.join("benchmark.json"),
        r#"{"group_id":"decode_frame","function_id":"fast/filters_on_1_thread","value_str":null,"throughput":null,"full_id":"decode_frame/fast/filters_on_1_thread","directory_name":"decode_frame/fast_filters_on_1_thread","title":"decode_frame/fast/filters_on_1_thread"}"#,
    )
    .unwrap();
    let ci = |lo: f64, hi: f64, pt: f64| {
        format!(
            r#"{{"confidence_interval":{{"confidence_level":0.95,"lower_bound":{lo},"upper_bound":{hi}}},"point_estimate":{pt},"standard_error":1.0}}"#
        )
    };
    std::fs::write(
        crit.join("estimates.json"),
        format!(
            r#"{{"mean":{},"median":{},"median_abs_dev":{},"slope":null,"std_dev":{}}}"#,
            ci(7.0e6, 8.0e6, 7.5e6),
            ci(7.1e6, 7.9e6, 7.4e6),
            ci(1.0, 2.0, 1.5),
            ci(1.0, 2.0, 1.5)
        ),
    )
    .unwrap();
    std::fs::create_dir_all(d.join("logs/kinect-usb")).unwrap();
    std::fs::write(
        d.join("logs/kinect-usb/decode.log"),
        "decode bench: default kernels on this CPU: Avx2\ncpu probe fast/filters_on_1_thread: 7.25 ms thread CPU time per frame, 7.40 ms wall (least of 30 each)\n",
    )
    .unwrap();
    std::fs::write(
        d.join("meta.txt"),
        "mode=full\ncpu=Test CPU\ncores=2\nmemory_gib=23.4\ncommit=abc\ndirty=no\nload_start=0.31 0.50 0.70\n\
         load_end=1.00 0.90 0.80\nidle_threshold=0.5\nwaited_s=45\nidle_reached=yes\nbench.kinect-usb/decode=ok\n\
         peer.register_peers=failed: exit 1 (log: x)\n",
    )
    .unwrap();
    let out = d.join("results.json");
    let args: Vec<std::ffi::OsString> = vec![
        "collect".into(),
        "--meta".into(),
        d.join("meta.txt").into(),
        "--criterion".into(),
        d.join("criterion").into(),
        "--log".into(),
        d.join("logs").into(),
        "--peer".into(),
        format!("register_peers={}", d.join("missing.json").display()).into(),
        "--recorded".into(),
        root().join("benches/results/libfreenect2-recorded.json").into(),
        "--out".into(),
        out.clone().into(),
    ];
    let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    let Some(run) = render_tables(test, &args) else { return };
    assert!(run.status.success(), "collect failed: {}", String::from_utf8_lossy(&run.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let dec = &r["benches"]["kinect-usb/decode"];
    let fast = &dec["results"]["decode_frame/fast/filters_on_1_thread"];
    assert_eq!(
        (fast["median_ns"].as_f64(), fast["low_ns"].as_f64(), fast["high_ns"].as_f64()),
        (Some(7.4e6), Some(7.1e6), Some(7.9e6))
    );
    assert_eq!(dec["decoder_kernels"], "Avx2");
    assert_eq!(dec["cpu_probe_ms"]["fast/filters_on_1_thread"].as_f64(), Some(7.25));
    assert_eq!(r["load"]["start"].as_array().unwrap().len(), 3);
    assert_eq!(r["load"]["start"][0].as_f64(), Some(0.31));
    assert_eq!(r["load"]["idle_reached"], true);
    assert_eq!(r["peers"]["register_peers"]["status"], "failed: exit 1 (log: x)");
    let lf2 = &r["peers"]["libfreenect2"];
    assert_eq!(lf2["status"], "recorded");
    assert_eq!(
        lf2["results"]["CpuDepthPacketProcessor, filters on, 1 thread, g++ -O2"]["median_ms"]
            .as_f64(),
        Some(72.5)
    );
    assert!(lf2["source"].as_str().unwrap().contains("fd64c5d9b214df6f6a55b4419357e51083f15d93"));
}

/// `collect` + `render` of the steps that are not criterion benches (`detect_stages`,
/// `sequence_e2e`, the viewer's frame-time test) and of the sequence bench's PNG table, from the
/// logs of a fixture run folder (`tests/fixtures/bench_tables/run`, the lines those programs
/// print): every cell is the printed figure, every table names the step's time and load.
#[test]
fn steps_tables_show_the_printed_figures_and_when_each_step_ran() {
    let test = "steps_tables_show_the_printed_figures_and_when_each_step_ran";
    let dir = tempfile::tempdir().unwrap();
    let run = fixture("run");
    let results = dir.path().join("results.json");
    let Some(doc) =
        collect_and_render(test, &run.join("meta.txt"), &run.join("logs"), &results, dir.path())
    else {
        return;
    };
    // detect_stages: one row per image class, the printed ms (two decimals) in the stage columns.
    assert_eq!(
        row(&doc, "gopro-wide-1280x960-8x6 (GOPR*)")[1..],
        ["36", "33", "4.00", "0.32", "0.44", "0.11", "0.03", "42.00", "48.20"]
    );
    assert_eq!(row(&doc, "rendered IR 512x424 (bench image)")[9], "2.41");
    assert!(doc.contains(
        "the median over 5 runs of every image, ms per image. This step ran at 03:10:05 UTC, \
         load (1/5/15 min) 1.02/0.80/0.70 at its start. Run 2026-12-02 03:00 → 03:14 UTC"
    ));
    // sequence_e2e: frames (missing), both frames/s, five stages, output size, load before.
    assert_eq!(
        row(&doc, "kfuse | 2 ")[2..],
        [
            "300 (0)",
            "48.4",
            "40.5",
            "1.90",
            "10.99",
            "7.69",
            "3.84",
            "1.40",
            "181 MB",
            "1.05/0.71/0.81"
        ]
    );
    assert_eq!(row(&doc, "tum | 1 ")[2..4], ["298 (2)", "38.3"]);
    assert!(doc.contains("a 300-frame simulated recording of 950 MB"));
    assert!(!doc.contains("stale"));
    // The sequence bench's stages and PNG encodings (criterion medians, sizes from its log).
    assert_eq!(row(&doc, "`stage/decode`")[1..], ["10.4 ms", "10.2 ms – 11.2 ms"]);
    assert_eq!(row(&doc, "`stage/write`")[1], "no result");
    assert_eq!(row(&doc, "fastest | none")[2..], ["0.63 MB", "2.60 ms", "2.50 ms – 2.90 ms"]);
    assert_eq!(row(&doc, "balanced | none")[2..], ["0.35 MB", "73.7 ms", "68.6 ms – 86.0 ms"]);
    assert_eq!(row(&doc, "fast | up")[2..4], ["—", "no result"]);
    // The viewer: adapter (with its parentheses), viewport, counts, ms per frame, upload, coverage.
    assert_eq!(
        row(&doc, "llvmpipe (LLVM 15.0.6, 256 bits)")[1..],
        ["1280×720", "368538", "186819", "100.25", "42.0 ms", "87.3 % of the view"]
    );
    // The run's header lists every step.
    assert!(doc.contains("* step `sequence_e2e`: ok; frames recorded: 300; started 03:11:40 UTC"));
}

/// A step that failed, was skipped, or printed no figures renders one "Not measured" line saying
/// why, never a table of stale or invented figures.
#[test]
fn a_step_without_figures_says_why() {
    let test = "a_step_without_figures_says_why";
    let dir = tempfile::tempdir().unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    let meta = std::fs::read_to_string(fixture("run/meta.txt"))
        .unwrap()
        .replace("step.detect_stages=ok", "step.detect_stages=skipped: no shared data at /nowhere");
    std::fs::write(dir.path().join("meta.txt"), meta).unwrap();
    // The sequence printed only its recording line; the viewer test found no adapter.
    std::fs::write(logs.join("step-sequence_e2e.log"), "recording: 300 frames, 950 MB\n").unwrap();
    std::fs::write(
        logs.join("step-viewer_frame_time.log"),
        "SKIP frame_time_kinect_textured_mesh: no wgpu adapter\ntest frame_time_kinect_textured_mesh ... ok\n",
    )
    .unwrap();
    let results = dir.path().join("results.json");
    let Some(doc) =
        collect_and_render(test, &dir.path().join("meta.txt"), &logs, &results, dir.path())
    else {
        return;
    };
    for says in [
        "Not measured: skipped: no shared data at /nowhere. This step ran at 03:10:05 UTC",
        "Not measured: failed: printed no figures. This step ran at 03:11:40 UTC",
        "Not measured: skipped: no wgpu adapter. This step ran at 03:13:20 UTC",
    ] {
        assert!(doc.contains(says), "no '{says}' in:\n{doc}");
    }
    assert!(!doc.contains("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&results).unwrap()).unwrap();
    assert_eq!(r["steps"]["viewer_frame_time"]["status"], "skipped: no wgpu adapter");
    assert_eq!(r["steps"]["sequence_e2e"]["recording_mb"].as_u64(), Some(950));
}

/// `collect --meta META --criterion run/criterion --log LOGS --out RESULTS`, then `render` of
/// `doc-steps.md` into DIR; the rendered text, or `None` where python3 is missing.
fn collect_and_render(
    test: &str,
    meta: &Path,
    logs: &Path,
    results: &Path,
    dir: &Path,
) -> Option<String> {
    let criterion = fixture("run/criterion");
    let args: Vec<&std::ffi::OsStr> = vec![
        "collect".as_ref(),
        "--meta".as_ref(),
        meta.as_os_str(),
        "--criterion".as_ref(),
        criterion.as_os_str(),
        "--log".as_ref(),
        logs.as_os_str(),
        "--out".as_ref(),
        results.as_os_str(),
    ];
    let run = render_tables(test, &args)?;
    assert!(run.status.success(), "collect failed: {}", String::from_utf8_lossy(&run.stderr));
    let out = dir.join("doc.md");
    let run = render(test, results, &fixture("doc-steps.md"), &out)?;
    assert!(run.status.success(), "render failed: {}", String::from_utf8_lossy(&run.stderr));
    Some(std::fs::read_to_string(out).unwrap())
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
