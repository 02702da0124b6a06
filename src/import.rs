//! `toporec import`: descriptors made elsewhere (PointNetVLAD, PCAN, MinkLoc3D, …) stored as
//! one more method of an index, matched to its scans by id, so `eval` compares them with the
//! same protocol as the computed ones.
//!
//! Inputs, by extension:
//! * `.parquet`: columns `scan_id` (any string type) and `descriptor` (a list of floats);
//! * `.npy`: a 2-D float32 or float64 array, one row per scan, with `--ids FILE` (one scan id per
//!   line, in row order);
//! * `.csv`: `scan_id` then the values, one row per scan (a header line is optional).
//!
//! Every row must name an `ok` scan of the index, once, with as many finite values as every
//! other row; anything else is an error naming the file and the row, and nothing is written.
//! Importing a method again replaces its descriptors in one commit.

use crate::error::{Error, Result, ResultExt};
use crate::methods::{IMPORTED, Method, MethodKind, TOPOREC, computed_names};
use crate::sinks::index::IndexWriter;
use crate::sinks::parquet::{DescriptorRow, Status};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Arguments of `toporec import`.
#[derive(clap::Args, Clone, Debug)]
pub struct ImportArgs {
    /// The index.
    #[command(flatten)]
    pub index: crate::flags::IndexFlag,
    /// The method's name (letters, digits, `_`, `-`; not one of toporec's own methods).
    #[arg(long)]
    pub method: String,
    /// The vectors: `.parquet`, `.npy` (with `--ids`) or `.csv`.
    pub file: PathBuf,
    /// For `.npy`: the scan ids, one per line, in row order.
    #[arg(long)]
    pub ids: Option<PathBuf>,
}

/// What an import stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Imported {
    /// Rows stored.
    pub rows: usize,
    /// Descriptor length.
    pub length: usize,
    /// The method's id (in every row's `codebook_id`).
    pub id: String,
}

/// Reads the vectors of `args.file` and stores them as method `args.method` of the index.
pub fn import(args: &ImportArgs) -> Result<Imported> {
    check_name(&args.method)?;
    if !args.index.path.join(crate::sinks::index::MANIFEST_FILE).is_file() {
        return Err(Error::index(
            &args.index.path,
            "no manifest.json: not an index toporec wrote (index its scans first)",
        ));
    }
    let rows = read_vectors(&args.file, args.ids.as_deref())?;
    let length = rows.first().map(|r| r.1.len()).unwrap_or(0);
    if length == 0 {
        return Err(Error::table(&args.file, "no vectors"));
    }
    let mut seen = HashSet::new();
    for (i, (id, v)) in rows.iter().enumerate() {
        if v.len() != length {
            return Err(Error::table(
                &args.file,
                format!("row {} (scan {id}): {} values, the first row has {length}", i + 1, v.len()),
            ));
        }
        if let Some(j) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::table(
                &args.file,
                format!("row {} (scan {id}): value {j} is not finite", i + 1),
            ));
        }
        if !seen.insert(id.as_str()) {
            return Err(Error::table(&args.file, format!("row {}: scan {id} comes twice", i + 1)));
        }
    }
    let mut writer = IndexWriter::open(&args.index.path, "", false)?;
    if writer.manifest().generation == 0 {
        return Err(Error::index(&args.index.path, "empty: index its scans first (`toporec run`)"));
    }
    let unknown: Vec<&str> =
        rows.iter().map(|r| r.0.as_str()).filter(|id| !writer.committed().contains_key(*id)).collect();
    if !unknown.is_empty() {
        let first: Vec<&str> = unknown.iter().take(5).copied().collect();
        return Err(Error::table(
            &args.file,
            format!(
                "{} scan ids are not in {} (the first: {})",
                unknown.len(),
                args.index.path.display(),
                first.join(", ")
            ),
        ));
    }
    if let Some((id, c)) = rows
        .iter()
        .filter_map(|r| writer.committed().get(&r.0).map(|c| (&r.0, c)))
        .find(|(_, c)| c.status != Status::Ok)
    {
        return Err(Error::table(
            &args.file,
            format!("scan {id} is {} in the index, not ok: it has no descriptors", c.status.as_str()),
        ));
    }
    let source = args.file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let method = Method { name: args.method.clone(), kind: MethodKind::Imported { length, source } };
    let id = method.id();
    let mut methods = writer.manifest().methods.clone();
    if let Some(e) = methods.get(&args.method).filter(|e| e.kind != IMPORTED) {
        return Err(Error::invalid(format!(
            "--method {}: the index computes a method of that name ({})",
            args.method, e.kind
        )));
    }
    methods.insert(args.method.clone(), crate::sinks::index::manifest::MethodEntry::of(&method));
    writer.drop_method(&args.method);
    writer.set_methods(methods);
    let n = rows.len();
    for (scan_id, values) in rows {
        let c = writer.committed()[&scan_id].clone();
        let row = DescriptorRow { scan_id, utime: c.utime, pose: c.pose, dim_used: None, values };
        writer.write_method_descriptor(&c.session, &args.method, &id, row)?;
    }
    writer.commit()?;
    Ok(Imported { rows: n, length, id })
}

