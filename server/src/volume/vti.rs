//! VTK XML image data (`.vti`), as ParaView, VTK and ITK write it.
//!
//! **What is read.** `<ImageData WholeExtent Spacing Origin [Direction]>` with one `<Piece>`
//! and its first scalar `<PointData>` array (the one `PointData Scalars="…"` names, else the
//! first `DataArray` with one component); types Int8 to Float64 (not 64-bit integers);
//! `format="ascii"`, `format="binary"` (base64 inline) and `format="appended"` (`<AppendedData
//! encoding="raw">` or `"base64"` after its `_`); uncompressed or `compressor=
//! "vtkZLibDataCompressor"` blocks; `header_type` UInt32 or UInt64; either `byte_order`.
//! An axis-aligned `Direction` (a permutation with flips) is applied by reordering the voxels;
//! VTK's world frame is taken as is (no RAS/LPS change). The origin only places the data in
//! VTK's world; the volume box starts at 0.
//!
//! **Refused.** Several pieces, cell data only, multi-component arrays, LZ4 or LZMA
//! compression, oblique directions.
//!
//! Parsed with `quick-xml`; every size (extent, header block sizes) is checked against the
//! voxel limit and the data present before anything is allocated or inflated. Never panics
//! (fuzzed through `load_volume`).

use super::orient::axis_aligned;
use super::stream::{stored_size, stream_volume, StreamSpec};
use super::{check_load, decode_voxels, voxel_bytes, LoadOptions, SourceInfo, Volume, VolumeError, VoxelType};
use base64::Engine;
use quick_xml::events::{BytesStart, Event};
use std::io::Read;
use std::path::Path;
use volwarp_core::Vec3;

const FORMAT: &str = "VTK image data";

fn bad(s: impl Into<String>) -> VolumeError {
    VolumeError::malformed(FORMAT, s)
}

/// True where `head` looks like a VTK XML image data file.
pub fn is_vti(head: &[u8]) -> bool {
    let s = String::from_utf8_lossy(&head[..head.len().min(1024)]);
    s.contains("<VTKFile") && s.contains("ImageData")
}

/// What the header says about the array read.
#[derive(Clone, Debug, Default)]
struct Array {
    ty: Option<VoxelType>,
    format: String,
    offset: Option<u64>,
    text: String,
}

#[derive(Clone, Debug, Default)]
struct Header {
    extent: Option<[i64; 6]>,
    spacing: [f64; 3],
    direction: Option<[f64; 9]>,
    big_endian: bool,
    header64: bool,
    zlib: bool,
    pieces: usize,
    array: Option<Array>,
    arrays_seen: Vec<String>,
    cell_arrays: usize,
    appended_encoding: Option<String>,
}

fn attrs(e: &BytesStart) -> Vec<(String, String)> {
    e.attributes()
        .flatten()
        .map(|a| {
            let k = String::from_utf8_lossy(a.key.as_ref()).into_owned();
            let v = a.unescape_value().map(|v| v.into_owned()).unwrap_or_default();
            (k, v)
        })
        .collect()
}

fn get<'a>(a: &'a [(String, String)], k: &str) -> Option<&'a str> {
    a.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str())
}

fn numbers<const N: usize>(s: &str, what: &str) -> Result<[f64; N], VolumeError> {
    let v: Vec<f64> = s
        .split_whitespace()
        .take(N + 1)
        .map(|x| x.parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad(format!("{what} {s:?} is not {N} numbers")))?;
    v.try_into().map_err(|_| bad(format!("{what} {s:?} is not {N} numbers")))
}

fn vtk_type(s: &str) -> Result<VoxelType, VolumeError> {
    Ok(match s {
        "Int8" | "Char" => VoxelType::I8,
        "UInt8" | "UnsignedChar" => VoxelType::U8,
        "Int16" | "Short" => VoxelType::I16,
        "UInt16" | "UnsignedShort" => VoxelType::U16,
        "Int32" | "Int" => VoxelType::I32,
        "UInt32" | "UnsignedInt" => VoxelType::U32,
        "Float32" | "Float" => VoxelType::F32,
        "Float64" | "Double" => VoxelType::F64,
        other => {
            return Err(VolumeError::unsupported(format!(
                "VTK array type {:?} (Int8 to Float64 scalars, not 64-bit integers)",
                other.chars().take(20).collect::<String>()
            )))
        }
    })
}

