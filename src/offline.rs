//! Work on stored diagrams, without sources or persistence: `toporec fit` fits a codebook and
//! `toporec vectorize` turns diagrams into descriptors. Both read diagram CSV files (as
//! `toporec diagram` prints them) or index folders (their `diagrams` tables, streamed scan by
//! scan).

use crate::diagram_csv;
use crate::error::{Error, Result, ResultExt};
use crate::fsutil::AtomicFile;
use crate::homology::Diagram;
use crate::ranges;
use crate::sinks::csv::field as csv_field;
use crate::sinks::index::IndexReader;
use crate::sinks::parquet::{DescriptorRow, DescriptorsFile};
use crate::vectorize::atol::{Contrast, Weighting};
use crate::vectorize::codebook::{Codebook, CodebookFitter, CodebookSpec, DimSelection};
use crate::vectorize::kmeans::{Algorithm, KMeansParams};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Arguments of `toporec fit`.
#[derive(clap::Args, Clone, Debug)]
pub struct FitArgs {
    /// Diagram CSV files (dim,birth,death) as `toporec diagram` writes them, or index folders
    /// (their diagrams tables).
    #[arg(required_unless_present = "pipeline", conflicts_with = "pipeline")]
    pub diagrams: Vec<PathBuf>,
    /// Where to write the codebook (JSON).
    #[arg(long, short, required_unless_present = "pipeline")]
    pub out: Option<PathBuf>,
    /// Instead of diagram files: fit the pipeline's codebook (its `[vectorize]` settings) on a
    /// sample of its scans and freeze it in its index, before a sharded run.
    #[arg(long, requires = "sample")]
    pub pipeline: Option<PathBuf>,
    /// With --pipeline: the fraction of scans, (0, 1], chosen by a hash of the scan id.
    #[arg(long, requires = "pipeline")]
    pub sample: Option<f64>,
    /// With --pipeline: the index to freeze the codebook in (default: the file's).
    #[arg(long, requires = "pipeline")]
    pub index: Option<PathBuf>,
    /// The codebook's settings.
    #[command(flatten)]
    pub codebook: CodebookArgs,
    /// Record that the diagrams are in radii, not squared radii.
    #[arg(long)]
    pub radius: bool,
}

/// How to fit a codebook (`toporec fit`, `toporec revectorize`).
#[derive(clap::Args, Clone, Debug)]
pub struct CodebookArgs {
    /// Centres per codebook (the descriptor length per part): [1, 100000].
    #[arg(long, short, default_value_t = 50, value_parser = ranges::centres)]
    pub b: usize,
    /// `paper` (H2, else H1, else H0) or a list like `0,1,2` (one codebook per dimension).
    #[arg(long, default_value = "paper", value_parser = DimSelection::parse)]
    pub dims: DimSelection,
    /// ATOL contrast: gaussian, laplacian or indicator.
    #[arg(long, value_enum, default_value = "laplacian")]
    pub contrast: Contrast,
    /// ATOL weighting: cloud (sum) or iidproba (mean).
    #[arg(long, value_enum, default_value = "cloud")]
    pub weighting: Weighting,
    /// The quantiser.
    #[arg(long, value_enum, default_value = "minibatch")]
    pub kmeans: Algorithm,
    /// Points kept (uniform sample) per codebook for fitting: [1, ∞).
    #[arg(long, default_value_t = 100_000, value_parser = ranges::count)]
    pub sample_size: usize,
    /// Seed of sampling and k-means.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl CodebookArgs {
    /// The codebook spec these arguments ask for, for diagrams in squared radii or radii.
    pub fn spec(&self, squared_radii: bool) -> CodebookSpec {
        CodebookSpec {
            dims: self.dims.clone(),
            b: self.b,
            contrast: self.contrast,
            weighting: self.weighting,
            kmeans: KMeansParams { algorithm: self.kmeans, ..KMeansParams::default() },
            sample_size: self.sample_size,
            seed: self.seed,
            squared_radii,
        }
    }
}

