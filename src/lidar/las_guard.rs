//! The LAS 1.0–1.4 public header, the VLR and EVLR chain and the LAZ chunk table, read
//! with our own bounds before the `las` and `laz` crates see a file. The crates size
//! buffers from these fields (an EVLR's 64-bit length, the chunk table's entry count, a
//! chunk's point count); here every such field is checked against the file length, or
//! against [`MAX_LAZ_CHUNK_BYTES`], so a crafted header of a few hundred bytes is refused
//! by name instead of aborting the process. Layout: ASPRS LAS 1.4 R15 §2.4–2.6 and the
//! LASzip chunk table (formats/lidar/README.md, "Limits").

use super::{LidarError, Result};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// Largest decompressed LAZ chunk accepted (points × point record bytes): a chunk is
/// decompressed whole, so this bounds the reader's memory whatever the header says.
/// LASzip writes 50 000-point chunks (≈ 2–3 MB); COPC nodes stay well below this.
pub const MAX_LAZ_CHUNK_BYTES: u64 = 256 << 20;

/// Most extra bytes per point a LAZ file's items may declare. The decompressor keeps
/// arithmetic models for every extra byte (≈ 2.4 KB each in LASzip 2 items, ≈ 10 KB in
/// LASzip 3's four contexts) in each chunk it decompresses at once, one per thread: a
/// crafted 8 KB file declaring 60 000 took 640 MB a thread. Real files carry a few to a
/// few dozen extra bytes.
pub const MAX_LAZ_EXTRA_BYTES: u64 = 1024;

/// Bytes of a VLR header and of an EVLR header (LAS 1.4 R15 §2.5, §2.6).
const VLR_HEADER: u64 = 54;
const EVLR_HEADER: u64 = 60;
/// The LASzip VLR (user id, record id).
const LASZIP_USER_ID: &[u8] = b"laszip encoded";
const LASZIP_RECORD_ID: u16 = 22204;

/// The fields of the public header that locate and size everything else.
#[derive(Debug, Clone)]
pub(crate) struct PublicHeader {
    /// Minor version (1.x).
    pub minor: u8,
    pub header_size: u64,
    pub offset_to_point_data: u64,
    pub vlr_count: u64,
    /// Point data record format as stored (bit 7: LAZ).
    pub point_format: u8,
    pub record_len: u64,
    /// The legacy count, else (LAS 1.4) the 64-bit one, as the `las` crate takes it.
    pub point_count: u64,
    /// LAS 1.4: start of the first EVLR and their number (0, 0 when none).
    pub first_evlr: u64,
    pub evlr_count: u64,
}

impl PublicHeader {
    pub fn compressed(&self) -> bool {
        self.point_format & 0x80 != 0
    }
}

fn too_large(path: &Path, what: String, claimed: u64, limit: u64, basis: String) -> LidarError {
    LidarError::TooLarge {
        path: path.to_path_buf(),
        what,
        claimed,
        limit,
        basis,
    }
}

fn truncated(path: &Path, what: &str) -> LidarError {
    LidarError::Las {
        path: path.to_path_buf(),
        message: format!("truncated: the file ends inside {what}"),
    }
}

fn le_u16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn le_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn le_u64(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// `N` bytes at `at`, or a "truncated" error naming `what`.
fn read_at<const N: usize>(path: &Path, f: &mut File, at: u64, what: &str) -> Result<[u8; N]> {
    let mut b = [0u8; N];
    f.seek(SeekFrom::Start(at))
        .and_then(|_| f.read_exact(&mut b))
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => truncated(path, what),
            _ => LidarError::io(path, e),
        })?;
    Ok(b)
}

