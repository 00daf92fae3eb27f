//! Files on disk: the one place that writes outputs, guards inputs and bounds reads.
//!
//! - [`write_file_atomic`] / [`write_dir_atomic`]: every output goes to a temporary sibling
//!   (`.NAME.tmp-PID`, synced) and is renamed into place only when complete, so a reader never
//!   sees half a file and an interrupted command leaves the old file (or nothing) behind;
//! - [`check_output_file`]: a single-file output never replaces an input of the same command or
//!   a file of another kind; an earlier output of the same kind only with `force`;
//! - [`RunLock`]: an exclusive advisory lock on a run directory (released by the kernel when the
//!   process dies, so kill -9 leaves no stale lock);
//! - [`read_bounded`]: reads a file, refusing more than a limit (also for pipes and devices,
//!   whose size is not known beforehand).

use crate::{Error, Result};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// A temporary sibling of `path`: same directory, `.NAME.tmp-PID-RANDOM` (NAME cut to 64
/// characters). The name cannot be guessed, so no file can be put there beforehand; callers
/// create it with [`create_new`] (or `create_dir`), which refuse anything already there. The
/// parent directory is created when missing.
pub fn temp_sibling(path: &Path) -> Result<PathBuf> {
    let parent = parent_dir(path);
    std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    let name: String = path.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy().chars().take(64).collect());
    Ok(parent.join(format!(".{name}.tmp-{}-{:016x}", std::process::id(), rand::random::<u64>())))
}

/// Creates `path` for writing, failing when anything is there already — a file, or a symbolic
/// link, which is never followed.
pub fn create_new(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new().write(true).create_new(true).custom_flags(libc::O_NOFOLLOW).open(path)
}

/// Opens `path` to append (creating it), refusing a symbolic link there.
pub fn open_append(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new().create(true).append(true).custom_flags(libc::O_NOFOLLOW).open(path)
}

fn parent_dir(path: &Path) -> &Path {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// Writes `value` as pretty-printed JSON to `path`, atomically ([`write_file_atomic`]).
pub fn write_json_atomic(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::format(path, e.to_string()))?;
    write_file_atomic(path, text.as_bytes())
}

