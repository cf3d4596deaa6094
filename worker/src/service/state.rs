//! What a worker holds per job: the loaded level and the assigned vectors, with
//! memory accounting and the idle-timeout reaper.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tonic::Status;

use texsyn_engine::{Engine, OwnedLevel, VectorSpace};

use super::budget::{Budget, Reservation};
use super::config::{WorkerConfig, WrongAnswers};

/// Most jobs held at once; more is RESOURCE_EXHAUSTED until one ends or expires.
pub(crate) const MAX_JOBS: usize = 64;

/// One pyramid level of a job: the images the master sent and its reference
/// positions, with the memory they hold reserved until the last user drops it.
#[derive(Debug)]
pub(crate) struct Level {
    data: OwnedLevel,
    _memory: Reservation,
}

impl Level {
    /// The level, holding `memory` (resized to what the level really holds).
    pub(crate) fn new(data: OwnedLevel, mut memory: Reservation) -> Result<Self, Status> {
        memory.resize(data.bytes(), "the loaded level")?;
        Ok(Self {
            data,
            _memory: memory,
        })
    }
}

impl std::ops::Deref for Level {
    type Target = OwnedLevel;

    fn deref(&self) -> &OwnedLevel {
        &self.data
    }
}

/// The vectors of the range a job's current level assigned to this worker.
#[derive(Debug)]
pub(crate) struct Assigned {
    pub level: Arc<Level>,
    pub epoch: u64,
    /// The range's vectors; empty (layout and start only) when `lbg` holds them.
    pub space: VectorSpace,
    pub bytes: u64,
    /// LBG search of the range (`lbg_probes` > 0): its codebook and the probes.
    pub lbg: Option<(texsyn_engine::lbg::Codebook, usize)>,
    /// `bytes`, reserved until the assignment is dropped.
    pub _memory: Reservation,
}

#[derive(Debug)]
struct Job {
    level: Option<Arc<Level>>,
    assigned: Option<Arc<Assigned>>,
    last_used: Instant,
}

impl Job {
    fn bytes(&self) -> u64 {
        self.level.as_ref().map_or(0, |l| l.bytes()) + self.assigned.as_ref().map_or(0, |a| a.bytes)
    }
}

/// State shared by every call of one worker.
pub(crate) struct Shared {
    pub engine: Engine,
    pub pool: Arc<rayon::ThreadPool>,
    pub threads: usize,
    /// The worker-wide memory cap (`--max-memory`) and what is reserved against it.
    pub budget: Arc<Budget>,
    /// How assigned ranges hold their vectors.
    pub storage: texsyn_engine::Storage,
    pub max_message: usize,
    /// Fault injection: answers are made up while this is true (see
    /// [`WorkerConfig::wrong_answers`]).
    pub wrong_answers: std::sync::atomic::AtomicBool,
    /// Fault injection: see [`WorkerConfig::low_reports`].
    pub low_reports: bool,
    /// Turns true when the server shuts down; search streams end on it.
    pub stop: tokio::sync::watch::Receiver<bool>,
    jobs: Mutex<HashMap<String, Job>>,
    /// f64 bits of the last calibrated throughput (pairs per second).
    calibrated: AtomicU64,
}

fn failed(msg: impl Into<String>) -> Status {
    Status::failed_precondition(msg)
}

impl Shared {
    pub(crate) fn new(
        config: &WorkerConfig,
        pool: rayon::ThreadPool,
        stop: tokio::sync::watch::Receiver<bool>,
    ) -> Self {
        Self {
            engine: Engine::new(config.kernel).with_spin(config.spin),
            pool: Arc::new(pool),
            threads: config.threads,
            budget: Budget::new(config.max_memory),
            storage: config.storage,
            max_message: config.max_message,
            wrong_answers: (config.wrong_answers == WrongAnswers::Always).into(),
            low_reports: config.low_reports,
            stop,
            jobs: Mutex::new(HashMap::new()),
            calibrated: AtomicU64::new(0f64.to_bits()),
        }
    }

    fn jobs(&self) -> MutexGuard<'_, HashMap<String, Job>> {
        // A panic elsewhere while holding the lock leaves the map consistent
        // (every update is a single insert/remove), so poisoning is ignored.
        self.jobs.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `f` on the search pool from a blocking task, so gRPC I/O never waits on it.
    pub(crate) async fn run<T, F>(&self, f: F) -> Result<T, Status>
    where
        T: Send + 'static,
        F: FnOnce() -> T + Send + 'static,
    {
        let pool = self.pool.clone();
        tokio::task::spawn_blocking(move || pool.install(f))
            .await
            .map_err(|e| Status::internal(format!("worker task failed: {e}")))
    }

    pub(crate) fn calibrated(&self) -> f64 {
        f64::from_bits(self.calibrated.load(Ordering::Relaxed))
    }

    pub(crate) fn set_calibrated(&self, pairs_per_second: f64) {
        self.calibrated
            .store(pairs_per_second.to_bits(), Ordering::Relaxed);
    }

    /// Bytes reserved now, by every job and every call in flight.
    pub(crate) fn memory_in_use(&self) -> u64 {
        self.budget.used()
    }

    pub(crate) fn job_count(&self) -> usize {
        self.jobs().len()
    }

