//! The pipeline of sources given on the command line (`toporec run <source>…`, `toporec loops
//! <source>…`), made with no pipeline file.
//!
//! Each source is whatever `inspect` recognises ([`crate::sources::Input`]): a message log, an
//! NCLT session, a KITTI sequence, a folder of clouds; its sessions are the ones `inspect` lists.
//! The pipeline is a value ([`Pipeline::of_parts`]): the sources with the options given
//! (`--topic`, the poses, settled by each source: [`crate::sources::Source::settle`]), toporec's
//! defaults, and toporec-plus (at its defaults, as everywhere), or the methods asked for. The index keeps it as
//! every run's: everything chosen (the topic, where the poses come from, their frames, the
//! tolerance) is written in it, so `toporec run` on it, and `toporec repair`, give the same index.
//! The index goes to `out/<first source's name>` unless `--index` says otherwise, and the next
//! call with the same sources brings it up to date (new or changed scans only); a default folder
//! holding the index of other sources is refused ([`check_default_index`]). A message log's
//! poses are settled before anything is indexed: a choice that cannot be made (several pose
//! topics, a transform chain that does not reach the cloud's frame, odometry that never overlaps
//! the scans) is an error naming the file and what to pass.

use super::config::Pipeline;
use crate::error::{Error, Result};
use crate::methods::{Method, REGISTRY};
use crate::sources::{Input, SourceOptions};
use std::path::{Path, PathBuf};

/// What `run <source>…` or `loops <source>…` made: the pipeline (kept by the index), and the
/// sessions the sources hold.
pub struct Made {
    /// The pipeline.
    pub pipeline: Pipeline,
    /// Its text, as the index keeps it.
    pub text: String,
    /// The sessions the sources hold, in order.
    pub sessions: Vec<String>,
    /// Notes on the logs that hold no pose (`<log>: no poses in the log …`); where the others'
    /// come from, the run's summary says ([`crate::pipeline::RunSummary::poses`]).
    pub poses: Vec<String>,
}

/// The default index folder of `sources`: `out/<the first one's name>`.
pub fn default_index(sources: &[PathBuf]) -> PathBuf {
    let first = sources.first().map(|p| {
        let p = p.as_path();
        let name = if p.is_dir() { p.file_name() } else { p.file_stem() };
        name.map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "index".into())
    });
    PathBuf::from("out").join(first.unwrap_or_else(|| "index".into()))
}

/// Refuses the default index folder `index` (`out/<name>`) when it holds an index of other
/// sources: one none of whose sessions comes from any of `made`'s places (a log, a session
/// folder). Two sources of the same name (a copy of a session folder elsewhere, another
/// `drive.bag`) never share an index silently; the same sources, or some of them with others
/// added, reuse it incrementally.
pub fn check_default_index(index: &Path, made: &Made) -> Result<()> {
    if !index.join(crate::sinks::index::MANIFEST_FILE).is_file() {
        return Ok(());
    }
    let Ok(held) = Pipeline::of_index(index) else { return Ok(()) };
    let places = |p: &Pipeline| -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = p
            .sources
            .iter()
            .flat_map(|s| s.sessions().unwrap_or_default())
            .map(|(_, place)| std::fs::canonicalize(&place).unwrap_or(place))
            .collect();
        out.sort();
        out.dedup();
        out
    };
    let (theirs, ours) = (places(&held), places(&made.pipeline));
    if theirs.is_empty() || ours.iter().any(|p| theirs.contains(p)) {
        return Ok(());
    }
    let list = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ");
    Err(Error::index(
        index,
        format!(
            "holds the index of {}, not of {}: give --index DIR for this source's own index (or remove {})",
            list(&theirs),
            list(&ours),
            index.display()
        ),
    ))
}

/// The pipeline of `sources` with `options`, computing `methods` (toporec-plus when empty),
/// into `index`; its logs' poses settled (an error names the file and what to pass).
pub fn made(sources: &[PathBuf], options: &SourceOptions, methods: &[String], index: &Path) -> Result<Made> {
    if sources.is_empty() {
        return Err(Error::invalid("no source given"));
    }
    let mut specs = Vec::new();
    let mut poses = Vec::new();
    for path in sources {
        // Absolute: the pipeline is anchored at the index, wherever the command ran.
        let path = &std::path::absolute(path).unwrap_or_else(|_| path.clone());
        let input = Input::detect(path)?;
        let Some(spec) = input.source(options.topic.as_deref()) else {
            return Err(Error::invalid(format!(
                "{}: a single cloud file, not a source of scans (a folder of them is one)",
                path.display()
            )));
        };
        let spec = match spec.settle(options) {
            Some(settled) => {
                let (spec, note) = settled?;
                poses.extend(note);
                spec
            }
            None if options.asks_for_poses() => {
                return Err(Error::invalid(format!(
                    "{}: a {}: --poses, --poses-topic and --pose-frames are for message logs (its own poses are read)",
                    path.display(),
                    input.name()
                )));
            }
            None => spec,
        };
        specs.push(spec);
    }
    let names: Vec<String> = if methods.is_empty() {
        vec![crate::methods::toporec_plus::NAME.to_string()]
    } else {
        methods.to_vec()
    };
    let sections: Vec<Method> = REGISTRY.iter().map(|r| r.default_method()).collect();
    let pipeline = Pipeline::of_parts(index, specs, &names, &sections)?;
    let mut sessions = Vec::new();
    for s in &pipeline.sources {
        sessions.extend(s.sessions()?.into_iter().map(|(name, _)| name));
    }
    let text = pipeline.effective_toml(index);
    Ok(Made { pipeline, text, sessions, poses })
}
