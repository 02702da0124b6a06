//! Pipeline files: one TOML file is one complete job. Parsing collects every error in the
//! file — unknown keys, wrong types, bad values, missing inputs — each with its key path,
//! before any data is read (`toporec validate`).
//!
//! ```toml
//! [output]
//! index = "../target/index"          # relative paths are relative to this file
//! [[sources]]                        # one or more; see crate::sources::SourceSpec
//! kind = "nclt"
//! sessions = ["../samples/nclt"]
//! [preprocess]                       # every step optional, applied in this order
//! range = { min = 1.0, max = 80.0 }  # metres from the sensor
//! ground = { method = "plane", threshold = 0.15 }   # or { method = "height", below = -1.5 }
//! voxel = 0.2                        # voxel-grid cell (m)
//! subsample = 4096                   # at most this many points, seeded by the scan's bytes
//! normalize = true                   # zero mean, max |coordinate| = 1
//! min_points = 16                    # fewer left: the scan is skipped with the reason
//! [persistence]
//! dims = [0, 1, 2]                   # dimensions stored in the diagrams table
//! squared = true                     # squared radii (GUDHI's default) or radii
//! [vectorize]                        # fit a codebook on this run's diagrams …
//! b = 50
//! dims = "paper"                     # or [0, 1, 2]
//! # codebook = "codebook.json"       # … or load a saved one
//! [descriptors]
//! methods = ["toporec", "scancontext", "m2dp", "solid", "lidar-iris"]   # default ["toporec"]
//! [scancontext]                      # optional: a method's parameters, one section per method
//! ```                                # computed from raw scans (crate::methods::REGISTRY)

pub use crate::error::ConfigErrors;
use crate::methods::{Method, Methods, REGISTRY, TOPOREC};
use crate::preprocess::Preprocess;
use crate::sources::SourceSpec;
use crate::vectorize::atol::{Contrast, Weighting};
use crate::vectorize::codebook::{Codebook, CodebookSpec, DimSelection};
use crate::vectorize::kmeans::{Algorithm, KMeansParams};
use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};
use toml::{Table, Value};

/// A parsed, validated pipeline.
#[derive(Clone, Debug)]
pub struct Pipeline {
    /// The file it came from.
    pub path: PathBuf,
    /// Where the index goes.
    pub index: PathBuf,
    /// Sources, in order.
    pub sources: Vec<SourceSpec>,
    /// Preprocessing.
    pub preprocess: Preprocess,
    /// Persistence settings.
    pub persistence: Persistence,
    /// Vectorizing.
    pub vectorize: Vectorize,
    /// The descriptor methods.
    pub methods: Methods,
}

/// Persistence settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Persistence {
    /// Dimensions stored in the diagrams table.
    pub dims: Vec<u8>,
    /// Squared radii (true, GUDHI's default) or radii.
    pub squared: bool,
}

/// Vectorize settings: fit a codebook on this run's diagrams, or load one.
#[derive(Clone, Debug, PartialEq)]
pub enum Vectorize {
    /// Fit with this spec.
    Fit(CodebookSpec),
    /// Use this saved codebook.
    Load(PathBuf, Box<Codebook>),
}

/// A table being read: remembers which keys were asked for, to report the others.
struct Section<'a> {
    table: &'a Table,
    path: String,
    seen: Vec<&'static str>,
}

impl<'a> Section<'a> {
    fn new(table: &'a Table, path: &str) -> Self {
        Section { table, path: path.to_string(), seen: Vec::new() }
    }

    fn key(&self, key: &str) -> String {
        if self.path.is_empty() { key.to_string() } else { format!("{}.{key}", self.path) }
    }

    fn get<T: DeserializeOwned>(&mut self, key: &'static str, errors: &mut Vec<String>) -> Option<T> {
        self.seen.push(key);
        let value = self.table.get(key)?;
        match value.clone().try_into::<T>() {
            Ok(v) => Some(v),
            Err(e) => {
                errors.push(format!("{}: {}", self.key(key), e.message().trim()));
                None
            }
        }
    }

