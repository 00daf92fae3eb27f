//! Haggling (Joo et al., CVPR 2019; CMU Panoptic Studio): body and speech pickles → [`Scene`].
//!
//! Both file kinds are Python pickles (Python-2 protocol 0 in the released dataset; Python-3
//! protocols 2–5 also occur), read by the safe reader in [`super::pickle`].
//!
//! # Body files (`panopticDB_body_pkl_hagglingProcessed/<name>.pkl`)
//! A dict with `startFrame`, `buyerId`, `sellerIds`, `winnerId`, `leftSellerId`,
//! `rightSellerId` and `subjects`: three dicts (buyer, winner, loser), each with `humanId`,
//! `joints19` `[57, frames]` (19 Panoptic joints, x y z interleaved per joint, centimetres,
//! y down), `scores` `[19, frames]`, `bodyNormal` and `faceNormal` `[3, frames]`; other keys are
//! ignored. [`load_body`] converts every joint with `(x, y, z) ↦ (x, z, −y) / 100` — metres, z up,
//! a proper rotation (determinant +1), as the reference implementation does — and builds a scene
//! at 30 fps on [`Skeleton::panoptic19`]:
//! - persons in file order (buyer, winner, loser); [`Person::id`] is the `humanId`; roles are
//!   `buyer`, `left_seller` and `right_seller` (from `leftSellerId` / `rightSellerId`);
//! - metadata: `source` (the file), `format` (`haggling_body_pkl`), `start_frame`, `buyer_id`,
//!   `seller_ids`, `left_seller_id`, `right_seller_id`, `winner_id` (and `end_frame` when the file
//!   has `endFrame`);
//! - validity: a person's pose at a frame is invalid when it is obviously missing — any
//!   coordinate non-finite, or all 57 coordinates exactly zero. Such poses are replaced by the
//!   person's nearest earlier valid pose (or the nearest later one at the start) so positions
//!   stay finite, and [`Scene::valid`] marks them; it is `None` when every pose is valid. A person
//!   without any valid pose is an error;
//! - `scores`, `bodyNormal` and `faceNormal` are not read (the reference discards them too);
//! - checks: exactly three subjects whose `humanId`s are `{buyerId} ∪ sellerIds`, `leftSellerId`
//!   and `rightSellerId` are the two sellers, `winnerId` is a seller, and every `joints19` has the
//!   same number of frames (a mismatch is an error naming the file and both subjects).
//!
//! # Speech files (`panopticDB_speech_pkl_hagglingProcessed/<name>.pkl`)
//! A dict with `startFrame`, `endFrame`, the same id keys, and `speechData`: three dicts with
//! `humanId`, `indicator` (float64 0/1, one entry per frame) and `word` (per frame, `None` or the
//! word being said). In all six real files checked, `indicator` has exactly
//! `endFrame − startFrame + 1` entries (the frame range is inclusive), and the speakers'
//! `humanId`s are `{buyerId} ∪ sellerIds`; [`load_speech`] requires both.
//!
//! # Alignment
//! Entry `i` of an indicator belongs to absolute frame `speech.startFrame + i`; body frame `t`
//! is absolute frame `body.startFrame + t`. [`scene_from_files`] / [`attach_speech`] add a
//! `speaking` signal `[frames, persons]` with `speaking[t, p] = indicator_p[body.startFrame + t −
//! speech.startFrame]`, requiring the speech file to cover every body frame and the buyer / left /
//! right ids to agree. With the dataset's files (same `startFrame`; per the reference the body
//! has `endFrame − startFrame` frames and the indicator one entry more — no real body file was
//! available to confirm the body side) this uses all but the last indicator entry, exactly the
//! reference's "drop the last entry".

use super::pickle::{read_pickle, NdArray, Value};
use super::scene::{Person, Scene};
use super::skeleton::Skeleton;
use crate::{bail, Error, Result};
use ndarray::{Array2, Array4};
use std::path::Path;

/// Frame rate of the Haggling recordings (Hz).
pub const FPS: f64 = 30.0;

/// One person's speech annotation.
#[derive(Clone, Debug, PartialEq)]
pub struct Speaker {
    /// The person's `humanId`.
    pub human_id: i64,
    /// 1.0 while the person speaks, else 0.0; entry `i` is frame `start_frame + i`.
    pub indicator: Vec<f32>,
    /// Per entry, the word being said (`None` when silent), if the file has `word`.
    pub words: Option<Vec<Option<String>>>,
}

