//! Who trains: one process, or W ranks over MPI, and how they agree.
//!
//! MPI matches collective operations by their order alone, so a rank that fails between two
//! collectives (a corrupt file, an error in its forward pass) while the others go on would
//! pair its next collective with one of theirs and the job would compute garbage or hang.
//! Therefore every small collective here is one [`Ranks::exchange`]: an all-reduce (sum) of a
//! fixed-size block that carries a *tag* saying what the rank is doing. When the tags of a
//! block disagree, every rank learns at that same block that some rank has left the common
//! path, and all of them go through [`Ranks::resolve`] together: the lowest failing rank's
//! message is broadcast and every rank stops with it. The only other collective, the
//! gradients' all-reduce, is reached only after a block in which every rank said its step
//! succeeded.

use anyhow::{Result, anyhow};

/// Values of one block after its two tag slots.
pub const PAYLOAD: usize = 30;
const BLOCK: usize = PAYLOAD + 2;

/// What a rank is doing at a block: every rank must be at the same one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Tag {
    /// Agreeing that a piece of work succeeded everywhere.
    Agree = 1,
    /// A denominator of a loss over the global batch (`share`).
    Denominator = 2,
    /// The end of a step: its loss terms and flags.
    Step = 3,
    /// Comparing a value with rank 0's.
    Compare = 4,
    /// This rank has failed.
    Failed = 5,
}

/// A block whose tags disagreed: some rank failed; [`Ranks::resolve`] tells which and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Diverged;

/// The ranks of a run.
pub struct Ranks {
    rank: usize,
    size: usize,
    local_rank: usize,
    local_size: usize,
    #[cfg(feature = "mpi")]
    mpi: Option<mpi_world::World>,
}

impl std::fmt::Debug for Ranks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "rank {} of {}", self.rank, self.size)
    }
}

impl Ranks {
    /// One process, which never communicates.
    pub fn single() -> Ranks {
        Ranks {
            rank: 0,
            size: 1,
            local_rank: 0,
            local_size: 1,
            #[cfg(feature = "mpi")]
            mpi: None,
        }
    }

    /// The ranks this process was started among: MPI's world when a launcher started it
    /// (`mpirun`, `srun --mpi=pmix`; a build with the `mpi` feature), else one process.
    /// Refuses a Slurm step of several tasks that MPI does not join (`srun` without
    /// `--mpi=pmix`): its tasks would each train alone into the same folder.
    pub fn from_environment() -> Result<Ranks> {
        let launched = launcher();
        #[cfg(feature = "mpi")]
        if let Some(how) = launched {
            let world = mpi_world::World::init().map_err(|e| anyhow!("{e} (started by {how})"))?;
            let ranks = Ranks {
                rank: world.rank,
                size: world.size,
                local_rank: world.local_rank,
                local_size: world.local_size,
                mpi: (world.size > 1).then_some(world),
            };
            if ranks.size > 1 {
                install_abort_on_panic(ranks.rank, ranks.size);
            }
            return Ok(ranks);
        }
        #[cfg(not(feature = "mpi"))]
        if let Some(how) = launched
            && world_size_of_launcher() > 1
        {
            anyhow::bail!(
                "started by {how} as one of {} processes, but this trainer was built without MPI: \
                 build it with `--features mpi` (needs libopenmpi-dev), or run one process",
                world_size_of_launcher()
            );
        }
        // Under a launcher the world is what it says (mpirun inside a Slurm allocation starts
        // its own daemons through srun, whose task count is then the node count).
        if launched.is_none() {
            check_slurm_tasks()?;
        }
        Ok(Ranks::single())
    }

    /// This rank, 0 ≤ rank < size.
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// How many ranks train, W.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Whether this rank writes the run's files (rank 0).
    pub fn is_root(&self) -> bool {
        self.rank == 0
    }

    /// This rank among those on its machine (what chooses its GPU).
    pub fn local_rank(&self) -> usize {
        self.local_rank
    }

    /// Ranks on this machine.
    pub fn local_size(&self) -> usize {
        self.local_size
    }