/// A method name: letters, digits, `_` and `-` (it names a folder), not a computed method's.
fn check_name(name: &str) -> Result<()> {
    if name == TOPOREC || computed_names().contains(&name) {
        return Err(Error::invalid(format!(
            "--method {name}: the name of a computed method; choose another"
        )));
    }
    let ok = !name.is_empty()
        && name.len() <= 64
        && name.bytes().all(|b| b.is_ascii_alphanumeric() || b"_-".contains(&b));
    if !ok {
        return Err(Error::invalid(format!(
            "--method {name:?}: use 1 to 64 letters, digits, `_` or `-` (it names a folder)"
        )));
    }
    Ok(())
}

/// (scan id, vector) rows of a file.
type Rows = Vec<(String, Vec<f32>)>;

/// Reads the rows of a `.parquet`, `.npy` or `.csv` file.
pub(crate) fn read_vectors(path: &Path, ids: Option<&Path>) -> Result<Rows> {
    let ext = path.extension().map(|e| e.to_string_lossy().to_lowercase()).unwrap_or_default();
    match (ext.as_str(), ids) {
        ("npy", Some(ids)) => read_npy(path, ids),
        ("npy", None) => Err(Error::invalid(format!(
            "{}: a .npy file holds no scan ids; give them with --ids FILE (one per line, in row order)",
            path.display()
        ))),
        (_, Some(_)) => Err(Error::invalid("--ids is for .npy files (Parquet and CSV name their scans)")),
        ("parquet", None) => read_parquet(path),
        ("csv", None) => read_csv(path),
        _ => Err(Error::invalid(format!("{}: expected a .parquet, .npy or .csv file", path.display()))),
    }
}

fn read_parquet(path: &Path) -> Result<Rows> {
    use arrow::array::{Array, AsArray};
    use arrow::datatypes::{DataType, Field, Float32Type};
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let file = std::fs::File::open(path).at(path)?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).at(path)?;
    let schema = builder.schema().clone();
    for name in ["scan_id", "descriptor"] {
        if schema.column_with_name(name).is_none() {
            return Err(Error::table(path, format!("no column `{name}` (needed: scan_id, descriptor)")));
        }
    }
    let list = DataType::List(std::sync::Arc::new(Field::new("item", DataType::Float32, true)));
    let mut out = Vec::new();
    for batch in builder.build().at(path)? {
        let batch = batch.at(path)?;
        let ids = arrow::compute::cast(batch.column_by_name("scan_id").expect("checked"), &DataType::Utf8)
            .map_err(|e| Error::table(path, format!("column `scan_id`: {e}")))?;
        let vectors = arrow::compute::cast(batch.column_by_name("descriptor").expect("checked"), &list)
            .map_err(|e| {
                Error::table(path, format!("column `descriptor`: expected a list of floats ({e})"))
            })?;
        let (ids, vectors) = (ids.as_string::<i32>(), vectors.as_list::<i32>());
        for i in 0..ids.len() {
            if ids.is_null(i) || vectors.is_null(i) {
                return Err(Error::table(
                    path,
                    format!("row {}: a null scan_id or descriptor", out.len() + 1),
                ));
            }
            let v = vectors.value(i);
            let v = v.as_primitive::<Float32Type>();
            if v.null_count() > 0 {
                return Err(Error::table(path, format!("row {}: a null value", out.len() + 1)));
            }
            out.push((ids.value(i).to_string(), v.values().to_vec()));
        }
    }
    Ok(out)
}

