//! The manifest: the index's commit point. It names every committed part file — with its row
//! count, size and checksum — the codebook the descriptors were made with (embedded, so the
//! switch to a new codebook is one atomic rename), and the hash of the settings that produced
//! the diagrams. A file it does not name is not part of the index: a writer killed mid-chunk
//! leaves such files behind, and the next writer deletes them. The format is documented as a
//! JSON Schema in `schemas/manifest.json`.

use crate::error::{Error, Result, ResultExt};
use crate::methods::{IMPORTED, Method, MethodKind, Methods, Registered};
use crate::vectorize::codebook::Codebook;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The `format` tag of a manifest.
pub(crate) const FORMAT: &str = "toporec-index";
/// The manifest layout this toporec writes (it reads every older one since 2).
pub(crate) const MANIFEST_VERSION: u64 = 3;

/// One committed part file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// `scans`, `diagrams` or `descriptors`.
    pub table: String,
    /// For `descriptors`: the method whose descriptors the file holds (absent: `toporec`, as
    /// in manifests before version 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<String>,
    /// The session (the partition).
    pub session: String,
    /// Path relative to the index folder.
    pub path: String,
    /// Rows in the file.
    pub rows: u64,
    /// Size in bytes.
    pub bytes: u64,
    /// xxh3-64 of the file's bytes, 16 hex digits.
    pub xxh3: String,
}

impl MethodEntry {
    /// The entry of a method (its kind, parameters, length and id).
    pub fn of(m: &Method) -> Self {
        MethodEntry { kind: m.kind_name().into(), params: m.params(), length: m.len(), id: m.id() }
    }

    /// The entries of a pipeline's computed methods, by name.
    pub fn of_computed(methods: &Methods) -> BTreeMap<String, MethodEntry> {
        methods.computed.iter().map(|m| (m.name.clone(), Self::of(m))).collect()
    }

    /// The method this entry records, named `name`; `None` for a kind this toporec does not
    /// know.
    pub fn method(&self, name: &str) -> Option<Method> {
        let kind = match Registered::of(&self.kind) {
            Some(entry) => entry.stored_method(&self.params).ok()?.kind,
            None if self.kind == IMPORTED => MethodKind::Imported {
                length: self.length,
                source: self.params.get("source").and_then(|s| s.as_str()).unwrap_or_default().to_string(),
            },
            None => return None,
        };
        Some(Method { name: name.to_string(), kind })
    }
}

impl FileEntry {
    /// The method of a descriptors file (`toporec` when the entry names none).
    pub fn method_name(&self) -> &str {
        self.method.as_deref().unwrap_or(crate::methods::TOPOREC)
    }
}

/// Scan counts over the whole index, by status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    /// Every scan row.
    pub scans: u64,
    /// Status ok.
    pub ok: u64,
    /// Status skipped.
    pub skipped: u64,
    /// Status error.
    pub errors: u64,
}

/// The manifest of an index.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always `FORMAT`.
    pub format: String,
    /// `MANIFEST_VERSION`.
    pub manifest_version: u64,
    /// The toporec version of the last commit.
    pub toporec_version: String,
    /// The table layout version (`toporec.schema_version` of every file).
    pub schema_version: String,
    /// Commits so far; each commit adds one.
    pub generation: u64,
    /// Hash of the preprocess and persistence settings every diagram was made with.
    pub settings_hash: String,
    /// The next free part number (file names are `part-<n>.parquet`, never reused).
    pub next_part: u64,
    /// Scan counts.
    pub counts: Counts,
    /// The codebook id, once there is one.
    pub codebook_id: Option<String>,
    /// The descriptor length, once there is a codebook.
    pub descriptor_length: Option<usize>,
    /// The codebook itself (its `codebook.json` form), once there is one.
    pub codebook: Option<serde_json::Value>,
    /// The descriptor methods besides the TopoRec one: name → what made the descriptors
    /// (parameters, length). Methods computed from raw scans ([`crate::methods::REGISTRY`]) and
    /// imported ones.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub methods: BTreeMap<String, MethodEntry>,
    /// The effective pipeline the index was made with (TOML: absolute paths, every default
    /// filled in), once a run has recorded it; `pipeline.toml` beside it is a copy.
    #[serde(default)]
    pub pipeline: Option<String>,
    /// Where the scans' poses came from, as the last run joined them: one entry per pose file
    /// or log, with the fingerprint of the poses the rows carry.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub poses: Vec<crate::sources::poses::PoseOrigin>,
    /// The committed part files, in commit order.
    pub files: Vec<FileEntry>,
}