    /// Sums `block` over the ranks (one all-reduce). `values.len()` ≤ [`PAYLOAD`]. Err when
    /// the ranks' tags disagree: call [`Ranks::resolve`] next, on every rank.
    pub fn exchange(&self, tag: Tag, values: &[f64]) -> Result<Vec<f64>, Diverged> {
        assert!(values.len() <= PAYLOAD, "a block holds {PAYLOAD} values");
        if self.size == 1 {
            return Ok(values.to_vec());
        }
        let t = tag as u8 as f64;
        let mut block = [0.0f64; BLOCK];
        block[0] = t;
        block[1] = t * t;
        block[2..2 + values.len()].copy_from_slice(values);
        let summed = self.sum_f64_block(&block);
        // Tags are small integers, so these sums are exact: all tags equal t iff the sum is
        // W·t and the sum of squares W·t² (otherwise their variance is positive).
        let w = self.size as f64;
        if summed[0] != w * t || summed[1] != w * t * t {
            return Err(Diverged);
        }
        Ok(summed[2..2 + values.len()].to_vec())
    }

    /// Whether `local` succeeded on every rank. On every rank the same: `Ok` where all
    /// succeeded, else the lowest failing rank's error (naming that rank).
    pub fn agree<T>(&self, local: Result<T>) -> Result<T> {
        if self.size == 1 {
            return local;
        }
        match local {
            Ok(v) => match self.exchange(Tag::Agree, &[]) {
                Ok(_) => Ok(v),
                Err(Diverged) => Err(self.resolve(None)),
            },
            Err(e) => Err(self.fail(e)),
        }
    }

    /// This rank failed: tells the others at their next block and returns the error all of
    /// them return.
    pub fn fail(&self, error: anyhow::Error) -> anyhow::Error {
        if self.size == 1 {
            return error;
        }
        // The block only marks the divergence: whatever the others were doing, this block
        // and theirs are the same collective, and its tags disagree (or are all Failed).
        let _ = self.exchange(Tag::Failed, &[]);
        self.resolve(Some(error))
    }

    /// Called by every rank after a block diverged (or after [`Ranks::fail`]): which ranks
    /// failed, and the lowest one's message, the same on every rank.
    pub fn resolve(&self, mine: Option<anyhow::Error>) -> anyhow::Error {
        if self.size == 1 {
            return mine.unwrap_or_else(|| anyhow!("failed"));
        }
        // Who failed: one flag per rank, summed (exact).
        let mut flags = vec![0.0f64; self.size];
        flags[self.rank] = if mine.is_some() { 1.0 } else { 0.0 };
        let failed: Vec<usize> = self
            .sum_f64(&flags)
            .iter()
            .enumerate()
            .filter(|(_, f)| **f > 0.0)
            .map(|(r, _)| r)
            .collect();
        let Some(&first) = failed.first() else {
            return anyhow!(
                "the ranks lost step with each other and no rank reported an error: they do not run the same \
                 computation (a different build, or an environment variable that differs between ranks and changes \
                 the run, such as VGG16_WEIGHTS); the last checkpoint is intact"
            );
        };
        let text = mine.map(|e| format!("{e:#}")).unwrap_or_default();
        let text = self.broadcast_text(first, &text);
        let others: Vec<String> = failed[1..].iter().map(|r| r.to_string()).collect();
        let also = if others.is_empty() {
            String::new()
        } else {
            format!(" (ranks {} failed too)", others.join(", "))
        };
        anyhow!("rank {first} of {}: {text}{also}", self.size)
    }