    fn table(&mut self, key: &'static str, errors: &mut Vec<String>) -> Option<Section<'a>> {
        self.seen.push(key);
        match self.table.get(key)? {
            Value::Table(t) => Some(Section::new(t, &self.key(key))),
            _ => {
                errors.push(format!("{}: expected a table", self.key(key)));
                None
            }
        }
    }

    fn finish(self, errors: &mut Vec<String>) {
        for k in self.table.keys() {
            if !self.seen.contains(&k.as_str()) {
                errors.push(format!("{}: unknown key", self.key(k)));
            }
        }
    }
}

impl Pipeline {
    /// Reads and validates a pipeline file.
    pub fn load(path: &Path) -> Result<Self, ConfigErrors> {
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let text = std::fs::read_to_string(path).map_err(|e| fail(vec![e.to_string()]))?;
        Self::parse(&text, path)
    }

    /// Reads a pipeline file without checking that its inputs exist (an index's effective
    /// pipeline, read for its settings).
    pub fn load_settings(path: &Path) -> Result<Self, ConfigErrors> {
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let text = std::fs::read_to_string(path).map_err(|e| fail(vec![e.to_string()]))?;
        Self::parse_with(&text, path, false)
    }

    /// The effective pipeline of an index (its settings; inputs need not exist any more): the
    /// one its manifest records, else its `pipeline.toml`.
    pub fn of_index(index: &Path) -> Result<Self, ConfigErrors> {
        let path = index.join(crate::sinks::index::PIPELINE_FILE);
        let manifest =
            crate::sinks::index::manifest::Manifest::load(&index.join(crate::sinks::index::MANIFEST_FILE));
        match manifest {
            Ok(Some(crate::sinks::index::manifest::Manifest { pipeline: Some(text), .. })) => {
                Self::parse_with(&text, &path, false)
            }
            _ => Self::load_settings(&path),
        }
    }

    /// The pipeline of `sources` computing the methods `names` (with the settings of `sections`,
    /// the registry's methods) into `index`, every other setting at its default (what a pipeline
    /// file of only those keys gives): the job `run <source>…` and `loops <source>…` make.
    /// Checked as a file is: its sources' keys and inputs, the methods and their settings.
    pub fn of_parts(
        index: &Path,
        sources: Vec<SourceSpec>,
        names: &[String],
        sections: &[Method],
    ) -> Result<Self, ConfigErrors> {
        let index = clean(&std::path::absolute(index).unwrap_or_else(|_| index.to_owned()));
        let path = index.join(crate::sinks::index::PIPELINE_FILE);
        let mut p = Parser { base: index.clone(), check_inputs: true, errors: Vec::new() };
        let defaults = Table::new();
        let mut root = Section::new(&defaults, "");
        let preprocess = p.preprocess(&mut root);
        let persistence = p.persistence(&mut root);
        let vectorize = p.vectorize(&mut root, &persistence);
        let mut sources = sources;
        for (i, s) in sources.iter_mut().enumerate() {
            s.clean_paths(clean);
            check_source(s, i, true, &mut p.errors);
        }
        let methods = methods_named(names, sections, &mut p.errors);
        if p.errors.is_empty() {
            check_unique_sessions(&sources, &mut p.errors);
        }
        if !p.errors.is_empty() {
            return Err(ConfigErrors { path, errors: p.errors });
        }
        Ok(Pipeline { path, index, sources, preprocess, persistence, vectorize, methods })
    }

    /// Parses pipeline text; `path` names the file and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigErrors> {
        Self::parse_with(text, path, true)
    }

