//! TensorBoard event files, written as a run goes, so `tensorboard --logdir RUN_DIR` (or
//! `wandb sync`) shows a live run.
//!
//! # Layout
//! - [`EventWriter`]: one `events.out.tfevents.*` file: TFRecord framing (length, masked
//!   CRC-32C of the length, the `Event` bytes, masked CRC-32C of them) around the protos of
//!   `coadapt_wire::tensorboard`; scalars, text (the text dashboard's string tensor) and images.
//!   It can be reopened cut back to a length a snapshot recorded, so a resumed run continues
//!   its curves without duplicated steps.
//! - [`read_events`]: the complete records of a file, stopping at a torn tail (what a reader
//!   sees of a file whose writer was killed mid-record).
//! - [`png_rgb`]: a PNG file of an RGB raster (stored deflate: no compression library), for
//!   image summaries.
//!
//! The format is small enough to write with prost (TensorBoard's own `RecordWriter` and
//! `tensorboard-rs` do the same framing); no crate of the registry writes it with the protos
//! kept in `coadapt-wire`, where this workspace keeps every prost type.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use coadapt_wire::tensorboard::{
    DataType, Event, Summary, SummaryMetadata, TensorProto, TensorShapeProto, event, summary, summary_metadata,
};
use prost::Message;

/// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), table-driven.
const CRC32C_TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0x82F6_3B78 } else { c >> 1 };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// CRC-32C of `data`.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c = CRC32C_TABLE[((c ^ u32::from(b)) & 0xff) as usize] ^ (c >> 8);
    }
    !c
}

/// TFRecord's masked CRC: rotated right by 15 bits plus a constant, so a CRC of data that
/// holds CRCs does not degenerate.
pub fn masked_crc32c(data: &[u8]) -> u32 {
    let c = crc32c(data);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord: `len: u64 LE`, `masked_crc(len)`, `data`, `masked_crc(data)` (all LE).
fn frame(data: &[u8], out: &mut Vec<u8>) {
    let len = (data.len() as u64).to_le_bytes();
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc32c(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc32c(data).to_le_bytes());
}

fn now() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().chars().filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_').collect::<String>())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".into())
}

fn named(e: io::Error, what: &str, path: &Path) -> io::Error {
    io::Error::new(e.kind(), format!("{what} {}: {e}", path.display()))
}

/// An event file being written.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: BufWriter<File>,
    /// Bytes written so far (a snapshot records it; a resume cuts back to it).
    bytes: u64,
    record: Vec<u8>,
}

impl EventWriter {
    /// A new file `dir/events.out.tfevents.<unix seconds>.<host>.<pid>.<suffix>` (TensorBoard
    /// reads any file with `tfevents` in its name; the suffix tells ours apart), starting with
    /// the `file_version` event TensorBoard expects.
    pub fn create(dir: &Path, suffix: &str) -> io::Result<Self> {
        let secs = now() as u64;
        let path = dir.join(format!("events.out.tfevents.{secs:010}.{}.{}.{suffix}", hostname(), std::process::id()));
        let file = File::create(&path).map_err(|e| named(e, "creating", &path))?;
        let mut w = Self { path, file: BufWriter::new(file), bytes: 0, record: Vec::new() };
        w.write(&Event { wall_time: now(), step: 0, what: Some(event::What::FileVersion("brain.Event:2".into())) })?;
        w.flush()?;
        Ok(w)
    }