/// Writes `bytes` to `path` atomically: a synced temporary sibling, then a rename. An existing
/// file is replaced (callers check with [`check_output_file`] first); a directory is an error.
pub fn write_file_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    if path.is_dir() {
        return Err(Error::format(path, "is a directory; give a file name"));
    }
    let tmp = temp_sibling(path)?;
    let result = (|| -> std::io::Result<()> {
        let mut f = create_new(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Creates the directory `dir` atomically: `fill` writes into a fresh temporary sibling, which
/// is renamed to `dir` when it succeeds and removed when it fails. An existing non-empty `dir`
/// is an error (nothing is overwritten); an existing empty one is replaced.
pub fn write_dir_atomic<T>(dir: &Path, fill: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    check_output_dir(dir)?;
    let tmp = temp_sibling(dir)?;
    std::fs::create_dir(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let result = fill(&tmp).and_then(|v| {
        if dir.exists() {
            std::fs::remove_dir(dir).map_err(|e| Error::io(dir, e))?;
        }
        std::fs::rename(&tmp, dir).map_err(|e| Error::io(dir, e))?;
        Ok(v)
    });
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result
}

/// An output directory must be absent or an empty directory.
pub fn check_output_dir(dir: &Path) -> Result<()> {
    if dir.exists() || dir.is_symlink() {
        if !dir.is_dir() {
            return Err(Error::format(dir, "exists and is not a directory; refusing to overwrite"));
        }
        if std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?.next().is_some() {
            return Err(Error::format(dir, "output directory exists and is not empty; refusing to overwrite"));
        }
    }
    Ok(())
}

/// The kinds of single-file output socdiff writes, recognised by their content so that
/// `--force` replaces only an earlier output of the same kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A viewer page of `socdiff view`.
    ViewerHtml,
    /// A positions JSON of `socdiff export --format json`.
    PositionsJson,
    /// A PNG image (`socdiff export --format png`).
    Png,
}

impl OutputKind {
    fn describe(self) -> &'static str {
        match self {
            OutputKind::ViewerHtml => "a socdiff viewer page",
            OutputKind::PositionsJson => "a socdiff positions JSON",
            OutputKind::Png => "a PNG image",
        }
    }

    /// Whether the first bytes of a file are of this kind.
    fn matches(self, head: &[u8]) -> bool {
        let text = String::from_utf8_lossy(head);
        match self {
            OutputKind::ViewerHtml => text.trim_start().starts_with("<!DOCTYPE html") && text.contains("socdiff"),
            OutputKind::PositionsJson => text.trim_start().starts_with('{') && text.contains("\"socdiff-positions\""),
            OutputKind::Png => head.starts_with(b"\x89PNG\r\n\x1a\n"),
        }
    }
}

/// `(device, inode)` of an existing path, following symlinks.
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// Whether `path` is `input` or lies inside it (for a directory input), compared by inode so
/// that other spellings, symlinks and hard links are caught.
fn is_within(path: &Path, input: &Path) -> bool {
    let Some(target) = file_id(input) else { return false };
    let mut p = Some(path);
    while let Some(q) = p {
        if file_id(q) == Some(target) {
            return true;
        }
        p = q.parent().filter(|x| !x.as_os_str().is_empty());
    }
    false
}

/// Checks that the single-file output `out` may be written by a command that reads `inputs`:
/// it must not be (or lie inside) an input, and an existing file is replaced only with `force`
/// and only when it is an earlier output of the same `kind`. Errors name `out`.
pub fn check_output_file(out: &Path, inputs: &[&Path], kind: OutputKind, force: bool) -> Result<()> {
    if out.is_dir() {
        return Err(Error::format(out, "is a directory; give a file name"));
    }
    let exists = out.exists() || out.is_symlink();
    for input in inputs {
        // `is_within` compares `out` itself first, so an input under any name is caught.
        if exists && is_within(out, input) {
            return Err(Error::format(out, format!("is an input of this command ({}); refusing to overwrite it", input.display())));
        }
    }
    if !exists {
        return Ok(());
    }
    if !out.is_file() {
        return Err(Error::format(out, "exists and is not a regular file; refusing to overwrite it"));
    }
    let mut head = vec![0u8; 4096];
    let n = std::fs::File::open(out).and_then(|mut f| f.read(&mut head)).map_err(|e| Error::io(out, e))?;
    head.truncate(n);
    if !kind.matches(&head) {
        return Err(Error::format(out, format!("exists and is not {}; refusing to overwrite it", kind.describe())));
    }
    if !force {
        return Err(Error::format(out, format!("exists ({}); pass `force` to replace it", kind.describe())));
    }
    Ok(())
}

/// Reads the whole file at `path`, refusing more than `limit` bytes before allocating them (a
/// regular file by its size, a pipe or device by reading at most `limit + 1` bytes). `what`
/// names the kind of file in the error.
pub fn read_bounded(path: &Path, limit: u64, what: &str) -> Result<Vec<u8>> {
    read_bounded_checked(path, limit, what, &|_| Ok(()))
}

/// [`read_bounded`], first checking the file's first bytes (up to 64) with `head`, so that a
/// file of the wrong kind (say /dev/zero) is refused before the rest is read.
pub fn read_bounded_checked(path: &Path, limit: u64, what: &str, head: &dyn Fn(&[u8]) -> std::result::Result<(), String>) -> Result<Vec<u8>> {
    check_readable(path, what)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::format(path, format!("is a directory, not a {what}")));
    }
    let too_big = |size: String| Error::format(path, format!("{size} is more than the {} MiB a {what} may have", limit >> 20));
    if meta.is_file() && meta.len() > limit {
        return Err(too_big(format!("{} bytes", meta.len())));
    }
    let mut reader = file.take(limit + 1);
    let mut bytes = Vec::with_capacity(if meta.is_file() { meta.len() as usize } else { 1 << 16 });
    let mut first = [0u8; 64];
    let mut n = 0;
    while n < first.len() {
        match reader.read(&mut first[n..]).map_err(|e| Error::io(path, e))? {
            0 => break,
            k => n += k,
        }
    }
    head(&first[..n]).map_err(|msg| Error::format(path, msg))?;
    bytes.extend_from_slice(&first[..n]);
    reader.read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > limit {
        return Err(too_big("its content".into()));
    }
    Ok(bytes)
}

