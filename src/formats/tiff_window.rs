//! Windows of an uncompressed TIFF read straight from the file: the layout scanners write
//! (8 or 16 bits a sample, grey or RGB(A), samples interleaved, in strips or tiles, no
//! compression), where the bytes of a pixel row of a strip or tile lie at a known offset.
//! A window of a film scan (the few square millimetres around a fiducial mark) is then a
//! few hundred reads of its own bytes, not a decode of the 10⁸-pixel scan.
//!
//! The IFD is parsed by the `tiff` crate (the `image` crate's TIFF decoder), which also
//! enforces its limits on tag sizes. Every strip or tile must lie within the file with the
//! bytes its pixels need, checked when the file is opened: a truncated scan is refused
//! whole, as decoding it whole refuses it, even when the windows read would lie in what is
//! left. Grey values are those [`super::image_open::decode_grey`] gives the same file.

use super::image_open::luma;
use super::{FormatError, Result};
use std::fs::File;
use std::io::{Read, Seek};
use std::path::{Path, PathBuf};
use tiff::decoder::{ChunkType, Decoder};
use tiff::tags::{ByteOrder, Tag};

/// The sample layout of a pixel, as [`super::image_open::decode_grey`] reduces it to grey.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layout {
    Grey,
    GreyAlpha,
    Rgb,
}

/// Where the pixels of an uncompressed TIFF lie in its file.
#[derive(Debug)]
struct Geometry {
    width: usize,
    height: usize,
    /// Strip or tile size in pixels (a strip is as wide as the image).
    chunk_width: usize,
    chunk_height: usize,
    /// Chunks across the image (1 for strips).
    across: usize,
    offsets: Vec<u64>,
    layout: Layout,
    samples: usize,
    sixteen: bool,
    big_endian: bool,
}

/// What [`geometry`] found: `Ok(None)` a TIFF not read here, `Err(None)` an IFD the
/// `tiff` crate cannot read (both read another way), `Err(Some)` a truncated or corrupt
/// file.
type Found = std::result::Result<Option<Geometry>, Option<FormatError>>;

/// An uncompressed TIFF open for window reads.
#[derive(Debug)]
pub struct TiffWindows {
    path: PathBuf,
    file: File,
    g: Geometry,
    /// The bytes of one read, kept for the next.
    row: Vec<u8>,
}

