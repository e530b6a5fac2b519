//! The properties the fuzz targets check, one function per target.
//!
//! This file is shared word for word by the cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`, on
//! nightly) and by their stable proptest mirrors (`core/tests/fuzz_mirror.rs` includes it with
//! `#[path]`), so a crash input found by the fuzzer replays unchanged under `cargo test`.
//! It depends only on `volwarp-core` and `embedded-io`. Every check panics (asserts) when a
//! property is violated; that panic is the finding.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::vec;
use std::vec::Vec;

use embedded_io::{ErrorKind, ErrorType, Read};
use volwarp_core::camera::Camera;
use volwarp_core::compact_frame;
use volwarp_core::heuristics::Heuristic;
use volwarp_core::sample::{Bounds, Dequantizer, RADIUS_MAX};
use volwarp_core::scene::Scene;
use volwarp_core::traversal::brute_force;
use volwarp_core::wire::{
    self, encode_to_vec, read_message, CameraRequest, Frame, FrameHeader, Limits, Message, MsgType, WireError,
    FRAME_FIXED_LEN, HEADER_LEN, MAX_ERROR_TEXT, MAX_TOKEN,
};
use volwarp_core::{Ray, Vec3};

/// The modest limits the decoding targets run under: frames up to 64 × 64 (4096 samples,
/// 49,248 bytes of payload).
pub const LIMITS: Limits = Limits::for_frames(64);

/// Slack over the payload limit that one decoded message may allocate (the message's own
/// bookkeeping; the sample arrays themselves are bounded by the payload limit).
pub const ALLOC_SLACK: usize = 4096;

/// What one `read_message` may allocate: the payload limit and [`ALLOC_SLACK`] for the 12-byte
/// messages, or the compact decoder's stated bound (a CompactFrame also holds its decompressed
/// body and zstd's window while it builds the frame); a frame sent in parts (version 6) also
/// holds its reassembled bytes and one part while it is decoded.
pub fn decode_alloc_limit(limits: &Limits) -> usize {
    let plain = limits.max_payload as usize + ALLOC_SLACK;
    let whole = plain.max(volwarp_core::compact_frame::decode_alloc_bound(limits) as usize);
    whole + HEADER_LEN + limits.max_payload as usize + wire::PART_LEN
}

// ---------------------------------------------------------------- allocation accounting

std::thread_local! {
    static LIVE: Cell<usize> = const { Cell::new(0) };
    static PEAK: Cell<usize> = const { Cell::new(0) };
}

fn note_alloc(n: usize) {
    let _ = LIVE.try_with(|l| {
        let v = l.get().saturating_add(n);
        l.set(v);
        let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
    });
}

fn note_free(n: usize) {
    let _ = LIVE.try_with(|l| l.set(l.get().saturating_sub(n)));
}

/// A global allocator that counts the bytes live on each thread (and their peak), so a check
/// can bound what one decode allocates. Install it with `#[global_allocator]`.
pub struct CountingAlloc;