/// A Haggling speech file.
#[derive(Clone, Debug, PartialEq)]
pub struct SpeechFile {
    /// First annotated frame (absolute).
    pub start_frame: i64,
    /// Last annotated frame (absolute, inclusive).
    pub end_frame: i64,
    /// `humanId` of the buyer.
    pub buyer_id: i64,
    /// `humanId`s of the two sellers.
    pub seller_ids: Vec<i64>,
    /// `humanId` of the seller on the buyer's left.
    pub left_seller_id: i64,
    /// `humanId` of the seller on the buyer's right.
    pub right_seller_id: i64,
    /// `humanId` of the seller who won the sale.
    pub winner_id: i64,
    /// One entry per person, in file order; each indicator has `end_frame − start_frame + 1`
    /// entries.
    pub speakers: Vec<Speaker>,
}

impl SpeechFile {
    /// Number of annotated frames, `end_frame − start_frame + 1`.
    pub fn num_entries(&self) -> usize {
        self.speakers.first().map_or(0, |s| s.indicator.len())
    }

    /// The speaker with this `humanId`.
    pub fn speaker(&self, human_id: i64) -> Option<&Speaker> {
        self.speakers.iter().find(|s| s.human_id == human_id)
    }
}

impl SpeechFile {
    /// What `socdiff data inspect` prints for a speech file read from `path`.
    pub fn report(&self, path: &Path) -> String {
        use std::fmt::Write as _;
        let mut out = format!("{}: Haggling speech annotations (no poses)\n", path.display());
        let _ = writeln!(out, "frames        {}..{} ({} frames)", self.start_frame, self.end_frame, self.end_frame - self.start_frame + 1);
        let _ = writeln!(out, "buyer         {}", self.buyer_id);
        let _ = writeln!(out, "sellers       {:?} (left {}, right {})", self.seller_ids, self.left_seller_id, self.right_seller_id);
        for sp in &self.speakers {
            let (n, speaking) = (sp.indicator.len(), sp.indicator.iter().filter(|&&v| v > 0.5).count());
            let _ = writeln!(out, "person {:>4}  {n} indicator values, speaking {:.1} % of frames", sp.human_id, 100.0 * speaking as f64 / n.max(1) as f64);
        }
        out
    }
}

/// Reads a speech file, checking that every indicator is 0/1 with `endFrame − startFrame + 1`
/// entries and that the speakers are the buyer and the two sellers. Errors name the file.
pub fn load_speech(path: &Path) -> Result<SpeechFile> {
    let v = read_pickle(path)?;
    parse_speech(&v).map_err(|e| e.in_file(path))
}

/// [`load_speech`] on an already parsed pickle.
pub fn parse_speech(v: &Value) -> Result<SpeechFile> {
    let ids = Ids::parse(v)?;
    let start_frame = v.req_i64("startFrame")?;
    let end_frame = v.req_i64("endFrame")?;
    if end_frame < start_frame {
        bail!("endFrame {end_frame} is before startFrame {start_frame}");
    }
    let expected = end_frame - start_frame + 1;
    let data = v.req_list("speechData")?;
    let mut speakers = Vec::with_capacity(data.len().min(16));
    for (i, sp) in data.iter().enumerate() {
        let human_id = sp.req_i64("humanId").map_err(|e| Error::invalid(format!("speechData[{i}]: {e}")))?;
        let who = format!("speechData[{i}] (humanId {human_id})");
        let raw = numbers(sp.req("indicator")?).ok_or_else(|| Error::invalid(format!("{who}: indicator is not a 1-D numeric array")))?;
        if raw.len() as i64 != expected {
            bail!("{who}: indicator has {} entries, expected endFrame − startFrame + 1 = {end_frame} − {start_frame} + 1 = {expected}", raw.len());
        }
        if let Some(k) = raw.iter().position(|&x| x != 0.0 && x != 1.0) {
            bail!("{who}: indicator entry {k} is {}, expected 0 or 1", raw[k]);
        }
        let words = match sp.get("word") {
            None | Some(Value::None) => None,
            Some(w) => {
                let list = w.as_list().ok_or_else(|| Error::invalid(format!("{who}: word is a {}, expected a list", w.type_name())))?;
                if list.len() != raw.len() {
                    bail!("{who}: word has {} entries, indicator {}", list.len(), raw.len());
                }
                let words: Option<Vec<Option<String>>> = list
                    .iter()
                    .map(|x| match x {
                        Value::None => Some(None),
                        other => other.as_str().map(|s| Some(s.to_string())),
                    })
                    .collect();
                Some(words.ok_or_else(|| Error::invalid(format!("{who}: word entries must be strings or None")))?)
            }
        };
        speakers.push(Speaker { human_id, indicator: raw.iter().map(|&x| x as f32).collect(), words });
    }
    let found: Vec<i64> = speakers.iter().map(|s| s.human_id).collect();
    ids.check_people(&found, "speechData")?;
    Ok(SpeechFile {
        start_frame,
        end_frame,
        buyer_id: ids.buyer,
        seller_ids: ids.sellers,
        left_seller_id: ids.left,
        right_seller_id: ids.right,
        winner_id: ids.winner,
        speakers,
    })
}

