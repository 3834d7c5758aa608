//! The robot bridge (`--env "bridge:CMD"`): leaves execute on a real (or simulated) robot behind a
//! child process, spoken to in JSON lines.
//!
//! Protocol, one line each way per action:
//! - sent on the child's stdin: `{"action": "PUTIN", "args": [{"name": "apple", "id": 12}, {"name":
//!   "fridge", "id": 10}], "line": "[PUTIN] <apple> (12) <fridge> (10)"}`;
//! - answered on its stdout: `{"status": "ok", "observation": "..."}` (observation optional),
//!   `{"status": "failed", "reason": "...", "kind": "..."}` (kind optional), or
//!   `{"status": "skipped", "reason": "..."}` (the effect already held).
//!
//! Fields other than these are ignored, with a warning the first time each is seen, so a robot can add
//! its own (timings, poses) without breaking the run.
//!
//! Each answer must come within the timeout. A child that exits or closes its stdout (crashed), stays
//! silent (timeout) or answers something that is not an outcome (garbage) is an [`EnvError`] naming what
//! was sent and what came back; the bridge is then dead (every later action gets the same error), the
//! child is killed, and the transcript keeps every exchange up to it. The child's stderr is passed
//! through to ours, so its logs stay visible, and its tail goes into crash reports.
//!
//! The planner's belief ([`Env::world`]) is a shadow [`World`] built from the scene and advanced by
//! the actions the robot reports ok, so grammars and symbolic checks work as in simulation.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::json;

use super::env::{world_step, Env, EnvError, Outcome};
use crate::action::Action;
use crate::world::World;

/// Bytes of the child's stderr kept for error messages.
const STDERR_TAIL: usize = 2048;

/// One exchange with the child: what was sent, what came back (`None`: nothing, see `error`).
#[derive(Clone, Debug, Serialize)]
pub struct Exchange {
    pub sent: String,
    pub received: Option<String>,
    pub outcome: Option<Outcome>,
    pub error: Option<String>,
}

/// An answer line as the child writes it; `extra` holds the fields the protocol does not define.
#[derive(Deserialize)]
struct RawOutcome {
    status: String,
    #[serde(default)]
    observation: Option<String>,
    #[serde(default)]
    reason: Option<String>,
    #[serde(default)]
    kind: Option<String>,
    #[serde(flatten)]
    extra: std::collections::BTreeMap<String, serde_json::Value>,
}

/// A child process executing actions (see the module documentation).
pub struct BridgeEnv {
    name: String,
    command: String,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<std::io::Result<String>>,
    stderr_tail: Arc<Mutex<Vec<u8>>>,
    timeout: Duration,
    shadow: World,
    focus: Vec<u32>,
    transcript: Vec<Exchange>,
    /// Set once the bridge has failed: the error every later action gets.
    dead: Option<String>,
    /// Answer fields outside the protocol already warned about (once each).
    warned: std::collections::BTreeSet<String>,
}

impl BridgeEnv {
    /// The default time a robot has to answer one action.
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(60);

    /// Parses `--env` values of the form `bridge:CMD` (CMD run by `sh -c`).
    pub fn command_of(spec: &str) -> Option<&str> {
        spec.strip_prefix("bridge:").map(str::trim).filter(|c| !c.is_empty())
    }