fn read_csv(path: &Path) -> Result<Rows> {
    let file = std::fs::File::open(path).at(path)?;
    let mut reader = csv::ReaderBuilder::new().has_headers(false).flexible(true).from_reader(file);
    let mut out = Vec::new();
    for (i, (line, record)) in crate::sources::csv::numbered_records(&mut reader).enumerate() {
        let record = record.map_err(|e| Error::table(path, format!("line {line}: {e}")))?;
        let id = record.get(0).unwrap_or_default().trim().trim_start_matches('\u{feff}').to_string();
        let values: std::result::Result<Vec<f32>, _> =
            record.iter().skip(1).map(|v| v.trim().parse::<f32>()).collect();
        match values {
            Ok(v) if !id.is_empty() => out.push((id, v)),
            // A header line: the first line, whose values are not numbers.
            Err(_) if i == 0 => continue,
            _ => {
                return Err(Error::table(path, format!("line {line}: expected a scan id then numbers")));
            }
        }
    }
    Ok(out)
}

fn read_npy(path: &Path, ids_path: &Path) -> Result<Rows> {
    let bad = |m: &str| Error::table(path, format!("not a .npy array this reads: {m}"));
    let file = std::io::BufReader::new(std::fs::File::open(path).at(path)?);
    let npy = npyz::NpyFile::new(file).map_err(|e| bad(&e.to_string()))?;
    let shape = npy.shape().to_vec();
    let [n, d] = shape[..] else {
        return Err(bad(&format!("shape {shape:?}; expected 2 dimensions (scans, values)")));
    };
    let (n, d) = (n as usize, d as usize);
    let fortran = npy.order() == npyz::Order::Fortran;
    let descr = npy.dtype().descr();
    let cut = |e: std::io::Error| bad(&format!("the data of shape ({n}, {d}) cannot be read whole ({e})"));
    let values: Vec<f32> = match descr.trim_matches('\'').trim_start_matches(['<', '>', '=']) {
        "f4" => npy.into_vec::<f32>().map_err(cut)?,
        "f8" => npy.into_vec::<f64>().map_err(cut)?.into_iter().map(|v| v as f32).collect(),
        _ => return Err(bad(&format!("dtype {descr}; expected float32 or float64"))),
    };
    if values.len() != n * d {
        return Err(bad(&format!("{} values for shape ({n}, {d})", values.len())));
    }
    let text = std::fs::read_to_string(ids_path).at(ids_path)?;
    let ids: Vec<String> = text.lines().map(|l| l.trim().to_string()).filter(|l| !l.is_empty()).collect();
    if ids.len() != n {
        return Err(Error::table(
            ids_path,
            format!("{} scan ids for the {n} rows of {}", ids.len(), path.display()),
        ));
    }
    // Row i, column j: at i·d + j in C order, at j·n + i in Fortran order.
    let at = |i: usize, j: usize| if fortran { values[j * n + i] } else { values[i * d + j] };
    Ok(ids.into_iter().enumerate().map(|(i, id)| (id, (0..d).map(|j| at(i, j)).collect())).collect())
}
