//! Opening and validating a GGUF model file: the architecture from `general.architecture`, clear
//! errors for a non-GGUF file, a truncated or damaged one, or an unsupported architecture, and
//! typed metadata getters whose errors name the missing or malformed key.
//!
//! Validation reads only the header (metadata and tensor table): tensor data is checked against
//! the file length, not read, so opening a 500 MB model costs milliseconds.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use candle_core::quantized::gguf_file::{Content, Value};
use candle_core::quantized::QTensor;
use candle_core::Device;

use super::error::{LlmError, Result};

/// The model architectures the runtime can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Arch {
    /// llama.cpp's LLAMA (SmolLM2): interleaved rope, usually tied embeddings.
    Llama,
    /// Qwen2 (Qwen2.5): q/k/v biases, NeoX-style rope, separate output matrix.
    Qwen2,
}

impl Arch {
    /// The value of `general.architecture` and the prefix of the architecture's metadata keys.
    pub fn gguf_name(self) -> &'static str {
        match self {
            Arch::Llama => "llama",
            Arch::Qwen2 => "qwen2",
        }
    }

    /// Parses a `general.architecture` value; `None` for an architecture we do not run.
    pub fn from_gguf_name(name: &str) -> Option<Arch> {
        match name {
            "llama" => Some(Arch::Llama),
            "qwen2" => Some(Arch::Qwen2),
            _ => None,
        }
    }
}

impl std::fmt::Display for Arch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.gguf_name())
    }
}

/// The magic bytes every GGUF file starts with.
const GGUF_MAGIC: &[u8; 4] = b"GGUF";

/// A validated GGUF file: header parsed, every tensor's data inside the file, architecture
/// supported. Tensor data is read on demand through [`GgufFile::tensor`].
#[derive(Debug)]
pub struct GgufFile {
    path: PathBuf,
    arch: Arch,
    file_len: u64,
    content: Content,
}

impl GgufFile {
    /// Opens and validates the GGUF file at `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let file =
            File::open(path).map_err(|error| LlmError::Io { path: path.to_path_buf(), error })?;
        Self::from_reader(&mut BufReader::new(file), path)
    }

    /// Validates GGUF data from any reader positioned at its start; `path` names it in errors.
    pub fn from_reader<R: Read + Seek>(reader: &mut R, path: &Path) -> Result<Self> {
        let io = |error| LlmError::Io { path: path.to_path_buf(), error };
        let file_len = reader.seek(SeekFrom::End(0)).map_err(io)?;
        reader.seek(SeekFrom::Start(0)).map_err(io)?;
        check_magic(reader, file_len, path)?;
        reader.seek(SeekFrom::Start(0)).map_err(io)?;
        let content = Content::read(reader).map_err(|e| LlmError::Truncated {
            path: path.to_path_buf(),
            detail: format!("the header (metadata and tensor table) cannot be read: {e}"),
        })?;
        check_tensor_extents(&content, file_len, path)?;
        let arch_name = match content.metadata.get("general.architecture") {
            Some(Value::String(s)) => s.clone(),
            Some(other) => {
                return Err(LlmError::Metadata {
                    path: path.to_path_buf(),
                    key: "general.architecture".into(),
                    detail: format!("expected a string, found {}", describe(other)),
                })
            }
            None => {
                return Err(LlmError::Metadata {
                    path: path.to_path_buf(),
                    key: "general.architecture".into(),
                    detail: "missing: the file does not say which architecture it is".into(),
                })
            }
        };
        let arch = Arch::from_gguf_name(&arch_name).ok_or_else(|| LlmError::UnsupportedArch {
            path: path.to_path_buf(),
            arch: arch_name,
        })?;
        Ok(GgufFile { path: path.to_path_buf(), arch, file_len, content })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn arch(&self) -> Arch {
        self.arch
    }

    /// The file's length in bytes.
    pub fn file_len(&self) -> u64 {
        self.file_len
    }

    /// The parsed header, for code that reads tensors itself (candle's model loaders).
    pub fn content(&self) -> &Content {
        &self.content
    }

    pub fn into_content(self) -> Content {
        self.content
    }

    /// Frees the tokenizer's metadata (`tokenizer.*`: for Qwen2.5 151k token strings and as many
    /// merges, ~33 MB as parsed values) once the tokenizer and chat template are built from it, so
    /// that it is not held through the weights' load, the peak of the process's memory.
    pub fn drop_tokenizer_metadata(&mut self) {
        self.content.metadata.retain(|key, _| !key.starts_with("tokenizer."));
        self.content.metadata.shrink_to_fit();
    }

    /// A fresh buffered reader on the file, for reading tensor data.
    pub fn reader(&self) -> Result<BufReader<File>> {
        let file = File::open(&self.path)
            .map_err(|error| LlmError::Io { path: self.path.clone(), error })?;
        Ok(BufReader::new(file))
    }

    /// Whether tensor `name` is present (e.g. `output.weight`, absent with tied embeddings).
    pub fn has_tensor(&self, name: &str) -> bool {
        self.content.tensor_infos.contains_key(name)
    }

    /// Reads tensor `name` from `reader` (the file this header came from).
    pub fn tensor<R: Read + Seek>(
        &self,
        reader: &mut R,
        name: &str,
        device: &Device,
    ) -> Result<QTensor> {
        if !self.has_tensor(name) {
            return Err(LlmError::Metadata {
                path: self.path.clone(),
                key: name.to_string(),
                detail: format!("tensor missing from a {} model", self.arch),
            });
        }
        self.content.tensor(reader, name, device).map_err(|e| LlmError::Truncated {
            path: self.path.clone(),
            detail: format!("tensor '{name}': {e}"),
        })
    }

    /// The metadata key for `suffix` under this file's architecture: `arch_key("block_count")`
    /// is `llama.block_count` for a llama model.
    pub fn arch_key(&self, suffix: &str) -> String {
        format!("{}.{suffix}", self.arch.gguf_name())
    }

    /// Typed access to the metadata; errors name this file and the key.
    pub fn metadata(&self) -> Metadata<'_> {
        Metadata { path: &self.path, map: &self.content.metadata }
    }
}

