//! Prefix snapshots on disk: the KV cache of a prompt's constant beginning (the planner's system
//! message, ~1,800 tokens), saved once and read back at the next start instead of recomputed.
//!
//! Why: every `step plan` starts by prefilling the same system message, 6-10 s of a first call's
//! time on two cores, where reading its keys and values back takes a fraction of a second. Why it is
//! safe: a snapshot is used only by the same build of the program, with the same model file, on a CPU
//! that takes the same kernels, for exactly the same tokens, so its numbers are the bits the model
//! would compute (no token's numbers depend on its batch; `Transformer::forward_rows`). Anything else
//! (another build, a changed model file, a truncated or corrupted snapshot) is a miss: the prefix is
//! computed and the snapshot rewritten. A snapshot is a cache, never an error: a directory that cannot
//! be written costs the time it would have saved, and says so.
//!
//! File: `<dir>/<key>.kv`, where the key hashes everything the numbers depend on. Inside: a magic
//! line, a JSON header (the tokens, layers, width), the floats (little-endian, layer by layer, keys
//! then values), and the SHA-256 of those floats. Written to a temporary file and renamed, so a killed
//! run leaves no half snapshot; at most [`KEEP`] snapshots are kept in a directory (the oldest go).

use std::fs::{self, File};
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::model::Transformer;

const MAGIC: &[u8; 8] = b"STEPKV1\n";
/// Snapshots kept in one directory: a rebuilt program or another model writes a new one (SmolLM2's
/// system message is 81 MB of keys and values), and the oldest beyond this many are deleted.
pub const KEEP: usize = 4;
/// The longest header read: a token list the length of any model's context, written as JSON.
const MAX_HEADER: usize = 16 << 20;

/// Where snapshots go when nothing is said: `$STEP_PREFIX_CACHE`, else `$XDG_CACHE_HOME/step/prefix`,
/// else `$HOME/.cache/step/prefix`.
pub fn default_dir() -> Option<PathBuf> {
    let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    env("STEP_PREFIX_CACHE")
        .or_else(|| env("XDG_CACHE_HOME").map(|d| d.join("step").join("prefix")))
        .or_else(|| env("HOME").map(|d| d.join(".cache").join("step").join("prefix")))
}

#[derive(Serialize, Deserialize, PartialEq, Debug)]
struct Header {
    tokens: Vec<u32>,
    layers: usize,
    width: usize,
}

impl Header {
    /// The header of `tokens`' snapshot for `model`'s shape.
    fn of(model: &Transformer, tokens: &[u32]) -> Header {
        let cfg = model.config();
        Header { tokens: tokens.to_vec(), layers: cfg.n_layer, width: cfg.n_head_kv * cfg.head_dim }
    }
}

