//! The docs cannot drift from the command line: every fenced `sh` block of README.md and
//! docs/*.md whose commands are toporec's own (`toporec …`, `cargo run --release -- …`, with
//! `sed` and `python3 scripts/…` beside them) and touch only `samples/`, `out/` and the sample
//! pipelines runs, in order, with the binary the tests build, in a scratch folder laid out as
//! the repository. A block whose first line says it takes minutes is left out.

use crate::util::*;
use std::path::PathBuf;
use std::process::Command;

/// The fenced `sh` blocks of a Markdown text, each as its lines.
fn sh_blocks(text: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut current: Option<Vec<String>> = None;
    for line in text.lines() {
        match (&mut current, line.trim_start()) {
            (None, "```sh") => current = Some(Vec::new()),
            (Some(_), "```") => out.push(current.take().expect("in a block")),
            (Some(block), _) => block.push(line.to_string()),
            _ => {}
        }
    }
    out
}

/// A block's commands: continuation lines joined, comments and blank lines dropped.
fn commands(block: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    let mut pending = String::new();
    for line in block {
        let line = strip_comment(line);
        if let Some(head) = line.trim_end().strip_suffix('\\') {
            pending.push_str(head);
            pending.push(' ');
            continue;
        }
        pending.push_str(&line);
        let command = std::mem::take(&mut pending).trim().to_string();
        if !command.is_empty() {
            out.push(command);
        }
    }
    out
}

/// The line without a `#` comment (a `#` outside quotes, after a space or at the start).
fn strip_comment(line: &str) -> String {
    let (mut quote, mut prev) = (None, ' ');
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '\'' | '"') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            (None, '#') if prev.is_whitespace() => return line[..i].to_string(),
            _ => {}
        }
        prev = c;
    }
    line.to_string()
}

/// Whether a block's commands are ones this test runs (see the module doc).
fn runnable(commands: &[String]) -> bool {
    const PATHS: [&str; 5] =
        ["samples/", "out/", "pipelines/sample.toml", "pipelines/compare.toml", "scripts/"];
    !commands.is_empty()
        && commands.iter().all(|c| {
            let words: Vec<&str> = c.split_whitespace().collect();
            let tool_ok = matches!(words.first(), Some(&"toporec") | Some(&"sed"))
                || c.starts_with("cargo run --release -- ")
                || c.starts_with("python3 scripts/");
            let paths_ok = words.iter().all(|w| {
                let w = w.trim_matches(|ch| ch == '\'' || ch == '"');
                // Path-like words: with a folder or a file extension (sed programs and scan-id
                // globs are not paths).
                let extensions = [".parquet", ".npy", ".csv", ".toml", ".json", ".txt", ".mcap", ".bin"];
                let path_like = (w.contains('/') || extensions.iter().any(|x| w.ends_with(x)))
                    && !w.starts_with("s#")
                    && !w.starts_with('*')
                    && !w.chars().next().is_some_and(|ch| ch.is_ascii_digit());
                !path_like || PATHS.iter().any(|p| w.starts_with(p))
            });
            tool_ok && paths_ok
        })
}

#[test]
fn every_doc_command_on_the_samples_runs() {
    let dir = scratch_dir("docs_commands");
    // The repository's layout: the sample pipelines (copied, so their relative paths stay in
    // here), the samples and scripts (read only), a fresh out/, and `toporec` on the PATH.
    std::fs::create_dir_all(dir.join("pipelines")).unwrap();
    for f in ["sample.toml", "compare.toml"] {
        std::fs::copy(root().join("pipelines").join(f), dir.join("pipelines").join(f)).unwrap();
    }
    for link in ["samples", "scripts"] {
        std::os::unix::fs::symlink(root().join(link), dir.join(link)).unwrap();
    }
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_toporec"), bin.join("toporec")).unwrap();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());

    let mut docs: Vec<PathBuf> = vec![root().join("README.md")];
    let mut rest: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    rest.sort();
    docs.extend(rest);
    let (mut ran, mut left) = (0, 0);
    for doc in &docs {
        let name = doc.strip_prefix(root()).unwrap_or(doc).display().to_string();
        for block in sh_blocks(&std::fs::read_to_string(doc).unwrap()) {
            let long = block.first().is_some_and(|l| l.contains("takes") && l.contains("minutes"));
            let commands = commands(&block);
            if long || !runnable(&commands) {
                left += 1;
                continue;
            }
            for command in &commands {
                let shell = command.replacen("cargo run --release -- ", "toporec ", 1);
                let o = Command::new("bash")
                    .args(["-euo", "pipefail", "-c", &shell])
                    .current_dir(&dir)
                    .env("PATH", &path)
                    .output()
                    .unwrap();
                assert!(
                    o.status.success(),
                    "{name}: `{command}` failed:\n{}{}",
                    text(&o.stdout),
                    text(&o.stderr)
                );
                ran += 1;
            }
        }
    }
    println!("{ran} commands run; {left} blocks left out (other data, or minutes long)");
    assert!(ran >= 7, "the README's quick tour at least: {ran}");
}