/// Typed getters over a GGUF metadata map. Integers are accepted at any stored width (writers
/// differ: u32, u64 and i32 are all seen); errors name the file and the key.
#[derive(Debug, Clone, Copy)]
pub struct Metadata<'a> {
    path: &'a Path,
    map: &'a HashMap<String, Value>,
}

impl<'a> Metadata<'a> {
    /// A view on `map`, a metadata map read from `path` (named in errors).
    pub fn new(path: &'a Path, map: &'a HashMap<String, Value>) -> Self {
        Metadata { path, map }
    }

    pub fn path(&self) -> &'a Path {
        self.path
    }

    /// The raw value of `key`, if present.
    pub fn value(&self, key: &str) -> Option<&'a Value> {
        self.map.get(key)
    }

    fn missing(&self, key: &str) -> LlmError {
        LlmError::Metadata {
            path: self.path.to_path_buf(),
            key: key.into(),
            detail: "missing".into(),
        }
    }

    fn malformed(&self, key: &str, want: &str, found: &Value) -> LlmError {
        LlmError::Metadata {
            path: self.path.to_path_buf(),
            key: key.into(),
            detail: format!("expected {want}, found {}", describe(found)),
        }
    }

    fn get(&self, key: &str) -> Result<&'a Value> {
        self.value(key).ok_or_else(|| self.missing(key))
    }

    /// An unsigned integer of any stored width (writers differ: u32, u64, i32 are all seen).
    pub fn get_u64(&self, key: &str) -> Result<u64> {
        let v = self.get(key)?;
        as_u64(v).ok_or_else(|| self.malformed(key, "a non-negative integer", v))
    }

    pub fn get_u32(&self, key: &str) -> Result<u32> {
        let n = self.get_u64(key)?;
        u32::try_from(n).map_err(|_| LlmError::Metadata {
            path: self.path.to_path_buf(),
            key: key.into(),
            detail: format!("{n} does not fit in 32 bits"),
        })
    }

    /// A count or size (`block_count`, `embedding_length`, …) as `usize`.
    pub fn get_usize(&self, key: &str) -> Result<usize> {
        Ok(self.get_u32(key)? as usize)
    }

    pub fn get_f32(&self, key: &str) -> Result<f32> {
        let v = self.get(key)?;
        match v {
            Value::F32(x) => Ok(*x),
            Value::F64(x) => Ok(*x as f32),
            other => Err(self.malformed(key, "a float", other)),
        }
    }

    pub fn get_bool(&self, key: &str) -> Result<bool> {
        match self.get(key)? {
            Value::Bool(b) => Ok(*b),
            other => Err(self.malformed(key, "a bool", other)),
        }
    }

    pub fn get_str(&self, key: &str) -> Result<&'a str> {
        match self.get(key)? {
            Value::String(s) => Ok(s.as_str()),
            other => Err(self.malformed(key, "a string", other)),
        }
    }

    /// An array of strings (`tokenizer.ggml.tokens`, `tokenizer.ggml.merges`).
    pub fn get_str_array(&self, key: &str) -> Result<Vec<&'a str>> {
        let v = self.get(key)?;
        let Value::Array(items) = v else {
            return Err(self.malformed(key, "an array of strings", v));
        };
        items
            .iter()
            .enumerate()
            .map(|(i, item)| match item {
                Value::String(s) => Ok(s.as_str()),
                other => Err(self.malformed(&format!("{key}[{i}]"), "a string", other)),
            })
            .collect()
    }

    /// An array of integers (`tokenizer.ggml.token_type`).
    pub fn get_i64_array(&self, key: &str) -> Result<Vec<i64>> {
        let v = self.get(key)?;
        let Value::Array(items) = v else {
            return Err(self.malformed(key, "an array of integers", v));
        };
        items
            .iter()
            .enumerate()
            .map(|(i, item)| {
                as_i64(item)
                    .ok_or_else(|| self.malformed(&format!("{key}[{i}]"), "an integer", item))
            })
            .collect()
    }

    /// `Ok(None)` when `key` is absent; an error only when it is present with the wrong type.
    pub fn opt_u32(&self, key: &str) -> Result<Option<u32>> {
        self.value(key).map(|_| self.get_u32(key)).transpose()
    }

    pub fn opt_f32(&self, key: &str) -> Result<Option<f32>> {
        self.value(key).map(|_| self.get_f32(key)).transpose()
    }

    pub fn opt_bool(&self, key: &str) -> Result<Option<bool>> {
        self.value(key).map(|_| self.get_bool(key)).transpose()
    }

    pub fn opt_str(&self, key: &str) -> Result<Option<&'a str>> {
        self.value(key).map(|_| self.get_str(key)).transpose()
    }
}

