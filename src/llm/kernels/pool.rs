//! A small worker pool for the forward pass that behaves on a shared CPU: between jobs the workers
//! spin only briefly (a decode step issues a job every few microseconds), then yield, then sleep on a
//! condition variable, so a busy neighbour gets the cores back instead of competing with spinners.
//! Tasks are handed out one at a time from a shared counter, so a worker the OS has descheduled does
//! not hold up the rest: the others take its share. The caller's thread works too.
//!
//! The thread count comes from `STEP_THREADS`, else `CANDLE_NUM_THREADS`/`RAYON_NUM_THREADS` (what
//! `step --threads N` sets); `auto`, or none of them, means the cores not already busy when the pool
//! starts ([`auto_threads`]): on a 2-core robot PC with one busy neighbour, one worker gets a core to
//! itself instead of two taking turns with the neighbour.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::{Duration, Instant};

/// One job: `n` tasks of a borrowed closure. The closure is only called while `done < n`, and the
/// submitting thread waits for `done == n` before the borrow ends.
struct Job {
    f: *const (dyn Fn(usize) + Sync),
    n: usize,
    next: AtomicUsize,
    done: AtomicUsize,
}

// SAFETY: `f` points to a `Sync` closure that outlives every call made through it (see `Pool::run`).
unsafe impl Send for Job {}
unsafe impl Sync for Job {}

impl Job {
    /// Runs tasks until none are left to claim.
    fn work(&self) {
        loop {
            let k = self.next.fetch_add(1, Ordering::Relaxed);
            if k >= self.n {
                return;
            }
            // SAFETY: k < n, so this task has not completed and `run` is still waiting: `f` is alive.
            unsafe { (*self.f)(k) };
            self.done.fetch_add(1, Ordering::Release);
        }
    }
}

struct Shared {
    /// Bumped for every new job; workers compare it with the last one they saw.
    generation: AtomicU64,
    job: Mutex<Option<Arc<Job>>>,
    wake: Condvar,
    sleepers: AtomicUsize,
}

/// The pool; see the module notes.
pub struct Pool {
    shared: Arc<Shared>,
    threads: usize,
    /// Serialises jobs from different caller threads (tests run models in parallel).
    submit: Mutex<()>,
}

/// How long an idle worker spins, then yields, before it sleeps.
const SPIN: Duration = Duration::from_micros(50);
const YIELD: Duration = Duration::from_micros(500);