/// Parses the XML part (everything before the appended data).
fn parse_xml(xml: &str) -> Result<Header, VolumeError> {
    let mut h = Header { spacing: [1.0; 3], ..Default::default() };
    let mut r = quick_xml::Reader::from_str(xml);
    let mut scalars_name: Option<String> = None;
    let (mut in_point_data, mut in_cell_data, mut reading) = (false, false, false);
    let mut saw_vtkfile = false;
    loop {
        let ev = r.read_event().map_err(|e| bad(format!("XML: {e}")))?;
        match ev {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let is_start = matches!(ev, Event::Start(_));
                let name = e.local_name().as_ref().to_vec();
                let a = attrs(e);
                match name.as_slice() {
                    b"VTKFile" => {
                        saw_vtkfile = true;
                        if get(&a, "type").is_some_and(|t| t != "ImageData") {
                            return Err(VolumeError::unsupported(format!(
                                "VTK XML {} files (only ImageData, .vti)",
                                get(&a, "type").unwrap_or("")
                            )));
                        }
                        h.big_endian = get(&a, "byte_order") == Some("BigEndian");
                        h.header64 = match get(&a, "header_type").unwrap_or("UInt32") {
                            "UInt32" => false,
                            "UInt64" => true,
                            t => return Err(bad(format!("header_type {t:?} (UInt32 or UInt64)"))),
                        };
                        h.zlib = match get(&a, "compressor").unwrap_or("") {
                            "" => false,
                            "vtkZLibDataCompressor" => true,
                            c => {
                                return Err(VolumeError::unsupported(format!(
                                    "VTK compressor {c:?} (only vtkZLibDataCompressor)"
                                )))
                            }
                        };
                    }
                    b"ImageData" => {
                        let ext = get(&a, "WholeExtent").ok_or_else(|| bad("ImageData without WholeExtent"))?;
                        h.extent = Some(numbers::<6>(ext, "WholeExtent")?.map(|x| x as i64));
                        if let Some(s) = get(&a, "Spacing") {
                            h.spacing = numbers::<3>(s, "Spacing")?;
                        }
                        if let Some(d) = get(&a, "Direction") {
                            h.direction = Some(numbers::<9>(d, "Direction")?);
                        }
                    }
                    b"Piece" => h.pieces += 1,
                    b"PointData" => {
                        in_point_data = true;
                        scalars_name = get(&a, "Scalars").map(str::to_string);
                    }
                    b"CellData" => in_cell_data = true,
                    b"DataArray" if in_cell_data => h.cell_arrays += 1,
                    b"DataArray" if in_point_data => {
                        let name = get(&a, "Name").unwrap_or("").to_string();
                        h.arrays_seen.push(name.clone());
                        let comps = get(&a, "NumberOfComponents").unwrap_or("1");
                        let wanted = match &scalars_name {
                            Some(s) => *s == name,
                            None => comps == "1",
                        };
                        if h.array.is_none() && wanted {
                            if comps != "1" {
                                return Err(VolumeError::unsupported(format!(
                                    "the scalars {name:?} have {comps} components (one is read)"
                                )));
                            }
                            let ty = vtk_type(get(&a, "type").unwrap_or(""))?;
                            let offset = match get(&a, "offset") {
                                Some(o) => Some(o.trim().parse::<u64>().map_err(|_| bad(format!("offset {o:?}")))?),
                                None => None,
                            };
                            h.array = Some(Array {
                                ty: Some(ty),
                                format: get(&a, "format").unwrap_or("ascii").to_string(),
                                offset,
                                text: String::new(),
                            });
                            reading = is_start;
                        }
                    }
                    b"AppendedData" => {
                        h.appended_encoding = Some(get(&a, "encoding").unwrap_or("raw").to_string());
                        break;
                    }
                    _ => {}
                }
            }
            Event::Text(t) if reading => {
                if let Some(a) = h.array.as_mut() {
                    a.text.push_str(&t.decode().map_err(|e| bad(format!("XML text: {e}")))?);
                }
            }
            Event::End(e) => match e.local_name().as_ref() {
                b"PointData" => in_point_data = false,
                b"CellData" => in_cell_data = false,
                b"DataArray" => reading = false,
                _ => {}
            },
            Event::Eof => break,
            _ => {}
        }
    }
    if !saw_vtkfile {
        return Err(bad("no <VTKFile> element"));
    }
    Ok(h)
}

