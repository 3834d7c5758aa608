//! The run's trace: JSON lines, one event a line, written and flushed as the tree grows, so a killed
//! run loses nothing. `step replay` reads it back and re-runs the same request with the same model
//! and settings.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_json::{json, Value};

/// Where trace events go: a file, or nowhere.
pub struct TraceWriter {
    out: Option<(PathBuf, BufWriter<File>)>,
    start: Instant,
    /// The first write error (the run goes on; the caller may report it at the end).
    error: Option<String>,
    events: usize,
    meta: Value,
    echo: Option<Box<dyn FnMut(&str, &Value)>>,
}

impl TraceWriter {
    /// A trace file at `path` (created or truncated).
    pub fn create(path: &Path) -> std::io::Result<TraceWriter> {
        let f = File::create(path)?;
        Ok(TraceWriter { out: Some((path.to_path_buf(), BufWriter::new(f))), start: Instant::now(), error: None, events: 0, meta: Value::Null, echo: None })
    }

    /// A trace that writes nothing.
    pub fn sink() -> TraceWriter {
        TraceWriter { out: None, start: Instant::now(), error: None, events: 0, meta: Value::Null, echo: None }
    }

    pub fn path(&self) -> Option<&Path> {
        self.out.as_ref().map(|(p, _)| p.as_path())
    }

    /// What the caller knows and the planner does not (model file, scene source, task id): written
    /// in the header event under `meta`.
    pub fn set_meta(&mut self, meta: Value) {
        self.meta = meta;
    }

    pub fn meta(&self) -> &Value {
        &self.meta
    }

    /// Also hands every event to `f` (the CLI prints the tree as it grows from these).
    pub fn set_echo(&mut self, f: Box<dyn FnMut(&str, &Value)>) {
        self.echo = Some(f);
    }

    /// Events written so far.
    pub fn events(&self) -> usize {
        self.events
    }

    /// The first write error, if any (a full disk must not kill the robot's run, so writes never fail
    /// the planner).
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Writes one event `{"event": kind, "t_ms": …, ...fields}` and flushes it.
    pub fn event(&mut self, kind: &str, fields: Value) {
        self.events += 1;
        if let Some(echo) = self.echo.as_mut() {
            echo(kind, &fields);
        }
        let Some((path, w)) = self.out.as_mut() else { return };
        let mut obj = serde_json::Map::new();
        obj.insert("event".into(), json!(kind));
        obj.insert("t_ms".into(), json!((self.start.elapsed().as_secs_f64() * 1e3 * 1e3).round() / 1e3));
        match fields {
            Value::Object(m) => obj.extend(m),
            Value::Null => {}
            other => {
                obj.insert("value".into(), other);
            }
        }
        let line = Value::Object(obj).to_string();
        let r = writeln!(w, "{line}").and_then(|_| w.flush());
        if let Err(e) = r {
            if self.error.is_none() {
                self.error = Some(format!("{}: {e}", path.display()));
            }
        }
    }
}
