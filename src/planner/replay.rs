//! Reading a trace back and comparing a re-run with it: `step replay` runs the same request with the
//! same model and settings and lists where the model's outputs, the executed actions or the stop differ.

use std::path::Path;

use serde_json::Value;

use super::PlanOutcome;

/// The parts of a trace a replay needs.
#[derive(Clone, Debug)]
pub struct TraceFile {
    pub header: Value,
    /// The `call` events, in order.
    pub calls: Vec<Value>,
    /// The `end` event (absent when the run was killed).
    pub end: Option<Value>,
    pub events: usize,
    /// The number of a last line cut off in the middle (a run killed while writing it), left out.
    pub cut_line: Option<usize>,
}

/// Reads a trace; errors name the file and line.
pub fn read_trace(path: &Path) -> Result<TraceFile, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut header = None;
    let mut calls = Vec::new();
    let mut end = None;
    let mut events = 0;
    let mut cut_line = None;
    let n_lines = text.lines().count();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: Value = match serde_json::from_str(line) {
            Ok(v) => v,
            // Events are written a whole line at a time, so only a kill can leave half of the last one.
            Err(e) if e.is_eof() && i + 1 == n_lines && !text.ends_with('\n') => {
                cut_line = Some(i + 1);
                break;
            }
            Err(e) => {
                return Err(format!(
                    "{}:{}: not a trace event ({e}); traces are written by `step plan --trace`",
                    path.display(),
                    i + 1
                ))
            }
        };
        events += 1;
        match v.get("event").and_then(Value::as_str) {
            Some("header") => header = Some(v),
            Some("call") => calls.push(v),
            Some("end") => end = Some(v),
            _ => {}
        }
    }
    let header =
        header.ok_or_else(|| format!("{}: no header event (is it a `step plan --trace` file?)", path.display()))?;
    Ok(TraceFile { header, calls, end, events, cut_line })
}

/// Where a re-run differs from the trace (empty: identical; for a trace cut short, identical as
/// far as it goes). Times are not compared.
pub fn compare(recorded: &TraceFile, out: &PlanOutcome) -> Vec<String> {
    let mut diffs = Vec::new();
    for (i, (r, c)) in recorded.calls.iter().zip(&out.stats.calls).enumerate() {
        let same = r["role"].as_str() == Some(c.role)
            && r["node"].as_u64() == Some(c.node as u64)
            && r["prompt_hash"].as_str() == Some(c.prompt_hash.as_str())
            && r["output"].as_str() == Some(c.output.as_str());
        if !same {
            let what = if r["prompt_hash"].as_str() != Some(c.prompt_hash.as_str()) { "prompt" } else { "output" };
            diffs.push(format!(
                "call {} ({} at node {}): the {what} differs: trace {:?} (prompt {}), replay {:?} (prompt {}) at node {}",
                i + 1,
                r["role"].as_str().unwrap_or("?"),
                r["node"],
                r["output"].as_str().unwrap_or(""),
                r["prompt_hash"].as_str().unwrap_or(""),
                c.output,
                c.prompt_hash,
                c.node
            ));
            // Everything after the first divergence follows from it.
            return diffs;
        }
    }
    // A trace cut short (no end event: the run was killed) is compared as far as it goes.
    let cut_short = recorded.end.is_none() && out.stats.calls.len() >= recorded.calls.len();
    if recorded.calls.len() != out.stats.calls.len() && !cut_short {
        diffs.push(format!("the trace has {} model calls, the replay {}", recorded.calls.len(), out.stats.calls.len()));
    }
    match &recorded.end {
        None => {}
        Some(end) => {
            let executed: Vec<String> = out.executed.iter().map(|a| a.to_string()).collect();
            let rec: Vec<String> = end["executed"]
                .as_array()
                .map(|a| a.iter().filter_map(|x| x.as_str().map(str::to_string)).collect())
                .unwrap_or_default();
            if rec != executed {
                diffs.push(format!("executed actions differ: trace {rec:?}, replay {executed:?}"));
            }
            let stop = serde_json::to_value(&out.stop).unwrap_or_default();
            if end["stop"] != stop {
                diffs.push(format!("the stop differs: trace {}, replay {stop}", end["stop"]));
            }
        }
    }
    diffs
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<TraceFile, String> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.jsonl");
        std::fs::write(&p, text).unwrap();
        read_trace(&p)
    }

    #[test]
    fn a_last_line_cut_off_by_a_kill_is_left_out_and_any_other_bad_line_is_an_error() {
        let head = "{\"event\":\"header\"}\n{\"event\":\"call\",\"output\":\"a\"}\n";
        let t = read(&format!("{head}{{\"event\":\"call\",\"out")).unwrap();
        assert_eq!((t.calls.len(), t.cut_line, t.events), (1, Some(3), 2));
        assert_eq!(read(head).unwrap().cut_line, None);
        // A whole line (it ends with a newline) that does not parse was not cut by a kill.
        let e = read(&format!("{head}{{\"event\":\"call\",\"out\n")).unwrap_err();
        assert!(e.contains("t.jsonl:3: not a trace event"), "{e}");
        let e = read(&format!("{{\"event\":\"header\"}}\nnot json\n{head}")).unwrap_err();
        assert!(e.contains("t.jsonl:2: not a trace event"), "{e}");
    }
}