/// Reads a header integer (UInt32 or UInt64) at `at`.
fn header_int(b: &[u8], at: usize, h64: bool, big: bool) -> Option<u64> {
    if h64 {
        let a: [u8; 8] = b.get(at..at + 8)?.try_into().ok()?;
        Some(if big { u64::from_be_bytes(a) } else { u64::from_le_bytes(a) })
    } else {
        let a: [u8; 4] = b.get(at..at + 4)?.try_into().ok()?;
        Some(if big { u32::from_be_bytes(a) } else { u32::from_le_bytes(a) } as u64)
    }
}

/// Where binary data comes from: bytes already decoded, or base64 text decoded on demand.
enum Source<'a> {
    Raw(&'a [u8]),
    Base64(&'a [u8]),
}

fn b64(chars: &[u8]) -> Result<Vec<u8>, VolumeError> {
    let clean: Vec<u8> = chars.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
    base64::engine::general_purpose::STANDARD.decode(&clean).map_err(|e| bad(format!("base64: {e}")))
}

/// The number of base64 characters that encode `n` bytes.
fn b64_len(n: usize) -> usize {
    n.div_ceil(3) * 4
}

impl Source<'_> {
    /// The header of `n` integers and the rest (for base64: header and data are encoded
    /// separately, as VTK writes them).
    fn split_header(&self, n: usize, isz: usize) -> Result<(Vec<u8>, Vec<u8>), VolumeError> {
        let hb = n * isz;
        match *self {
            Source::Raw(b) => {
                if b.len() < hb {
                    return Err(bad(format!(
                        "the data block holds {} bytes, fewer than its {hb}-byte header",
                        b.len()
                    )));
                }
                Ok((b[..hb].to_vec(), b[hb..].to_vec()))
            }
            Source::Base64(t) => {
                let t: Vec<u8> = t.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
                let hl = b64_len(hb);
                if t.len() < hl {
                    return Err(bad("the base64 data block is shorter than its header"));
                }
                Ok((b64(&t[..hl])?, t[hl..].to_vec()))
            }
        }
    }
}

/// Decodes one binary block (inline base64 or appended) of `expected` bytes.
fn read_block(src: Source, h: &Header, expected: u64) -> Result<Vec<u8>, VolumeError> {
    let isz = if h.header64 { 8 } else { 4 };
    let int = |b: &[u8], i: usize| header_int(b, i * isz, h.header64, h.big_endian).ok_or_else(|| bad("short header"));
    let is_b64 = matches!(src, Source::Base64(_));
    if !h.zlib {
        let (hdr, rest) = src.split_header(1, isz)?;
        let n = int(&hdr, 0)?;
        if n != expected {
            return Err(super::VolumeError::new(super::VolumeErrorKind::SizeMismatch { expected, actual: n }));
        }
        let data = if is_b64 { b64(&rest)? } else { rest };
        if (data.len() as u64) < expected {
            return Err(super::VolumeError::new(super::VolumeErrorKind::SizeMismatch {
                expected,
                actual: data.len() as u64,
            }));
        }
        return Ok(data[..expected as usize].to_vec());
    }
    // Compressed: [blocks, block size, last block size, compressed sizes...].
    let (first, _) = src.split_header(3, isz)?;
    let (blocks, block, last) = (int(&first, 0)?, int(&first, 1)?, int(&first, 2)?);
    check_blocks(blocks, block, last, expected)?;
    let (hdr, rest) = src.split_header(3 + blocks as usize, isz)?;
    let data = if is_b64 { b64(&rest)? } else { rest };
    let mut out = Vec::with_capacity(expected as usize);
    let mut at = 0usize;
    for i in 0..blocks as usize {
        let csize = int(&hdr, 3 + i)?;
        let chunk = usize::try_from(csize)
            .ok()
            .and_then(|c| data.get(at..at.checked_add(c)?))
            .ok_or_else(|| bad(format!("compressed block {i} of {csize} bytes runs past the data")))?;
        at += chunk.len();
        let want = if i + 1 == blocks as usize && last != 0 { last } else { block };
        inflate_block(i, chunk, want, &mut out).map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidData => VolumeError::new(super::VolumeErrorKind::Decompress(e.to_string())),
            _ => VolumeError::new(super::VolumeErrorKind::Io(e)),
        })?;
    }
    Ok(out)
}