/// The geometry of the first image of `dec` (a file of `file_len` bytes), its strips or
/// tiles checked against the file.
fn geometry<R: Read + Seek>(path: &Path, dec: &mut Decoder<R>, file_len: u64) -> Found {
    let unread = |e: tiff::TiffError| {
        tracing::debug!(path = %path.display(), "TIFF not read by windows: {e}");
        None
    };
    let mut tag = |t: Tag, default: u16| -> std::result::Result<u16, Option<FormatError>> {
        Ok(dec
            .find_tag_unsigned::<u16>(t)
            .map_err(unread)?
            .unwrap_or(default))
    };
    let compression = tag(Tag::Compression, 1)?;
    let planar = tag(Tag::PlanarConfiguration, 1)?;
    let predictor = tag(Tag::Predictor, 1)?;
    let photometric = tag(Tag::PhotometricInterpretation, u16::MAX)?;
    let spp = tag(Tag::SamplesPerPixel, 1)?;
    let formats = dec
        .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
        .map_err(unread)?
        .unwrap_or_default();
    let (w, h) = dec.dimensions().map_err(unread)?;
    let (width, height) = (w as usize, h as usize);
    if width == 0 || height == 0 {
        return Ok(None);
    }
    let strips = dec.get_chunk_type() == ChunkType::Strip;
    let (chunk_width, chunk_height, across, offsets_tag, counts_tag) = match dec.get_chunk_type() {
        ChunkType::Strip => {
            let rows = (dec.chunk_dimensions().1 as usize).clamp(1, height);
            (width, rows, 1, Tag::StripOffsets, Tag::StripByteCounts)
        }
        ChunkType::Tile => {
            let (tw, th) = dec.chunk_dimensions();
            let (tw, th) = (tw as usize, th as usize);
            if tw == 0 || th == 0 {
                return Ok(None);
            }
            (
                tw,
                th,
                width.div_ceil(tw),
                Tag::TileOffsets,
                Tag::TileByteCounts,
            )
        }
    };
    let mut offsets = dec.get_tag_u64_vec(offsets_tag).map_err(unread)?;
    let counts = dec.get_tag_u64_vec(counts_tag).map_err(unread)?;
    let corrupt = |m: String| {
        Some(FormatError::invalid(
            path,
            format!("truncated or corrupt TIFF: {m}"),
        ))
    };
    // A planar file stores each sample's plane in strips or tiles of its own.
    let planes = if planar == 2 {
        usize::from(spp.max(1))
    } else {
        1
    };
    let chunks = across.saturating_mul(height.div_ceil(chunk_height));
    let stored = chunks.saturating_mul(planes);
    if offsets.len() < stored || counts.len() < stored {
        return Err(corrupt(format!(
            "{} offsets and {} byte counts for {stored} strips or tiles",
            offsets.len(),
            counts.len()
        )));
    }
    for k in 0..stored {
        if offsets[k]
            .checked_add(counts[k])
            .is_none_or(|end| end > file_len)
        {
            return Err(corrupt(format!(
                "strip or tile {k} of {} bytes at byte {} ends beyond the file's {file_len} \
                 bytes",
                counts[k], offsets[k]
            )));
        }
    }
    if compression != 1 || planar != 1 || predictor != 1 || formats.iter().any(|&f| f != 1) {
        return Ok(None);
    }
    use tiff::ColorType as C;
    let (layout, samples, bits) = match (photometric, dec.colortype().map_err(unread)?) {
        (1, C::Gray(b)) => (Layout::Grey, 1, b),
        (1, C::GrayA(b)) => (Layout::GreyAlpha, 2, b),
        (2, C::RGB(b)) => (Layout::Rgb, 3, b),
        (2, C::RGBA(b)) => (Layout::Rgb, 4, b),
        _ => return Ok(None),
    };
    if (bits != 8 && bits != 16) || usize::from(spp) != samples {
        return Ok(None);
    }
    let pixel_bytes = samples * usize::from(bits / 8);
    for (k, &bytes) in counts.iter().enumerate().take(chunks) {
        // A strip's last rows may be left out at the image's bottom; a tile is whole.
        let rows = if strips {
            chunk_height.min(height - k * chunk_height)
        } else {
            chunk_height
        };
        // Saturating: a tile's size comes from the file (up to 2³² a side).
        let need = (rows as u64)
            .saturating_mul(chunk_width as u64)
            .saturating_mul(pixel_bytes as u64);
        if bytes < need {
            return Err(corrupt(format!(
                "strip or tile {k} holds {bytes} bytes, its pixels need {need}"
            )));
        }
    }
    offsets.truncate(chunks);
    Ok(Some(Geometry {
        width,
        height,
        chunk_width,
        chunk_height,
        across,
        offsets,
        layout,
        samples,
        sixteen: bits == 16,
        big_endian: dec.byte_order() == ByteOrder::BigEndian,
    }))
}

impl TiffWindows {
    /// Opens `path` for window reads when it is an uncompressed TIFF of a layout read here;
    /// `None` for another TIFF (compressed, planar, another sample type) or one whose IFD
    /// the `tiff` crate cannot read, which the caller reads another way. A TIFF with a
    /// strip or tile beyond the file's end is refused, whatever its layout.
    pub fn open(path: &Path) -> Result<Option<Self>> {
        let (file, meta) = super::input::open_file(path, super::input::Links::Follow)?;
        let ifd = file.try_clone().map_err(|e| FormatError::io(path, e))?;
        let Ok(mut dec) = Decoder::new(std::io::BufReader::new(ifd)) else {
            return Ok(None);
        };
        match geometry(path, &mut dec, meta.len()) {
            Ok(Some(g)) => Ok(Some(Self {
                path: path.to_path_buf(),
                file,
                g,
                row: Vec::new(),
            })),
            Ok(None) | Err(None) => Ok(None),
            Err(Some(e)) => Err(e),
        }
    }