/// The snapshot's file name for `tokens` of `model` (a file path): a hash of the program's build
/// (its executable's size and modification time), the model file's path, size and modification
/// time, the CPU's kernel path, and the tokens.
pub fn key(model: &Path, tokens: &[u32]) -> String {
    let mut h = Sha256::new();
    h.update(b"step prefix snapshot 1\0");
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    for file in [std::env::current_exe().ok(), Some(model.to_path_buf())].into_iter().flatten() {
        let file = fs::canonicalize(&file).unwrap_or(file);
        h.update(file.to_string_lossy().as_bytes());
        if let Ok(m) = fs::metadata(&file) {
            h.update(m.len().to_le_bytes());
            let t = m.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
            h.update(t.map_or(0, |t| t.as_nanos()).to_le_bytes());
        }
        h.update(b"\0");
    }
    h.update(super::kernels::cpu_signature().as_bytes());
    for t in tokens {
        h.update(t.to_le_bytes());
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Fills the model's cache with the snapshot at `path` if it holds exactly `tokens`; `Ok(false)` when
/// there is none, `Err` (with why) when it is unreadable or does not match. On any failure the
/// model's cache is left empty.
pub fn load(model: &mut Transformer, path: &Path, tokens: &[u32]) -> Result<bool, String> {
    let file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(format!("cannot open {}: {e}", path.display())),
    };
    let mut r = BufReader::with_capacity(1 << 20, file);
    let bad = |what: &str| format!("{} is not a usable prefix snapshot: {what}", path.display());
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic).map_err(|e| bad(&e.to_string()))?;
    if &magic != MAGIC {
        return Err(bad("wrong magic"));
    }
    let mut len = [0u8; 4];
    r.read_exact(&mut len).map_err(|e| bad(&e.to_string()))?;
    let len = u32::from_le_bytes(len) as usize;
    // The header lists the tokens (a few KB); a damaged length must not become a huge allocation.
    if len > MAX_HEADER {
        return Err(bad(&format!("a header of {len} bytes")));
    }
    let mut json = vec![0u8; len];
    r.read_exact(&mut json).map_err(|e| bad(&e.to_string()))?;
    let header: Header = serde_json::from_slice(&json).map_err(|e| bad(&format!("header: {e}")))?;
    if header != Header::of(model, tokens) {
        return Err(bad("it holds other tokens or another model's shape"));
    }
    let mut hash = Sha256::new();
    let mut bytes = Vec::new();
    let read = model.restore_cache(tokens.len(), |dst: &mut [f32]| {
        bytes.resize(dst.len() * 4, 0);
        r.read_exact(&mut bytes).map_err(|e| bad(&e.to_string()))?;
        hash.update(&bytes);
        for (d, b) in dst.iter_mut().zip(bytes.chunks_exact(4)) {
            *d = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        Ok(())
    });
    let mut sum = [0u8; 32];
    let checked = read.and_then(|()| r.read_exact(&mut sum).map_err(|e| bad(&e.to_string())));
    if let Err(e) = checked {
        model.truncate(0);
        return Err(e);
    }
    if sum[..] != hash.finalize()[..] {
        model.truncate(0);
        return Err(bad("its checksum does not match (a damaged file)"));
    }
    Ok(true)
}

/// Writes the model's first `tokens.len()` cached positions to `path` (through a temporary file,
/// renamed), then deletes the oldest snapshots beyond [`KEEP`] in its directory.
pub fn save(model: &Transformer, path: &Path, tokens: &[u32]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let written = (|| {
        let mut w = BufWriter::with_capacity(1 << 20, File::create(&tmp)?);
        let json = serde_json::to_vec(&Header::of(model, tokens))?;
        w.write_all(MAGIC)?;
        w.write_all(&(json.len() as u32).to_le_bytes())?;
        w.write_all(&json)?;
        let mut hash = Sha256::new();
        let mut bytes = Vec::new();
        for slice in model.cache_slices(tokens.len()) {
            bytes.clear();
            bytes.extend(slice.iter().flat_map(|x| x.to_le_bytes()));
            hash.update(&bytes);
            w.write_all(&bytes)?;
        }
        w.write_all(&hash.finalize())?;
        w.into_inner().map_err(|e| e.into_error())?.sync_all()
    })();
    match written.and_then(|()| fs::rename(&tmp, path)) {
        Ok(()) => {
            evict(dir, KEEP);
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Deletes the least recently written snapshots of `dir` beyond `keep` (only files named as
/// snapshots are touched).
fn evict(dir: &Path, keep: usize) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    let mut snaps: Vec<(std::time::SystemTime, PathBuf)> = entries
        .flatten()
        .filter(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            name.len() == 67 && name.ends_with(".kv") && name[..64].bytes().all(|b| b.is_ascii_hexdigit())
        })
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .collect();
    snaps.sort();
    let extra = snaps.len().saturating_sub(keep);
    for (_, p) in snaps.into_iter().take(extra) {
        let _ = fs::remove_file(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eviction_keeps_the_newest_snapshots_and_touches_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let t0 = std::time::SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(1_000_000);
        let mut names = Vec::new();
        for i in 0..6u64 {
            let name = format!("{:064x}.kv", i);
            let f = File::create(dir.path().join(&name)).unwrap();
            f.set_modified(t0 + std::time::Duration::from_secs(i)).unwrap();
            names.push(name);
        }
        fs::write(dir.path().join("notes.kv"), b"mine").unwrap();
        evict(dir.path(), 4);
        let mut left: Vec<String> =
            fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        left.sort();
        let mut want: Vec<String> = names[2..].to_vec();
        want.push("notes.kv".into());
        want.sort();
        assert_eq!(left, want);
    }

    #[test]
    fn a_damaged_header_length_is_a_miss_not_an_allocation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(format!("{:064x}.kv", 1));
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&u32::MAX.to_le_bytes());
        fs::write(&path, &bytes).unwrap();
        let spec = crate::llm::tiny::TinySpec::llama();
        let gguf = dir.path().join("tiny.gguf");
        crate::llm::tiny::write_tiny_gguf(&spec, &gguf).unwrap();
        let mut model = Transformer::load(&crate::llm::gguf::GgufFile::open(&gguf).unwrap()).unwrap();
        let err = load(&mut model, &path, &[1, 2, 3]).unwrap_err();
        assert!(err.contains("a header of 4294967295 bytes"), "{err}");
        assert_eq!(model.cached_len(), 0);
    }

    #[test]
    fn the_key_changes_with_the_tokens_and_the_model() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.gguf"), dir.path().join("b.gguf"));
        fs::write(&a, b"one").unwrap();
        fs::write(&b, b"two").unwrap();
        assert_eq!(key(&a, &[1, 2, 3]), key(&a, &[1, 2, 3]));
        assert_ne!(key(&a, &[1, 2, 3]), key(&a, &[1, 2, 4]));
        assert_ne!(key(&a, &[1, 2, 3]), key(&b, &[1, 2, 3]));
        assert_eq!(key(&a, &[]).len(), 64);
    }
}
