//! Compaction: each partition's part files merged into one, written in the table's declared
//! layout whatever layout each input has, in one commit.

use super::{IndexWriter, Staged};
use crate::error::{Result, ResultExt};
use crate::methods::TOPOREC;
use crate::sinks::index::manifest::FileEntry;
use crate::sinks::parquet::TableFile;
use crate::sinks::schema::tables;
use std::collections::BTreeMap;

impl IndexWriter {
    /// Merges each partition's part files of each table into one file, in one commit.
    /// Returns how many files were merged into how many.
    pub fn compact(&mut self) -> Result<(usize, usize)> {
        let mut groups: BTreeMap<(String, Option<String>, String), Vec<FileEntry>> = BTreeMap::new();
        for f in &self.manifest.files {
            let method = (f.table == tables::DESCRIPTORS).then(|| f.method_name().to_string());
            groups.entry((f.table.clone(), method, f.session.clone())).or_default().push(f.clone());
        }
        let (mut merged, mut into) = (0, 0);
        for ((table, method, session), files) in groups.into_iter().filter(|(_, files)| files.len() > 1) {
            let table = tables::ALL.into_iter().find(|t| *t == table).expect("a table name");
            let length = match &method {
                Some(m) if m != TOPOREC => self.manifest.methods.get(m).map(|e| e.length),
                _ => self.manifest.descriptor_length,
            };
            let (rel, target) = self.next_part(table, method.as_deref(), &session);
            // Written in the table's declared layout, whatever layout each input has (a part an
            // older toporec wrote may lack a nullable column added since: nulls).
            let declared = crate::sinks::index::reader::declared(table, method.as_deref(), length)
                .expect("a table name");
            let mut extra = Vec::new();
            if let Some(m) = &method {
                let id = match self.manifest.methods.get(m) {
                    Some(e) => Some(e.id.clone()),
                    None => self.manifest.codebook_id.clone(),
                };
                extra.push((crate::sinks::schema::meta::CODEBOOK_ID, id.unwrap_or_default()));
                extra.push((crate::sinks::schema::meta::METHOD, m.clone()));
            }
            let mut out = TableFile::create(&target, &declared, &extra)?;
            for f in &files {
                let bytes = self.verified_bytes(f)?;
                let path = self.path_of(f);
                // Each input is read as its table: an error names the input.
                for batch in crate::sinks::index::reader::declared_batches(&path, bytes, &declared)? {
                    let batch = batch.with_schema(out.schema().clone()).at(&path)?;
                    out.write_batch(&batch)?;
                }
                self.dropped.insert(f.path.clone());
            }
            let (file, rows) = out.finish()?;
            self.compacted.push(Staged::of(table, method, &session, rel, file, rows)?);
            merged += files.len();
            into += 1;
        }
        crate::fault::point("compact-mid");
        self.commit()?;
        Ok((merged, into))
    }
}