/// Bytes read first: the XML part of a file with appended data fits in them (else the whole
/// file is read).
const HEAD_BYTES: u64 = 1 << 20;

/// Loads a `.vti` file. Raw appended data (plain or zlib blocks) in the stored order or
/// mirrored in x and y streams from the file into bricks; other files are read whole.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Volume, VolumeError> {
    let mut f = std::fs::File::open(path).map_err(|e| VolumeError::io(path, e))?;
    let file_len = f.metadata().map_err(|e| VolumeError::io(path, e))?.len();
    let mut head = Vec::with_capacity(file_len.min(HEAD_BYTES) as usize);
    f.by_ref().take(HEAD_BYTES).read_to_end(&mut head).map_err(|e| VolumeError::io(path, e))?;
    if let Some(v) = stream_appended(path, &head, f, file_len, opts).map_err(|e| e.at(path))? {
        return Ok(v);
    }
    let bytes =
        if head.len() as u64 == file_len { head } else { std::fs::read(path).map_err(|e| VolumeError::io(path, e))? };
    load_bytes(path, &bytes, opts).map_err(|e| e.at(path))
}

/// The XML part's end and where the appended data starts (after its `_`), if the file has
/// appended data and `bytes` reach it.
fn appended_start(bytes: &[u8]) -> Result<Option<(usize, usize)>, VolumeError> {
    let Some(i) = find(bytes, b"<AppendedData") else { return Ok(None) };
    let close = bytes[i..]
        .iter()
        .position(|&c| c == b'>')
        .map(|p| i + p + 1)
        .ok_or_else(|| bad("unclosed <AppendedData> tag"))?;
    let us = bytes[close..]
        .iter()
        .position(|&c| c == b'_')
        .map(|p| close + p + 1)
        .ok_or_else(|| bad("no `_` starting the appended data"))?;
    Ok(Some((close, us)))
}

/// What the header says about the volume: dims and the array read.
fn volume_of(h: &Header) -> Result<([u32; 3], Array), VolumeError> {
    if h.pieces > 1 {
        return Err(VolumeError::unsupported(format!("{} pieces (one piece is read)", h.pieces)));
    }
    let e = h.extent.ok_or_else(|| bad("no <ImageData WholeExtent>"))?;
    let mut dims = [0u32; 3];
    for a in 0..3 {
        let n = e[2 * a + 1].checked_sub(e[2 * a]).and_then(|d| d.checked_add(1)).filter(|&n| n >= 1);
        dims[a] = n
            .and_then(|n| u32::try_from(n).ok())
            .ok_or_else(|| bad(format!("WholeExtent {:?} is empty or too large along axis {a}", e)))?;
    }
    let Some(arr) = h.array.clone() else {
        return Err(if h.cell_arrays > 0 {
            VolumeError::unsupported("cell data only (point data is read)")
        } else if h.arrays_seen.is_empty() {
            bad("no PointData DataArray")
        } else {
            VolumeError::unsupported(format!("no one-component point data array among {:?}", h.arrays_seen))
        });
    };
    Ok((dims, arr))
}