    fn parse_with(text: &str, path: &Path, check_inputs: bool) -> Result<Self, ConfigErrors> {
        let fail = |errors| ConfigErrors { path: path.to_owned(), errors };
        let doc: Table =
            text.parse().map_err(|e: toml::de::Error| fail(vec![e.to_string().trim().to_string()]))?;
        // Absolute, so the effective pipeline written into an index stays valid anywhere.
        let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let base = std::path::absolute(base).unwrap_or_else(|_| base.to_owned());
        let mut p = Parser { base, check_inputs, errors: Vec::new() };
        let mut root = Section::new(&doc, "");
        let index = p.output(&mut root);
        let sources = p.sources(&mut root, &doc);
        let preprocess = p.preprocess(&mut root);
        let persistence = p.persistence(&mut root);
        let vectorize = p.vectorize(&mut root, &persistence);
        let methods = p.methods(&mut root);
        root.finish(&mut p.errors);
        if check_inputs && p.errors.is_empty() {
            check_unique_sessions(&sources, &mut p.errors);
        }
        if !p.errors.is_empty() {
            return Err(fail(p.errors));
        }
        Ok(Pipeline {
            path: path.to_owned(),
            index: index.expect("an error was recorded otherwise"),
            sources,
            preprocess,
            persistence,
            vectorize,
            methods,
        })
    }

    /// The fingerprint of everything that makes a scan's rows: the preprocess and
    /// persistence settings, and the descriptor methods when they are not the default
    /// TopoRec alone (16 hex digits). An index records it; rows made with other settings are
    /// outdated.
    pub fn settings_hash(&self) -> String {
        #[derive(serde::Serialize)]
        struct Settings<'a> {
            preprocess: &'a Preprocess,
            persistence: &'a Persistence,
            #[serde(skip_serializing_if = "Option::is_none")]
            methods: Option<String>,
        }
        let methods = (self.methods != Methods::default()).then(|| {
            // By name: the order a file lists them in changes no row.
            let mut entries: Vec<String> =
                self.methods.computed.iter().map(|m| format!("{}={}", m.name, m.id())).collect();
            entries.sort();
            format!("toporec={};{}", self.methods.toporec, entries.join(";"))
        });
        let settings = Settings { preprocess: &self.preprocess, persistence: &self.persistence, methods };
        let text = toml::to_string(&settings).expect("TOML of plain data");
        crate::fingerprint::hex(crate::fingerprint::of_bytes(text.as_bytes()))
    }

    /// The effective pipeline as TOML (absolute paths, defaults filled in, the codebook as
    /// loaded, `index` as the folder written): written into the index beside the tables.
    pub fn effective_toml(&self, index: &Path) -> String {
        let mut doc = Table::new();
        let mut output = Table::new();
        let index = std::path::absolute(index).unwrap_or_else(|_| index.to_owned());
        output.insert("index".into(), Value::String(clean(&index).display().to_string()));
        doc.insert("output".into(), Value::Table(output));
        let sources: Vec<Value> = self.sources.iter().map(|s| Value::Table(s.table())).collect();
        doc.insert("sources".into(), Value::Array(sources));
        let pre = Value::try_from(&self.preprocess).expect("plain data");
        doc.insert("preprocess".into(), pre);
        doc.insert("persistence".into(), Value::try_from(&self.persistence).expect("plain data"));
        let mut v = Table::new();
        match &self.vectorize {
            Vectorize::Load(p, _) => {
                v.insert("codebook".into(), Value::String(p.display().to_string()));
            }
            Vectorize::Fit(s) => {
                v.insert("b".into(), Value::Integer(s.b as i64));
                v.insert(
                    "dims".into(),
                    match &s.dims {
                        DimSelection::Paper => Value::String("paper".into()),
                        DimSelection::Dims(d) => {
                            Value::Array(d.iter().map(|&x| Value::Integer(x as i64)).collect())
                        }
                    },
                );
                v.insert("contrast".into(), Value::try_from(s.contrast).expect("plain data"));
                v.insert("weighting".into(), Value::try_from(s.weighting).expect("plain data"));
                v.insert("kmeans".into(), Value::try_from(s.kmeans.algorithm).expect("plain data"));
                v.insert("seed".into(), Value::Integer(s.seed as i64));
                v.insert("sample_size".into(), Value::Integer(s.sample_size as i64));
            }
        }
        doc.insert("vectorize".into(), Value::Table(v));
        let mut d = Table::new();
        let names = self.methods.names().into_iter().map(Value::String).collect();
        d.insert("methods".into(), Value::Array(names));
        doc.insert("descriptors".into(), Value::Table(d));
        for m in &self.methods.computed {
            doc.insert(m.name.clone(), Value::try_from(m.params()).expect("plain data"));
        }
        format!(
            "# The effective pipeline of this index (resolved by toporec {}).\n{}",
            env!("CARGO_PKG_VERSION"),
            toml::to_string(&doc).expect("TOML of plain data")
        )
    }
}