impl Pool {
    /// A pool whose jobs run on `threads` threads in all (the caller's included).
    pub fn new(threads: usize) -> Self {
        let threads = threads.max(1);
        let shared = Arc::new(Shared {
            generation: AtomicU64::new(0),
            job: Mutex::new(None),
            wake: Condvar::new(),
            sleepers: AtomicUsize::new(0),
        });
        for i in 1..threads {
            let s = shared.clone();
            std::thread::Builder::new()
                .name(format!("step-worker-{i}"))
                .spawn(move || worker(&s))
                .expect("spawning a worker thread");
        }
        Self { shared, threads, submit: Mutex::new(()) }
    }

    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `f(0..n)`, each index exactly once, and returns when all have finished.
    pub fn run(&self, n: usize, f: &(dyn Fn(usize) + Sync)) {
        if n == 0 {
            return;
        }
        if self.threads == 1 || n == 1 {
            (0..n).for_each(f);
            return;
        }
        let _guard = self.submit.lock().unwrap_or_else(|e| e.into_inner());
        // SAFETY (lifetime erasure): the job is only called through while tasks remain, and this
        // function does not return before every task is done.
        let f: *const (dyn Fn(usize) + Sync + '_) = f;
        let f: *const (dyn Fn(usize) + Sync) = unsafe { std::mem::transmute(f) };
        let job = Arc::new(Job { f, n, next: AtomicUsize::new(0), done: AtomicUsize::new(0) });
        {
            let mut slot = self.shared.job.lock().unwrap_or_else(|e| e.into_inner());
            *slot = Some(job.clone());
            self.shared.generation.fetch_add(1, Ordering::Release);
            if self.shared.sleepers.load(Ordering::Relaxed) > 0 {
                self.shared.wake.notify_all();
            }
        }
        job.work();
        // Tasks claimed by other workers may still be running; wait politely.
        let start = Instant::now();
        while job.done.load(Ordering::Acquire) < n {
            if start.elapsed() < SPIN {
                std::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
    }
}

fn worker(s: &Shared) {
    let mut seen = 0u64;
    loop {
        let start = Instant::now();
        let mut spins = 0u32;
        // Wait for a new generation: spin, then yield, then sleep.
        loop {
            if s.generation.load(Ordering::Acquire) != seen {
                break;
            }
            spins += 1;
            if spins % 64 != 0 {
                std::hint::spin_loop();
                continue;
            }
            let waited = start.elapsed();
            if waited < SPIN {
                continue;
            }
            if waited < YIELD {
                std::thread::yield_now();
                continue;
            }
            let slot = s.job.lock().unwrap_or_else(|e| e.into_inner());
            s.sleepers.fetch_add(1, Ordering::Relaxed);
            let _slot = s
                .wake
                .wait_while(slot, |_| s.generation.load(Ordering::Acquire) == seen)
                .unwrap_or_else(|e| e.into_inner());
            s.sleepers.fetch_sub(1, Ordering::Relaxed);
            break;
        }
        let job = {
            let slot = s.job.lock().unwrap_or_else(|e| e.into_inner());
            seen = s.generation.load(Ordering::Acquire);
            slot.clone()
        };
        if let Some(job) = job {
            job.work();
        }
    }
}

/// The thread count asked for in the environment (the first of the variables that is set); `auto`,
/// anything that is not a positive count, or nothing set: [`auto_threads`].
pub fn configured_threads() -> usize {
    let asked = ["STEP_THREADS", "CANDLE_NUM_THREADS", "RAYON_NUM_THREADS"].iter().find_map(|k| std::env::var(k).ok());
    match asked.and_then(|v| v.trim().parse::<usize>().ok()) {
        Some(n) if n > 0 => n,
        _ => auto_threads(),
    }
}

/// The hardware threads not already busy: the machine's parallelism less the other runnable
/// threads at this moment (Linux's `procs_running`, which counts the caller), at least 1; the whole
/// machine where `/proc/stat` cannot be read. Read once, when the pool starts.
pub fn auto_threads() -> usize {
    let machine = std::thread::available_parallelism().map_or(1, |n| n.get());
    match std::fs::read_to_string("/proc/stat") {
        Ok(stat) => free_threads(machine, &stat),
        Err(_) => machine,
    }
}

/// [`auto_threads`] over the text of `/proc/stat`.
fn free_threads(machine: usize, proc_stat: &str) -> usize {
    let running = proc_stat.lines().find_map(|l| l.strip_prefix("procs_running")?.trim().parse::<usize>().ok());
    match running {
        // The caller is running too: the others are `running - 1`.
        Some(r) => machine.saturating_sub(r.saturating_sub(1)).max(1),
        None => machine,
    }
}

/// The process-wide pool, created on first use with [`configured_threads`].
pub fn global() -> &'static Pool {
    static POOL: OnceLock<Pool> = OnceLock::new();
    POOL.get_or_init(|| Pool::new(configured_threads()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_runs_once_across_many_jobs() {
        let pool = Pool::new(3);
        for n in [1usize, 2, 7, 100] {
            let hits: Vec<AtomicUsize> = (0..n).map(|_| AtomicUsize::new(0)).collect();
            for _ in 0..50 {
                pool.run(n, &|k| {
                    hits[k].fetch_add(1, Ordering::Relaxed);
                });
            }
            assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 50), "n = {n}");
        }
    }

    #[test]
    fn auto_takes_the_cores_other_runnable_threads_leave() {
        let stat = |r: usize| format!("cpu  1 2 3\nctxt 99\nprocs_running {r}\nprocs_blocked 0\n");
        assert_eq!(free_threads(2, &stat(1)), 2, "only the caller runs");
        assert_eq!(free_threads(2, &stat(2)), 1, "one busy neighbour");
        assert_eq!(free_threads(2, &stat(5)), 1, "never fewer than one");
        assert_eq!(free_threads(8, &stat(3)), 6);
        assert_eq!(free_threads(4, "cpu 1 2 3\n"), 4, "no procs_running line: the whole machine");
        assert!(auto_threads() >= 1);
    }

    #[test]
    fn workers_wake_after_sleeping() {
        let pool = Pool::new(2);
        let count = AtomicUsize::new(0);
        pool.run(4, &|_| {
            count.fetch_add(1, Ordering::Relaxed);
        });
        std::thread::sleep(YIELD * 4);
        pool.run(4, &|_| {
            count.fetch_add(1, Ordering::Relaxed);
        });
        assert_eq!(count.load(Ordering::Relaxed), 8);
    }
}