fn check_magic<R: Read>(reader: &mut R, file_len: u64, path: &Path) -> Result<()> {
    let not_gguf = |reason: String| Err(LlmError::NotGguf { path: path.to_path_buf(), reason });
    if file_len < 8 {
        return not_gguf(format!("the file is {file_len} bytes long, shorter than a GGUF header"));
    }
    let mut head = [0u8; 8];
    reader
        .read_exact(&mut head)
        .map_err(|error| LlmError::Io { path: path.to_path_buf(), error })?;
    if &head[..4] != GGUF_MAGIC {
        let shown: String =
            head[..4].iter().map(|&b| if b.is_ascii_graphic() { b as char } else { '.' }).collect();
        return not_gguf(format!(
            "it starts with bytes {:02x} {:02x} {:02x} {:02x} ('{shown}') instead of 'GGUF'",
            head[0], head[1], head[2], head[3]
        ));
    }
    let version = u32::from_le_bytes([head[4], head[5], head[6], head[7]]);
    if !(1..=3).contains(&version) {
        return not_gguf(format!("GGUF version {version} is not supported (1 to 3 are)"));
    }
    Ok(())
}

/// Every tensor's bytes must lie inside the file: a cut-short download keeps a valid header but
/// loses the tail, and would otherwise fail only when that tensor is loaded.
fn check_tensor_extents(content: &Content, file_len: u64, path: &Path) -> Result<()> {
    let truncated = |detail: String| Err(LlmError::Truncated { path: path.to_path_buf(), detail });
    if content.tensor_data_offset > file_len {
        return truncated(format!(
            "tensor data should start at byte {} but the file has {file_len} bytes",
            content.tensor_data_offset
        ));
    }
    // Sorted by name so the error names the same tensor on every run.
    let mut infos: Vec<_> = content.tensor_infos.iter().collect();
    infos.sort_by(|a, b| a.0.cmp(b.0));
    let mut worst: Option<(&String, u64)> = None;
    for (name, info) in infos {
        let elems = info.shape.elem_count();
        let block = info.ggml_dtype.block_size();
        if block == 0 || elems % block != 0 {
            return truncated(format!(
                "tensor '{name}' has {elems} elements, not a multiple of the {:?} block size {block}",
                info.ggml_dtype
            ));
        }
        let size = (elems / block) as u64 * info.ggml_dtype.type_size() as u64;
        let end = content.tensor_data_offset.saturating_add(info.offset).saturating_add(size);
        if end > file_len && worst.is_none_or(|(_, e)| end > e) {
            worst = Some((name, end));
        }
    }
    if let Some((name, end)) = worst {
        return truncated(format!(
            "tensor '{name}' ends at byte {end} but the file has only {file_len} bytes \
             ({} bytes missing); the download or copy was cut short: delete the file and install it again",
            end - file_len
        ));
    }
    Ok(())
}