/// The methods `names` lists (`descriptors.methods`), each computed one with its settings in
/// `sections`; every problem (an empty list, a name twice, an unknown name, bad settings)
/// pushed to `errors`.
pub(crate) fn methods_named(names: &[String], sections: &[Method], errors: &mut Vec<String>) -> Methods {
    let known = || format!("{TOPOREC}, {}", crate::methods::computed_names().join(", "));
    let mut methods = Methods { toporec: false, computed: Vec::new() };
    if names.is_empty() {
        errors.push(format!("descriptors.methods: empty ({})", known()));
    }
    for (i, name) in names.iter().enumerate() {
        if names[..i].contains(name) {
            errors.push(format!("descriptors.methods: `{name}` is listed twice"));
            continue;
        }
        if name == TOPOREC {
            methods.toporec = true;
        } else if let Some(m) = sections.iter().find(|m| m.name == *name) {
            errors.extend(m.as_computed().expect("a registered method").problems());
            methods.computed.push(m.clone());
        } else {
            errors.push(format!(
                "descriptors.methods: unknown method `{name}` ({}; vectors made elsewhere come in with \
                 `toporec import`)",
                known()
            ));
        }
    }
    methods
}

/// One pass over a pipeline file: a parser per section, every error collected.
struct Parser {
    /// The file's folder (absolute): relative paths are relative to it.
    base: PathBuf,
    /// Whether input paths must exist: not for an index's own effective pipeline, where a
    /// method setting the text lacks means what it meant when it was written
    /// ([`crate::methods::stored_settings`]).
    check_inputs: bool,
    errors: Vec<String>,
}

impl Parser {
    fn resolve(&self, p: PathBuf) -> PathBuf {
        clean(&if p.is_relative() { self.base.join(p) } else { p })
    }

    /// A section, or an empty one when the file leaves it out.
    fn section<'a>(&mut self, root: &mut Section<'a>, key: &'static str) -> Section<'a> {
        static EMPTY: std::sync::OnceLock<Table> = std::sync::OnceLock::new();
        root.table(key, &mut self.errors).unwrap_or_else(|| Section::new(EMPTY.get_or_init(Table::new), key))
    }

    /// `[output]`: the index folder.
    fn output(&mut self, root: &mut Section) -> Option<PathBuf> {
        let index = root.table("output", &mut self.errors).and_then(|mut s| {
            let index: Option<PathBuf> = s.get("index", &mut self.errors);
            s.finish(&mut self.errors);
            index
        });
        if index.is_none() {
            self.errors.push("output.index: missing (the index folder to write)".into());
        }
        index.map(|p| self.resolve(p))
    }

