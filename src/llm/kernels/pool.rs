//! A small worker pool for the forward pass that behaves on a shared CPU: between jobs the workers
//! spin only briefly (a decode step issues a job every few microseconds), then yield, then sleep on a
//! condition variable, so a busy neighbour gets the cores back instead of competing with spinners.
//! Tasks are handed out one at a time from a shared counter, so a worker the OS has descheduled does
//! not hold up the rest: the others take its share. The caller's thread works too.
//!
//! The thread count comes from `STEP_THREADS`, else `CANDLE_NUM_THREADS`/`RAYON_NUM_THREADS` (what
//! `step --threads N` sets), else the machine's available parallelism.

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

/// The thread count asked for in the environment, else the machine's parallelism.
pub fn configured_threads() -> usize {
    ["STEP_THREADS", "CANDLE_NUM_THREADS", "RAYON_NUM_THREADS"]
        .iter()
        .find_map(|k| std::env::var(k).ok().and_then(|v| v.trim().parse::<usize>().ok()))
        .filter(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
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
