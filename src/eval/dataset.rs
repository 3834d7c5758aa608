//! EAI's VirtualHome data set, read where it lies (never copied into the repo):
//! `eai/init_and_final_graphs.tar.xz` (342 `{init_graph, final_graph}` files, streamed straight out of
//! the archive), `eai/resources/task_state_LTL_formula_accurate.json` (goals),
//! `eai/resources/id2task.json` (task names) and `eai/executable_programs/file<id>.txt` (gold plans).
//!
//! The data root is `--data DIR`, else `$STEP_VH_DATA`, else the first `shared/bench/virtualhome` found
//! beside the current directory or the crate, or an ancestor of either (the repo's
//! `../shared/bench/virtualhome`).

use std::collections::{BTreeMap, BTreeSet};
use std::io::Read;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::goal::RawGoal;
use super::EvalError;
use crate::world::{parse_scene, SceneFile};

/// The environment variable naming the data root.
pub const DATA_ENV: &str = "STEP_VH_DATA";

const GRAPHS: &str = "eai/init_and_final_graphs.tar.xz";
const GOALS: &str = "eai/resources/task_state_LTL_formula_accurate.json";
const ID2TASK: &str = "eai/resources/id2task.json";
const PROGRAMS: &str = "eai/executable_programs";

/// Finds the data root: `explicit` (from `--data`), else `$STEP_VH_DATA`, else the default places.
/// A root counts when it holds EAI's goal file. The error lists every place looked at.
pub fn locate(explicit: Option<&Path>) -> Result<PathBuf, EvalError> {
    let mut looked = Vec::new();
    let from_env = std::env::var_os(DATA_ENV).filter(|p| !p.is_empty());
    let given = explicit.is_some() || from_env.is_some();
    let candidates: Vec<PathBuf> = if let Some(p) = explicit {
        vec![p.to_path_buf()]
    } else if let Some(p) = from_env {
        vec![PathBuf::from(p)]
    } else {
        let mut bases = Vec::new();
        if let Ok(cwd) = std::env::current_dir() {
            bases.push(cwd);
        }
        bases.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
        let mut v = Vec::new();
        for b in bases {
            for a in b.ancestors() {
                let c = a.join("shared/bench/virtualhome");
                if !v.contains(&c) {
                    v.push(c);
                }
            }
        }
        v
    };
    for c in candidates {
        if c.join(GOALS).is_file() {
            return Ok(c);
        }
        looked.push(c);
    }
    Err(EvalError::DataMissing { looked, explicit: given })
}

/// One EAI task's metadata (no graphs): name, goal, and where its gold program is.
#[derive(Clone, Debug)]
pub struct EaiTaskMeta {
    pub id: String,
    pub task_name: String,
    pub goal: RawGoal,
}

/// EAI's data set at a root directory.
#[derive(Clone, Debug)]
pub struct EaiData {
    pub root: PathBuf,
}

fn read_text(path: &Path) -> Result<String, EvalError> {
    std::fs::read_to_string(path)
        .map(|t| crate::program::strip_bom(&t).to_string())
        .map_err(|error| EvalError::Io { path: path.to_path_buf(), error })
}

fn json_error(path: &Path, e: serde_json::Error) -> EvalError {
    EvalError::Json { path: path.to_path_buf(), line: e.line(), column: e.column(), message: e.to_string() }
}

/// Orders EAI task ids `27_2` by (27, 2), then as text.
pub fn task_id_key(id: &str) -> (u64, u64, String) {
    let mut it = id.split('_').map(|p| p.parse::<u64>().unwrap_or(u64::MAX));
    (it.next().unwrap_or(u64::MAX), it.next().unwrap_or(u64::MAX), id.to_string())
}

impl EaiData {
    pub fn open(explicit: Option<&Path>) -> Result<EaiData, EvalError> {
        locate(explicit).map(|root| EaiData { root })
    }

    pub fn graphs_path(&self) -> PathBuf {
        self.root.join(GRAPHS)
    }

    /// Every task's name and goal, in id order (`27_2` by its numbers).
    pub fn tasks_meta(&self) -> Result<Vec<EaiTaskMeta>, EvalError> {
        let goals_path = self.root.join(GOALS);
        type Goals = BTreeMap<String, BTreeMap<String, BTreeMap<String, GoalEntry>>>;
        #[derive(serde::Deserialize)]
        struct GoalEntry {
            vh_goal: RawGoal,
        }
        let goals: Goals = serde_json::from_str(&read_text(&goals_path)?).map_err(|e| json_error(&goals_path, e))?;
        let id_path = self.root.join(ID2TASK);
        let id2task: BTreeMap<String, String> =
            serde_json::from_str(&read_text(&id_path)?).map_err(|e| json_error(&id_path, e))?;
        let scene = goals.get("scene_1").ok_or_else(|| EvalError::Data {
            path: goals_path.clone(),
            message: "no \"scene_1\" entry (EAI's VirtualHome tasks are all in scene 1)".into(),
        })?;
        let mut out = Vec::with_capacity(id2task.len());
        for (id, name) in &id2task {
            let entry = scene.get(name).and_then(|t| t.get(id)).ok_or_else(|| EvalError::Data {
                path: goals_path.clone(),
                message: format!("task {id} ('{name}', listed in {ID2TASK}) has no goal entry"),
            })?;
            out.push(EaiTaskMeta { id: id.clone(), task_name: name.clone(), goal: entry.vh_goal.clone() });
        }
        out.sort_by_key(|m| task_id_key(&m.id));
        Ok(out)
    }