/// Reads the public header. `None` when the file is not LAS (no `LASF`) or ends inside
/// the header: the `las` crate reports those as it always has.
pub(crate) fn public_header(f: &mut File, file_len: u64) -> std::io::Result<Option<PublicHeader>> {
    let mut b = [0u8; 375];
    let n = (file_len.min(375)) as usize;
    f.seek(SeekFrom::Start(0))?;
    f.read_exact(&mut b[..n])?;
    if n < 227 || &b[0..4] != b"LASF" {
        return Ok(None);
    }
    let minor = b[25];
    if minor >= 4 && n < 375 {
        return Ok(None);
    }
    let legacy = u64::from(le_u32(&b, 107));
    let (first_evlr, evlr_count, count64) = if minor >= 4 {
        (le_u64(&b, 235), u64::from(le_u32(&b, 243)), le_u64(&b, 247))
    } else {
        (0, 0, 0)
    };
    Ok(Some(PublicHeader {
        minor,
        header_size: u64::from(le_u16(&b, 94)),
        offset_to_point_data: u64::from(le_u32(&b, 96)),
        vlr_count: u64::from(le_u32(&b, 100)),
        point_format: b[104],
        record_len: u64::from(le_u16(&b, 105)),
        point_count: if legacy != 0 { legacy } else { count64 },
        first_evlr,
        evlr_count,
    }))
}

/// Checks the header, VLRs, EVLRs and (LAZ) the chunk table against the file length.
/// `None` when the file is not LAS or ends inside its header (left to the `las` crate).
pub(crate) fn guard(path: &Path, f: &mut File, file_len: u64) -> Result<Option<PublicHeader>> {
    let h = match public_header(f, file_len).map_err(|e| LidarError::io(path, e))? {
        Some(h) => h,
        None => return Ok(None),
    };
    // The `las` crate reads the VLRs after the version's whole header however small the
    // header size field is; a smaller field would have the checks below read elsewhere.
    let least = match h.minor {
        0..=2 => 227,
        3 => 235,
        _ => 375,
    };
    if h.header_size < least {
        return Err(LidarError::Las {
            path: path.to_path_buf(),
            message: format!(
                "header size {} bytes is smaller than a LAS 1.{} header ({least} bytes)",
                h.header_size, h.minor
            ),
        });
    }
    // The `las` crate adds the point data's length (count × record length) to its start
    // unchecked: a count beyond what a 64-bit offset can address overflows (a panic where
    // overflow checks are on). A LAZ file's count is checked against its chunks below,
    // but only when it has a chunk table.
    let most = (u64::MAX - h.offset_to_point_data) / h.record_len.max(1);
    if h.point_count > most {
        return Err(too_large(
            path,
            "point count".into(),
            h.point_count,
            most,
            format!(
                "the {}-byte point records a 64-bit file offset can address",
                h.record_len
            ),
        ));
    }
    for (what, at) in [
        ("header size", h.header_size),
        ("offset to point data", h.offset_to_point_data),
    ] {
        if at > file_len {
            return Err(too_large(
                path,
                what.into(),
                at,
                file_len,
                "the file length".into(),
            ));
        }
    }

    // VLRs: each header is 54 bytes, so the count is bounded before any is read.
    let room = file_len.saturating_sub(h.header_size);
    if h.vlr_count.saturating_mul(VLR_HEADER) > room {
        return Err(too_large(
            path,
            "VLR count".into(),
            h.vlr_count,
            room / VLR_HEADER,
            format!("what the {room} bytes after the header can hold"),
        ));
    }
    let mut laszip = None;
    let mut at = h.header_size;
    for i in 0..h.vlr_count {
        let v: [u8; 54] = read_at(path, f, at, &format!("VLR {i}"))?;
        let len = u64::from(le_u16(&v, 20));
        let end = at + VLR_HEADER + len;
        if end > file_len {
            return Err(too_large(
                path,
                format!("VLR {i} length"),
                len,
                file_len.saturating_sub(at + VLR_HEADER),
                "the bytes left in the file".into(),
            ));
        }
        let user = &v[2..18];
        let user = &user[..user.iter().position(|&c| c == 0).unwrap_or(16)];
        if user == LASZIP_USER_ID && le_u16(&v, 18) == LASZIP_RECORD_ID {
            let mut data = vec![0u8; len as usize];
            f.read_exact(&mut data)
                .map_err(|_| truncated(path, "the LASzip VLR"))?;
            laszip = Some(data);
        }
        at = end;
    }

    // EVLRs (LAS 1.4): a 64-bit length each, which the `las` crate allocates as given.
    if h.evlr_count > 0 && h.first_evlr > 0 {
        if h.first_evlr > file_len {
            return Err(too_large(
                path,
                "start of the first EVLR".into(),
                h.first_evlr,
                file_len,
                "the file length".into(),
            ));
        }
        let room = file_len - h.first_evlr;
        if h.evlr_count.saturating_mul(EVLR_HEADER) > room {
            return Err(too_large(
                path,
                "EVLR count".into(),
                h.evlr_count,
                room / EVLR_HEADER,
                format!("what the last {room} bytes of the file can hold"),
            ));
        }
        let mut at = h.first_evlr;
        for i in 0..h.evlr_count {
            let v: [u8; 60] = read_at(path, f, at, &format!("EVLR {i}"))?;
            let len = le_u64(&v, 20);
            let left = file_len.saturating_sub(at + EVLR_HEADER);
            if len > left {
                return Err(too_large(
                    path,
                    format!("EVLR {i} length"),
                    len,
                    left,
                    "the bytes left in the file".into(),
                ));
            }
            at += EVLR_HEADER + len;
        }
    }

    // Without a LASzip VLR the `las` crate refuses a compressed file by name.
    if let (true, Some(vlr)) = (h.compressed(), laszip) {
        check_chunk_table(path, f, file_len, &h, &vlr)?;
    }
    Ok(Some(h))
}