    /// Refuses to go on unless `value` (a checksum) is rank 0's on every rank; `what` names
    /// it in the error of the first rank that differs, e.g. "the manifest ../m.toml".
    pub fn same_as_root(&self, what: &str, value: &[u8; 32]) -> Result<()> {
        if self.size == 1 {
            return Ok(());
        }
        // Rank 0's first 16 bytes, as 8 exact u16 values; the other ranks add zeros.
        let chunks: Vec<f64> = value[..16]
            .chunks(2)
            .map(|c| {
                if self.is_root() {
                    u16::from_le_bytes([c[0], c[1]]) as f64
                } else {
                    0.0
                }
            })
            .collect();
        let root = match self.exchange(Tag::Compare, &chunks) {
            Ok(v) => v,
            Err(Diverged) => return Err(self.resolve(None)),
        };
        let mine: Vec<f64> = value[..16]
            .chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]) as f64)
            .collect();
        if mine == root {
            self.agree(Ok(()))
        } else {
            let hex: String = value[..8].iter().map(|b| format!("{b:02x}")).collect();
            self.agree(Err(anyhow!("{what} differs from rank 0's (blake3 {hex}…)")))
        }
    }

    /// The sum over the ranks of `values`, element by element.
    pub fn sum_f64(&self, values: &[f64]) -> Vec<f64> {
        self.sum_f64_block(values)
    }

    /// Sums `values` over the ranks in place (the gradients: one all-reduce).
    pub fn sum_f32_in_place(&self, values: &mut [f32]) {
        #[cfg(feature = "mpi")]
        if let Some(w) = &self.mpi {
            w.sum_f32(values);
        }
        let _ = values;
    }

    fn sum_f64_block(&self, values: &[f64]) -> Vec<f64> {
        #[cfg(feature = "mpi")]
        if let Some(w) = &self.mpi {
            return w.sum_f64(values);
        }
        values.to_vec()
    }

    fn broadcast_text(&self, root: usize, text: &str) -> String {
        #[cfg(feature = "mpi")]
        if let Some(w) = &self.mpi {
            return w.broadcast_text(root, text);
        }
        let _ = root;
        text.to_owned()
    }
}

/// Sizes Rayon's global pool (Burn's CPU backend computes in it) for this rank: the
/// `MATEDIT_THREADS` variable, else the machine's cores shared by the ranks on it. One
/// process without the variable keeps Rayon's default. Returns the thread count.
pub fn set_threads(ranks: &Ranks) -> Result<usize> {
    let given = std::env::var("MATEDIT_THREADS").ok();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let Some(n) = thread_count(given.as_deref(), cores, ranks.local_size())? else {
        return Ok(rayon::current_num_threads());
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| anyhow!("cannot size the compute threads to {n}: {e}"))?;
    Ok(n)
}

/// The threads of a rank: `given` (`MATEDIT_THREADS`, 1–4096), else `cores` shared by the
/// `local` ranks of its machine (at least 1); `None` for one process left to Rayon's default.
fn thread_count(given: Option<&str>, cores: usize, local: usize) -> Result<Option<usize>> {
    match given {
        Some(v) => v
            .trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=4096).contains(n))
            .map(Some)
            .ok_or_else(|| anyhow!("MATEDIT_THREADS = {v:?}: expected a thread count from 1 to 4096")),
        None if local > 1 => Ok(Some((cores / local).max(1))),
        None => Ok(None),
    }
}

/// How this process was started when a launcher started it: the variables OpenMPI's
/// `mpirun`, PMIx (`srun --mpi=pmix`) and MPICH's Hydra set in every rank.
fn launcher() -> Option<&'static str> {
    [
        ("OMPI_COMM_WORLD_SIZE", "mpirun (OpenMPI)"),
        ("PMIX_RANK", "a PMIx launcher (srun --mpi=pmix)"),
        ("PMI_SIZE", "a PMI launcher (MPICH's mpiexec)"),
    ]
    .into_iter()
    .find(|(var, _)| std::env::var_os(var).is_some())
    .map(|(_, how)| how)
}

#[cfg(not(feature = "mpi"))]
fn world_size_of_launcher() -> usize {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "SLURM_STEP_NUM_TASKS"]
        .into_iter()
        .find_map(|v| std::env::var(v).ok()?.parse().ok())
        .unwrap_or(1)
}

/// A Slurm step of several tasks that no MPI launcher joined (`srun -n N` without
/// `--mpi=pmix`) would train N copies of the run into one folder.
fn check_slurm_tasks() -> Result<()> {
    let tasks: usize = std::env::var("SLURM_STEP_NUM_TASKS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    if tasks > 1 {
        anyhow::bail!(
            "srun started {tasks} tasks but no MPI launcher joined them: launch with `srun --mpi=pmix` and a trainer \
             built with `--features mpi` (scripts/train_slurm.sh does both)"
        );
    }
    Ok(())
}