    /// Starts `command` (through `sh -c`) with `scene` as the shadow world's start and `focus` the
    /// objects observations describe.
    pub fn spawn(command: &str, scene: World, focus: Vec<u32>, timeout: Duration) -> Result<BridgeEnv, EnvError> {
        let spawn_err = |detail: String| EnvError::Spawn { command: command.to_string(), detail };
        if command.trim().is_empty() {
            return Err(spawn_err("the command is empty (write --env \"bridge:CMD\", e.g. bridge:./robot.py)".into()));
        }
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(command)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| spawn_err(format!("{e} (is `sh` on the PATH?)")))?;
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().ok_or_else(|| spawn_err("no stdout pipe".into()))?;
        let stderr = child.stderr.take();
        // Lines arrive on a thread so each wait can have a timeout.
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut r = BufReader::new(stdout);
            loop {
                let mut line = String::new();
                match r.read_line(&mut line) {
                    Ok(0) => break, // EOF: the channel closes
                    Ok(_) => {
                        if tx.send(Ok(line)).is_err() {
                            break;
                        }
                    }
                    Err(e) => {
                        let _ = tx.send(Err(e));
                        break;
                    }
                }
            }
        });
        let tail = Arc::new(Mutex::new(Vec::new()));
        if let Some(mut err) = stderr {
            let tail = Arc::clone(&tail);
            std::thread::spawn(move || {
                let mut buf = [0u8; 1024];
                while let Ok(n) = err.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    let _ = std::io::stderr().write_all(&buf[..n]);
                    if let Ok(mut t) = tail.lock() {
                        t.extend_from_slice(&buf[..n]);
                        let excess = t.len().saturating_sub(STDERR_TAIL);
                        t.drain(..excess);
                    }
                }
            });
        }
        Ok(BridgeEnv {
            name: format!("bridge:{command}"),
            command: command.to_string(),
            child,
            stdin,
            lines: rx,
            stderr_tail: tail,
            timeout,
            shadow: scene,
            focus,
            transcript: Vec::new(),
            dead: None,
            warned: Default::default(),
        })
    }

    /// Every exchange so far, the failing one included.
    pub fn transcript(&self) -> &[Exchange] {
        &self.transcript
    }

    pub fn command(&self) -> &str {
        &self.command
    }

    /// The request line for `action`.
    pub fn request(action: &Action) -> String {
        let args: Vec<_> = action.args.iter().map(|o| json!({"name": o.class_name, "id": o.id})).collect();
        json!({"action": action.verb.name(), "args": args, "line": action.to_string()}).to_string()
    }

    /// Reads one answer line into an outcome and the names of the fields outside the protocol;
    /// `Err(detail)` when it is not an outcome.
    fn read_outcome(line: &str) -> Result<(Outcome, Vec<String>), String> {
        let raw: RawOutcome = serde_json::from_str(line.trim()).map_err(|e| {
            format!("{e} (expected {{\"status\": \"ok\"|\"failed\"|\"skipped\", \"observation\"|\"reason\": \"...\"}})")
        })?;
        let extra = raw.extra.keys().cloned().collect();
        let outcome = match raw.status.as_str() {
            "ok" => Ok(Outcome::Ok { observation: raw.observation.filter(|o| !o.trim().is_empty()) }),
            "failed" => match raw.reason {
                Some(reason) if !reason.trim().is_empty() => Ok(Outcome::Failed { reason, kind: raw.kind }),
                _ => Err("a \"failed\" outcome needs a non-empty \"reason\"".into()),
            },
            "skipped" => {
                Ok(Outcome::Skipped { reason: raw.reason.unwrap_or_else(|| "its effect already held".into()) })
            }
            s => Err(format!("unknown status {s:?} (expected \"ok\", \"failed\" or \"skipped\")")),
        }?;
        Ok((outcome, extra))
    }

    fn stderr_tail(&self) -> String {
        let t = self.stderr_tail.lock().map(|t| String::from_utf8_lossy(&t).trim().to_string()).unwrap_or_default();
        if t.is_empty() {
            String::new()
        } else {
            format!(
                "; its stderr ended with: {}",
                t.lines().rev().take(5).collect::<Vec<_>>().into_iter().rev().collect::<Vec<_>>().join(" | ")
            )
        }
    }

    /// Why the child is gone: its exit status (waited for briefly) and its stderr's tail.
    fn crash_detail(&mut self, what: &str) -> String {
        let mut status = None;
        for _ in 0..50 {
            if let Ok(Some(s)) = self.child.try_wait() {
                status = Some(s);
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        // The stderr thread may still be draining the last lines.
        std::thread::sleep(Duration::from_millis(20));
        let st = status.map_or_else(|| "it is still running".to_string(), |s| format!("it exited with {s}"));
        format!("{what}; {st}{}", self.stderr_tail())
    }

    fn fail(&mut self, sent: String, received: Option<String>, err: EnvError) -> EnvError {
        self.dead = Some(err.to_string());
        self.transcript.push(Exchange { sent, received, outcome: None, error: Some(err.to_string()) });
        self.stdin = None;
        let _ = self.child.kill();
        let _ = self.child.wait();
        err
    }
}

impl Env for BridgeEnv {
    fn name(&self) -> &str {
        &self.name
    }

    fn observe(&self, first: &[u32], budget: usize) -> String {
        self.shadow.observe_first(&self.focus, first, budget)
    }

    fn execute(&mut self, action: &Action) -> Result<Outcome, EnvError> {
        let sent = Self::request(action);
        if let Some(why) = &self.dead {
            return Err(EnvError::Crashed { sent, detail: format!("the bridge already failed: {why}") });
        }
        let wrote = match self.stdin.as_mut() {
            Some(w) => send_line(w, &sent),
            None => Err(std::io::Error::new(std::io::ErrorKind::BrokenPipe, "no stdin")),
        };
        if let Err(e) = wrote {
            let detail = self.crash_detail(&format!("writing the action failed ({e})"));
            return Err(self.fail(sent.clone(), None, EnvError::Crashed { sent, detail }));
        }
        let line = match self.lines.recv_timeout(self.timeout) {
            Ok(Ok(line)) => line,
            Ok(Err(e)) => {
                let detail = self.crash_detail(&format!("reading its answer failed ({e})"));
                return Err(self.fail(sent.clone(), None, EnvError::Crashed { sent, detail }));
            }
            Err(RecvTimeoutError::Disconnected) => {
                let detail = self.crash_detail("it closed its stdout without answering");
                return Err(self.fail(sent.clone(), None, EnvError::Crashed { sent, detail }));
            }
            Err(RecvTimeoutError::Timeout) => {
                let timeout_ms = self.timeout.as_millis() as u64;
                return Err(self.fail(sent.clone(), None, EnvError::Timeout { sent, timeout_ms }));
            }
        };
        let received = line.trim_end_matches(['\n', '\r']).to_string();
        match Self::read_outcome(&received) {
            Ok((outcome, extra)) => {
                for field in extra {
                    if self.warned.insert(field.clone()) {
                        eprintln!(
                            "warning: the robot answered {sent} with a field the bridge protocol does not define, \
                             {field:?}; it is ignored (read are \"status\", \"observation\", \"reason\", \"kind\")"
                        );
                    }
                }
                if matches!(outcome, Outcome::Ok { .. }) {
                    // The shadow follows the robot; an action the shadow cannot run leaves it as it was
                    // (the robot is the authority on what happened).
                    let _ = world_step(&mut self.shadow, action);
                }
                self.transcript.push(Exchange {
                    sent,
                    received: Some(received),
                    outcome: Some(outcome.clone()),
                    error: None,
                });
                Ok(outcome)
            }
            Err(detail) => {
                let err = EnvError::Garbage { sent: sent.clone(), received: received.clone(), detail };
                Err(self.fail(sent, Some(received), err))
            }
        }
    }

    fn world(&self) -> Option<&World> {
        Some(&self.shadow)
    }
}

impl Drop for BridgeEnv {
    fn drop(&mut self) {
        // Closing stdin tells a well-behaved child to finish; one that does not is killed.
        self.stdin = None;
        for _ in 0..20 {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Writes one line to the bridge. A bridge that has exited makes this an error (reported with its
/// stderr), not the end of `step`: the CLI restores SIGPIPE's default action so that a closed
/// stdout ends it quietly, and a write to a closed pipe raises that signal. It is held back on this
/// thread for the write and, if raised, taken off before the thread's mask is restored.
fn send_line(w: &mut ChildStdin, line: &str) -> std::io::Result<()> {
    let write = |w: &mut ChildStdin| writeln!(w, "{line}").and_then(|_| w.flush());
    #[cfg(not(unix))]
    return write(w);
    #[cfg(unix)]
    // SAFETY: the sets are initialised by sigemptyset/pthread_sigmask/sigpending before use; the
    // mask is changed for this thread only and restored before returning.
    unsafe {
        let mut pipe: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut pipe);
        libc::sigaddset(&mut pipe, libc::SIGPIPE);
        let mut old: libc::sigset_t = std::mem::zeroed();
        libc::pthread_sigmask(libc::SIG_BLOCK, &pipe, &mut old);
        let wrote = write(w);
        let mut pending: libc::sigset_t = std::mem::zeroed();
        // (only if this write raised it and it was not blocked already by the caller)
        if libc::sigpending(&mut pending) == 0
            && libc::sigismember(&pending, libc::SIGPIPE) == 1
            && libc::sigismember(&old, libc::SIGPIPE) == 0
        {
            let mut taken = 0;
            libc::sigwait(&pipe, &mut taken);
        }
        libc::pthread_sigmask(libc::SIG_SETMASK, &old, std::ptr::null_mut());
        wrote
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::{ObjRef, Verb};

    fn walk(id: u32, name: &str) -> Action {
        Action::new(Verb::Walk, vec![ObjRef::new(name, id)]).unwrap()
    }

    /// Writes `body` as an executable script in a temp dir; returns the dir (kept alive) and the command.
    fn script(body: &str) -> (tempfile::TempDir, String) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("robot.py");
        std::fs::write(&p, body).unwrap();
        let cmd = format!("python3 -u {}", p.display());
        (dir, cmd)
    }

    fn bridge(cmd: &str, timeout_ms: u64) -> BridgeEnv {
        let w = World::demo();
        let focus: Vec<u32> = w.nodes().map(|n| n.id).collect();
        BridgeEnv::spawn(cmd, w, focus, Duration::from_millis(timeout_ms)).unwrap()
    }

    const GOOD: &str = r#"
import json, sys
for line in sys.stdin:
    a = json.loads(line)
    if a["action"] == "GRAB":
        print(json.dumps({"status": "failed", "reason": "gripper is empty-handed: " + a["line"], "kind": "hardware"}))
    else:
        print(json.dumps({"status": "ok", "observation": "did " + a["line"]}))
    sys.stdout.flush()
"#;

    #[test]
    fn a_good_bridge_answers_and_the_shadow_follows_what_it_reports_ok() {
        let (_d, cmd) = script(GOOD);
        let mut b = bridge(&cmd, 10_000);
        assert_eq!(b.name(), format!("bridge:{cmd}"));
        let fridge = b.world().unwrap().ids_of_class("fridge")[0];
        let before = b.world().unwrap().clone();
        let out = b.execute(&walk(fridge, "fridge")).unwrap();
        assert_eq!(out, Outcome::Ok { observation: Some(format!("did [WALK] <fridge> ({fridge})")) });
        let me = before.character();
        assert!(b.world().unwrap().related(me, crate::world::Relation::Close).contains(&fridge), "the shadow walked");
        let apple = before.ids_of_class("apple")[0];
        let grab = Action::new(Verb::Grab, vec![ObjRef::new("apple", apple)]).unwrap();
        match b.execute(&grab).unwrap() {
            Outcome::Failed { reason, kind } => {
                assert!(reason.contains("[GRAB] <apple>"), "{reason}");
                assert_eq!(kind.as_deref(), Some("hardware"));
            }
            o => panic!("{o:?}"),
        }
        assert!(b.world().unwrap().held().is_empty(), "a failed action leaves the shadow as it was");
        assert_eq!(b.transcript().len(), 2);
        assert!(b.transcript()[0].sent.contains("\"action\":\"WALK\""));
    }

    #[test]
    fn a_slow_bridge_times_out_and_stays_dead() {
        let (_d, cmd) = script("import sys, time\nfor line in sys.stdin:\n    time.sleep(30)\n");
        let mut b = bridge(&cmd, 300);
        let t0 = std::time::Instant::now();
        let e = b.execute(&walk(1, "kitchen")).unwrap_err();
        assert!(t0.elapsed() < Duration::from_secs(10));
        assert!(matches!(e, EnvError::Timeout { timeout_ms: 300, .. }), "{e}");
        assert!(e.to_string().contains("[WALK] <kitchen> (1)"), "the error names what was sent: {e}");
        let again = b.execute(&walk(1, "kitchen")).unwrap_err();
        assert!(again.to_string().contains("already failed"), "{again}");
        assert_eq!(b.transcript().len(), 1, "the transcript keeps the failed exchange");
        assert!(b.transcript()[0].error.is_some());
    }

    #[test]
    fn a_crashing_bridge_is_a_clear_error_with_its_exit_status_and_stderr() {
        let body = "import json, sys\nline = sys.stdin.readline()\nprint(json.dumps({'status': 'ok'}), flush=True)\nsys.stdin.readline()\nsys.stderr.write('motor driver fault\\n')\nsys.exit(3)\n";
        let (_d, cmd) = script(body);
        let mut b = bridge(&cmd, 10_000);
        assert_eq!(b.execute(&walk(1, "kitchen")).unwrap(), Outcome::Ok { observation: None });
        let e = b.execute(&walk(2, "living_room")).unwrap_err();
        let s = e.to_string();
        assert!(matches!(e, EnvError::Crashed { .. }), "{s}");
        assert!(s.contains("living_room") && s.contains("exit status: 3") && s.contains("motor driver fault"), "{s}");
        assert_eq!(b.transcript().len(), 2);
        assert!(b.transcript()[0].outcome.is_some() && b.transcript()[1].error.is_some());
    }

    #[test]
    fn a_garbage_speaking_bridge_names_what_it_said() {
        let (_d, cmd) = script("import sys\nfor line in sys.stdin:\n    print('OK ROBOT READY', flush=True)\n");
        let mut b = bridge(&cmd, 10_000);
        let e = b.execute(&walk(1, "kitchen")).unwrap_err();
        let s = e.to_string();
        assert!(matches!(e, EnvError::Garbage { .. }), "{s}");
        assert!(s.contains("OK ROBOT READY") && s.contains("[WALK] <kitchen> (1)") && s.contains("expected"), "{s}");
        // A well-formed line with a bad status or no reason is garbage too.
        assert!(BridgeEnv::read_outcome(r#"{"status": "done"}"#).unwrap_err().contains("unknown status"));
        assert!(BridgeEnv::read_outcome(r#"{"status": "failed"}"#).unwrap_err().contains("reason"));
        assert!(BridgeEnv::read_outcome(r#"["ok"]"#).unwrap_err().contains("expected"));
        assert_eq!(
            BridgeEnv::read_outcome(r#"{"status": "skipped", "reason": "already open"}"#).unwrap(),
            (Outcome::Skipped { reason: "already open".into() }, vec![])
        );
        // A robot's own fields (telemetry) are named, not an error; the outcome is read as without them.
        assert_eq!(
            BridgeEnv::read_outcome(r#"{"status": "ok", "duration_ms": 3, "pose": [1, 2]}"#).unwrap(),
            (Outcome::Ok { observation: None }, vec!["duration_ms".to_string(), "pose".to_string()])
        );
    }

    #[test]
    fn a_missing_command_is_a_spawn_or_crash_error() {
        assert_eq!(BridgeEnv::command_of("bridge: ./robot --port 3"), Some("./robot --port 3"));
        assert_eq!(BridgeEnv::command_of("bridge:"), None);
        assert_eq!(BridgeEnv::command_of("sim"), None);
        assert!(matches!(BridgeEnv::spawn("  ", World::demo(), vec![], BridgeEnv::DEFAULT_TIMEOUT), Err(EnvError::Spawn { .. })));
        // `sh` starts, the command does not exist: the first action reports the crash.
        let mut b = bridge("/nonexistent/robot-bridge", 10_000);
        let e = b.execute(&walk(1, "kitchen")).unwrap_err();
        assert!(matches!(e, EnvError::Crashed { .. }), "{e}");
        assert!(e.to_string().contains("exit status: 127"), "{e}");
    }
}