/// Checks the LAZ chunk table's entry count, byte counts and point counts against the
/// file and [`MAX_LAZ_CHUNK_BYTES`], and the header's point count against what the
/// chunks can hold.
fn check_chunk_table(
    path: &Path,
    f: &mut File,
    file_len: u64,
    h: &PublicHeader,
    vlr_data: &[u8],
) -> Result<()> {
    let bad = |m: String| LidarError::Las {
        path: path.to_path_buf(),
        message: m,
    };
    let vlr = laz::LazVlr::from_buffer(vlr_data).map_err(|e| bad(format!("LASzip VLR: {e}")))?;
    // The decompressor fills buffers sized by the header's record length with records of
    // the VLR's item sizes; laz 0.12 asserts (in release builds too) that they agree. The
    // sum is taken here in u64: laz's `items_size` adds the u16 sizes in u16, which
    // overflows on crafted items (a wrapped sum could even match).
    let items: u64 = vlr.items().iter().map(|i| u64::from(i.size())).sum();
    if items != h.record_len {
        return Err(bad(format!(
            "the LASzip VLR's items make {items}-byte point records but the header's point \
             record length is {} bytes",
            h.record_len
        )));
    }
    let extra: u64 = vlr
        .items()
        .iter()
        .filter(|i| {
            matches!(
                i.item_type(),
                laz::LazItemType::Byte(_) | laz::LazItemType::Byte14(_)
            )
        })
        .map(|i| u64::from(i.size()))
        .sum();
    if extra > MAX_LAZ_EXTRA_BYTES {
        return Err(too_large(
            path,
            "LAZ extra bytes per point".into(),
            extra,
            MAX_LAZ_EXTRA_BYTES,
            "what the decompressor keeps models for".into(),
        ));
    }
    let point_bytes = items.max(1);
    let chunk_limit = MAX_LAZ_CHUNK_BYTES / point_bytes;
    let variable = vlr.uses_variable_size_chunks();
    if !variable && u64::from(vlr.chunk_size()) > chunk_limit {
        return Err(too_large(
            path,
            "LAZ chunk size (points)".into(),
            vlr.chunk_size().into(),
            chunk_limit,
            format!(
                "{} MiB of {point_bytes}-byte points per chunk",
                MAX_LAZ_CHUNK_BYTES >> 20
            ),
        ));
    }
    // The point data starts with the chunk table's offset; a writer that could not seek
    // back leaves it unset and repeats it in the file's last 8 bytes (as laz-rs reads it).
    let data_start = h.offset_to_point_data;
    let mut table = i64::from_le_bytes(read_at(path, f, data_start, "the LAZ chunk table offset")?);
    if table <= data_start as i64 && file_len >= 8 {
        table = i64::from_le_bytes(read_at(
            path,
            f,
            file_len - 8,
            "the LAZ chunk table offset",
        )?);
    }
    if table <= data_start as i64 {
        // No chunk table: laz-rs refuses the file by name.
        return Ok(());
    }
    let table = table as u64;
    if table.saturating_add(8) > file_len {
        return Err(bad(format!(
            "truncated: the LAZ chunk table at byte {table} lies beyond the end of the file \
             ({file_len} bytes)"
        )));
    }
    let t: [u8; 8] = read_at(path, f, table, "the LAZ chunk table")?;
    let chunks = u64::from(le_u32(&t, 4));
    // Every chunk takes at least one byte of the compressed point data.
    let data_bytes = table.saturating_sub(data_start + 8);
    if chunks > data_bytes {
        return Err(too_large(
            path,
            "LAZ chunk table entry count".into(),
            chunks,
            data_bytes,
            "the bytes of compressed point data".into(),
        ));
    }
    f.seek(SeekFrom::Start(data_start))
        .map_err(|e| LidarError::io(path, e))?;
    let entries = laz::laszip::ChunkTable::read_from(&mut *f, &vlr)
        .map_err(|e| bad(format!("LAZ chunk table: {e}")))?;
    let mut capacity = 0u64;
    let mut bytes = 0u64;
    for (i, e) in entries.as_ref().iter().enumerate() {
        if variable && e.point_count > chunk_limit {
            return Err(too_large(
                path,
                format!("LAZ chunk {i} point count"),
                e.point_count,
                chunk_limit,
                format!(
                    "{} MiB of {point_bytes}-byte points per chunk",
                    MAX_LAZ_CHUNK_BYTES >> 20
                ),
            ));
        }
        capacity = capacity.saturating_add(e.point_count);
        bytes = bytes.saturating_add(e.byte_count);
    }
    if bytes > data_bytes {
        return Err(too_large(
            path,
            "LAZ chunk table byte count".into(),
            bytes,
            data_bytes,
            "the bytes of compressed point data".into(),
        ));
    }
    if h.point_count > capacity {
        return Err(too_large(
            path,
            "point count".into(),
            h.point_count,
            capacity,
            format!("what the {} LAZ chunks can hold", entries.len()),
        ));
    }
    check_layers(
        path,
        f,
        &vlr,
        h.record_len,
        data_start + 8,
        entries.as_ref(),
    )
}