/// Reads a body file into a scene (see the module documentation for the conversion, roles,
/// metadata and validity). Errors name the file.
pub fn load_body(path: &Path) -> Result<Scene> {
    let v = read_pickle(path)?;
    let name = path.file_stem().map_or_else(|| "haggling".to_string(), |s| s.to_string_lossy().into_owned());
    let mut scene = parse_body(&v, &name).map_err(|e| e.in_file(path))?;
    scene.metadata.insert("source".into(), path.display().to_string().into());
    Ok(scene)
}

/// [`load_body`] on an already parsed pickle; `name` becomes the scene name.
pub fn parse_body(v: &Value, name: &str) -> Result<Scene> {
    let ids = Ids::parse(v)?;
    let start_frame = v.req_i64("startFrame")?;
    let subjects = v.req_list("subjects")?;
    if subjects.len() != 3 {
        bail!("subjects has {} entries, expected 3 (buyer, winner, loser)", subjects.len());
    }
    let mut human_ids: Vec<i64> = Vec::new();
    let mut joints: Vec<&NdArray> = Vec::new();
    for (i, s) in subjects.iter().enumerate() {
        let hid = s.req_i64("humanId").map_err(|e| Error::invalid(format!("subjects[{i}]: {e}")))?;
        let j = s.req_array("joints19").map_err(|e| Error::invalid(format!("subjects[{i}] (humanId {hid}): {e}")))?;
        match j.shape() {
            [57, t] if *t > 0 && j.data.len() == 57 * *t => {}
            other => bail!("subjects[{i}] (humanId {hid}): joints19 has shape {other:?}, expected [57, frames] with frames > 0"),
        }
        if let (Some(first), Some(first_id)) = (joints.first(), human_ids.first()) {
            let (n, n0) = (j.shape()[1], first.shape()[1]);
            if n != n0 {
                bail!("subjects[{i}] (humanId {hid}) has {n} frames in joints19 but subjects[0] (humanId {first_id}) has {n0}");
            }
        }
        human_ids.push(hid);
        joints.push(j);
    }
    ids.check_people(&human_ids, "subjects")?;
    let frames = joints[0].shape()[1];
    let persons = joints.len();

    // (x, y, z) cm, y down ↦ (x, z, −y) / 100 m, z up.
    let mut positions = Array4::<f32>::zeros((frames, persons, 19, 3));
    let mut valid = Array2::from_elem((frames, persons), true);
    for (p, j) in joints.iter().enumerate() {
        let d = &j.data; // [57, frames], C order
        for t in 0..frames {
            let at = |r: usize| d[r * frames + t];
            // Missing: all zeros, or anything non-finite (also after conversion to f32).
            let mut pose = [[0f32; 3]; 19];
            for (k, xyz) in pose.iter_mut().enumerate() {
                let (x, y, z) = (at(3 * k), at(3 * k + 1), at(3 * k + 2));
                *xyz = [(x / 100.0) as f32, (z / 100.0) as f32, (-y / 100.0) as f32];
            }
            let all_zero = (0..57).all(|r| at(r) == 0.0);
            if all_zero || !pose.iter().flatten().all(|c| c.is_finite()) {
                valid[[t, p]] = false;
                continue;
            }
            for (k, xyz) in pose.iter().enumerate() {
                for (c, &x) in xyz.iter().enumerate() {
                    positions[[t, p, k, c]] = x;
                }
            }
        }
        fill_missing(&mut positions, &valid, p)
            .map_err(|()| Error::invalid(format!("subjects[{p}] (humanId {}): no valid pose in {frames} frames", human_ids[p])))?;
    }

    let mut scene = Scene::new(name, FPS, Skeleton::panoptic19(), positions)?;
    if valid.iter().any(|&v| !v) {
        scene = scene.with_valid(valid)?;
    }
    let persons: Vec<Person> = human_ids.iter().map(|&h| Person { id: h.to_string(), role: Some(ids.role(h).to_string()) }).collect();
    scene = scene.with_persons(persons)?;
    let m = &mut scene.metadata;
    m.insert("format".into(), "haggling_body_pkl".into());
    m.insert("start_frame".into(), start_frame.into());
    if let Some(e) = v.get("endFrame").and_then(Value::as_i64) {
        m.insert("end_frame".into(), e.into());
    }
    m.insert("buyer_id".into(), ids.buyer.into());
    m.insert("seller_ids".into(), ids.sellers.clone().into());
    m.insert("left_seller_id".into(), ids.left.into());
    m.insert("right_seller_id".into(), ids.right.into());
    m.insert("winner_id".into(), ids.winner.into());
    Ok(scene)
}