/// Refuses to read `path` when it is a pipe, socket or device, before opening it (opening a
/// FIFO would wait for a writer forever); `what` names the kind of file expected.
pub fn check_readable(path: &Path, what: &str) -> Result<()> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::format(path, format!("is a directory, not a {what}")));
    }
    if !meta.is_file() {
        return Err(Error::format(path, format!("is a pipe, socket or device, not a {what}")));
    }
    Ok(())
}

/// Longest name socdiff turns into a file or folder name (a sequence, person, method or
/// label), in bytes.
pub const MAX_NAME_BYTES: usize = 200;

/// Checks that `name` can be one path component of an output: non-empty, at most
/// [`MAX_NAME_BYTES`], not `.` or `..`, no `/`, `\` or control characters. `what` says what the
/// name is; the error shows it escaped.
pub fn check_name(what: &str, name: &str) -> Result<()> {
    let problem = if name.is_empty() {
        "is empty"
    } else if name.len() > MAX_NAME_BYTES {
        "is longer than 200 bytes"
    } else if name == "." || name == ".." {
        "is a relative directory"
    } else if name.contains(['/', '\\']) {
        "contains a path separator"
    } else if name.chars().any(char::is_control) {
        "contains a control character"
    } else {
        return Ok(());
    };
    let shown: String = name.chars().take(60).collect::<String>();
    let more = if name.chars().count() > 60 { "…" } else { "" };
    Err(Error::invalid(format!("{what} {shown:?}{more} {problem}: names become file names, so they must be one plain path component")))
}

/// At most `max` of `items`, comma-separated, with how many more there are.
pub fn list_some<S: AsRef<str>>(items: &[S], max: usize) -> String {
    let shown: Vec<&str> = items.iter().take(max).map(AsRef::as_ref).collect();
    match items.len().saturating_sub(max) {
        0 => shown.join(", "),
        more => format!("{} and {more} more", shown.join(", ")),
    }
}

/// An exclusive lock on a directory that a command is writing (a run directory): the file
/// `DIR/.socdiff-lock` holds the writer's process id and an OS lock, which the kernel releases
/// when the process ends in any way. Dropping the value releases it.
#[derive(Debug)]
pub struct RunLock {
    file: std::fs::File,
    path: PathBuf,
}

/// Name of the lock file inside a locked directory.
pub const LOCK_FILE: &str = ".socdiff-lock";

impl RunLock {
    /// Takes the lock of `dir` (which must exist). Another live writer: "DIR is being written
    /// by process N".
    pub fn acquire(dir: &Path) -> Result<Self> {
        let path = dir.join(LOCK_FILE);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| !m.is_file()) {
            return Err(Error::format(&path, "is not a regular file (a symbolic link?): socdiff writes its lock only as a file of its own"));
        }
        use std::os::unix::fs::OpenOptionsExt;
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .custom_flags(libc::O_NOFOLLOW)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut text = String::new();
                let _ = file.read_to_string(&mut text);
                let who = text.trim().parse::<u32>().map_or_else(|_| "another process".to_string(), |pid| format!("process {pid}"));
                return Err(Error::format(dir, format!("is being written by {who}; wait for it to finish or choose another directory")));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(Error::io(&path, e)),
        }
        file.set_len(0).and_then(|_| file.write_all(std::process::id().to_string().as_bytes())).map_err(|e| Error::io(&path, e))?;
        Ok(Self { file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let _ = self.file.unlock();
    }
}