    /// `[[sources]]`: one or more source tables, paths resolved (and checked).
    fn sources(&mut self, root: &mut Section, doc: &Table) -> Vec<SourceSpec> {
        root.seen.push("sources");
        let mut sources = Vec::new();
        match doc.get("sources") {
            Some(Value::Array(items)) if !items.is_empty() => {
                for (i, item) in items.iter().enumerate() {
                    if let Some(mut s) = source_entry(item, i, &mut self.errors) {
                        s.resolve_paths(&self.base);
                        s.clean_paths(clean);
                        check_source(&s, i, self.check_inputs, &mut self.errors);
                        sources.push(s);
                    }
                }
            }
            _ => self.errors.push("sources: missing (one or more [[sources]] tables)".into()),
        }
        sources
    }

    /// `[preprocess]`: every step optional.
    fn preprocess(&mut self, root: &mut Section) -> Preprocess {
        let mut s = self.section(root, "preprocess");
        let errors = &mut self.errors;
        let d = Preprocess::default();
        let p = Preprocess {
            range: s.get("range", errors),
            ground: s.get("ground", errors),
            voxel: s.get("voxel", errors),
            subsample: s.get("subsample", errors),
            normalize: s.get("normalize", errors).unwrap_or(d.normalize),
            min_points: s.get("min_points", errors).unwrap_or(d.min_points),
        };
        s.finish(errors);
        errors.extend(p.problems());
        p
    }

    /// `[persistence]`: stored dimensions and units.
    fn persistence(&mut self, root: &mut Section) -> Persistence {
        let mut s = self.section(root, "persistence");
        let errors = &mut self.errors;
        let dims: Vec<u8> = s.get("dims", errors).unwrap_or(vec![0, 1, 2]);
        let squared = s.get("squared", errors).unwrap_or(true);
        s.finish(errors);
        if dims.is_empty() || dims.iter().any(|&d| d > 2) {
            errors.push(format!("persistence.dims: expected a list of 0, 1, 2; found {dims:?}"));
        }
        Persistence { dims, squared }
    }

    /// `[vectorize]`: fit keys, or a saved codebook; checked against the stored dimensions.
    fn vectorize(&mut self, root: &mut Section, persistence: &Persistence) -> Vectorize {
        let mut s = self.section(root, "vectorize");
        let codebook: Option<PathBuf> = s.get("codebook", &mut self.errors);
        let given: Vec<&str> =
            CODEBOOK_FIT_KEYS.iter().copied().filter(|k| s.table.contains_key(*k)).collect();
        let spec = self.codebook_spec(&mut s, persistence.squared);
        s.finish(&mut self.errors);
        let vectorize = match codebook {
            None => Vectorize::Fit(spec),
            Some(p) => {
                if !given.is_empty() {
                    self.errors.push(format!(
                        "vectorize: {} given with a saved codebook (it fixes them); remove one or the other",
                        given.join(", ")
                    ));
                }
                let p = self.resolve(p);
                match Codebook::load(&p) {
                    Ok(cb) => {
                        if cb.spec.squared_radii != persistence.squared {
                            self.errors.push(format!(
                                "vectorize.codebook: made for {} but persistence.squared = {}",
                                if cb.spec.squared_radii { "squared radii" } else { "radii" },
                                persistence.squared
                            ));
                        }
                        Vectorize::Load(p, Box::new(cb))
                    }
                    Err(e) => {
                        self.errors.push(format!("vectorize.codebook: {e}"));
                        Vectorize::Fit(spec)
                    }
                }
            }
        };
        let needed = dims_needed(&vectorize.codebook_dims());
        if let Some(d) = needed.iter().find(|d| !persistence.dims.contains(d)) {
            self.errors
                .push(format!("persistence.dims: the descriptor needs H{d}; add {d} to the stored dims"));
        }
        vectorize
    }

    /// `[descriptors]` (the methods) and the sections of the methods asked for.
    fn methods(&mut self, root: &mut Section) -> Methods {
        let mut s = self.section(root, "descriptors");
        let names: Vec<String> = s.get("methods", &mut self.errors).unwrap_or_else(|| vec![TOPOREC.into()]);
        s.finish(&mut self.errors);
        // Every method's section is read (and checked to parse) whether it is listed or not.
        let sections: Vec<Method> = REGISTRY.iter().map(|r| self.method_section(root, r)).collect();
        methods_named(&names, &sections, &mut self.errors)
    }