/// The reordering into the volume's axes: VTK's row-major Direction (column `i` is axis `i`'s
/// direction) and the spacing signs.
fn reorient_of(h: &Header) -> Result<super::orient::Reorient, VolumeError> {
    let (d, s) = (h.direction.unwrap_or([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), h.spacing);
    axis_aligned(std::array::from_fn(|i| [d[i] * s[i], d[3 + i] * s[i], d[6 + i] * s[i]]))
}

/// What [`Volume::source`] says of a `.vti` file.
fn source_of(ty: VoxelType, r: &super::orient::Reorient, data_bytes: u64) -> SourceInfo {
    SourceInfo {
        format: "VTK image data".into(),
        voxel_type: Some(ty),
        orientation: if r.is_identity() {
            "none (the stored order)".into()
        } else {
            format!("{} (Direction and Spacing signs)", r.describe())
        },
        data_bytes,
        files: 1,
    }
}

/// Streams raw appended data (`file` positioned after `head`) into bricks; `None` where the
/// file is not one that streams (inline or base64 data, a permuted or z-flipped Direction).
fn stream_appended(
    path: &Path,
    head: &[u8],
    mut file: std::fs::File,
    file_len: u64,
    opts: &LoadOptions,
) -> Result<Option<Volume>, VolumeError> {
    use std::io::{Seek, SeekFrom};
    let Some((xml_end, start)) = appended_start(head)? else { return Ok(None) };
    let xml = std::str::from_utf8(&head[..xml_end]).map_err(|_| bad("the XML part is not UTF-8"))?;
    let h = parse_xml(xml)?;
    let (dims, arr) = volume_of(&h)?;
    let r = reorient_of(&h)?;
    if arr.format != "appended" || h.appended_encoding.as_deref() != Some("raw") || r.perm != [0, 1, 2] || r.flip[2] {
        return Ok(None);
    }
    let ty = arr.ty.unwrap_or(VoxelType::F32);
    let voxels = check_load(dims, r.spacing, opts, stored_size(ty), 0)?;
    let expected = voxel_bytes(voxels, ty)?;
    let off = arr.offset.ok_or_else(|| bad("an appended DataArray without offset"))?;
    let at = (start as u64)
        .checked_add(off)
        .filter(|&a| a <= file_len)
        .ok_or_else(|| bad(format!("offset {off} is past the appended data")))?;
    file.seek(SeekFrom::Start(at)).map_err(|e| VolumeError::io(path, e))?;
    let mut file = std::io::BufReader::with_capacity(1 << 20, file);
    let isz = if h.header64 { 8 } else { 4 };
    let mut ints = |n: usize| -> Result<Vec<u64>, VolumeError> {
        if (n * isz) as u64 > file_len - at {
            return Err(bad("the data block is shorter than its header"));
        }
        let mut b = vec![0u8; n * isz];
        file.read_exact(&mut b).map_err(|e| VolumeError::io(path, e))?;
        Ok((0..n).filter_map(|i| header_int(&b, i * isz, h.header64, h.big_endian)).collect())
    };
    let spec = StreamSpec {
        name: path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume"),
        dims,
        spacing: opts.spacing.unwrap_or(r.spacing),
        ty,
        big_endian: h.big_endian,
        flip_xy: [r.flip[0], r.flip[1]],
        path,
    };
    let vol = if !h.zlib {
        let n = ints(1)?[0];
        if n != expected {
            return Err(VolumeError::new(super::VolumeErrorKind::SizeMismatch { expected, actual: n }));
        }
        stream_volume(&spec, file.take(expected))?
    } else {
        let first = ints(3)?;
        let (blocks, block, last) = (first[0], first[1], first[2]);
        check_blocks(blocks, block, last, expected)?;
        let sizes = ints(blocks as usize)?;
        let reader = ZlibBlocks::new(file, sizes, block, last);
        stream_volume(&spec, reader).map_err(|e| match e.kind {
            super::VolumeErrorKind::Io(io) if io.kind() == std::io::ErrorKind::InvalidData => {
                VolumeError::new(super::VolumeErrorKind::Decompress(io.to_string()))
            }
            _ => e,
        })?
    };
    Ok(Some(vol.with_source(source_of(ty, &r, expected))))
}

/// Checks a zlib header's block count and sizes against the `expected` bytes.
fn check_blocks(blocks: u64, block: u64, last: u64, expected: u64) -> Result<(), VolumeError> {
    let max_blocks = expected / block.max(1) + 2;
    if blocks > max_blocks || blocks == 0 && expected > 0 {
        return Err(bad(format!("{blocks} compressed blocks of {block} bytes cannot hold {expected} bytes")));
    }
    let total = if blocks == 0 {
        0
    } else {
        (blocks - 1)
            .checked_mul(block)
            .and_then(|t| t.checked_add(if last == 0 { block } else { last }))
            .ok_or_else(|| bad("compressed block sizes overflow"))?
    };
    if total != expected {
        return Err(super::VolumeError::new(super::VolumeErrorKind::SizeMismatch { expected, actual: total }));
    }
    Ok(())
}

/// Inflates one zlib block that must give `want` bytes, appending them to `out`.
fn inflate_block(i: usize, chunk: &[u8], want: u64, out: &mut Vec<u8>) -> std::io::Result<()> {
    let before = out.len();
    out.resize(before + want as usize, 0);
    inflate_into(i, chunk, &mut out[before..])
}

/// Inflates one zlib block into `out`, which it must fill exactly (bytes past it are ignored),
/// with this thread's inflate state (reset, not reallocated, per block).
fn inflate_into(i: usize, chunk: &[u8], out: &mut [u8]) -> std::io::Result<()> {
    use flate2::{Decompress, FlushDecompress};
    thread_local! {
        static INFLATE: std::cell::RefCell<Decompress> = std::cell::RefCell::new(Decompress::new(true));
    }
    let bad = |msg: String| std::io::Error::new(std::io::ErrorKind::InvalidData, msg);
    INFLATE.with(|d| {
        let mut d = d.borrow_mut();
        d.reset(true);
        d.decompress(chunk, out, FlushDecompress::Finish).map_err(|e| bad(format!("zlib block {i}: {e}")))?;
        let got = d.total_out();
        if got != out.len() as u64 {
            return Err(bad(format!("zlib block {i} inflates to {got} bytes, not {}", out.len())));
        }
        Ok(())
    })
}

/// The blocks of a zlib-compressed appended array as one stream: a thread reads them in batches
/// and inflates each batch on all cores straight into its buffer (the blocks are independent),
/// one batch ahead of the reader, which is building bricks meanwhile.
struct ZlibBlocks {
    batches: std::sync::mpsc::Receiver<std::io::Result<Vec<u8>>>,
    /// Emptied buffers, back to the inflating thread.
    spent: std::sync::mpsc::SyncSender<Vec<u8>>,
    out: Vec<u8>,
    pos: usize,
}

/// Blocks inflated at a time (32 KiB each as VTK writes them: 4 MiB a batch).
const BATCH_BLOCKS: usize = 128;

impl ZlibBlocks {
    /// Starts inflating the blocks of `sizes` (compressed bytes each; `block` bytes inflated,
    /// `last` for the last one unless 0) read from `src`.
    fn new<R: Read + Send + 'static>(mut src: R, sizes: Vec<u64>, block: u64, last: u64) -> ZlibBlocks {
        let (tx, batches) = std::sync::mpsc::sync_channel(1);
        let (spent, back) = std::sync::mpsc::sync_channel::<Vec<u8>>(2);
        std::thread::spawn(move || {
            let mut comp = Vec::new();
            let mut next = 0;
            while next < sizes.len() {
                let out = back.try_recv().unwrap_or_default();
                let batch = inflate_batch(&mut src, &sizes, block, last, next, &mut comp, out);
                let failed = batch.is_err();
                if tx.send(batch).is_err() || failed {
                    return; // the reader is gone, or this was the error it gets
                }
                next = (next + BATCH_BLOCKS).min(sizes.len());
            }
        });
        ZlibBlocks { batches, spent, out: Vec::new(), pos: 0 }
    }
}