/// Byte counts a LASzip 3 item keeps in each chunk's header, one per layer (laz's
/// `read_layers_sizes`); the items of point formats 0–5 are not layered.
fn layers(item: &laz::LazItem) -> u64 {
    match item.item_type() {
        laz::LazItemType::Point14 => 9,
        laz::LazItemType::RGB14 | laz::LazItemType::WavePacket14 => 1,
        laz::LazItemType::RGBNIR14 => 2,
        laz::LazItemType::Byte14(_) => u64::from(item.size()),
        _ => 0,
    }
}

/// A LASzip 3 chunk is the first point raw, the chunk's point count, the byte count of
/// every layer, then the layers; laz sizes a buffer from each byte count before reading
/// the layer (a 2.8 KB file claiming a 4 GB layer took 4 GB). Every chunk's layers must
/// fit in the chunk's bytes (the chunk table's, checked against the file above).
fn check_layers(
    path: &Path,
    f: &mut File,
    vlr: &laz::LazVlr,
    record_len: u64,
    first_chunk: u64,
    entries: &[laz::laszip::ChunkTableEntry],
) -> Result<()> {
    let layered: u64 = vlr.items().iter().map(layers).sum();
    if layered == 0 {
        return Ok(());
    }
    let head = record_len + 4 + 4 * layered;
    let mut start = first_chunk;
    let mut sizes = vec![0u8; 4 * layered as usize];
    for (i, e) in entries.iter().enumerate() {
        // A chunk too short for its header fails in laz's reader, naming the file.
        if e.point_count > 0 && e.byte_count >= head {
            f.seek(SeekFrom::Start(start + record_len + 4))
                .and_then(|_| f.read_exact(&mut sizes))
                .map_err(|x| LidarError::io(path, x))?;
            let claimed: u64 = sizes.chunks_exact(4).map(|b| u64::from(le_u32(b, 0))).sum();
            let room = e.byte_count - head;
            if claimed > room {
                return Err(too_large(
                    path,
                    format!("LAZ chunk {i} layer bytes"),
                    claimed,
                    room,
                    "the bytes of the chunk after its header".into(),
                ));
            }
        }
        start = start.saturating_add(e.byte_count);
    }
    Ok(())
}