/// A panic on one rank must end the job: unwinding would finalise MPI while the other ranks
/// wait in a collective, and the job would hang. After the usual message the process aborts,
/// which `mpirun` and `srun --kill-on-bad-exit` turn into the end of every rank.
#[cfg(feature = "mpi")]
fn install_abort_on_panic(rank: usize, size: usize) {
    let report = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        report(info);
        eprintln!(
            "rank {rank} of {size} panicked: ending the job (the last checkpoint is intact; resume with --resume)"
        );
        std::process::abort();
    }));
}

#[cfg(feature = "mpi")]
mod mpi_world {
    //! The MPI calls, in one place.
    use mpi::collective::SystemOperation;
    use mpi::environment::Universe;
    use mpi::topology::{Communicator, SimpleCommunicator};
    use mpi::traits::*;

    pub struct World {
        // Dropped last: finalises MPI.
        _universe: Universe,
        world: SimpleCommunicator,
        pub rank: usize,
        pub size: usize,
        pub local_rank: usize,
        pub local_size: usize,
    }

    impl World {
        pub fn init() -> Result<World, String> {
            // Burn's CPU backend runs its own threads; only this (the main) thread calls MPI.
            let (universe, _) = mpi::initialize_with_threading(mpi::Threading::Funneled)
                .ok_or("MPI was initialised twice in this process")?;
            let world = universe.world();
            let local = world.split_shared(world.rank());
            Ok(World {
                rank: world.rank() as usize,
                size: world.size() as usize,
                local_rank: local.rank() as usize,
                local_size: local.size() as usize,
                world,
                _universe: universe,
            })
        }

        pub fn sum_f64(&self, values: &[f64]) -> Vec<f64> {
            let mut out = vec![0.0; values.len()];
            self.world.all_reduce_into(values, &mut out[..], SystemOperation::sum());
            out
        }

        pub fn sum_f32(&self, values: &mut [f32]) {
            let send = values.to_vec();
            self.world.all_reduce_into(&send[..], values, SystemOperation::sum());
        }

        pub fn broadcast_text(&self, root: usize, text: &str) -> String {
            let process = self.world.process_at_rank(root as i32);
            let mut len = text.len() as u64;
            process.broadcast_into(&mut len);
            let mut bytes = if self.rank == root {
                text.as_bytes().to_vec()
            } else {
                vec![0u8; len as usize]
            };
            process.broadcast_into(&mut bytes[..]);
            String::from_utf8_lossy(&bytes).into_owned()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_counts_over_the_whole_range_and_bad_values() {
        assert_eq!(
            thread_count(None, 16, 1).ok(),
            Some(None),
            "one process keeps Rayon's default"
        );
        assert_eq!(thread_count(None, 16, 4).ok(), Some(Some(4)));
        assert_eq!(
            thread_count(None, 2, 4).ok(),
            Some(Some(1)),
            "oversubscribed: at least one"
        );
        assert_eq!(thread_count(None, 1, usize::MAX).ok(), Some(Some(1)));
        for (v, n) in [("1", 1), ("4096", 4096), (" 8 ", 8)] {
            assert_eq!(thread_count(Some(v), 2, 2).ok(), Some(Some(n)), "{v:?}");
        }
        for v in ["0", "4097", "-1", "", "two", "1e3", "18446744073709551616"] {
            let e = thread_count(Some(v), 2, 2).expect_err(v).to_string();
            assert!(e.contains("MATEDIT_THREADS") && e.contains("1 to 4096"), "{v:?}: {e}");
        }
    }

    #[test]
    fn one_process_agrees_with_itself_and_passes_errors_through() {
        let r = Ranks::single();
        assert_eq!((r.rank(), r.size(), r.is_root()), (0, 1, true));
        assert_eq!(r.exchange(Tag::Step, &[1.5, -2.0]), Ok(vec![1.5, -2.0]));
        assert_eq!(r.agree(Ok(7)).ok(), Some(7));
        let e = r.agree::<()>(Err(anyhow!("cannot open x"))).unwrap_err();
        assert_eq!(e.to_string(), "cannot open x");
        assert!(r.same_as_root("the manifest", &[3; 32]).is_ok());
        let mut g = vec![1.0f32, 2.0];
        r.sum_f32_in_place(&mut g);
        assert_eq!(g, [1.0, 2.0]);
    }
}