    /// Makes room for a new level of `job_id`: drops the job's previous level and
    /// assignment, or registers a new job if there is room for one.
    pub(crate) fn begin_level(&self, job_id: &str) -> Result<(), Status> {
        let mut jobs = self.jobs();
        if let Some(job) = jobs.get_mut(job_id) {
            job.level = None;
            job.assigned = None;
            job.last_used = Instant::now();
            return Ok(());
        }
        if jobs.len() >= MAX_JOBS {
            return Err(Status::resource_exhausted(format!(
                "this worker already holds {MAX_JOBS} jobs; end one (EndJob) or wait for the idle timeout"
            )));
        }
        jobs.insert(
            job_id.to_string(),
            Job {
                level: None,
                assigned: None,
                last_used: Instant::now(),
            },
        );
        Ok(())
    }

    /// Installs a computed level as the job's current one.
    pub(crate) fn install_level(&self, job_id: &str, level: Arc<Level>) {
        self.jobs().insert(
            job_id.to_string(),
            Job {
                level: Some(level),
                assigned: None,
                last_used: Instant::now(),
            },
        );
    }

    /// The job's current level, which must be `level`.
    pub(crate) fn level(&self, job_id: &str, level: u32) -> Result<Arc<Level>, Status> {
        let mut jobs = self.jobs();
        let job = jobs.get_mut(job_id).ok_or_else(|| {
            failed(format!(
                "unknown job '{job_id}' (never loaded, ended or expired); send LoadLevel first"
            ))
        })?;
        job.last_used = Instant::now();
        match &job.level {
            Some(l) if l.level == level as usize => Ok(l.clone()),
            Some(l) => Err(failed(format!(
                "job '{job_id}' has level {} loaded, not level {level}; send LoadLevel for level {level}",
                l.level
            ))),
            None => Err(failed(format!(
                "job '{job_id}' has no level loaded yet; send LoadLevel first"
            ))),
        }
    }

    /// Drops the job's assignment (before a new one is built), if the level is still `level`.
    pub(crate) fn clear_assignment(&self, job_id: &str, level: &Arc<Level>) {
        if let Some(job) = self.jobs().get_mut(job_id) {
            if job.level.as_ref().is_some_and(|l| Arc::ptr_eq(l, level)) {
                job.assigned = None;
            }
        }
    }

    /// Installs a built assignment unless the level changed meanwhile.
    pub(crate) fn install_assignment(
        &self,
        job_id: &str,
        assigned: Arc<Assigned>,
    ) -> Result<(), Status> {
        let mut jobs = self.jobs();
        let job = jobs
            .get_mut(job_id)
            .ok_or_else(|| failed(format!("job '{job_id}' ended while its range was built")))?;
        if !job
            .level
            .as_ref()
            .is_some_and(|l| Arc::ptr_eq(l, &assigned.level))
        {
            return Err(failed(format!(
                "the level of job '{job_id}' was replaced while its range was built; assign again"
            )));
        }
        job.assigned = Some(assigned);
        job.last_used = Instant::now();
        Ok(())
    }

    /// The job's assignment for `level` at `epoch`.
    pub(crate) fn assigned(
        &self,
        job_id: &str,
        level: u32,
        epoch: u64,
    ) -> Result<Arc<Assigned>, Status> {
        let l = self.level(job_id, level)?;
        let jobs = self.jobs();
        let a = jobs
            .get(job_id)
            .and_then(|j| j.assigned.clone())
            .filter(|a| Arc::ptr_eq(&a.level, &l))
            .ok_or_else(|| {
                failed(format!(
                    "job '{job_id}' level {level} has no range assigned; send Assign first"
                ))
            })?;
        if a.epoch != epoch {
            return Err(failed(format!(
                "stale epoch: the batch is for epoch {epoch} but job '{job_id}' was assigned at epoch {}",
                a.epoch
            )));
        }
        Ok(a)
    }

    /// Marks the job as used (so the idle timeout does not free it).
    pub(crate) fn touch(&self, job_id: &str) {
        if let Some(job) = self.jobs().get_mut(job_id) {
            job.last_used = Instant::now();
        }
    }

    /// Frees a job; returns the bytes it held (0 for an unknown job).
    pub(crate) fn end_job(&self, job_id: &str) -> u64 {
        self.jobs().remove(job_id).map_or(0, |j| j.bytes())
    }

    /// Frees the jobs unused for longer than `idle`.
    pub(crate) fn reap(&self, idle: Duration) -> Vec<(String, u64)> {
        let now = Instant::now();
        let mut freed = Vec::new();
        self.jobs().retain(|id, job| {
            let keep = now.duration_since(job.last_used) <= idle;
            if !keep {
                freed.push((id.clone(), job.bytes()));
            }
            keep
        });
        freed
    }

    pub(crate) fn clear(&self) {
        self.jobs().clear();
    }
}

/// Background task: frees jobs idle for longer than `idle`.
pub(crate) async fn reap_idle_jobs(shared: Arc<Shared>, idle: Duration) {
    let period = (idle / 4).clamp(Duration::from_millis(20), Duration::from_secs(5));
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        for (job, bytes) in shared.reap(idle) {
            tracing::info!(job, bytes, "job idle for {:?}; freed", idle);
        }
    }
}