/// The README's quick tour, line by line as a reader types it (comments and all), in a
/// scratch copy of the repository with `toporec` on the PATH, as its install step puts it: each
/// exits 0. The install step puts the binary on the PATH.
#[test]
fn the_readme_tour_runs_as_written() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let install = readme.split("## Install").nth(1).and_then(|s| sh_blocks(s).into_iter().next()).unwrap();
    assert!(
        install.iter().any(|l| l.starts_with("cargo install --locked --path .")),
        "the install step puts toporec on the PATH: {install:?}"
    );
    let tour = readme.split("## A quick tour").nth(1).and_then(|s| sh_blocks(s).into_iter().next()).unwrap();
    assert!(runnable(&commands(&tour)), "every tour line runs on the samples: {tour:?}");
    let dir = scratch_dir("docs_tour");
    for f in ["samples", "pipelines"] {
        copy_tree(&root().join(f), &dir.join(f));
    }
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_toporec"), bin.join("toporec")).unwrap();
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let lines: Vec<&String> = tour.iter().filter(|l| !l.trim().is_empty()).collect();
    assert!(lines.len() >= 8, "{lines:?}");
    for line in lines {
        let o =
            Command::new("bash").args(["-c", line]).current_dir(&dir).env("PATH", &path).output().unwrap();
        assert!(o.status.success(), "`{line}` failed:\n{}{}", text(&o.stdout), text(&o.stderr));
    }
    // The tour's query asks where day 2 was on day 1: no scan finds itself.
    let line = tour.iter().find(|l| l.starts_with("toporec query --index out/sample")).unwrap();
    let o = Command::new("bash").args(["-c", line]).current_dir(&dir).env("PATH", &path).output().unwrap();
    let hits = text(&o.stdout);
    for row in hits.lines().skip(1) {
        let c: Vec<&str> = row.split(',').collect();
        assert_eq!(c[3], "2026-01-01", "{row}");
    }
}

/// Copies a folder tree.
fn copy_tree(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        let target = to.join(e.file_name());
        if e.path().is_dir() {
            copy_tree(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

#[test]
fn blocks_are_read_as_a_shell_reads_them() {
    let block: Vec<String> =
        ["# a comment", "toporec a \\", "    --b 'x # y' # c", "", "toporec d"].map(String::from).to_vec();
    assert_eq!(commands(&block), ["toporec a      --b 'x # y'", "toporec d"]);
    assert!(runnable(&["toporec query --index out/x samples/town -k 3".into()]));
    assert!(!runnable(&["toporec run pipelines/nclt.toml --index /shared/x".into()]));
    assert!(!runnable(&["pip install ./python".into()]));
    assert!(!runnable(&["toporec import --index out/x --method m vectors.parquet".into()]));
}

/// The lists of methods and sources the registries know, where the docs and the manifest's
/// schema spell them out: every computed method in the pipeline-file reference (its
/// `descriptors.methods`) and the baselines' page, every source kind in the pipeline-file reference, and the manifest schema's
/// method kinds equal to the registry.
#[test]
fn the_docs_list_every_registered_method_and_source() {
    let read = |p: &str| std::fs::read_to_string(root().join(p)).unwrap();
    let (pipeline_files, baselines) = (read("docs/pipeline-files.md"), read("docs/baselines.md"));
    let names = |text: &str, name: &str| {
        [format!("`{name}`"), format!("\"{name}\""), format!("[{name}]")]
            .iter()
            .any(|n| text.contains(n.as_str()))
    };
    for name in toporec::methods::computed_names() {
        assert!(names(&pipeline_files, name), "docs/pipeline-files.md does not name `{name}`");
        assert!(names(&baselines, name), "docs/baselines.md does not name `{name}`");
    }
    for kind in toporec::sources::SOURCES {
        assert!(
            pipeline_files.contains(&format!("kind = \"{}\"", kind.name)),
            "docs/pipeline-files.md: no `kind = \"{}\"`",
            kind.name
        );
    }
    let schema = read_json(&root().join("schemas/manifest.json"));
    let kinds = &schema["properties"]["methods"]["additionalProperties"]["properties"]["kind"]["enum"];
    let mut listed: Vec<&str> =
        kinds.as_array().expect("the kinds' enum").iter().map(|k| k.as_str().unwrap()).collect();
    let mut known = toporec::methods::computed_names();
    known.push("imported");
    listed.sort();
    known.sort();
    assert_eq!(listed, known, "schemas/manifest.json: the method kinds");
}