/// Reads the compressed blocks `first..` (a batch) from `src` into `comp` and inflates them in
/// parallel into `out` (grown as they are read, never by what a header claims).
fn inflate_batch(
    src: &mut impl Read,
    sizes: &[u64],
    block: u64,
    last: u64,
    first: usize,
    comp: &mut Vec<u8>,
    mut out: Vec<u8>,
) -> std::io::Result<Vec<u8>> {
    use rayon::prelude::*;
    let end = (first + BATCH_BLOCKS).min(sizes.len());
    comp.clear();
    let mut bounds = Vec::with_capacity(end - first);
    for (i, &size) in sizes.iter().enumerate().take(end).skip(first) {
        let start = comp.len();
        let n = src.take(size).read_to_end(comp)?;
        if (n as u64) < size {
            let msg = format!("compressed block {i} of {size} bytes runs past the data");
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, msg));
        }
        bounds.push(start..comp.len());
    }
    let want = |i: usize| (if i + 1 == sizes.len() && last != 0 { last } else { block }) as usize;
    out.resize((first..end).map(want).sum(), 0);
    let mut slices = Vec::with_capacity(end - first);
    let mut rest = &mut out[..];
    for i in first..end {
        let (a, b) = rest.split_at_mut(want(i));
        slices.push(a);
        rest = b;
    }
    let comp = &*comp;
    slices.into_par_iter().zip(bounds).enumerate().try_for_each(|(k, (o, r))| inflate_into(first + k, &comp[r], o))?;
    Ok(out)
}