    /// The file at `path` cut back to its first `bytes` (a length [`Self::bytes`] gave after
    /// a [`Self::sync`]), appended to from there: what came after is gone, so steps written
    /// again after a resume appear once.
    pub fn reopen(path: &Path, bytes: u64) -> io::Result<Self> {
        let f = File::options().write(true).open(path).map_err(|e| named(e, "opening", path))?;
        let len = f.metadata().map_err(|e| named(e, "reading", path))?.len();
        if len < bytes {
            return Err(named(
                io::Error::new(io::ErrorKind::InvalidData, format!("{len} bytes, shorter than the {bytes} a snapshot recorded")),
                "reopening",
                path,
            ));
        }
        f.set_len(bytes).map_err(|e| named(e, "cutting", path))?;
        f.sync_all().map_err(|e| named(e, "syncing", path))?;
        let file = File::options().append(true).open(path).map_err(|e| named(e, "opening", path))?;
        Ok(Self { path: path.to_path_buf(), file: BufWriter::new(file), bytes, record: Vec::new() })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes written so far, flushed or not.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    fn write(&mut self, e: &Event) -> io::Result<()> {
        self.record.clear();
        frame(&e.encode_to_vec(), &mut self.record);
        self.file.write_all(&self.record).map_err(|err| named(err, "writing", &self.path))?;
        self.bytes += self.record.len() as u64;
        Ok(())
    }

    fn summary(&mut self, step: i64, value: Vec<summary::Value>) -> io::Result<()> {
        self.write(&Event { wall_time: now(), step, what: Some(event::What::Summary(Summary { value })) })
    }

    /// Scalars `(tag, value)` at `step`, in one event. Non-finite values are skipped (TensorBoard
    /// would draw them as gaps anyway, and a NaN loss is reported elsewhere).
    pub fn scalars(&mut self, step: i64, values: &[(&str, f64)]) -> io::Result<()> {
        let value: Vec<summary::Value> = values
            .iter()
            .filter(|(_, v)| v.is_finite())
            .map(|(tag, v)| summary::Value {
                tag: (*tag).into(),
                metadata: None,
                value: Some(summary::value::Value::SimpleValue(*v as f32)),
            })
            .collect();
        if value.is_empty() {
            return Ok(());
        }
        self.summary(step, value)
    }

    /// A text summary (Markdown, as TensorBoard's text dashboard renders it).
    pub fn text(&mut self, tag: &str, step: i64, text: &str) -> io::Result<()> {
        let metadata = SummaryMetadata {
            plugin_data: Some(summary_metadata::PluginData { plugin_name: "text".into(), content: Vec::new() }),
            display_name: String::new(),
            summary_description: String::new(),
        };
        let tensor = TensorProto {
            dtype: DataType::DtString as i32,
            tensor_shape: Some(TensorShapeProto { dim: Vec::new() }),
            string_val: vec![text.as_bytes().to_vec()],
        };
        self.summary(
            step,
            vec![summary::Value { tag: tag.into(), metadata: Some(metadata), value: Some(summary::value::Value::Tensor(tensor)) }],
        )
    }

    /// An image summary of a PNG file `png` of `width x height` RGB pixels.
    pub fn image(&mut self, tag: &str, step: i64, png: Vec<u8>, width: u32, height: u32) -> io::Result<()> {
        let image = summary::Image { height: height as i32, width: width as i32, colorspace: 3, encoded_image_string: png };
        self.summary(step, vec![summary::Value { tag: tag.into(), metadata: None, value: Some(summary::value::Value::Image(image)) }])
    }

    /// Hands what is buffered to the OS: a reader (a live TensorBoard) sees it.
    pub fn flush(&mut self) -> io::Result<()> {
        self.file.flush().map_err(|e| named(e, "writing", &self.path))
    }

    /// Flushes and fsyncs (before a snapshot records [`Self::bytes`]).
    pub fn sync(&mut self) -> io::Result<()> {
        self.flush()?;
        self.file.get_ref().sync_all().map_err(|e| named(e, "syncing", &self.path))
    }
}

/// Why a file's records could not be read.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// A whole record whose CRC does not match (corruption, not a torn tail).
    #[error("record at byte {0}: its {1} CRC does not match")]
    Crc(u64, &'static str),
    #[error("record at byte {0}: not an Event")]
    Decode(u64),
}

/// The events of the complete records of `bytes`, and how many bytes they take. A record cut
/// short at the end (a writer killed mid-record) ends the list without an error, as
/// TensorBoard's reader waits for the rest of it.
pub fn read_events(bytes: &[u8]) -> Result<(Vec<Event>, u64), ReadError> {
    let mut at = 0usize;
    let mut out = Vec::new();
    while bytes.len() - at >= 12 {
        let len_bytes = &bytes[at..at + 8];
        let crc = u32::from_le_bytes([bytes[at + 8], bytes[at + 9], bytes[at + 10], bytes[at + 11]]);
        if crc != masked_crc32c(len_bytes) {
            return Err(ReadError::Crc(at as u64, "length"));
        }
        let len = u64::from_le_bytes(len_bytes.try_into().unwrap_or([0; 8]));
        let Some(end) = usize::try_from(len).ok().and_then(|l| (at + 12).checked_add(l)).and_then(|e| e.checked_add(4)) else {
            break;
        };
        if end > bytes.len() {
            break;
        }
        let data = &bytes[at + 12..end - 4];
        let crc = u32::from_le_bytes([bytes[end - 4], bytes[end - 3], bytes[end - 2], bytes[end - 1]]);
        if crc != masked_crc32c(data) {
            return Err(ReadError::Crc(at as u64, "data"));
        }
        out.push(Event::decode(data).map_err(|_| ReadError::Decode(at as u64))?);
        at = end;
    }
    Ok((out, at as u64))
}

/// A PNG file of `width x height` RGB pixels (`rgb`: rows top to bottom, 3 bytes a pixel):
/// IHDR, one IDAT of stored (uncompressed) deflate blocks, IEND.
pub fn png_rgb(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    assert_eq!(rgb.len(), width as usize * height as usize * 3, "rgb is not width x height x 3");
    let row = width as usize * 3;
    let mut raw = Vec::with_capacity((row + 1) * height as usize);
    for r in rgb.chunks_exact(row.max(1)).take(height as usize) {
        raw.push(0); // filter: none
        raw.extend_from_slice(r);
    }
    let mut z = vec![0x78, 0x01];
    let blocks: Vec<&[u8]> = if raw.is_empty() { vec![&[][..]] } else { raw.chunks(65_535).collect() };
    for (i, b) in blocks.iter().enumerate() {
        z.push(u8::from(i + 1 == blocks.len()));
        let n = b.len() as u16;
        z.extend_from_slice(&n.to_le_bytes());
        z.extend_from_slice(&(!n).to_le_bytes());
        z.extend_from_slice(b);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in &raw {
        a = (a + u32::from(x)) % 65_521;
        b = (b + a) % 65_521;
    }
    z.extend_from_slice(&((b << 16) | a).to_be_bytes());

    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8; 4], data: &[u8]| {
        png.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut h = crc32fast::Hasher::new();
        h.update(kind);
        h.update(data);
        png.extend_from_slice(kind);
        png.extend_from_slice(data);
        png.extend_from_slice(&h.finalize().to_be_bytes());
    };
    let mut ihdr = Vec::with_capacity(13);
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8 bits, RGB, deflate, no filter, no interlace
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", &z);
    chunk(b"IEND", &[]);
    png
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_the_standard_check_values() {
        // RFC 3720 (iSCSI) B.4 and the CRC catalogue's check value.
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xffu8; 32]), 0x62A8_AB43);
        let inc: Vec<u8> = (0..32).collect();
        assert_eq!(crc32c(&inc), 0x46DD_794E);
    }
}
