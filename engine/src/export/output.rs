//! Writing scene groups in one export format: one file (JSON or PNG of one scene) or a
//! directory of files, each written atomically so that a failure leaves no partial output.

use super::bvh_export::{person_to_bvh, write_scene_bvh, BvhExportOptions, ExportedBvh};
use super::png::{filmstrip_png, write_filmstrip, FilmstripOptions};
use super::{json, safe_file_name, write_dir_atomic, SceneGroup};
use crate::files::OutputKind;
use crate::{Error, Result, Scene};
use std::path::Path;

/// An export format with its options.
#[derive(Clone, Debug)]
pub enum ExportFormat {
    /// One BVH file per person (a directory).
    Bvh(BvhExportOptions),
    /// Joint positions as nested arrays, one file per sequence.
    Json,
    /// A filmstrip per scene, one row per sample.
    Png(FilmstripOptions),
}

/// What [`export_groups`] wrote.
#[derive(Clone, Debug, Default)]
pub struct Exported {
    /// Files written.
    pub files: usize,
    /// Sequences (JSON, BVH) or scenes (PNG) exported.
    pub items: usize,
    /// Whether `out` is a single file.
    pub single_file: bool,
    /// BVH only: each file's root joint and re-import errors (texts dropped).
    pub bvh: Vec<ExportedBvh>,
}

impl ExportFormat {
    /// File extension of the format.
    pub fn extension(&self) -> &'static str {
        match self {
            ExportFormat::Bvh(_) => "bvh",
            ExportFormat::Json => "json",
            ExportFormat::Png(_) => "png",
        }
    }

    /// The kind of a single output file, checked before it is replaced (BVH never writes one).
    pub fn single_file_kind(&self, out: &Path) -> Result<Option<OutputKind>> {
        let kind = match self {
            ExportFormat::Bvh(_) => None,
            ExportFormat::Json => Some(OutputKind::PositionsJson),
            ExportFormat::Png(_) => Some(OutputKind::Png),
        };
        let ext = self.extension();
        match out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase) {
            Some(e) if e == ext && kind.is_none() => Err(Error::format(out, "a BVH export writes a directory (one file per person); give a directory")),
            Some(e) if e == ext => Ok(kind),
            Some(e) if ["json", "png", "bvh", "html", "txt", "jpg"].contains(&e.as_str()) => {
                Err(Error::format(out, format!("expected a .{ext} file or a directory for a {ext} export")))
            }
            _ => Ok(None),
        }
    }
}

/// Writes `groups` to `out` in `format`: a single file when `out` ends in the format's
/// extension (one scene), else a directory of files. `on_progress(done, total)` counts
/// person-frames (BVH), sequences (JSON) or scenes (PNG).
pub fn export_groups(groups: &[SceneGroup], format: &ExportFormat, out: &Path, on_progress: &mut dyn FnMut(u64, u64)) -> Result<Exported> {
    let scenes: Vec<&Scene> = groups.iter().flat_map(|g| g.samples.iter().map(|s| &s.scene)).collect();
    if format.single_file_kind(out)?.is_some() {
        let items = if matches!(format, ExportFormat::Png(_)) { groups.len() } else { scenes.len() };
        if items != 1 {
            return Err(Error::format(out, format!("one file holds one scene, and the input holds {items}: pick one, or write a directory")));
        }
        match format {
            ExportFormat::Json => json::write_json(scenes[0], out)?,
            ExportFormat::Png(opts) => write_filmstrip(&groups[0], out, opts)?,
            ExportFormat::Bvh(_) => unreachable!("a BVH export is a directory"),
        }
        on_progress(1, 1);
        return Ok(Exported { files: 1, items: 1, single_file: true, bvh: Vec::new() });
    }
    write_dir_atomic(out, |dir| {
        let write = |name: &str, bytes: &[u8]| {
            let path = dir.join(name);
            std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))
        };
        match format {
            ExportFormat::Bvh(opts) => {
                let total = scenes.iter().map(|s| (s.num_frames() * s.num_persons()) as u64).sum();
                let mut done = 0;
                let mut bvh = Vec::new();
                for s in &scenes {
                    for mut e in write_scene_bvh(s, dir, opts, &mut |_| {
                        done += s.num_frames() as u64;
                        on_progress(done, total)
                    })? {
                        e.text = String::new();
                        bvh.push(e);
                    }
                }
                Ok(Exported { files: bvh.len(), items: scenes.len(), single_file: false, bvh })
            }
            ExportFormat::Json => {
                for (i, s) in scenes.iter().enumerate() {
                    write(&format!("{}.json", safe_file_name(&s.name)), json::scene_to_json(s)?.as_bytes())?;
                    on_progress(i as u64 + 1, scenes.len() as u64);
                }
                Ok(Exported { files: scenes.len(), items: scenes.len(), single_file: false, bvh: Vec::new() })
            }
            ExportFormat::Png(opts) => {
                for (i, g) in groups.iter().enumerate() {
                    write(&format!("{}.png", safe_file_name(&g.name)), &filmstrip_png(g, opts)?)?;
                    on_progress(i as u64 + 1, groups.len() as u64);
                }
                Ok(Exported { files: groups.len(), items: groups.len(), single_file: false, bvh: Vec::new() })
            }
        }
    })
}