fn as_u64(v: &Value) -> Option<u64> {
    match *v {
        Value::U8(x) => Some(x as u64),
        Value::U16(x) => Some(x as u64),
        Value::U32(x) => Some(x as u64),
        Value::U64(x) => Some(x),
        Value::I8(x) => u64::try_from(x).ok(),
        Value::I16(x) => u64::try_from(x).ok(),
        Value::I32(x) => u64::try_from(x).ok(),
        Value::I64(x) => u64::try_from(x).ok(),
        _ => None,
    }
}

fn as_i64(v: &Value) -> Option<i64> {
    match *v {
        Value::U8(x) => Some(x as i64),
        Value::U16(x) => Some(x as i64),
        Value::U32(x) => Some(x as i64),
        Value::U64(x) => i64::try_from(x).ok(),
        Value::I8(x) => Some(x as i64),
        Value::I16(x) => Some(x as i64),
        Value::I32(x) => Some(x as i64),
        Value::I64(x) => Some(x),
        _ => None,
    }
}

/// A short description of a value for error messages (never the whole token list).
fn describe(v: &Value) -> String {
    match v {
        Value::String(s) if s.len() > 40 => format!("a string ({} bytes)", s.len()),
        Value::String(s) => format!("the string {s:?}"),
        Value::Array(a) => format!("an array of {} items", a.len()),
        Value::Bool(b) => format!("the bool {b}"),
        other => format!("{other:?}"),
    }
}

/// Helpers for tests in this module and others: the installed real models, skipped with a note
/// when absent unless `STEP_REQUIRE_MODELS=1`.
#[cfg(test)]
pub(crate) mod test_models {
    use std::path::PathBuf;

    /// The path of installed model `file` under the crate's `models/`, or `None` (after printing
    /// why) when it is absent and models are not required.
    pub fn real_model(file: &str) -> Option<PathBuf> {
        let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models").join(file);
        if p.is_file() {
            return Some(p);
        }
        if std::env::var("STEP_REQUIRE_MODELS").is_ok_and(|v| v == "1") {
            panic!(
                "{} is required (STEP_REQUIRE_MODELS=1) but absent: run models/install.sh",
                p.display()
            );
        }
        eprintln!(
            "note: skipping, {} is not installed (models/install.sh installs it)",
            p.display()
        );
        None
    }

    /// The opened real model, shared by all tests of the binary (the header of the Qwen file
    /// holds 300k strings; reading it once keeps the suite fast).
    pub fn real_gguf(file: &'static str) -> Option<&'static super::GgufFile> {
        use std::sync::OnceLock;
        static SMOL: OnceLock<Option<super::GgufFile>> = OnceLock::new();
        static QW: OnceLock<Option<super::GgufFile>> = OnceLock::new();
        let cell = if file == SMOLLM2 { &SMOL } else { &QW };
        cell.get_or_init(|| {
            let p = real_model(file)?;
            Some(super::GgufFile::open(&p).expect("installed model opens"))
        })
        .as_ref()
    }

    /// The real model's tokenizer, built once per test binary (a build reads the whole vocabulary).
    pub fn real_tokenizer(
        file: &'static str,
    ) -> Option<&'static crate::llm::tokenizer::GgufTokenizer> {
        use crate::llm::tokenizer::GgufTokenizer;
        use std::sync::OnceLock;
        static SMOL: OnceLock<Option<GgufTokenizer>> = OnceLock::new();
        static QW: OnceLock<Option<GgufTokenizer>> = OnceLock::new();
        let cell = if file == SMOLLM2 { &SMOL } else { &QW };
        cell.get_or_init(|| {
            Some(GgufTokenizer::from_gguf(real_gguf(file)?).expect("tokenizer builds"))
        })
        .as_ref()
    }

