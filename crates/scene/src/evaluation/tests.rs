//! Tests of the evaluation module: JSON Lines reading and writing, error messages, TRE and
//! percentiles checked against hand computations.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::*;

/// A temporary directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("livereg-eval-{}-{n}-{tag}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn write(&self, name: &str, data: &str) -> PathBuf {
        let path = self.path(name);
        std::fs::write(&path, data).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn structures(list: &[(&str, Vec<[f64; 3]>)]) -> BTreeMap<String, Vec<[f64; 3]>> {
    list.iter()
        .map(|(k, v)| (k.to_string(), v.clone()))
        .collect()
}

fn result(
    frame: usize,
    converged: bool,
    error: Option<&str>,
    list: &[(&str, Vec<[f64; 3]>)],
) -> ResultRecord {
    ResultRecord {
        frame,
        source: format!("pc{frame:02}.txt"),
        wall_ms: 12.5,
        converged,
        rigid: RigidRecord {
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0, 0.0, 0.0],
            uncertainty: None,
        },
        diagnostics: DiagnosticsRecord {
            error: error.map(str::to_string),
            ..DiagnosticsRecord::default()
        },
        structures: structures(list),
        contact_force: None,
        expected_error: None,
    }
}

fn truth(frame: usize, list: &[(&str, Vec<[f64; 3]>)]) -> TruthRecord {
    TruthRecord {
        frame,
        structures: structures(list),
    }
}

fn close(a: f64, b: f64) {
    assert!((a - b).abs() <= 1e-12, "{a} != {b}");
}

fn close_summary(s: &Summary, count: usize, mean: f64, median: f64, p95: f64, max: f64) {
    assert_eq!(s.count, count);
    close(s.mean, mean);
    close(s.median, median);
    close(s.p95, p95);
    close(s.max, max);
}