/// Arguments of `toporec vectorize`.
#[derive(clap::Args, Clone, Debug)]
pub struct VectorizeArgs {
    /// Diagram CSV files or index folders.
    #[arg(required = true)]
    pub diagrams: Vec<PathBuf>,
    /// The codebook (JSON from `toporec fit`).
    #[arg(long, short)]
    pub codebook: PathBuf,
    /// Output: `*.parquet` for a descriptors table (the index's schema), else CSV
    /// `diagram,dim_used,v1..vb` (default stdout).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// Diagrams from CSV files (id = the path) or index folders (id = the scan id), streamed.
pub(crate) fn diagram_inputs(paths: &[PathBuf]) -> impl Iterator<Item = Result<(String, Diagram)>> + '_ {
    paths.iter().flat_map(|path| -> Box<dyn Iterator<Item = Result<(String, Diagram)>>> {
        if path.is_dir() {
            match IndexReader::open(path).and_then(|r| r.diagrams()) {
                Ok(it) => Box::new(it),
                Err(e) => Box::new(std::iter::once(Err(e))),
            }
        } else {
            Box::new(std::iter::once(diagram_csv::read(path).map(|d| (path.display().to_string(), d))))
        }
    })
}

/// Fits the codebook `args` asks for on its diagrams and saves it; returns it.
pub fn fit(args: &FitArgs) -> Result<Codebook> {
    let mut fitter = CodebookFitter::new(args.codebook.spec(!args.radius));
    for item in diagram_inputs(&args.diagrams) {
        let (id, diagram) = item?;
        fitter.add(&diagram, &id);
    }
    let start = std::time::Instant::now();
    let out = args.out.clone().ok_or_else(|| Error::invalid("fit: --out is required with diagram inputs"))?;
    let codebook = fitter
        .finish()
        .map_err(|e| Error::Codebook { path: out.clone(), message: format!("fitting the codebook: {e}") })?;
    tracing::info!(elapsed = ?start.elapsed(), "codebook fitted");
    codebook.save(&out)?;
    Ok(codebook)
}

/// Vectorizes the diagrams of `args` into its output (`out`: stdout, when no file is named);
/// returns the codebook used and the number of descriptors.
pub fn vectorize(args: &VectorizeArgs, stdout: &mut dyn Write) -> Result<(Codebook, u64)> {
    let codebook = Codebook::load(&args.codebook)?;
    let rows = match &args.out {
        Some(out) if out.extension().is_some_and(|e| e == "parquet") => to_parquet(args, &codebook, out)?,
        Some(out) => {
            let mut file = AtomicFile::create(out)?;
            let rows = to_csv(args, &codebook, &mut file, out)?;
            file.commit()?;
            rows
        }
        None => to_csv(args, &codebook, stdout, Path::new("<stdout>"))?,
    };
    Ok((codebook, rows))
}

/// A descriptors table with the index's schema (id = scan id or CSV path; utime and pose null).
fn to_parquet(args: &VectorizeArgs, codebook: &Codebook, out: &Path) -> Result<u64> {
    let mut file = DescriptorsFile::create(out, crate::methods::TOPOREC, codebook.len(), &codebook.id())?;
    let mut rows = 0;
    for item in diagram_inputs(&args.diagrams) {
        let (id, diagram) = item?;
        file.push(DescriptorRow::new(id, None, None, &codebook.vectorize(&diagram)))?;
        rows += 1;
    }
    file.finish()?.0.publish()?;
    Ok(rows)
}

/// CSV rows `diagram,dim_used,v1..vb`.
fn to_csv(args: &VectorizeArgs, codebook: &Codebook, out: &mut dyn Write, name: &Path) -> Result<u64> {
    let mut header = String::from("diagram,dim_used");
    for j in 1..=codebook.len() {
        header += &format!(",v{j}");
    }
    writeln!(out, "{header}").at(name)?;
    let mut rows = 0;
    for item in diagram_inputs(&args.diagrams) {
        let (id, diagram) = item?;
        let d = codebook.vectorize(&diagram);
        let mut line =
            format!("{},{}", csv_field(&id), d.dim_used.map(|d| d.to_string()).unwrap_or_default());
        for v in &d.values {
            line += &format!(",{v:?}");
        }
        writeln!(out, "{line}").at(name)?;
        rows += 1;
    }
    out.flush().at(name)?;
    Ok(rows)
}