    pub const SMOLLM2: &str = "SmolLM2-135M-Instruct.Q4_1.gguf";
    pub const QWEN: &str = "Qwen2.5-Coder-0.5B-Instruct.Q4_K_M.gguf";
}

#[cfg(test)]
mod tests {
    use super::test_models::*;
    use super::*;
    use crate::llm::tiny::{tiny_gguf_bytes, write_tiny_gguf, TinySpec};
    use candle_core::quantized::gguf_file;

    #[test]
    fn tiny_models_open_with_their_arch() {
        let dir = tempfile::tempdir().unwrap();
        for spec in [TinySpec::llama(), TinySpec::qwen2()] {
            let p = dir.path().join(format!("{}.gguf", spec.arch));
            write_tiny_gguf(&spec, &p).unwrap();
            let g = GgufFile::open(&p).unwrap();
            assert_eq!(g.arch(), spec.arch);
            assert_eq!(g.metadata().get_usize(&g.arch_key("block_count")).unwrap(), spec.n_layer);
            assert_eq!(g.metadata().get_usize(&g.arch_key("embedding_length")).unwrap(), 64);
            assert!(
                (g.metadata().get_f32(&g.arch_key("rope.freq_base")).unwrap() - 10_000.0).abs()
                    < 1e-3
            );
            assert_eq!(g.metadata().get_str("tokenizer.ggml.model").unwrap(), "gpt2");
            assert_eq!(
                g.metadata().get_str_array("tokenizer.ggml.tokens").unwrap().len(),
                spec.vocab_size()
            );
            assert_eq!(
                g.metadata().get_i64_array("tokenizer.ggml.token_type").unwrap().len(),
                spec.vocab_size()
            );
            assert!(!g.metadata().get_bool("tokenizer.ggml.add_bos_token").unwrap());
            assert_eq!(g.metadata().opt_u32("no.such.key").unwrap(), None);
            assert_eq!(g.has_tensor("output.weight"), spec.arch == Arch::Qwen2);
            let q =
                g.tensor(&mut g.reader().unwrap(), "blk.0.attn_q.weight", &Device::Cpu).unwrap();
            assert_eq!(q.shape().dims(), &[64, 64]);
        }
    }

    #[test]
    fn getters_name_the_missing_or_malformed_key() {
        let bytes = tiny_gguf_bytes(&TinySpec::llama()).unwrap();
        let g = GgufFile::from_reader(&mut std::io::Cursor::new(bytes), Path::new("tiny.gguf"))
            .unwrap();
        let err = g.metadata().get_u32("llama.expert_count").unwrap_err();
        assert!(
            matches!(&err, LlmError::Metadata { key, .. } if key == "llama.expert_count"),
            "{err}"
        );
        let msg = g.metadata().get_u32("tokenizer.ggml.model").unwrap_err().to_string();
        assert!(
            msg.contains("tokenizer.ggml.model") && msg.contains("expected a non-negative integer"),
            "{msg}"
        );
        assert!(msg.contains("tiny.gguf"), "{msg}");
        let msg = g.metadata().get_f32("general.architecture").unwrap_err().to_string();
        assert!(msg.contains("expected a float") && msg.contains("\"llama\""), "{msg}");
        let err = g
            .tensor(&mut std::io::Cursor::new(Vec::new()), "blk.9.attn_q.weight", &Device::Cpu)
            .unwrap_err();
        assert!(err.to_string().contains("blk.9.attn_q.weight"), "{err}");
    }