/// Replaces invalid poses of person `p` by the nearest earlier valid pose (nearest later one
/// before the first valid frame). `Err(())` if the person has no valid pose.
fn fill_missing(positions: &mut Array4<f32>, valid: &Array2<bool>, p: usize) -> std::result::Result<(), ()> {
    let frames = valid.nrows();
    let first = (0..frames).find(|&t| valid[[t, p]]).ok_or(())?;
    let mut src = first;
    for t in 0..frames {
        if valid[[t, p]] {
            src = t;
        } else {
            for k in 0..19 {
                for c in 0..3 {
                    positions[[t, p, k, c]] = positions[[src, p, k, c]];
                }
            }
        }
    }
    Ok(())
}

/// Loads a body file and, if given, its speech file, adding the `speaking` signal (see
/// [`attach_speech`]). Errors name the file at fault.
pub fn scene_from_files(body: &Path, speech: Option<&Path>) -> Result<Scene> {
    let scene = load_body(body)?;
    let Some(speech_path) = speech else { return Ok(scene) };
    let sp = load_speech(speech_path)?;
    let mut scene = attach_speech(scene, &sp).map_err(|e| match e {
        Error::Invalid(msg) => Error::format(speech_path, format!("{msg} (body file {})", body.display())),
        other => other,
    })?;
    scene.metadata.insert("speech_source".into(), speech_path.display().to_string().into());
    Ok(scene)
}

/// Adds the `speaking` signal `[frames, persons]` to a scene from [`load_body`], matching
/// persons by `humanId` and frames by absolute frame number (`start_frame` in the scene's
/// metadata): `speaking[t, p] = indicator_p[start_frame + t − speech.start_frame]`.
///
/// Errors when the ids differ, a person has no speech entry, or the speech file does not cover
/// every body frame.
pub fn attach_speech(scene: Scene, speech: &SpeechFile) -> Result<Scene> {
    let body_start = scene
        .metadata
        .get("start_frame")
        .and_then(serde_json::Value::as_i64)
        .ok_or_else(|| Error::invalid(format!("scene {} has no start_frame in its metadata (not from a Haggling body file?)", scene.name)))?;
    let frames = scene.num_frames();
    let entries = speech.num_entries() as i64;
    let offset = body_start - speech.start_frame;
    if offset < 0 || offset + frames as i64 > entries {
        bail!(
            "speech annotations cover frames {}..={} but the body has frames {}..={} ({} frames from startFrame {})",
            speech.start_frame,
            speech.start_frame + entries - 1,
            body_start,
            body_start + frames as i64 - 1,
            frames,
            body_start
        );
    }
    for (what, a, b) in [
        ("buyerId", scene.metadata.get("buyer_id").and_then(serde_json::Value::as_i64), speech.buyer_id),
        ("leftSellerId", scene.metadata.get("left_seller_id").and_then(serde_json::Value::as_i64), speech.left_seller_id),
        ("rightSellerId", scene.metadata.get("right_seller_id").and_then(serde_json::Value::as_i64), speech.right_seller_id),
    ] {
        if let Some(a) = a {
            if a != b {
                bail!("{what} is {b} in the speech file but {a} in the body file");
            }
        }
    }
    let mut speaking = Array2::<f32>::zeros((frames, scene.num_persons()));
    for (p, person) in scene.persons.iter().enumerate() {
        let hid: i64 = person.id.parse().map_err(|_| Error::invalid(format!("person id {:?} is not a Haggling humanId", person.id)))?;
        let sp = speech.speaker(hid).ok_or_else(|| Error::invalid(format!("no speech annotation for humanId {hid}")))?;
        let entries = sp
            .indicator
            .get(offset as usize..offset as usize + frames)
            .ok_or_else(|| Error::invalid(format!("humanId {hid}: indicator has {} entries, fewer than the body needs", sp.indicator.len())))?;
        for (t, &x) in entries.iter().enumerate() {
            speaking[[t, p]] = x;
        }
    }
    scene.with_signal("speaking", speaking)
}