/// Two frames of results (given in reverse order), three frames of truth.
///
/// Hand computation of the distances (offsets chosen as Pythagorean triples, coordinates all
/// different so that mixing up components changes the result):
/// - frame 0, `a`: (3,4,0) → 5, (0,6,8) → 10; `b`: 0, (1,2,2) → 3.
/// - frame 1, `a`: (0,0,2) → 2, (12,5,0) → 13; `b`: 0, (−2,−3,−6) → 7.
fn fixture() -> (Vec<ResultRecord>, Vec<TruthRecord>) {
    let results = vec![
        result(
            1,
            false,
            None,
            &[
                ("a", vec![[1.0, 2.0, 5.0], [16.0, 10.0, 6.0]]),
                ("b", vec![[7.0, 8.0, 9.0], [-2.0, -2.0, -4.0]]),
            ],
        ),
        result(
            0,
            true,
            None,
            &[
                ("a", vec![[3.0, 4.0, 0.0], [1.0, 8.0, 11.0]]),
                ("b", vec![[10.0, -20.0, 30.0], [1.0, 2.0, 2.0]]),
                ("c", vec![[100.0, 0.0, 0.0]]), // not in the truth: ignored
            ],
        ),
    ];
    let truths = vec![
        truth(
            0,
            &[
                ("a", vec![[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]),
                ("b", vec![[10.0, -20.0, 30.0], [0.0, 0.0, 0.0]]),
            ],
        ),
        truth(
            1,
            &[
                ("a", vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]),
                ("b", vec![[7.0, 8.0, 9.0], [0.0, 1.0, 2.0]]),
            ],
        ),
        truth(2, &[("a", vec![[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])]),
    ];
    (results, truths)
}

#[test]
fn tre_matches_hand_computation() {
    let (results, truths) = fixture();
    let r = evaluate(&results, &truths).unwrap();

    assert_eq!(r.frames.len(), 2);
    let f0 = &r.frames[0];
    assert_eq!((f0.frame, f0.source.as_str()), (0, "pc00.txt"));
    assert!(f0.converged && !f0.failed && f0.error.is_none());
    assert_eq!(f0.structures.keys().collect::<Vec<_>>(), ["a", "b"]);
    assert_eq!(
        f0.structures["a"],
        StructureFrameTre {
            mean: 7.5,
            max: 10.0,
            points: 2
        }
    );
    assert_eq!(
        f0.structures["b"],
        StructureFrameTre {
            mean: 1.5,
            max: 3.0,
            points: 2
        }
    );
    // (5 + 10 + 0 + 3) / 4
    close(f0.mean, 4.5);
    assert_eq!((f0.max, f0.points), (10.0, 4));

    let f1 = &r.frames[1];
    assert_eq!(f1.frame, 1);
    assert!(!f1.converged && f1.failed);
    close(f1.structures["a"].mean, 7.5); // (2 + 13) / 2
    close(f1.structures["a"].max, 13.0);
    close(f1.structures["b"].mean, 3.5); // (0 + 7) / 2
    close(f1.structures["b"].max, 7.0);
    close(f1.mean, 5.5); // (2 + 13 + 0 + 7) / 4
    assert_eq!((f1.max, f1.points), (13.0, 4));

    // a: sorted [2, 5, 10, 13]; h = 3·0.5 = 1.5 → 5 + 0.5·5 = 7.5; h = 3·0.95 = 2.85 →
    // 10 + 0.85·3 = 12.55.
    close_summary(&r.structures["a"], 4, 7.5, 7.5, 12.55, 13.0);
    // b: sorted [0, 0, 3, 7]; median 0 + 0.5·3 = 1.5; p95 3 + 0.85·4 = 6.4.
    close_summary(&r.structures["b"], 4, 2.5, 1.5, 6.4, 7.0);
    assert_eq!(r.structures.len(), 2);
    // all: sorted [0, 0, 2, 3, 5, 7, 10, 13], sum 40; h = 7·0.5 = 3.5 → 3 + 0.5·2 = 4;
    // h = 7·0.95 = 6.65 → 10 + 0.65·3 = 11.95.
    close_summary(&r.overall, 8, 5.0, 4.0, 11.95, 13.0);

    assert_eq!(r.missing_frames, [2]);
    assert_eq!(r.failed_frames, [1]);
}

#[test]
fn frames_with_an_error_are_failed_but_evaluated() {
    let results = vec![result(
        0,
        true,
        Some("Newton diverged"),
        &[("a", vec![[4.0, 2.0, 7.0]])],
    )];
    let truths = vec![truth(0, &[("a", vec![[1.0, 2.0, 3.0]])])];
    let r = evaluate(&results, &truths).unwrap();
    assert_eq!(r.failed_frames, [0]);
    assert!(r.frames[0].failed);
    assert_eq!(r.frames[0].error.as_deref(), Some("Newton diverged"));
    assert_eq!(r.overall.mean, 5.0);
    assert!(r.missing_frames.is_empty());
}

#[test]
fn percentiles_by_linear_interpolation() {
    // NumPy: np.percentile([3, 1, 4, 1, 5, 9, 2, 6], [0, 25, 50, 95, 100])
    //      = [1, 1.75, 3.5, 7.95, 9].
    let mut v = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0];
    v.sort_by(f64::total_cmp);
    close(percentile(&v, 0.0), 1.0);
    close(percentile(&v, 0.25), 1.75); // h = 1.75: 1 + 0.75·(2 − 1)
    close(percentile(&v, 0.5), 3.5); // h = 3.5: 3 + 0.5·(4 − 3)
    close(percentile(&v, 0.95), 7.95); // h = 6.65: 6 + 0.65·(9 − 6)
    close(percentile(&v, 1.0), 9.0);
    assert_eq!(percentile(&[4.0], 0.95), 4.0);
    // Odd count: the median is the middle value.
    assert_eq!(percentile(&[1.0, 2.0, 10.0], 0.5), 2.0);

    let s = Summary::of(&[3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0]).unwrap();
    close_summary(&s, 8, 31.0 / 8.0, 3.5, 7.95, 9.0);
    assert!(Summary::of(&[]).is_none());
}

#[test]
fn report_serialises_and_prints() {
    let (results, truths) = fixture();
    let r = evaluate(&results, &truths).unwrap();
    let json = serde_json::to_value(&r).unwrap();
    assert_eq!(json["overall"]["count"], 8);
    assert_eq!(json["overall"]["max"], 13.0);
    assert_eq!(json["structures"]["a"]["median"], 7.5);
    assert_eq!(json["frames"][1]["failed"], true);
    assert_eq!(json["frames"][1]["structures"]["b"]["points"], 2);
    assert!(json["frames"][0].get("error").is_none());
    assert_eq!(json["missing_frames"], serde_json::json!([2]));
    assert_eq!(json["failed_frames"], serde_json::json!([1]));

    let expected = "\
TRE in scene units over 2 frame(s); 1 failed (not converged or with an error): 1
1 truth frame(s) without a result: 2
structure    points        mean      median         p95         max
a                 4       7.500       7.500       12.55       13.00
b                 4       2.500       1.500       6.400       7.000
all               8       5.000       4.000       11.95       13.00
worst frame: 1 (pc01.txt): mean 5.500, max 13.00
";
    assert_eq!(r.to_table(), expected);
}