    /// A registered method with the settings of its section (`[scancontext]`, `[m2dp]`,
    /// `[toporec-plus]`, …), defaults filled in; its defaults when the section does not parse.
    fn method_section(&mut self, root: &mut Section, entry: &crate::methods::Registered) -> Method {
        root.seen.push(entry.name);
        let stored = |v: &Value| serde_json::to_value(v).map_err(|e| e.to_string());
        match root.table.get(entry.name) {
            None => entry.default_method(),
            Some(v) if !self.check_inputs => {
                stored(v).and_then(|v| entry.stored_method(&v)).unwrap_or_else(|e| {
                    self.errors.push(format!("{}: {e}", entry.name));
                    entry.default_method()
                })
            }
            Some(v) => entry.method_from_toml(v.clone()).unwrap_or_else(|e| {
                self.errors.push(format!("{}: {e}", entry.name));
                entry.default_method()
            }),
        }
    }

    /// The fit keys of `[vectorize]`, defaults filled in.
    fn codebook_spec(&mut self, s: &mut Section, squared_radii: bool) -> CodebookSpec {
        let errors = &mut self.errors;
        let dims = match s.get::<Value>("dims", errors) {
            None => Some(DimSelection::Paper),
            Some(Value::String(t)) => {
                DimSelection::parse(&t).map_err(|e| errors.push(format!("vectorize.{e}"))).ok()
            }
            Some(v) => match v.try_into::<Vec<u8>>() {
                Ok(list) => {
                    DimSelection::from_list(list).map_err(|e| errors.push(format!("vectorize.{e}"))).ok()
                }
                Err(_) => {
                    errors.push("vectorize.dims: expected \"paper\" or a list like [0, 1, 2]".into());
                    None
                }
            },
        };
        let d = CodebookSpec::default();
        let kmeans: Option<Algorithm> = s.get("kmeans", errors);
        let spec = CodebookSpec {
            dims: dims.unwrap_or(DimSelection::Paper),
            b: s.get("b", errors).unwrap_or(d.b),
            contrast: s.get::<Contrast>("contrast", errors).unwrap_or(d.contrast),
            weighting: s.get::<Weighting>("weighting", errors).unwrap_or(d.weighting),
            kmeans: KMeansParams {
                algorithm: kmeans.unwrap_or(Algorithm::MiniBatch),
                ..KMeansParams::default()
            },
            seed: s.get("seed", errors).unwrap_or(d.seed),
            sample_size: s.get("sample_size", errors).unwrap_or(d.sample_size),
            squared_radii,
        };
        if !(1..=100_000).contains(&spec.b) {
            errors.push(format!("vectorize.b: must be in [1, 100000]; found {}", spec.b));
        }
        if spec.sample_size == 0 {
            errors.push("vectorize.sample_size: must be in [1, inf); found 0".into());
        }
        spec
    }
}

/// The `[vectorize]` keys that fit a codebook (not allowed beside `codebook`).
const CODEBOOK_FIT_KEYS: [&str; 7] = ["b", "dims", "contrast", "weighting", "kmeans", "seed", "sample_size"];

impl Vectorize {
    /// The dimension selection of the codebook to fit or loaded.
    pub fn codebook_dims(&self) -> DimSelection {
        match self {
            Vectorize::Fit(s) => s.dims.clone(),
            Vectorize::Load(_, cb) => cb.spec.dims.clone(),
        }
    }
}

/// Removes `.` and `name/..` components without touching the file system.
pub fn clean(path: &Path) -> PathBuf {
    use std::path::Component;
    let mut out: Vec<Component> = Vec::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    if out.is_empty() { PathBuf::from(".") } else { out.iter().collect() }
}