impl Read for ZlibBlocks {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.pos == self.out.len() {
            match self.batches.recv() {
                Ok(batch) => {
                    let spent = std::mem::replace(&mut self.out, batch?);
                    let _ = self.spent.try_send(spent);
                    self.pos = 0;
                }
                Err(_) => return Ok(0), // every batch read
            }
        }
        let n = buf.len().min(self.out.len() - self.pos);
        buf[..n].copy_from_slice(&self.out[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn load_bytes(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<Volume, VolumeError> {
    // The XML part ends with the `<AppendedData …>` tag; raw appended bytes follow its `_`.
    let (xml_end, appended) = match appended_start(bytes)? {
        Some((close, us)) => (close, Some(&bytes[us..])),
        None => (bytes.len(), None),
    };
    let xml = std::str::from_utf8(&bytes[..xml_end]).map_err(|_| bad("the XML part is not UTF-8"))?;
    let h = parse_xml(xml)?;
    let (dims, arr) = volume_of(&h)?;
    let ty = arr.ty.unwrap_or(VoxelType::F32);
    let s = h.spacing;
    let sp = Vec3::new(s[0].abs() as f32, s[1].abs() as f32, s[2].abs() as f32);
    let voxels = check_load(dims, sp, opts, 4, 8)?;
    let expected = voxel_bytes(voxels, ty)?;
    let values = match arr.format.as_str() {
        "ascii" => {
            let mut v = Vec::with_capacity(voxels as usize);
            for tok in arr.text.split_whitespace() {
                if v.len() as u64 == voxels {
                    return Err(bad(format!("the ascii array holds more than {voxels} values")));
                }
                v.push(
                    tok.parse::<f64>()
                        .map_err(|_| bad(format!("{:?} is not a number", tok.chars().take(20).collect::<String>())))?
                        as f32,
                );
            }
            if v.len() as u64 != voxels {
                return Err(bad(format!("the ascii array holds {} values, the extent {voxels}", v.len())));
            }
            v
        }
        "binary" => {
            let data = read_block(Source::Base64(arr.text.trim().as_bytes()), &h, expected)?;
            decode_voxels(&data, ty, h.big_endian)
        }
        "appended" => {
            let app = appended.ok_or_else(|| bad("format=\"appended\" without <AppendedData>"))?;
            let off = arr.offset.ok_or_else(|| bad("an appended DataArray without offset"))?;
            let at = usize::try_from(off)
                .ok()
                .filter(|&o| o <= app.len())
                .ok_or_else(|| bad(format!("offset {off} is past the appended data")))?;
            let src = match h.appended_encoding.as_deref() {
                Some("raw") => Source::Raw(&app[at..]),
                Some("base64") => {
                    // The block ends at the closing tag (or the next block: base64 decoding
                    // stops where the header says).
                    let rest = &app[at..];
                    let end = find(rest, b"</AppendedData").unwrap_or(rest.len());
                    Source::Base64(&rest[..end])
                }
                other => {
                    return Err(VolumeError::unsupported(format!("AppendedData encoding {other:?} (raw or base64)")))
                }
            };
            let data = read_block(src, &h, expected)?;
            decode_voxels(&data, ty, h.big_endian)
        }
        f => {
            return Err(VolumeError::unsupported(format!(
                "DataArray format {:?} (ascii, binary or appended)",
                f.chars().take(20).collect::<String>()
            )))
        }
    };
    // Negative spacings and an axis-aligned Direction: reorder.
    let r = reorient_of(&h)?;
    let values = r.apply(values, dims);
    let out_dims = r.dims(dims);
    let spacing = opts.spacing.unwrap_or(r.spacing);
    let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("volume");
    Ok(Volume::from_values(name, out_dims, spacing, values)?.with_source(source_of(ty, &r, expected)))
}

/// The zlib block size [`write()`] uses (VTK's default).
const ZLIB_BLOCK: usize = 32 << 10;

/// How [`write()`] stores the array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteFormat {
    /// Numbers in the XML.
    Ascii,
    /// Base64 inline, optionally zlib-compressed.
    Binary {
        /// Zlib blocks.
        zlib: bool,
    },
    /// Raw appended data, optionally zlib-compressed.
    AppendedRaw {
        /// Zlib blocks.
        zlib: bool,
    },
}

/// Writes a `.vti` file (UInt64 headers where `header64`, little-endian, zlib blocks of
/// `block` bytes): tests and exports.
pub fn write(
    path: &Path,
    volume_bytes: &[u8],
    ty: VoxelType,
    dims: [u32; 3],
    spacing: Vec3,
    format: WriteFormat,
    header64: bool,
) -> std::io::Result<()> {
    use std::io::Write;
    let tname = match ty {
        VoxelType::I8 => "Int8",
        VoxelType::U8 => "UInt8",
        VoxelType::I16 => "Int16",
        VoxelType::U16 => "UInt16",
        VoxelType::I32 => "Int32",
        VoxelType::U32 => "UInt32",
        VoxelType::F32 => "Float32",
        VoxelType::F64 => "Float64",
    };
    let int = |v: u64| if header64 { v.to_le_bytes().to_vec() } else { (v as u32).to_le_bytes().to_vec() };
    let zlib = matches!(format, WriteFormat::Binary { zlib: true } | WriteFormat::AppendedRaw { zlib: true });
    // (header, data) of a binary block.
    let block = || -> std::io::Result<(Vec<u8>, Vec<u8>)> {
        if !zlib {
            return Ok((int(volume_bytes.len() as u64), volume_bytes.to_vec()));
        }
        // VTK's 32 KiB blocks, and at least four for small arrays (readers see several).
        let bs = ZLIB_BLOCK.min(volume_bytes.len().div_ceil(4)).max(1);
        let chunks: Vec<&[u8]> = volume_bytes.chunks(bs).collect();
        let mut header = int(chunks.len() as u64);
        header.extend(int(bs as u64));
        header.extend(int((volume_bytes.len() % bs) as u64));
        let mut data = Vec::new();
        for c in &chunks {
            let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            e.write_all(c)?;
            let z = e.finish()?;
            header.extend(int(z.len() as u64));
            data.extend(z);
        }
        Ok((header, data))
    };
    let b64e = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let (fmt_attr, inline, appended) = match format {
        WriteFormat::Ascii => {
            let vals = decode_voxels(volume_bytes, ty, false);
            let text: Vec<String> = vals.iter().map(|v| v.to_string()).collect();
            ("format=\"ascii\"".to_string(), text.join(" "), None)
        }
        WriteFormat::Binary { .. } => {
            let (h, d) = block()?;
            ("format=\"binary\"".to_string(), format!("{}{}", b64e(&h), b64e(&d)), None)
        }
        WriteFormat::AppendedRaw { .. } => {
            let (mut h, d) = block()?;
            h.extend(d);
            ("format=\"appended\" offset=\"0\"".to_string(), String::new(), Some(h))
        }
    };
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(
        f,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"{}\"{}>\n\
  <ImageData WholeExtent=\"0 {} 0 {} 0 {}\" Origin=\"0 0 0\" Spacing=\"{} {} {}\">\n\
    <Piece Extent=\"0 {} 0 {} 0 {}\">\n      <PointData Scalars=\"scalars\">\n\
        <DataArray type=\"{tname}\" Name=\"scalars\" {fmt_attr}>\n{inline}\n        </DataArray>\n\
      </PointData>\n      <CellData>\n      </CellData>\n    </Piece>\n  </ImageData>\n",
        if header64 { "UInt64" } else { "UInt32" },
        if zlib { " compressor=\"vtkZLibDataCompressor\"" } else { "" },
        dims[0] - 1,
        dims[1] - 1,
        dims[2] - 1,
        spacing.x,
        spacing.y,
        spacing.z,
        dims[0] - 1,
        dims[1] - 1,
        dims[2] - 1,
    )?;
    if let Some(a) = appended {
        f.write_all(b"  <AppendedData encoding=\"raw\">\n   _")?;
        f.write_all(&a)?;
        f.write_all(b"\n  </AppendedData>\n")?;
    }
    f.write_all(b"</VTKFile>\n")?;
    f.flush()
}