// SAFETY: every method forwards to `System` unchanged; the counting touches only const-initialized
// thread-locals without destructors, which never allocate.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        // SAFETY: the caller keeps `GlobalAlloc::alloc`'s contract, which `System` takes over.
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            note_alloc(l.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        // SAFETY: the caller keeps `GlobalAlloc::alloc_zeroed`'s contract, which `System` takes over.
        let p = unsafe { System.alloc_zeroed(l) };
        if !p.is_null() {
            note_alloc(l.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` and `l` come from this allocator, i.e. from `System` (its contract).
        unsafe { System.dealloc(p, l) };
        note_free(l.size());
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        // SAFETY: `p`, `l` and `new` keep `GlobalAlloc::realloc`'s contract, which `System` takes over.
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            note_free(l.size());
            note_alloc(new);
        }
        q
    }
}

/// Runs `f` and returns its result with the peak number of bytes it had allocated on this
/// thread beyond what was live when it started (0 unless [`CountingAlloc`] is installed).
pub fn peak_alloc<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let start = LIVE.with(|l| l.get());
    PEAK.with(|p| p.set(start));
    let r = f();
    let peak = PEAK.with(|p| p.get());
    (r, peak.saturating_sub(start))
}

// ---------------------------------------------------------------- a reader with chunking and faults

/// A reader over `data` that returns at most one chunk per `read` call (chunk sizes cycle
/// through `pattern`, each byte `b` meaning `b % 32 + 1` bytes; an empty pattern returns
/// everything at once), and fails with an I/O error once it reaches byte `fail_at`.
pub struct FaultyReader<'a> {
    data: &'a [u8],
    pos: usize,
    pattern: &'a [u8],
    step: usize,
    fail_at: Option<usize>,
}

impl<'a> FaultyReader<'a> {
    /// A reader of `data` with the given chunk pattern and fault position.
    pub fn new(data: &'a [u8], pattern: &'a [u8], fail_at: Option<usize>) -> Self {
        FaultyReader { data, pos: 0, pattern, step: 0, fail_at }
    }
    /// Bytes handed out so far.
    pub fn pos(&self) -> usize {
        self.pos
    }
}

impl ErrorType for FaultyReader<'_> {
    type Error = ErrorKind;
}

impl Read for FaultyReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        if buf.is_empty() {
            return Ok(0);
        }
        let end = match self.fail_at {
            Some(f) if self.pos >= f => return Err(ErrorKind::ConnectionReset),
            Some(f) => f.min(self.data.len()),
            None => self.data.len(),
        };
        let want = if self.pattern.is_empty() {
            usize::MAX
        } else {
            let b = self.pattern[self.step % self.pattern.len()];
            self.step += 1;
            b as usize % 32 + 1
        };
        let n = want.min(buf.len()).min(end - self.pos);
        buf[..n].copy_from_slice(&self.data[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

/// Decodes messages from `r` until the first error; checks every decoded message and bounds
/// what each decode allocates. Returns the messages and the final error.
fn decode_all<R: Read>(r: &mut R, limits: &Limits) -> (Vec<Message>, WireError) {
    let mut out = Vec::new();
    loop {
        let (res, peak) = peak_alloc(|| read_message(r, limits));
        assert!(
            peak <= decode_alloc_limit(limits),
            "one decode allocated {peak} bytes, over the payload limit {} + slack (or a CompactFrame's bound)",
            limits.max_payload
        );
        match res {
            Ok(m) => {
                check_message(&m, limits);
                out.push(m);
            }
            Err(e) => return (out, e),
        }
    }
}

// ---------------------------------------------------------------- invariants of decoded messages

/// Checks what every accepted message guarantees.
pub fn check_message(m: &Message, limits: &Limits) {
    match m {
        Message::Hello(h) => assert!(h.token.len() <= MAX_TOKEN),
        Message::CameraRequest(r) => {
            check_camera(&r.camera, limits);
            assert!(r.radius_scale > 0.0 && r.radius_scale <= 16.0, "radius scale {}", r.radius_scale);
            assert!(usize::from(r.layers) <= wire::MAX_LAYERS, "layers wanted {}", r.layers);
        }
        Message::Frame(f) => check_frame(&f.header, &f.samples, &f.colors, limits),
        Message::Error(e) => assert!(e.text.len() <= MAX_ERROR_TEXT),
        Message::Bye => {}
        Message::VisualEdit(_) | Message::VisualState(_) => {
            assert!(visual_valid(m), "an accepted visual message holds a non-finite number or an empty name: {m:?}")
        }
    }
}

/// Whether a VisualEdit or VisualState is one the decoder accepts: every float it uses finite,
/// every name it sends non-empty (the codec's own bounds hold by the types).
pub fn visual_valid(m: &Message) -> bool {
    let fin = |v: &[f32]| v.iter().all(|x| x.is_finite());
    match m {
        Message::VisualEdit(e) => {
            e.window_level.is_none_or(|v| fin(&v))
                && e.opacity_scale.is_none_or(|v| v.is_finite())
                && e.crop.is_none_or(|v| fin(&v))
                && e.clip.is_none_or(|c| c.is_none_or(|v| fin(&v)))
                && e.preset.as_ref().is_none_or(|n| !n.is_empty())
                && e.transfer_function
                    .as_ref()
                    .is_none_or(|t| t.color.iter().all(|p| fin(p)) && t.opacity.iter().all(|p| fin(p)))
        }
        Message::VisualState(s) => {
            fin(&s.window_level)
                && s.opacity_scale.is_finite()
                && fin(&s.crop)
                && s.clip.is_none_or(|v| fin(&v))
                && s.presets.iter().all(|n| !n.is_empty())
        }
        _ => true,
    }
}

fn check_camera(c: &Camera, limits: &Limits) {
    assert_eq!(c.validate(limits.max_viewport), Ok(()), "accepted camera fails validation: {c:?}");
    let basis = c.ray_basis();
    for (x, y) in
        [(0, 0), (c.width - 1, 0), (0, c.height - 1), (c.width - 1, c.height - 1), (c.width / 2, c.height / 2)]
    {
        let d = basis.dir(x, y);
        assert!(d.is_finite(), "ray ({x}, {y}) of an accepted camera is not finite: {d:?} ({c:?})");
    }
}

/// Checks an accepted frame: count consistent with the buffers, limits and viewport; camera,
/// bounds and radius unit valid; every decoded sample center and radius finite.
pub fn check_frame(h: &FrameHeader, samples: &[u64], colors: &[u32], limits: &Limits) {
    assert_eq!(samples.len(), h.count as usize);
    assert_eq!(colors.len(), h.count as usize);
    assert!(h.count <= limits.max_samples, "count {} over the limit", h.count);
    assert!(h.count as u64 <= h.camera.width as u64 * h.camera.height as u64, "more samples than pixels");
    check_camera(&h.camera, limits);
    assert!(h.bounds.is_valid(), "accepted bounds are invalid: {:?}", h.bounds);
    assert!(h.radius_unit > 0.0 && (h.radius_unit * RADIUS_MAX as f32).is_finite(), "radius unit {}", h.radius_unit);
    let deq = h.dequantizer();
    for &s in samples {
        let c = deq.center(s);
        assert!(c.is_finite(), "sample {s:#x} decodes to a non-finite center {c:?} (bounds {:?})", h.bounds);
        let r = deq.radius(s);
        assert!(r.is_finite() && r >= 0.0, "sample {s:#x} decodes to radius {r}");
    }
}

// ---------------------------------------------------------------- target 1: wire_decode_chunked

/// Splits a fuzz input into (chunk pattern, fault position, stream): byte 0 gives the pattern
/// length (`% 8`), then the pattern, then a little-endian `u16` fault position (`0xffff`: none).
pub fn split_chunked_input(data: &[u8]) -> (&[u8], Option<usize>, &[u8]) {
    let Some((&n, rest)) = data.split_first() else { return (&[], None, &[]) };
    let n = (n as usize % 8).min(rest.len());
    let (pattern, rest) = rest.split_at(n);
    if rest.len() < 2 {
        return (pattern, None, &[]);
    }
    let f = u16::from_le_bytes([rest[0], rest[1]]);
    (pattern, if f == u16::MAX { None } else { Some(f as usize) }, &rest[2..])
}

/// Target `wire_decode_chunked`: decodes the stream of messages in the input through a reader
/// that returns arbitrary chunks (and may fail at an arbitrary byte), with [`LIMITS`]. No panic,
/// every decode allocates at most the payload limit, every accepted message is valid, and the
/// result (messages and final error) is exactly the one of reading the same bytes in one piece.
pub fn wire_decode_chunked(data: &[u8]) {
    let (pattern, fail_at, stream) = split_chunked_input(data);
    let mut r = FaultyReader::new(stream, pattern, fail_at);
    let chunked = decode_all(&mut r, &LIMITS);
    let whole = decode_all(&mut FaultyReader::new(stream, &[], fail_at), &LIMITS);
    assert_eq!(chunked, whole, "the chunking changed the decoded result");
    // `Closed` means a clean end between messages, after the last byte.
    if chunked.1 == WireError::Closed {
        assert_eq!(r.pos(), stream.len(), "Closed before the end of the stream");
    }
}

// ---------------------------------------------------------------- target 2: frame_decode

/// Target `frame_decode`: the allocation-free Frame path (`read_header`, `read_frame_header`,
/// `read_frame_body` into caller buffers). Accepted frames satisfy [`check_frame`]; too-small
/// buffers are refused with `BufferTooSmall`; the result equals `read_message`'s.
pub fn frame_decode(data: &[u8]) {
    let mut r = data;
    let Ok(h) = wire::read_header(&mut r, &LIMITS) else { return };
    assert!(h.len <= LIMITS.max_payload);
    if h.ty != MsgType::Frame {
        return;
    }
    let fh = match wire::read_frame_header(&mut r, &h, &LIMITS) {
        Ok(fh) => fh,
        // A layered frame (version 3): only `read_message` reads it (the `frame_decode` of
        // layered frames is `read_message` itself, checked by the other targets).
        Err(WireError::Layers(volwarp_core::segments::LayerError::Layered)) => return,
        Err(_) => {
            assert!(read_message(&mut &data[..], &LIMITS).is_err(), "read_message accepts what the frame path refused");
            return;
        }
    };
    assert_eq!(h.len as usize, FRAME_FIXED_LEN + fh.count as usize * 12, "count inconsistent with the length");
    let n = fh.count as usize;
    if n > 0 {
        let mut s = vec![0u64; n - 1];
        let mut c = vec![0u32; n];
        assert_eq!(wire::read_frame_body(&mut &r[..], &fh, &mut s, &mut c), Err(WireError::BufferTooSmall));
    }
    // Oversized buffers: only the first `count` entries are written.
    let mut samples = vec![u64::MAX; n + 1];
    let mut colors = vec![u32::MAX; n + 1];
    let body = wire::read_frame_body(&mut r, &fh, &mut samples, &mut colors);
    assert_eq!(samples[n], u64::MAX);
    assert_eq!(colors[n], u32::MAX);
    let whole = read_message(&mut &data[..], &LIMITS);
    match body {
        Ok(()) => {
            check_frame(&fh, &samples[..n], &colors[..n], &LIMITS);
            let f = Frame {
                header: fh,
                samples: samples[..n].to_vec(),
                colors: colors[..n].to_vec(),
                segments: Vec::new(),
            };
            assert_eq!(whole, Ok(Message::Frame(f)));
        }
        Err(e) => {
            assert_eq!(e, WireError::UnexpectedEof, "a slice reader can only run out");
            assert_eq!(whole, Err(e));
        }
    }
}

// ---------------------------------------------------------------- target 3: roundtrip

/// Target `roundtrip` (bytes half): every message decoded from the input re-encodes to bytes
/// that decode to an equal message, and re-encoding is a fixed point.
pub fn roundtrip_bytes(data: &[u8]) {
    let (msgs, _) = decode_all(&mut &data[..], &LIMITS);
    for m in &msgs {
        let bytes = encode_to_vec(m);
        let back = read_message(&mut &bytes[..], &LIMITS).expect("a re-encoded message decodes");
        assert_eq!(&back, m);
        assert_eq!(encode_to_vec(&back), bytes, "encoding is not a fixed point");
    }
}

/// Whether `m`, encoded, is a message the decoder must accept under `limits` (the spec of the
/// wire format, written independently of the decoder).
pub fn expected_valid(m: &Message, limits: &Limits) -> bool {
    let cam_ok = |c: &Camera| c.validate(limits.max_viewport).is_ok();
    match m {
        Message::Hello(_) | Message::Error(_) | Message::Bye => true,
        Message::VisualEdit(_) | Message::VisualState(_) => visual_valid(m),
        Message::CameraRequest(r) => {
            cam_ok(&r.camera)
                && r.radius_scale > 0.0
                && r.radius_scale <= 16.0
                && usize::from(r.layers) <= wire::MAX_LAYERS
        }
        Message::Frame(f) => {
            let h = &f.header;
            let n = f.samples.len() as u64;
            cam_ok(&h.camera)
                && h.bounds.is_valid()
                && h.radius_unit > 0.0
                && (h.radius_unit * RADIUS_MAX as f32).is_finite()
                && n <= limits.max_samples as u64
                && n <= h.camera.width as u64 * h.camera.height as u64
                && FRAME_FIXED_LEN as u64 + 12 * n <= limits.max_payload as u64
        }
    }
}

/// Target `roundtrip` (structured half): encoding a structured message never panics, gives
/// `12 + payload` bytes, and decodes to an equal message exactly when the message is valid
/// ([`expected_valid`]); otherwise the decoder names what is wrong. `f.samples` and `f.colors`
/// of a Frame must have equal lengths (the encoder refuses others).
pub fn roundtrip_message(m: &Message, limits: &Limits) {
    let bytes = encode_to_vec(m);
    assert!(bytes.len() >= HEADER_LEN);
    let len = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    assert_eq!(bytes.len(), HEADER_LEN + len);
    let back = read_message(&mut &bytes[..], limits);
    if expected_valid(m, limits) {
        assert_eq!(back.as_ref(), Ok(m), "a valid message did not round-trip");
        assert_eq!(encode_to_vec(&back.unwrap()), bytes);
    } else {
        match back {
            Err(
                WireError::BadCamera(_)
                | WireError::BadBounds
                | WireError::BadRadius
                | WireError::TooManySamples { .. }
                | WireError::TooLarge { .. }
                | WireError::Layers(volwarp_core::segments::LayerError::TooManyLayers { .. })
                | WireError::BadVisual(_),
            ) => {}
            other => panic!("an invalid message decoded as {other:?}"),
        }
    }
}

// ---------------------------------------------------------------- target 4: lbvh

/// Reads little-endian values from fuzz input; zeros once it is exhausted.
pub struct Bytes<'a>(pub &'a [u8]);

impl Bytes<'_> {
    /// Whether nothing is left.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        let n = N.min(self.0.len());
        a[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        a
    }
    /// A byte.
    pub fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    /// A `u16`.
    pub fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    /// A `u32`.
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    /// A `u64`.
    pub fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    /// Any `f32` bit pattern.
    pub fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
    /// A "nice" float: a small integer times a power of two (exact, often equal to others).
    pub fn nice(&mut self) -> f32 {
        let m = self.u8() as i8 as f32;
        let e = (self.u8() % 24) as i32 - 12;
        m * (2.0f32).powi(e)
    }
    /// Raw bits or a nice float, chosen by the next byte.
    pub fn float(&mut self) -> f32 {
        if self.u8() & 1 == 0 {
            self.nice()
        } else {
            self.f32()
        }
    }
    /// A vector of [`Bytes::float`]s.
    pub fn vec3(&mut self) -> Vec3 {
        Vec3::new(self.float(), self.float(), self.float())
    }
}

/// Smallest radius unit the `lbvh` target traces (2⁻⁴⁰; see `docs/fuzzing.md`).
pub const MIN_TRACED_RADIUS_UNIT: f32 = 1.0 / 1_099_511_627_776.0;

/// Largest coordinate and radius magnitude the `lbvh` target traces (2⁴⁰).
pub const MAX_TRACED_MAGNITUDE: f32 = 1_099_511_627_776.0;

/// Whether every component is at most [`MAX_TRACED_MAGNITUDE`] in magnitude.
pub fn in_traced_range(v: Vec3) -> bool {
    v.abs().max_element() <= MAX_TRACED_MAGNITUDE
}

/// Largest sample count the `lbvh` target builds.
pub const LBVH_MAX_N: usize = 96;

/// The frame the `lbvh` target builds from its input, if the input's bounds and radius unit
/// pass validation. Layout: bounds (two [`Bytes::vec3`]), radius unit ([`Bytes::float`]), count
/// (`u8 % (LBVH_MAX_N + 1)`), then per sample a selector byte: a copy of an earlier sample, a
/// sample in a small 4×4×4 cell range, or raw 64 bits.
pub fn lbvh_frame(b: &mut Bytes) -> Option<Frame> {
    let min = b.vec3();
    let max = b.vec3();
    let bounds = Bounds::new(min, max);
    let radius_unit = b.float().abs();
    let unit_ok = radius_unit > 0.0 && (radius_unit * RADIUS_MAX as f32).is_finite();
    if !(bounds.is_valid() && unit_ok) {
        return None;
    }
    // The wire accepts any positive unit and any finite bounds; outside 2⁻⁴⁰..2⁴⁰ squared
    // distances and radii underflow or overflow, and the sphere test reports hits that are
    // rounding artifacts (or at t = ∞), which no box test can agree with.
    if radius_unit < MIN_TRACED_RADIUS_UNIT || !(in_traced_range(min) && in_traced_range(max)) {
        return None;
    }
    if radius_unit * RADIUS_MAX as f32 > MAX_TRACED_MAGNITUDE {
        return None;
    }
    let n = b.u8() as usize % (LBVH_MAX_N + 1);
    let mut samples: Vec<u64> = Vec::with_capacity(n);
    for i in 0..n {
        let sel = b.u8();
        let s = match sel % 4 {
            0 if i > 0 => samples[b.u8() as usize % i],
            1 | 0 => {
                let (x, y, z) = (b.u8() as u64 % 4, b.u8() as u64 % 4, b.u8() as u64 % 4);
                let r = b.u16() as u64 % (RADIUS_MAX as u64 + 1);
                x | y << 18 | z << 36 | r << 54
            }
            _ => b.u64(),
        };
        samples.push(s);
    }
    let colors = (0..n as u32).map(|i| i.wrapping_mul(0x9e37_79b9)).collect();
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 60.0, 64, 64);
    let header = FrameHeader {
        seq: 0,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit,
        render_us: 0,
        level: 0,
        count: n as u32,
    };
    Some(Frame { header, samples, colors, segments: Vec::new() })
}

/// The next ray of the `lbvh` target: a selector byte picks raw origin and direction, a ray
/// from an arbitrary origin aimed at a sample's center, an axis-aligned ray through a sample's
/// center, or a pixel ray of a camera framing the bounds. `None` for unusable directions.
pub fn lbvh_ray(b: &mut Bytes, samples: &[u64], deq: &Dequantizer, bounds: &Bounds) -> Option<Ray> {
    let sel = b.u8();
    let pick = |b: &mut Bytes| {
        if samples.is_empty() {
            None
        } else {
            Some(deq.center(samples[b.u16() as usize % samples.len()]))
        }
    };
    let (origin, dir) = match sel % 4 {
        0 => (b.vec3(), b.vec3()),
        1 => {
            let o = b.vec3();
            let c = pick(b)?;
            (o, c - o)
        }
        2 => {
            let c = pick(b)?;
            let axis = b.u8();
            let mut d = Vec3::ZERO;
            d[(axis % 3) as usize] = if axis & 4 == 0 { 1.0 } else { -1.0 };
            let back = b.nice().abs();
            (c - d * back, d)
        }
        _ => {
            let (w, h) = (b.u8() as u32 % 64 + 1, b.u8() as u32 % 64 + 1);
            let cam = Camera::framing(bounds.min(), bounds.max(), b.nice(), b.nice(), 45.0, w, h);
            cam.validate(4096).ok()?;
            let (x, y) = (b.u8() as u32 % w, b.u8() as u32 % h);
            let r = cam.ray(x, y);
            (r.origin, r.dir)
        }
    };
    let l = dir.length();
    if !in_traced_range(origin) || l.is_nan() || l <= 0.0 || !l.is_finite() {
        return None;
    }
    let dir = dir / l;
    // Traversal takes unit directions (every camera ray is one, within 2 ulp; the box test
    // widens t by 4e-7 relative, see core `BOX_T_FAR_SCALE`). Dividing a vector whose squared
    // length is subnormal by its length leaves it visibly off unit length (0.9999969 was found),
    // and then the sphere t and the box t disagree by more than the box test's margin.
    (dir.is_finite() && (dir.length() - 1.0).abs() <= 2.5e-7).then_some(Ray { origin, dir })
}

/// Target `lbvh`: builds a scene from arbitrary samples (bounds and radius unit that pass the
/// wire validation) and checks the tree (`Lbvh::check`), that leaves are a permutation of the
/// input with colors attached, and that `trace` equals `brute_force` for up to 8 rays.
///
/// Empty samples (radius code 0) are built and checked, but traced with radius code 1: a
/// sphere of radius 0 is "hit" only when rounding (or underflow) makes the ray pass exactly
/// through its center, where the box test rightly sees a miss (`docs/fuzzing.md`).
pub fn lbvh(data: &[u8]) {
    let mut b = Bytes(data);
    let Some(mut frame) = lbvh_frame(&mut b) else { return };
    check_scene(&frame);
    for s in frame.samples.iter_mut() {
        if *s >> 54 == 0 {
            *s |= 1 << 54;
        }
    }
    let scene = Scene::build(&frame);
    let bvh = scene.lbvh();
    for _ in 0..8 {
        if b.is_empty() {
            break;
        }
        let Some(ray) = lbvh_ray(&mut b, &scene.samples, &scene.deq, &frame.header.bounds) else { continue };
        let fast = bvh.trace(&ray);
        let slow = brute_force(&scene.samples, &scene.deq, &ray);
        assert_eq!(fast, slow, "trace differs from brute force for {ray:?}");
        // t may be +inf: a sphere whose radius squares past f32::MAX (radius unit near the
        // wire limit) around the origin is left at infinity; never NaN, never behind.
        if let Some(h) = fast {
            assert!(h.t > 0.0, "hit at t = {}", h.t);
        }
    }
}

/// Builds the scene of `frame` and checks its tree and leaf order (part of target `lbvh`).
pub fn check_scene(frame: &Frame) {
    let scene = Scene::build(frame);
    let n = frame.samples.len();
    let mut seen = vec![0u8; (2 * n).saturating_sub(1)];
    assert_eq!(scene.lbvh().check(&mut seen), Ok(()), "invalid tree over {n} samples");
    let mut a: Vec<(u64, u32)> = frame.samples.iter().copied().zip(frame.colors.iter().copied()).collect();
    let mut b: Vec<(u64, u32)> = scene.samples.iter().copied().zip(scene.colors.iter().copied()).collect();
    a.sort_unstable();
    b.sort_unstable();
    assert_eq!(a, b, "leaves are not a permutation of the input samples with their colors");
}

/// A CameraRequest with the given fields (convenience for the structured generators).
pub fn camera_request(seq: u64, camera: Camera, heuristic: Heuristic, radius_scale: f32, layers: u8) -> Message {
    Message::CameraRequest(CameraRequest { seq, camera, heuristic, radius_scale, layers })
}

// ---------------------------------------------------------------- target 5: compact_decode

/// Target `compact_decode`. Byte 0 even: the rest is a stream of messages, decoded
/// with `read_message` under [`LIMITS`] (CompactFrames among them): no panic, every decode within
/// [`decode_alloc_limit`], accepted frames valid ([`check_frame`]), and a CompactFrame decodes to
/// the same result through `compact_frame::decode_payload` on its payload. Byte 0 odd: the rest
/// describes a *consistent* compact frame ([`compact_frame_from`]: viewport up to 24², mask,
/// residual planes, depth and radius parameters, stored or zstd body), which must decode, to as
/// many samples as mask bits, every center finite, and re-encode (when its samples still sit on
/// their pixels' rays) to a message that decodes to the same colors and radius codes.
pub fn compact_decode(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else { return };
    if mode & 1 == 0 {
        let (msgs, _) = decode_all(&mut &rest[..], &LIMITS);
        // Every CompactFrame in the stream: the payload alone decodes the same way.
        let mut at = 0usize;
        let mut i = 0;
        while at + HEADER_LEN <= rest.len() && i < msgs.len() {
            let len = u32::from_le_bytes([rest[at + 8], rest[at + 9], rest[at + 10], rest[at + 11]]) as usize;
            let end = at + HEADER_LEN + len;
            if rest[at + 6] == MsgType::CompactFrame as u8 && end <= rest.len() {
                let payload = &rest[at + HEADER_LEN..end];
                let direct = compact_frame::decode_payload(payload, &LIMITS);
                assert_eq!(direct.as_ref().ok().map(|f| Message::Frame(f.clone())).as_ref(), Some(&msgs[i]));
                compare_compact_decoders(payload);
            }
            at = end;
            i += 1;
        }
        return;
    }
    let Some((bytes, planes_body)) = compact_frame_from(rest) else { return };
    compare_compact_decoders(&bytes[HEADER_LEN..]);
    let (res, peak) = peak_alloc(|| read_message(&mut &bytes[..], &LIMITS));
    assert!(peak <= decode_alloc_limit(&LIMITS), "decode allocated {peak}");
    let f = match res {
        Ok(Message::Frame(f)) => f,
        other => panic!("a consistent compact frame was refused: {other:?}"),
    };
    check_frame(&f.header, &f.samples, &f.colors, &LIMITS);
    let mask_bits: u32 = planes_body
        .iter()
        .take(compact_frame::mask_len(f.header.camera.width, f.header.camera.height) as usize)
        .map(|b| b.count_ones())
        .sum();
    assert_eq!(f.samples.len() as u32, mask_bits);
    let stored = compact_frame::EncodeOptions { coder: compact_frame::Coder::Stored, ..Default::default() };
    if let Ok(again) = compact_frame::encode(&f, &stored) {
        match read_message(&mut &again[..], &LIMITS) {
            Ok(Message::Frame(g)) => {
                assert_eq!(g.colors, f.colors, "colors changed in a re-encode");
                let codes = |s: &[u64]| s.iter().map(|&s| volwarp_core::sample::radius_code(s)).collect::<Vec<_>>();
                assert_eq!(codes(&g.samples), codes(&f.samples), "radius codes changed in a re-encode");
            }
            other => panic!("a re-encoded frame does not decode: {other:?}"),
        }
    }
}

/// The compact decoder's alternatives on one CompactFrame payload agree: the fast
/// reconstruction (`decode_body`) and its scalar reference give the same frame or the same
/// error on whatever body either decompressor (C zstd, ruzstd) yields, and a decompressed
/// body always has exactly the stated length.
pub fn compare_compact_decoders(payload: &[u8]) {
    let Ok((header, params)) = compact_frame::read_params(payload, &LIMITS) else { return };
    let coded = &payload[compact_frame::COMPACT_FIXED_LEN..];
    let bodies = [compact_frame::decompress_c(coded, &params), compact_frame::decompress_ruzstd(coded, &params)];
    for body in bodies.iter().flatten() {
        assert_eq!(body.len(), params.raw_len as usize);
        let fast = compact_frame::decode_body(&header, &params, body);
        let reference = compact_frame::decode_body_reference(&header, &params, body);
        assert!(
            fast == reference,
            "fast and reference reconstruction differ: {:?} / {:?}",
            fast.err(),
            reference.err()
        );
    }
}

/// A consistent CompactFrame message built from fuzz bytes (see [`compact_decode`]) and its
/// uncompressed body; `None` if the input is too short for the header bytes.
pub fn compact_frame_from(data: &[u8]) -> Option<(Vec<u8>, Vec<u8>)> {
    if data.len() < 12 {
        return None;
    }
    let mut b = Bytes(data);
    let w = 1 + b.u8() as u32 % 24;
    let h = 1 + b.u8() as u32 % 24;
    let yaw = b.u8() as f32 * 1.5;
    let zstd = b.u8() & 1 == 1;
    let depth_min = (b.u8() as f32) * 0.05;
    let depth_step = (1 + b.u16() as u32) as f32 * 1e-5;
    let constant = b.u8() as f32 * 1e-4;
    let per_depth = b.u8() as f32 * 1e-4;
    let bounds = Bounds::new(Vec3::splat(-1.0), Vec3::splat(1.0));
    let camera = Camera::framing(bounds.min(), bounds.max(), yaw, 10.0, 40.0, w, h);
    let mlen = compact_frame::mask_len(w, h) as usize;
    let mut body = Vec::with_capacity(mlen);
    let pixels = (w * h) as usize;
    for i in 0..mlen {
        let valid = (pixels - i * 8).min(8);
        let m = if valid == 8 { 0xff } else { (1u16 << valid) as u8 - 1 };
        body.push(b.u8() & m);
    }
    let n: usize = body.iter().map(|x| x.count_ones() as usize).sum();
    for plane in 0..8 {
        for _ in 0..n {
            let v = b.u8();
            body.push(if plane == 3 { v & 3 } else { v });
        }
    }
    let header = FrameHeader {
        seq: 1,
        camera,
        heuristic: Heuristic::Threshold,
        bounds,
        radius_unit: 1e-3,
        render_us: 0,
        level: 0,
        count: n as u32,
    };
    // Colors plain, or against green with any scales (0–31 eighths).
    let green = b.u8() & 1 == 1;
    let color_scale = if green { [b.u8() & 31, b.u8() & 31, b.u8() & 31] } else { [0; 3] };
    let params = compact_frame::CompactParams {
        depth_min,
        depth_step,
        radius: compact_frame::RadiusPrediction { constant, per_depth },
        coder: if zstd { compact_frame::Coder::Zstd } else { compact_frame::Coder::Stored },
        colors: if green { compact_frame::ColorCoding::AgainstGreen } else { compact_frame::ColorCoding::Plain },
        color_scale,
        raw_len: body.len() as u32,
    };
    // C zstd (fast; ruzstd's encoder under the sanitizer made this target crawl).
    let coded = if zstd { compact_frame::compress_c(&body, 1) } else { body.clone() };
    let msg = compact_frame::assemble(&header, &params, &coded).ok()?;
    Some((msg, body))
}