/// A descriptor method of an index, besides the TopoRec one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MethodEntry {
    /// A computed method's name ([`crate::methods::REGISTRY`]), or `imported`.
    pub kind: String,
    /// Its parameters (computed methods) or where the vectors came from (imported ones).
    pub params: serde_json::Value,
    /// Descriptor length.
    pub length: usize,
    /// The id every row of its files carries (in the `codebook_id` column): a hash of `kind`
    /// and `params`.
    pub id: String,
}

impl Manifest {
    /// The manifest of an empty index made with `settings_hash`.
    pub fn empty(settings_hash: &str) -> Self {
        Manifest {
            format: FORMAT.into(),
            manifest_version: MANIFEST_VERSION,
            toporec_version: env!("CARGO_PKG_VERSION").into(),
            schema_version: crate::sinks::schema::SCHEMA_VERSION.into(),
            generation: 0,
            settings_hash: settings_hash.into(),
            next_part: 0,
            counts: Counts::default(),
            codebook_id: None,
            descriptor_length: None,
            codebook: None,
            methods: BTreeMap::new(),
            pipeline: None,
            poses: Vec::new(),
            files: Vec::new(),
        }
    }

    /// Reads `path`; `Ok(None)` when there is no manifest.
    pub fn load(path: &Path) -> Result<Option<Self>> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).at(path),
        };
        let bad = |message: String| Error::index(path.parent().unwrap_or(path), message);
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad(format!("manifest.json is not JSON: {e}")))?;
        let version = value.get("manifest_version").and_then(|v| v.as_u64());
        if value.get("format").and_then(|v| v.as_str()) != Some(FORMAT) || version.is_none() {
            return Err(bad(
                "made by an older toporec (its manifest has no manifest_version); rebuild it with `toporec run --full`"
                    .into(),
            ));
        }
        if version > Some(MANIFEST_VERSION) {
            return Err(bad(format!(
                "manifest version {} is newer than this toporec reads ({MANIFEST_VERSION})",
                version.unwrap_or_default()
            )));
        }
        serde_json::from_value(value).map(Some).map_err(|e| bad(format!("manifest.json: {e}")))
    }

    /// The committed files of `table`, in commit order.
    pub fn files_of<'a>(&'a self, table: &'a str) -> impl Iterator<Item = &'a FileEntry> + 'a {
        self.files.iter().filter(move |f| f.table == table)
    }

    /// The committed descriptors files of `method`, in commit order.
    pub fn descriptor_files_of<'a>(&'a self, method: &'a str) -> impl Iterator<Item = &'a FileEntry> + 'a {
        self.files_of(crate::sinks::schema::tables::DESCRIPTORS).filter(move |f| f.method_name() == method)
    }

    /// The committed codebook, if any.
    pub fn codebook(&self, index: &Path) -> Result<Option<Codebook>> {
        match &self.codebook {
            None => Ok(None),
            Some(v) => Codebook::from_json(v)
                .map(Some)
                .map_err(|e| Error::index(index, format!("manifest.json: codebook: {e}"))),
        }
    }

    /// The JSON text written to disk.
    pub fn to_text(&self) -> String {
        serde_json::to_string_pretty(self).expect("JSON of plain values") + "\n"
    }
}

/// The xxh3-64 of a file's bytes, as 16 hex digits.
pub fn file_checksum(path: &Path) -> Result<(u64, String)> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).at(path)?;
    let mut hasher = twox_hash::XxHash3_64::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut bytes = 0u64;
    loop {
        let n = f.read(&mut buf).at(path)?;
        if n == 0 {
            break;
        }
        bytes += n as u64;
        std::hash::Hasher::write(&mut hasher, &buf[..n]);
    }
    Ok((bytes, format!("{:016x}", std::hash::Hasher::finish(&hasher))))
}
