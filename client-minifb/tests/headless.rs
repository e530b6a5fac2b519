//! End to end: the real binary against its in-process server over TCP, headless; record and
//! replay.

mod common;

use common::*;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(120);

fn differing_pixels(a: &[u8], b: &[u8]) -> usize {
    a.chunks(4).zip(b.chunks(4)).filter(|(p, q)| p != q).count()
}

#[test]
fn headless_orbit_writes_frames_that_differ_and_replay_reproduces_them() {
    let dir = scratch("headless");
    let live = dir.join("live");
    let rec = dir.join("stream.vwrec");
    let out = run(
        &[
            "--headless",
            "--frames",
            "8",
            "--fps",
            "12",
            "--orbit",
            "50",
            "--size",
            "160x120",
            "--threads",
            "1",
            "--out",
            live.to_str().unwrap(),
            "--record",
            rec.to_str().unwrap(),
        ],
        LIMIT,
    );
    assert!(out.status.success(), "stderr:\n{}", String::from_utf8_lossy(&out.stderr));

    // Non-empty PNGs of the right size, showing the volume, differing as the camera orbits.
    let files = pngs(&live);
    assert_eq!(files.len(), 8);
    let bg = volwarp_core::BACKGROUND.to_le_bytes();
    let frames: Vec<Vec<u8>> = files
        .iter()
        .map(|f| {
            let (w, h, px) = load_png(f);
            assert_eq!((w, h), (160, 120));
            let volume = px.chunks(4).filter(|p| *p != bg).count();
            assert!(volume > 160 * 120 / 20, "{}: only {volume} pixels differ from the background", f.display());
            px
        })
        .collect();
    for w in frames.windows(2) {
        assert!(differing_pixels(&w[0], &w[1]) > 50, "consecutive frames of the orbit should differ");
    }
    assert!(differing_pixels(&frames[0], &frames[7]) > 160 * 120 / 10);

    // timings.csv: a header and one line per frame with the documented columns.
    let csv = std::fs::read_to_string(live.join("timings.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(lines[0].starts_with("frame,display_ms,frame_age_ms,samples,renderer"));
    assert_eq!(lines.len(), 9);
    for (i, l) in lines[1..].iter().enumerate() {
        let cols: Vec<&str> = l.split(',').collect();
        assert_eq!(cols[0], i.to_string());
        assert!(cols[1].parse::<f64>().unwrap() >= 0.0);
        assert!(cols[2].parse::<f64>().unwrap() >= 0.0, "frame age known: {l}");
        assert!(cols[3].parse::<usize>().unwrap() > 0);
        assert_eq!(cols[4], volwarp_core::RendererKind::DEFAULT.name());
    }
    // Paced at 12 FPS the display swaps in newer frames as they arrive (replay must follow).
    let seqs: std::collections::BTreeSet<&str> = lines[1..].iter().map(|l| l.split(',').nth(6).unwrap()).collect();
    assert!(seqs.len() >= 2, "all display frames showed the same server frame: {seqs:?}");

    // Replay through the same renderer: the very same images.
    let again = dir.join("replay");
    let out = run(
        &["--headless", "--replay", rec.to_str().unwrap(), "--out", again.to_str().unwrap(), "--threads", "1"],
        LIMIT,
    );
    assert!(out.status.success(), "stderr:\n{}", String::from_utf8_lossy(&out.stderr));
    let replayed = pngs(&again);
    assert_eq!(replayed.len(), 8);
    for (i, f) in replayed.iter().enumerate() {
        let (_, _, px) = load_png(f);
        assert!(
            px == frames[i],
            "replayed frame {i} differs from the live one in {} pixels",
            differing_pixels(&px, &frames[i])
        );
    }

    // Replay through another renderer works too (and draws points, not spheres).
    let pts = dir.join("points");
    let out = run(
        &["--headless", "--replay", rec.to_str().unwrap(), "--out", pts.to_str().unwrap(), "--renderer", "points1"],
        LIMIT,
    );
    assert!(out.status.success(), "stderr:\n{}", String::from_utf8_lossy(&out.stderr));
    let pf = pngs(&pts);
    assert_eq!(pf.len(), 8);
    let (_, _, p7) = load_png(&pf[7]);
    assert!(differing_pixels(&p7, &frames[7]) > 0);
    let csv = std::fs::read_to_string(pts.join("timings.csv")).unwrap();
    assert!(csv.lines().nth(1).unwrap().contains(",points1,"));
}

#[test]
fn bad_record_files_are_clear_errors() {
    let dir = scratch("badrec");
    let f = dir.join("not-a-record");
    std::fs::write(&f, b"hello, this is not a record").unwrap();
    let out = run(&["--headless", "--replay", f.to_str().unwrap(), "--out", dir.to_str().unwrap()], LIMIT);
    assert_eq!(out.status.code(), Some(1));
    assert!(error_line(&out).contains("not a volwarp record file"), "{}", error_line(&out));
    let out = run(&["--headless", "--replay", dir.join("missing").to_str().unwrap(), "--out", "x"], LIMIT);
    assert_eq!(out.status.code(), Some(1));
    assert!(error_line(&out).contains("cannot open"), "{}", error_line(&out));
    // Truncated inside an entry.
    let mut bytes = volwarp_core::record::RECORD_MAGIC.to_vec();
    bytes.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, b'V', b'W']);
    std::fs::write(&f, bytes).unwrap();
    let out = run(&["--headless", "--replay", f.to_str().unwrap(), "--out", dir.to_str().unwrap()], LIMIT);
    assert_eq!(out.status.code(), Some(1));
    assert!(error_line(&out).contains("record file"), "{}", error_line(&out));
}

#[test]
fn help_lists_the_controls() {
    let out = run(&["--help"], LIMIT);
    assert!(out.status.success());
    let s = String::from_utf8_lossy(&out.stdout);
    for k in ["left drag", "right drag", "wheel", "--headless", "--record", "--replay", "--latency-ms", "spheres-gpu"] {
        assert!(s.contains(k), "--help lacks {k}");
    }
}
