//! The two halves of a snapshot's contents: named `f32` arrays in one binary file (each with
//! its length and CRC-32, written and read at disk speed without per-value conversion) and
//! everything else as JSON values by name.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Write};
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::SnapshotError;

/// Where one array sits in `arrays.bin`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArrayEntry {
    pub offset: u64,
    /// Values (not bytes).
    pub len: u64,
    pub crc32: u32,
}

/// The contents being written: arrays stream to the binary file as they come.
#[derive(Debug)]
pub struct StateOut {
    bin: BufWriter<File>,
    pos: u64,
    arrays: BTreeMap<String, ArrayEntry>,
    values: serde_json::Map<String, serde_json::Value>,
}

impl StateOut {
    pub(super) fn create(bin: &Path) -> io::Result<Self> {
        Ok(Self {
            bin: BufWriter::with_capacity(1 << 20, File::create(bin)?),
            pos: 0,
            arrays: BTreeMap::new(),
            values: serde_json::Map::new(),
        })
    }

    /// Writes the array `name` (its values in native order: snapshots are refused on a
    /// machine of the other endianness, see [`super::Manifest`]).
    pub fn f32s(&mut self, name: &str, v: &[f32]) -> io::Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(v);
        self.bin.write_all(bytes)?;
        let e = ArrayEntry { offset: self.pos, len: v.len() as u64, crc32: crc32fast::hash(bytes) };
        self.pos += bytes.len() as u64;
        if self.arrays.insert(name.to_string(), e).is_some() {
            return Err(io::Error::other(format!("snapshot array {name} written twice")));
        }
        Ok(())
    }

    /// Stores `v` under `name`.
    pub fn put<T: Serialize + ?Sized>(&mut self, name: &str, v: &T) -> io::Result<()> {
        let v = serde_json::to_value(v).map_err(|e| io::Error::other(format!("snapshot value {name}: {e}")))?;
        self.values.insert(name.to_string(), v);
        Ok(())
    }

    /// Flushes and fsyncs the binary file; returns the index and values for `state.json`.
    pub(super) fn finish(self) -> io::Result<StateIndex> {
        let f = self.bin.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        Ok(StateIndex { arrays: self.arrays, values: self.values })
    }
}

/// `state.json`: the arrays' index and the named values.
#[derive(Debug, Serialize, Deserialize)]
pub struct StateIndex {
    pub arrays: BTreeMap<String, ArrayEntry>,
    pub values: serde_json::Map<String, serde_json::Value>,
}

/// A snapshot's contents, every array read and checked against its CRC before anything is
/// restored from it.
#[derive(Debug)]
pub struct StateIn {
    arrays: BTreeMap<String, Vec<f32>>,
    values: serde_json::Map<String, serde_json::Value>,
}

impl StateIn {
    pub(super) fn read(bin: &Path, index: StateIndex, bin_bytes: u64) -> Result<Self, SnapshotError> {
        let corrupt = |why: String| SnapshotError::Corrupt(format!("arrays.bin: {why}"));
        let mut entries: Vec<(&String, &ArrayEntry)> = index.arrays.iter().collect();
        entries.sort_by_key(|(_, e)| e.offset);
        let mut r = BufReader::with_capacity(1 << 20, File::open(bin)?);
        let mut pos = 0u64;
        let mut arrays = BTreeMap::new();
        for (name, e) in entries {
            let bytes = e.len.checked_mul(4).ok_or_else(|| corrupt(format!("array {name}: length {} overflows", e.len)))?;
            if e.offset != pos || e.offset.saturating_add(bytes) > bin_bytes {
                return Err(corrupt(format!(
                    "array {name} at {} ({} bytes) does not follow the previous one or passes the end",
                    e.offset, bytes
                )));
            }
            let n = usize::try_from(e.len).map_err(|_| corrupt(format!("array {name}: length {} too large", e.len)))?;
            let mut v = vec![0f32; n];
            r.read_exact(bytemuck::cast_slice_mut(&mut v)).map_err(|err| corrupt(format!("array {name}: {err}")))?;
            let crc = crc32fast::hash(bytemuck::cast_slice(&v));
            if crc != e.crc32 {
                return Err(corrupt(format!("array {name}: checksum {crc:08x}, expected {:08x}", e.crc32)));
            }
            pos += bytes;
            arrays.insert(name.clone(), v);
        }
        if pos != bin_bytes {
            return Err(corrupt(format!("{} bytes after the last array", bin_bytes - pos)));
        }
        Ok(Self { arrays, values: index.values })
    }

    /// Takes the array `name`, which must have `len` values.
    pub fn f32s(&mut self, name: &str, len: usize) -> Result<Vec<f32>, SnapshotError> {
        let v = self.arrays.remove(name).ok_or_else(|| SnapshotError::Mismatch(format!("no array {name}")))?;
        if v.len() != len {
            return Err(SnapshotError::Mismatch(format!("array {name} has {} values, this run needs {len}", v.len())));
        }
        Ok(v)
    }

    /// Takes the array `name`, whatever its length.
    pub fn f32s_any(&mut self, name: &str) -> Result<Vec<f32>, SnapshotError> {
        self.arrays.remove(name).ok_or_else(|| SnapshotError::Mismatch(format!("no array {name}")))
    }

    /// The value `name`.
    pub fn get<T: DeserializeOwned>(&self, name: &str) -> Result<T, SnapshotError> {
        let v = self.values.get(name).ok_or_else(|| SnapshotError::Mismatch(format!("no value {name}")))?;
        serde_json::from_value(v.clone()).map_err(|e| SnapshotError::Mismatch(format!("value {name}: {e}")))
    }
}