#[test]
fn evaluation_errors_name_frame_and_structure() {
    let (results, truths) = fixture();

    let mut extra = results.clone();
    extra.push(result(5, true, None, &[("a", vec![[0.0; 3]; 2])]));
    assert_eq!(
        evaluate(&extra, &truths).unwrap_err().to_string(),
        "result frame 5 has no truth frame"
    );

    let mut wrong = results.clone();
    wrong[1]
        .structures
        .get_mut("a")
        .unwrap()
        .push([0.0, 0.0, 0.0]);
    assert_eq!(
        evaluate(&wrong, &truths).unwrap_err().to_string(),
        "frame 0: structure `a` has 3 points in the result but 2 in the truth"
    );

    let mut missing = results.clone();
    missing[0].structures.remove("b");
    assert_eq!(
        evaluate(&missing, &truths).unwrap_err().to_string(),
        "frame 1: structure `b` is in the truth but not in the result"
    );

    let mut dup = results.clone();
    dup.push(results[0].clone());
    assert_eq!(
        evaluate(&dup, &truths).unwrap_err().to_string(),
        "result frame 1 appears more than once"
    );
    let mut dup_truth = truths.clone();
    dup_truth.push(truths[2].clone());
    assert_eq!(
        evaluate(&results, &dup_truth).unwrap_err().to_string(),
        "truth frame 2 appears more than once"
    );

    let mut empty = truths.clone();
    empty[0].structures.get_mut("b").unwrap().clear();
    assert_eq!(
        evaluate(&results, &empty).unwrap_err().to_string(),
        "frame 0: structure `b` has no points in the truth"
    );
    let mut bare = truths.clone();
    bare[1].structures.clear();
    assert_eq!(
        evaluate(&results, &bare).unwrap_err().to_string(),
        "truth frame 1 has no structures"
    );

    assert_eq!(
        evaluate(&[], &truths).unwrap_err().to_string(),
        "no result frames to evaluate"
    );
}

#[test]
fn jsonl_round_trip() {
    let dir = TempDir::new("round-trip");
    let path = dir.path("results.jsonl");
    let (mut results, truths) = fixture();
    // Every optional diagnostic filled in, and awkward numbers.
    let d = &mut results[0].diagnostics;
    d.icp_iterations = 6;
    d.newton_iterations = 14;
    d.surface_rms = 0.0011;
    d.rigid_iterations = 3;
    d.cloud_points = 5000;
    d.sources = 812;
    d.timings_ms.insert("rigid".into(), 1.25);
    d.timings_ms.insert("non_rigid".into(), 20.125);
    d.flags.push("icp_not_converged".into());
    d.error = Some("line search failed".into());
    d.warnings.push("bisection limit".into());
    results[1].rigid.translation = [0.1, -1e-300, 1.0 / 3.0];
    results[1].structures.get_mut("a").unwrap()[0] = [f64::MAX, -0.0, 5e-324];

    let mut w = JsonlWriter::create(&path).unwrap();
    assert_eq!(w.path(), path);
    for r in &results {
        w.write(r).unwrap();
    }
    // Every line is on disk before the writer is dropped.
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(text.lines().count(), 2);
    assert!(text.ends_with('\n'));
    assert_eq!(read_results(&path).unwrap(), results);
    drop(w);

    // A results file is also a valid truth file (extra fields ignored).
    let as_truth = read_truth(&path).unwrap();
    assert_eq!(as_truth.len(), 2);
    assert_eq!(as_truth[0].frame, 1);
    assert_eq!(as_truth[1].structures, results[1].structures);

    let tpath = dir.path("truth.jsonl");
    let mut w = JsonlWriter::create(&tpath).unwrap();
    for t in &truths {
        w.write(t).unwrap();
    }
    drop(w);
    assert_eq!(read_truth(&tpath).unwrap(), truths);
}