/// The id keys shared by body and speech files.
struct Ids {
    buyer: i64,
    sellers: Vec<i64>,
    left: i64,
    right: i64,
    winner: i64,
}

impl Ids {
    fn parse(v: &Value) -> Result<Self> {
        let sellers: Vec<i64> = v
            .req_list("sellerIds")?
            .iter()
            .map(|x| x.as_i64().ok_or_else(|| Error::invalid(format!("sellerIds holds a {}, expected integers", x.type_name()))))
            .collect::<Result<_>>()?;
        let ids = Self {
            buyer: v.req_i64("buyerId")?,
            sellers,
            left: v.req_i64("leftSellerId")?,
            right: v.req_i64("rightSellerId")?,
            winner: v.req_i64("winnerId")?,
        };
        let s = &ids.sellers;
        if s.len() != 2 || s[0] == s[1] || s.contains(&ids.buyer) {
            bail!("sellerIds {s:?} must be two distinct ids other than buyerId {}", ids.buyer);
        }
        let mut lr = [ids.left, ids.right];
        lr.sort_unstable();
        let mut ss = [s[0], s[1]];
        ss.sort_unstable();
        if lr != ss {
            bail!("leftSellerId {} and rightSellerId {} are not the sellerIds {s:?}", ids.left, ids.right);
        }
        if !s.contains(&ids.winner) {
            bail!("winnerId {} is not one of the sellerIds {s:?}", ids.winner);
        }
        Ok(ids)
    }

    /// Checks that `found` (humanIds in file order) is a permutation of {buyer} ∪ sellers.
    fn check_people(&self, found: &[i64], what: &str) -> Result<()> {
        let mut a = found.to_vec();
        a.sort_unstable();
        let mut b = vec![self.buyer, self.sellers[0], self.sellers[1]];
        b.sort_unstable();
        if a != b {
            bail!("{what} has humanIds {found:?}, expected buyerId {} and sellerIds {:?}", self.buyer, self.sellers);
        }
        Ok(())
    }

    fn role(&self, human_id: i64) -> &'static str {
        if human_id == self.buyer {
            "buyer"
        } else if human_id == self.left {
            "left_seller"
        } else {
            "right_seller"
        }
    }
}