/// Syncs a directory so that renames inside it survive a power loss (best effort).
pub fn sync_dir(dir: &Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("socdiff-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn outputs_never_replace_inputs_or_foreign_files() {
        let d = tmp("guard");
        let ds = d.join("A");
        std::fs::create_dir(&ds).unwrap();
        std::fs::write(ds.join("dataset.json"), "{\"name\": \"x\"}").unwrap();
        // The input's own file, however spelled.
        let e = check_output_file(&ds.join("dataset.json"), &[&ds], OutputKind::ViewerHtml, true).unwrap_err().to_string();
        assert!(e.contains("is an input of this command"), "{e}");
        let e = check_output_file(&d.join("A/../A/dataset.json"), &[&ds], OutputKind::ViewerHtml, true).unwrap_err().to_string();
        assert!(e.contains("is an input"), "{e}");
        // A single-file input as its own output.
        let bvh = d.join("x.bvh");
        std::fs::write(&bvh, "HIERARCHY\n").unwrap();
        let e = check_output_file(&bvh, &[&bvh], OutputKind::ViewerHtml, true).unwrap_err().to_string();
        assert!(e.contains("is an input"), "{e}");
        // A hard link to the input.
        let link = d.join("link.html");
        std::fs::hard_link(&bvh, &link).unwrap();
        assert!(check_output_file(&link, &[&bvh], OutputKind::ViewerHtml, true).unwrap_err().to_string().contains("is an input"));
        // A foreign file: refused even with force.
        let notes = d.join("notes.html");
        std::fs::write(&notes, "<html>my notes</html>").unwrap();
        let e = check_output_file(&notes, &[&bvh], OutputKind::ViewerHtml, true).unwrap_err().to_string();
        assert!(e.contains("is not a socdiff viewer page"), "{e}");
        // An earlier output of the same kind: only with force.
        let page = d.join("page.html");
        std::fs::write(&page, "<!DOCTYPE html>\n<title>socdiff</title><script id=\"socdiff-meta\"></script>").unwrap();
        assert!(check_output_file(&page, &[&bvh], OutputKind::ViewerHtml, false).unwrap_err().to_string().contains("`force`"));
        check_output_file(&page, &[&bvh], OutputKind::ViewerHtml, true).unwrap();
        // A new file inside an input directory replaces nothing.
        check_output_file(&ds.join("view.html"), &[&ds], OutputKind::ViewerHtml, false).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }

    /// Temporary names cannot be guessed, and a symbolic link prepared where an output goes is
    /// replaced, never written through.
    #[test]
    fn writes_never_follow_a_prepared_link() {
        let d = tmp("nofollow");
        std::fs::create_dir_all(&d).unwrap();
        let out = d.join("view.html");
        assert_ne!(temp_sibling(&out).unwrap(), temp_sibling(&out).unwrap());
        let victim = d.join("victim.txt");
        std::fs::write(&victim, "keep me").unwrap();
        std::os::unix::fs::symlink(&victim, &out).unwrap();
        write_file_atomic(&out, b"page").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        assert!(!std::fs::symlink_metadata(&out).unwrap().file_type().is_symlink());
        assert_eq!(std::fs::read(&out).unwrap(), b"page");
        // A link where a new file is created is refused, not followed.
        let link = d.join("made");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        assert!(create_new(&link).is_err() && open_append(&link).is_err());
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn bounded_reads_refuse_devices_and_large_files() {
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20, "BVH file").unwrap_err().to_string();
        assert!(e.contains("/dev/zero") && e.contains("pipe, socket or device, not a BVH file"), "{e}");
        let d = tmp("bounded");
        let f = d.join("big.bvh");
        std::fs::write(&f, vec![b'x'; 3000]).unwrap();
        assert!(read_bounded(&f, 2048, "BVH file").unwrap_err().to_string().contains("3000 bytes"));
        assert_eq!(read_bounded(&f, 4096, "BVH file").unwrap().len(), 3000);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_locked_directory_names_its_writer() {
        let d = tmp("lock");
        let lock = RunLock::acquire(&d).unwrap();
        let e = RunLock::acquire(&d).unwrap_err().to_string();
        assert!(e.contains(&format!("is being written by process {}", std::process::id())), "{e}");
        drop(lock);
        RunLock::acquire(&d).unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }
}