    /// The path of a task's gold program.
    pub fn program_path(&self, id: &str) -> PathBuf {
        self.root.join(PROGRAMS).join(format!("file{id}.txt"))
    }

    /// The raw text of a task's gold program file.
    pub fn program_text(&self, id: &str) -> Result<String, EvalError> {
        read_text(&self.program_path(id))
    }

    /// Reads the scene files of the wanted task ids (all when `None`) from the archive, parsing them
    /// in parallel while the archive streams, and maps each with `f`. Results are in id order.
    /// Missing wanted ids are an error naming them.
    pub fn scenes<T, F>(&self, wanted: Option<&BTreeSet<String>>, f: F) -> Result<Vec<(String, T)>, EvalError>
    where
        T: Send,
        F: Fn(&str, SceneFile) -> Result<T, EvalError> + Sync,
    {
        self.scene_texts(wanted, |id, text, origin| f(id, parse_scene(text, origin)?))
    }

    /// As [`EaiData::scenes`], handing `f` each file's JSON text (and a name for errors), for callers
    /// that parse it their own way.
    pub fn scene_texts<T, F>(&self, wanted: Option<&BTreeSet<String>>, f: F) -> Result<Vec<(String, T)>, EvalError>
    where
        T: Send,
        F: Fn(&str, &str, &str) -> Result<T, EvalError> + Sync,
    {
        let path = self.graphs_path();
        let archive_err = |message: String| EvalError::Archive { path: path.clone(), message };
        let file = std::fs::File::open(&path).map_err(|error| EvalError::Io { path: path.clone(), error })?;
        let (tx, rx) = std::sync::mpsc::sync_channel::<(String, Vec<u8>)>(4);
        let remaining = wanted.map(|w| w.len());
        let results = std::thread::scope(|s| {
            // The archive decompresses on one thread (xz is sequential); files parse on the pool.
            let reader = s.spawn(move || -> Result<(), EvalError> {
                let mut ar = tar::Archive::new(xz2::read::XzDecoder::new(std::io::BufReader::new(file)));
                let mut left = remaining;
                for entry in ar.entries().map_err(|e| archive_err(e.to_string()))? {
                    if left == Some(0) {
                        break; // every wanted file found: no need to decompress the rest
                    }
                    let mut entry = entry.map_err(|e| archive_err(e.to_string()))?;
                    let name = entry.path().map_err(|e| archive_err(e.to_string()))?.to_string_lossy().into_owned();
                    let Some(id) = name
                        .rsplit('/')
                        .next()
                        .and_then(|f| f.strip_prefix("file"))
                        .and_then(|f| f.strip_suffix(".json"))
                        .map(str::to_string)
                    else {
                        continue;
                    };
                    if wanted.is_some_and(|w| !w.contains(&id)) {
                        continue;
                    }
                    let mut bytes = Vec::with_capacity(entry.size() as usize);
                    entry.read_to_end(&mut bytes).map_err(|e| archive_err(format!("{name}: {e}")))?;
                    left = left.map(|n| n - 1);
                    if tx.send((id, bytes)).is_err() {
                        break; // the parsers stopped on an error
                    }
                }
                Ok(())
            });
            let parsed: Vec<Result<(String, T), EvalError>> = rx
                .into_iter()
                .par_bridge()
                .map(|(id, bytes)| {
                    let origin = format!("{}:file{id}.json", path.display());
                    let text = std::str::from_utf8(&bytes).map_err(|e| EvalError::Archive {
                        path: path.clone(),
                        message: format!("file{id}.json: {e}"),
                    })?;
                    Ok((id.clone(), f(&id, text, &origin)?))
                })
                .collect();
            let read = reader.join().unwrap_or_else(|_| Err(archive_err("the archive reader panicked".into())));
            read.map(|()| parsed)
        })?;
        let mut out = results.into_iter().collect::<Result<Vec<_>, _>>()?;
        out.sort_by_key(|(id, _)| task_id_key(id));
        if let Some(w) = wanted {
            let found: BTreeSet<&str> = out.iter().map(|(id, _)| id.as_str()).collect();
            let missing: Vec<&str> = w.iter().map(String::as_str).filter(|id| !found.contains(id)).collect();
            if !missing.is_empty() {
                return Err(EvalError::Archive {
                    path,
                    message: format!("no scene file for task(s) {}", missing.join(", ")),
                });
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_data_root_says_where_it_looked_and_how_to_point_at_it() {
        let dir = tempfile::tempdir().unwrap();
        let e = locate(Some(dir.path())).unwrap_err().to_string();
        assert!(e.contains(&dir.path().display().to_string()), "{e}");
        assert!(e.contains("--data") && e.contains(DATA_ENV), "{e}");
    }

    #[test]
    fn task_ids_sort_by_number() {
        let mut ids = vec!["1003_2", "101_2", "27_1", "27_2", "x"];
        ids.sort_by_key(|i| task_id_key(i));
        assert_eq!(ids, ["27_1", "27_2", "101_2", "1003_2", "x"]);
    }
}