/// Writes `dataset` as a dataset directory `out` with `bvh/` beside its splits: one BVH file
/// per person of every sequence (every text made before anything is written).
pub fn write_dataset_with_bvh(dataset: &crate::Dataset, out: &Path, opts: &BvhExportOptions) -> Result<Vec<ExportedBvh>> {
    let mut bvhs = Vec::new();
    for s in &dataset.sequences {
        for p in 0..s.scene.num_persons() {
            bvhs.push(person_to_bvh(&s.scene, p, opts)?);
        }
    }
    crate::data::dataset::write_dataset_with(dataset, out, |dir| {
        let bvh_dir = dir.join("bvh");
        std::fs::create_dir(&bvh_dir).map_err(|e| Error::io(&bvh_dir, e))?;
        for b in &bvhs {
            let path = bvh_dir.join(&b.file_name);
            std::fs::write(&path, &b.text).map_err(|e| Error::io(&path, e))?;
        }
        Ok(())
    })?;
    Ok(bvhs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::test_util::tmp;
    use crate::export::bvh_export::BvhUnits;

    fn groups() -> Vec<SceneGroup> {
        let a = crate::data::synthetic::walkers(12, 2, 0.0);
        let mut b = a.clone();
        b.name = "other".into();
        vec![SceneGroup::single(a, None).unwrap(), SceneGroup::single(b, None).unwrap()]
    }

    #[test]
    fn writes_a_directory_or_one_file() {
        let g = groups();
        let dir = tmp("export-output");
        let mut calls = Vec::new();
        let bvh = ExportFormat::Bvh(BvhExportOptions { units: BvhUnits::Metres, ..Default::default() });
        let e = export_groups(&g, &bvh, &dir.join("bvh"), &mut |d, t| calls.push((d, t))).unwrap();
        // Two scenes of two persons: four files, progress in person-frames up to 2 · 2 · 12.
        assert_eq!((e.files, e.items, e.single_file), (4, 2, false));
        assert_eq!(calls.last(), Some(&(48, 48)));
        assert_eq!(std::fs::read_dir(dir.join("bvh")).unwrap().count(), 4);
        assert!(e.bvh.iter().all(|b| b.text.is_empty() && b.max_error_m < 1e-3), "{:?}", e.bvh.iter().map(|b| b.max_error_m).collect::<Vec<_>>());
        let json = export_groups(&g, &ExportFormat::Json, &dir.join("json"), &mut |_, _| {}).unwrap();
        assert_eq!((json.files, std::fs::read_dir(dir.join("json")).unwrap().count()), (2, 2));
        // One file holds one scene: two are refused and nothing is written.
        let one = dir.join("one.json");
        let err = export_groups(&g, &ExportFormat::Json, &one, &mut |_, _| {}).unwrap_err().to_string();
        assert!(err.contains("one file holds one scene") && err.contains("holds 2"), "{err}");
        assert!(!one.exists());
        let single = export_groups(&g[..1], &ExportFormat::Json, &one, &mut |_, _| {}).unwrap();
        assert!(single.single_file && json::read_json(&one).unwrap().num_frames() == 12);
        // Extensions of other formats are refused; a BVH file name too.
        assert!(ExportFormat::Json.single_file_kind(&dir.join("x.png")).unwrap_err().to_string().contains("expected a .json file"));
        assert!(bvh.single_file_kind(&dir.join("x.bvh")).unwrap_err().to_string().contains("writes a directory"));
        assert_eq!(ExportFormat::Json.single_file_kind(&dir.join("plain")).unwrap(), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