    /// Width and height in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.g.width, self.g.height)
    }

    /// Grey values of the window `(col, row, width, height)` (inside the image), row-major,
    /// appended to `out`.
    pub fn read(
        &mut self,
        (c, r, w, h): (usize, usize, usize, usize),
        out: &mut Vec<f32>,
    ) -> Result<()> {
        let g = &self.g;
        if w == 0 || h == 0 || c + w > g.width || r + h > g.height {
            return Err(FormatError::invalid(
                &self.path,
                format!(
                    "window {w}×{h} at ({c}, {r}) is outside the {}×{} image",
                    g.width, g.height
                ),
            ));
        }
        let pb = g.pixel_bytes();
        for y in r..r + h {
            let (ty, y_in) = (y / g.chunk_height, y % g.chunk_height);
            let mut x = c;
            while x < c + w {
                let tx = x / g.chunk_width;
                let x_end = ((tx + 1) * g.chunk_width).min(c + w);
                let chunk = ty * g.across + tx;
                let at = g.offsets[chunk]
                    + ((y_in * g.chunk_width + x - tx * g.chunk_width) * pb) as u64;
                let n = (x_end - x) * pb;
                self.row.resize(n, 0);
                read_at(&mut self.file, at, &mut self.row)
                    .map_err(|e| FormatError::io(&self.path, e))?;
                append_grey(g, &self.row, out);
                x = x_end;
            }
        }
        Ok(())
    }
}

impl Geometry {
    /// Bytes of one pixel in the file.
    fn pixel_bytes(&self) -> usize {
        self.samples * if self.sixteen { 2 } else { 1 }
    }
}

/// Appends the grey values of the pixels in `row` (bytes as the file holds them).
fn append_grey(g: &Geometry, row: &[u8], out: &mut Vec<f32>) {
    let (sixteen, big_endian) = (g.sixteen, g.big_endian);
    // Most scans: 8-bit grey, widened as a plain loop the compiler vectorises.
    if g.layout == Layout::Grey && !sixteen {
        out.extend(row.iter().map(|&b| f32::from(b)));
        return;
    }
    let s = |b: &[u8], k: usize| -> f32 {
        if sixteen {
            let v = [b[2 * k], b[2 * k + 1]];
            f32::from(if big_endian {
                u16::from_be_bytes(v)
            } else {
                u16::from_le_bytes(v)
            })
        } else {
            f32::from(b[k])
        }
    };
    out.extend(row.chunks_exact(g.pixel_bytes()).map(|b| match g.layout {
        Layout::Grey => s(b, 0),
        // As decode_grey: 8-bit grey with alpha through the luma weights, 16-bit as is.
        Layout::GreyAlpha if sixteen => s(b, 0),
        Layout::GreyAlpha => {
            let l = s(b, 0);
            luma(l, l, l)
        }
        Layout::Rgb => luma(s(b, 0), s(b, 1), s(b, 2)),
    }));
}

/// Fills `buf` from byte `at` of `file`: one system call where positioned reads exist (a
/// window is hundreds of them).
#[cfg(unix)]
fn read_at(file: &mut File, at: u64, buf: &mut [u8]) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, at)
}

#[cfg(not(unix))]
fn read_at(file: &mut File, at: u64, buf: &mut [u8]) -> std::io::Result<()> {
    file.seek(std::io::SeekFrom::Start(at))?;
    file.read_exact(buf)
}