/// The numbers of a 1-D array or a list of numbers.
fn numbers(v: &Value) -> Option<Vec<f64>> {
    match v {
        Value::NdArray(a) if a.ndim() == 1 => Some(a.data.clone()),
        Value::List(items) | Value::Tuple(items) => items.iter().map(Value::as_f64).collect(),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::pickle::NdArray;
    use std::path::PathBuf;

    fn fixture(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/haggling").join(name)
    }

    fn real_speech_files() -> Vec<PathBuf> {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/haggling_speech"));
        if !dir.is_dir() {
            crate::testing::skip_absent(dir, "real Haggling speech files");
            return Vec::new();
        }
        let mut files: Vec<PathBuf> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "pkl")).collect();
        files.sort();
        assert_eq!(files.len(), 6, "expected the six real speech files in {}", dir.display());
        files
    }

    /// All six real files: indicator length is endFrame − startFrame + 1, values 0/1, speakers
    /// are {buyerId} ∪ sellerIds, words line up with the indicator.
    #[test]
    fn real_speech_files_load_and_satisfy_the_length_relation() {
        for path in real_speech_files() {
            let raw = read_pickle(&path).unwrap();
            let (start, end) = (raw.req_i64("startFrame").unwrap(), raw.req_i64("endFrame").unwrap());
            let sp = load_speech(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!((sp.start_frame, sp.end_frame), (start, end));
            assert_eq!(sp.speakers.len(), 3);
            let mut ids: Vec<i64> = sp.speakers.iter().map(|s| s.human_id).collect();
            ids.sort_unstable();
            let mut want = vec![sp.buyer_id, sp.seller_ids[0], sp.seller_ids[1]];
            want.sort_unstable();
            assert_eq!(ids, want, "{}", path.display());
            assert!(sp.seller_ids.contains(&sp.winner_id));
            for s in &sp.speakers {
                // The relation found in every real file: one entry per frame of the inclusive
                // range startFrame..=endFrame.
                assert_eq!(s.indicator.len() as i64, end - start + 1, "{} humanId {}", path.display(), s.human_id);
                assert!(s.indicator.iter().all(|&x| x == 0.0 || x == 1.0));
                let words = s.words.as_ref().expect("real files have words");
                assert_eq!(words.len(), s.indicator.len());
                for (w, &x) in words.iter().zip(&s.indicator) {
                    assert_eq!(w.is_some(), x == 1.0, "{}: words are present exactly while speaking", path.display());
                }
            }
            assert_eq!(sp.num_entries() as i64, end - start + 1);
        }
    }

    /// Checks a body fixture against its own raw pickle: every joint is (x, z, −y)/100.
    fn check_conversion(path: &Path, scene: &Scene) {
        let raw = read_pickle(path).unwrap();
        let subjects = raw.req_list("subjects").unwrap();
        for (p, s) in subjects.iter().enumerate() {
            let j: &NdArray = s.req_array("joints19").unwrap();
            let frames = j.shape()[1];
            for t in 0..frames {
                if !scene.is_valid(t, p) {
                    continue;
                }
                for k in 0..19 {
                    let at = |r: usize| j.data[r * frames + t];
                    let want = [at(3 * k) / 100.0, at(3 * k + 2) / 100.0, -at(3 * k + 1) / 100.0];
                    for (c, w) in want.iter().enumerate() {
                        let got = scene.positions[[t, p, k, c]] as f64;
                        assert!((got - w).abs() < 1e-5, "{}: frame {t} person {p} joint {k}", path.display());
                    }
                }
            }
        }
    }

    fn check_body(name: &str, frames: usize) -> Scene {
        let path = fixture(name);
        let scene = load_body(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.positions.dim(), (frames, 3, 19, 3), "{name}");
        assert_eq!(scene.fps, 30.0);
        assert_eq!(scene.skeleton, Skeleton::panoptic19());
        assert_eq!(scene.name, name.trim_end_matches(".pkl"));
        // Ids and roles (file order: buyer 5, winner 4 = left seller, loser 3 = right seller).
        let ids: Vec<(&str, Option<&str>)> = scene.persons.iter().map(|p| (p.id.as_str(), p.role.as_deref())).collect();
        assert_eq!(ids, [("5", Some("buyer")), ("4", Some("left_seller")), ("3", Some("right_seller"))], "{name}");
        assert_eq!(scene.metadata["winner_id"], 4);
        assert_eq!(scene.metadata["start_frame"], 1000);
        assert!(scene.metadata["source"].as_str().unwrap().ends_with(name));
        // Known value: the buyer's neck at frame 0 is at world (0, −1, 1.45) m,
        // Panoptic (0, −145, −100) cm.
        let neck = scene.positions.slice(ndarray::s![0, 0, 0, ..]).to_vec();
        for (g, w) in neck.iter().zip([0.0f32, -1.0, 1.45]) {
            assert!((g - w).abs() < 1e-5, "{name}: neck {neck:?}");
        }
        // Upright: head (nose) above pelvis above both ankles, for everyone, always.
        for t in 0..frames {
            for p in 0..3 {
                let z = |j: usize| scene.positions[[t, p, j, 2]];
                assert!(z(1) > z(2) && z(2) > z(8) && z(2) > z(14), "{name}: frame {t} person {p}");
                assert!(z(8) > 0.0 && z(8) < 0.2, "{name}: ankles near the floor");
            }
        }
        check_conversion(&path, &scene);
        scene
    }

    #[test]
    fn body_protocol0_python2() {
        let scene = check_body("body_p0.pkl", 10);
        assert!(scene.valid.is_none());
        assert!(scene.signals.is_empty());
    }

    #[test]
    fn body_protocol2_with_missing_pose_and_extra_keys() {
        let scene = check_body("body_p2.pkl", 30);
        // The buyer's all-zero pose at frame 7 is invalid and filled from frame 6.
        assert_eq!(scene.num_invalid(), 1);
        assert!(!scene.is_valid(7, 0) && scene.is_valid(7, 1) && scene.is_valid(6, 0));
        assert_eq!(scene.person(0).index_axis(ndarray::Axis(0), 7), scene.person(0).index_axis(ndarray::Axis(0), 6));
        assert_eq!(scene.metadata["end_frame"], 1030);
    }

    #[test]
    fn body_protocol4_float32_fortran() {
        let scene = check_body("body_p4.pkl", 30);
        assert!(scene.valid.is_none());
        // Same motion as the protocol-2 file (f4 precision), except the missing pose.
        let p2 = load_body(&fixture("body_p2.pkl")).unwrap();
        for (a, b) in scene.positions.iter().zip(p2.positions.iter()).skip(19 * 3 * 3 * 8) {
            assert!((a - b).abs() < 1e-4);
        }
    }

    #[test]
    fn speech_fixture_and_scene_with_speaking_signal() {
        let sp = load_speech(&fixture("speech_p0.pkl")).unwrap();
        assert_eq!((sp.start_frame, sp.end_frame, sp.num_entries()), (1000, 1030, 31));
        assert_eq!((sp.buyer_id, sp.left_seller_id, sp.right_seller_id, sp.winner_id), (5, 4, 3, 4));
        // The generator's pattern: humanId h speaks at entry i when (i + phase_h) % 20 < 6.
        let expect = |phase: usize, i: usize| if (i + phase) % 20 < 6 { 1.0 } else { 0.0 };
        for (hid, phase) in [(5, 0), (4, 7), (3, 15)] {
            let s = sp.speaker(hid).unwrap();
            assert!(s.indicator.iter().enumerate().all(|(i, &x)| x == expect(phase, i)));
            assert_eq!(s.words.as_ref().unwrap()[0].as_deref(), if expect(phase, 0) == 1.0 { Some("Speak") } else { None });
        }
        // 30 body frames + 31 entries: the last entry is unused.
        for body in ["body_p2.pkl", "body_p4.pkl", "body_p0.pkl"] {
            let scene = scene_from_files(&fixture(body), Some(&fixture("speech_p0.pkl"))).unwrap_or_else(|e| panic!("{e}"));
            let speaking = &scene.signals["speaking"];
            assert_eq!(speaking.dim(), (scene.num_frames(), 3));
            for (p, phase) in [(0, 0), (1, 7), (2, 15)] {
                for t in 0..scene.num_frames() {
                    assert_eq!(speaking[[t, p]], expect(phase, t), "{body}: frame {t} person {p}");
                }
            }
            assert!(scene.metadata["speech_source"].as_str().unwrap().ends_with("speech_p0.pkl"));
        }
        // Without a speech file: no signal.
        assert!(scene_from_files(&fixture("body_p0.pkl"), None).unwrap().signals.is_empty());
    }

    #[test]
    fn misaligned_or_mismatched_speech_is_an_error() {
        let sp = load_speech(&fixture("speech_p0.pkl")).unwrap();
        let body = load_body(&fixture("body_p2.pkl")).unwrap();
        // Body starting 1 frame later: the speech file misses its last frame.
        let mut late = body.clone();
        late.metadata.insert("start_frame".into(), 1002.into());
        let e = attach_speech(late, &sp).unwrap_err().to_string();
        assert!(e.contains("cover frames 1000..=1030") && e.contains("1002..=1031"), "{e}");
        let mut early = body.clone();
        early.metadata.insert("start_frame".into(), 999.into());
        assert!(attach_speech(early, &sp).is_err());
        // Different people.
        let mut other = sp.clone();
        other.speakers[0].human_id = 99;
        let e = attach_speech(body.clone(), &other).unwrap_err().to_string();
        assert!(e.contains("humanId 5"), "{e}");
        let mut other = sp.clone();
        other.left_seller_id = 3;
        assert!(attach_speech(body, &other).unwrap_err().to_string().contains("leftSellerId"));
        // Speech file as body file and the reverse: clear errors naming the file.
        let e = load_body(&fixture("speech_p0.pkl")).unwrap_err().to_string();
        assert!(e.contains("speech_p0.pkl") && e.contains("subjects"), "{e}");
        let e = load_speech(&fixture("body_p0.pkl")).unwrap_err().to_string();
        assert!(e.contains("body_p0.pkl") && e.contains("endFrame"), "{e}");
    }

    /// Seeded mutations of the body and speech fixtures (and the real speech files): loading
    /// never panics, whatever the pickle reader lets through.
    #[test]
    fn fuzz_mutated_haggling_files_never_panic() {
        use rand::{Rng, SeedableRng};
        let mut inputs: Vec<PathBuf> = ["body_p0.pkl", "body_p2.pkl", "body_p4.pkl", "speech_p0.pkl"].iter().map(|n| fixture(n)).collect();
        inputs.extend(real_speech_files().into_iter().take(2));
        let mut ok = 0;
        for (idx, path) in inputs.iter().enumerate() {
            let original = std::fs::read(path).unwrap();
            for round in 0..150u64 {
                let seed = (idx as u64) << 32 | round;
                let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
                let mut b = original.clone();
                // Numbers and bytes in the data region: keeps most mutants parseable.
                for _ in 0..rng.gen_range(1..=3) {
                    let i = rng.gen_range(0..b.len());
                    match rng.gen_range(0..3) {
                        0 => b[i] = rng.gen(),
                        1 => b[i] = b"0123456789"[rng.gen_range(0..10)],
                        _ => {
                            let big = [&b"99999999999"[..], b"-5", b"0"][rng.gen_range(0..3)];
                            b.splice(i..i, big.iter().copied());
                        }
                    }
                }
                let r = std::panic::catch_unwind(|| {
                    let Ok(v) = crate::data::pickle::parse_pickle(&b) else { return false };
                    let body = parse_body(&v, "fuzz");
                    let speech = parse_speech(&v);
                    if let (Ok(scene), Ok(sp)) = (&body, load_speech(&fixture("speech_p0.pkl"))) {
                        let _ = attach_speech(scene.clone(), &sp);
                    }
                    body.is_ok() || speech.is_ok()
                });
                match r {
                    Ok(true) => ok += 1,
                    Ok(false) => {}
                    Err(_) => panic!("loading {} mutated with seed {seed} panicked", path.display()),
                }
            }
        }
        eprintln!("haggling fuzz: {ok} mutants loaded");
    }

    /// Broken body files: errors name the file and the problem.
    #[test]
    fn malformed_body_files_are_errors_naming_the_file() {
        let e = load_body(&fixture("body_bad_frames_p0.pkl")).unwrap_err().to_string();
        assert!(e.contains("body_bad_frames_p0.pkl"), "{e}");
        assert!(e.contains("subjects[2] (humanId 3) has 2 frames in joints19 but subjects[0] (humanId 5) has 3"), "{e}");
        // Variants of the protocol-0 fixture with one thing broken.
        let original = std::fs::read(fixture("body_p0.pkl")).unwrap();
        let dir = std::env::temp_dir().join(format!("socdiff-haggling-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let check = |label: &str, bytes: Vec<u8>, needle: &str| {
            let path = dir.join(format!("{label}.pkl"));
            std::fs::write(&path, bytes).unwrap();
            let e = load_body(&path).unwrap_err().to_string();
            assert!(e.contains(&format!("{label}.pkl")) && e.contains(needle), "{label}: {e}");
        };
        let replace_first = |from: &[u8], to: &[u8]| {
            let i = original.windows(from.len()).position(|w| w == from).unwrap();
            let mut b = original[..i].to_vec();
            b.extend_from_slice(to);
            b.extend_from_slice(&original[i + from.len()..]);
            b
        };
        check("bad_seller", replace_first(b"S'rightSellerId'\np7\nI3", b"S'rightSellerId'\np7\nI5"), "rightSellerId");
        check("bad_global", replace_first(b"cnumpy\ndtype", b"cos\nsystem"), "unknown global os.system");
        check("truncated", original[..original.len() / 2].to_vec(), "truncated");
        std::fs::remove_dir_all(&dir).ok();
        // Missing file: an I/O error.
        assert!(matches!(load_body(&fixture("missing.pkl")), Err(Error::Io { .. })));
    }
}