#[test]
fn blank_lines_are_skipped() {
    let dir = TempDir::new("blank");
    let path = dir.write(
        "truth.jsonl",
        "\n{\"frame\": 0, \"structures\": {\"a\": [[1, 2, 3]]}, \"note\": \"x\"}\n  \r\n\
         {\"frame\": 1, \"structures\": {}}\r\n\n",
    );
    let t = read_truth(&path).unwrap();
    assert_eq!(
        t,
        [truth(0, &[("a", vec![[1.0, 2.0, 3.0]])]), truth(1, &[])]
    );
    let empty = dir.write("empty.jsonl", "");
    assert!(read_results(&empty).unwrap().is_empty());
}

#[test]
fn read_errors_name_file_and_line() {
    let dir = TempDir::new("errors");
    let good = r#"{"frame": 0, "structures": {"a": [[1, 2, 3]]}}"#;

    let path = dir.write("truth.jsonl", &format!("{good}\n\n{{\"frame\": 2}}\n"));
    assert_eq!(
        read_truth(&path).unwrap_err().to_string(),
        format!("{}:3: missing field `structures`", path.display())
    );

    let path = dir.write(
        "broken.jsonl",
        &format!("{good}\n{{\"frame\": 1, \"structures\": {{\"a\": [[1, 2\n"),
    );
    assert_eq!(
        read_truth(&path).unwrap_err().to_string(),
        format!(
            "{}:2: EOF while parsing a list at column 39",
            path.display()
        )
    );

    let path = dir.write("junk.jsonl", &format!("{good}\n{good} x\n"));
    assert_eq!(
        read_truth(&path).unwrap_err().to_string(),
        format!("{}:2: trailing characters at column 48", path.display())
    );

    let path = dir.write(
        "null.jsonl",
        r#"{"frame": 0, "structures": {"a": [[1, null, 3]]}}"#,
    );
    let err = read_truth(&path).unwrap_err();
    assert!(matches!(err, EvalError::Parse { line: 1, .. }));
    assert_eq!(
        err.to_string(),
        format!(
            "{}:1: invalid type: null, expected f64 at column 42 (JSON has no NaN or infinity; \
             a writer puts null in their place, so this value was probably not finite)",
            path.display()
        )
    );

    // A result line missing a contract field.
    let path = dir.write(
        "results.jsonl",
        r#"{"frame": 0, "source": "x", "wall_ms": 1, "converged": true, "structures": {}}"#,
    );
    assert_eq!(
        read_results(&path).unwrap_err().to_string(),
        format!("{}:1: missing field `rigid`", path.display())
    );

    let absent = dir.path("absent.jsonl");
    let err = read_results(&absent).unwrap_err();
    assert!(matches!(err, EvalError::Io { .. }));
    assert!(err
        .to_string()
        .starts_with(&format!("{}: ", absent.display())));

    let err = JsonlWriter::create(dir.path("no-such-dir/out.jsonl")).unwrap_err();
    assert!(matches!(err, EvalError::Io { .. }));
}

/// `contact_force` keeps its three states through JSON: absent (none estimated), `null`
/// (estimated but untrusted) and a force; an absent key is not written, a `null` one is.
#[test]
fn the_contact_force_tells_absent_from_null_from_a_force() {
    let force = ContactForceRecord {
        resultant_n: [0.5, -1.0, 2.0],
        magnitude_n: 2.291_287_847_477_92,
        centre: [1.0, 2.0, 3.0],
        expected_error_n: Some(0.75),
    };
    for (state, key) in [
        (None, None),
        (Some(None), Some("null")),
        (Some(Some(force)), Some("{")),
    ] {
        let mut r = result(0, true, None, &[("a", vec![[1.0, 2.0, 3.0]])]);
        r.contact_force = state.clone();
        let line = serde_json::to_string(&r).unwrap();
        match key {
            None => assert!(!line.contains("contact_force"), "{line}"),
            Some(start) => assert!(
                line.contains(&format!("\"contact_force\":{start}")),
                "{line}"
            ),
        }
        let back: ResultRecord = serde_json::from_str(&line).unwrap();
        assert_eq!(back.contact_force, state, "{line}");
    }
}