    #[test]
    fn truncated_copy_is_truncated() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = tiny_gguf_bytes(&TinySpec::qwen2()).unwrap();
        // Cut in the tensor data: the header parses, the tail tensors are missing.
        let p = dir.path().join("cut.gguf");
        std::fs::write(&p, &bytes[..bytes.len() * 9 / 10]).unwrap();
        let err = GgufFile::open(&p).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LlmError::Truncated { .. }), "{msg}");
        assert!(msg.contains("bytes missing") && msg.contains("cut.gguf"), "{msg}");
        // Cut in the header: the metadata cannot be read.
        std::fs::write(&p, &bytes[..200]).unwrap();
        let err = GgufFile::open(&p).unwrap_err();
        assert!(matches!(err, LlmError::Truncated { .. }), "{err}");
        assert!(err.to_string().contains("header"), "{err}");
    }

    #[test]
    fn text_and_empty_files_are_not_gguf() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("notes.txt");
        std::fs::write(&p, "{\n  \"model\": \"this is JSON, not a model\"\n}\n").unwrap();
        let err = GgufFile::open(&p).unwrap_err();
        assert!(matches!(err, LlmError::NotGguf { .. }), "{err}");
        assert!(err.to_string().contains("instead of 'GGUF'"), "{err}");
        std::fs::write(&p, "").unwrap();
        assert!(matches!(GgufFile::open(&p), Err(LlmError::NotGguf { .. })));
        let mut v = b"GGUF".to_vec();
        v.extend_from_slice(&99u32.to_le_bytes());
        v.extend_from_slice(&[0u8; 64]);
        std::fs::write(&p, &v).unwrap();
        let err = GgufFile::open(&p).unwrap_err();
        assert!(
            matches!(err, LlmError::NotGguf { .. }) && err.to_string().contains("version 99"),
            "{err}"
        );
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let err = GgufFile::open(Path::new("/nonexistent/dir/model.gguf")).unwrap_err();
        assert!(matches!(err, LlmError::Io { .. }));
        assert!(err.to_string().contains("/nonexistent/dir/model.gguf"));
    }

    fn gguf_with_arch(arch: Option<Value>) -> Vec<u8> {
        let t = candle_core::Tensor::zeros(32, candle_core::DType::F32, &Device::Cpu).unwrap();
        let q = QTensor::quantize(&t, candle_core::quantized::GgmlDType::F32).unwrap();
        let name = Value::String("x".into());
        let mut md: Vec<(&str, &Value)> = vec![("general.name", &name)];
        if let Some(a) = &arch {
            md.push(("general.architecture", a));
        }
        let mut cur = std::io::Cursor::new(Vec::new());
        gguf_file::write(&mut cur, &md, &[("x.weight", &q)]).unwrap();
        cur.into_inner()
    }

    #[test]
    fn other_architectures_are_unsupported() {
        let bytes = gguf_with_arch(Some(Value::String("mamba".into())));
        let err = GgufFile::from_reader(&mut std::io::Cursor::new(bytes), Path::new("m.gguf"))
            .unwrap_err();
        assert!(matches!(&err, LlmError::UnsupportedArch { arch, .. } if arch == "mamba"), "{err}");
        assert!(err.to_string().contains("supported: llama, qwen2"));
        let bytes = gguf_with_arch(None);
        let err = GgufFile::from_reader(&mut std::io::Cursor::new(bytes), Path::new("m.gguf"))
            .unwrap_err();
        assert!(
            matches!(&err, LlmError::Metadata { key, .. } if key == "general.architecture"),
            "{err}"
        );
        let bytes = gguf_with_arch(Some(Value::U32(3)));
        let err = GgufFile::from_reader(&mut std::io::Cursor::new(bytes), Path::new("m.gguf"))
            .unwrap_err();
        assert!(err.to_string().contains("expected a string"), "{err}");
    }

    #[test]
    fn real_models_open() {
        for (file, arch, layers) in [(SMOLLM2, Arch::Llama, 30), (QWEN, Arch::Qwen2, 24)] {
            let Some(g) = real_gguf(file) else { continue };
            assert_eq!(g.arch(), arch);
            assert_eq!(g.metadata().get_usize(&g.arch_key("block_count")).unwrap(), layers);
            assert_eq!(g.has_tensor("output.weight"), arch == Arch::Qwen2);
        }
    }
}