/// Diagram dimensions a descriptor reads.
pub(crate) fn dims_needed(dims: &DimSelection) -> Vec<u8> {
    match dims {
        DimSelection::Paper => vec![0, 1, 2],
        DimSelection::Dims(d) => d.clone(),
    }
}

/// What parsing a source does not catch (numbers; with `inputs`, paths), each with its key path.
fn check_source(s: &SourceSpec, i: usize, inputs: bool, errors: &mut Vec<String>) {
    let problems = s.problems(inputs).into_iter();
    errors.extend(problems.map(|(key, message)| format!("sources[{i}].{key}: {message}")));
}

/// One `[[sources]]` entry, or every error in it, each with its key path (`sources[0].sessions:
/// invalid type …`): a key of the wrong type or unknown is reported and left out, and the rest
/// of the entry is read again, so one bad key does not hide the next.
fn source_entry(item: &Value, i: usize, errors: &mut Vec<String>) -> Option<SourceSpec> {
    use crate::sources::SourceKind;
    let kinds = SourceKind::names();
    let Value::Table(table) = item else {
        errors.push(format!("sources[{i}]: expected a table ([[sources]]), found {}", item.type_str()));
        return None;
    };
    let kind = match table.get("kind") {
        Some(Value::String(k)) => k.clone(),
        Some(other) => {
            errors
                .push(format!("sources[{i}].kind: expected a string ({kinds}), found {}", other.type_str()));
            return None;
        }
        None => {
            errors.push(format!("sources[{i}].kind: missing ({kinds})"));
            return None;
        }
    };
    let Some(entry) = SourceKind::of(&kind) else {
        errors.push(format!("sources[{i}].kind: unknown kind `{kind}` (expected {kinds})"));
        return None;
    };
    let mut rest = table.clone();
    rest.remove("kind");
    let mut left_out: Vec<String> = Vec::new();
    loop {
        let crate::sources::KeyError { path, message } = match entry.parse(&rest) {
            Ok(spec) => return left_out.is_empty().then_some(spec),
            Err(e) => e,
        };
        // The key at fault: the path's first segment, or the one an unknown-field error names.
        let key = match path.split(['.', '[']).next().filter(|k| !k.is_empty()) {
            Some(k) => Some(k.to_string()),
            None => {
                message.strip_prefix("unknown field `").and_then(|m| m.split('`').next()).map(str::to_string)
            }
        };
        match key {
            Some(key) if rest.contains_key(&key) => {
                let at = if path.is_empty() { key.clone() } else { path };
                errors.push(format!("sources[{i}].{at}: {message}"));
                rest.remove(&key);
                left_out.push(key);
            }
            _ => {
                // A key found bad above and left out is not reported again as missing.
                if !left_out.iter().any(|k| message.contains(&format!("`{k}`"))) {
                    errors.push(format!("sources[{i}]: {message}"));
                }
                return None;
            }
        }
    }
}

/// Every session comes from one place: a session reached twice (a folder of sessions and one
/// of them), or two of one name from different folders, would give scans the same ids.
fn check_unique_sessions(sources: &[SourceSpec], errors: &mut Vec<String>) {
    let mut seen: std::collections::HashMap<String, (usize, PathBuf)> = std::collections::HashMap::new();
    for (i, s) in sources.iter().enumerate() {
        let sessions = match s.sessions() {
            Ok(s) => s,
            Err(e) => {
                errors.push(format!("sources[{i}]: {e}"));
                continue;
            }
        };
        for (name, path) in sessions {
            match seen.get(&name) {
                Some((j, first)) => errors.push(format!(
                    "sources[{i}]: session `{name}` comes twice, from {} (sources[{j}]) and {}; its scans would share ids",
                    first.display(),
                    path.display()
                )),
                None => {
                    seen.insert(name, (i, path));
                }
            }
        }
    }
}
