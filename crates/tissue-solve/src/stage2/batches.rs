//! Iterations in batches, on any device and in either stage: a device runs
//! several iterations per submission and reports what each measured; the
//! rule that stops the run is asked after every one of them, in order, and
//! a batch in which it held is replayed up to that iteration. So a device
//! that batches stops at the same iteration as one that does not.

/// A device's side of a batched run.
pub trait Batches {
    /// What one iteration measured (the step norms the rule reads).
    type Measure;
    /// The device's error.
    type Error;

    /// Runs up to `count` iterations (`done` ran before them) and returns,
    /// per iteration that ran, what it measured: fewer than `count` when
    /// the device cut the batch short. Keeps what [`Batches::replay`] needs.
    fn run(&mut self, done: usize, count: usize) -> Result<Vec<Self::Measure>, Self::Error>;

    /// Puts the state back where the last [`Batches::run`] started and runs
    /// its first `count` iterations again.
    fn replay(&mut self, count: usize) -> Result<(), Self::Error>;
}

/// Runs iterations in batches of at most `batch` until `stop` holds after
/// one (asked with the iterations done before it and its measure) or `max`
/// have run; returns the iterations run and whether `stop` held. The device
/// is left where `stop` held.
pub fn run_batched<B: Batches>(
    device: &mut B,
    max: usize,
    batch: usize,
    stop: impl FnMut(usize, &B::Measure) -> Result<bool, B::Error>,
) -> Result<(usize, bool), B::Error> {
    run_batched_from(device, max, batch, batch, stop)
}

/// [`run_batched`] with a first batch of `first` iterations, each batch
/// after it twice the last, up to `batch`: for a run that may stop after
/// a few iterations (a tracking frame's), which a full first batch would
/// run past and replay.
pub fn run_batched_from<B: Batches>(
    device: &mut B,
    max: usize,
    first: usize,
    batch: usize,
    mut stop: impl FnMut(usize, &B::Measure) -> Result<bool, B::Error>,
) -> Result<(usize, bool), B::Error> {
    let mut done = 0;
    let mut size = first.clamp(1, batch.max(1));
    while done < max {
        let measured = device.run(done, size.clamp(1, max - done))?;
        size = (2 * size).min(batch.max(1));
        if measured.is_empty() {
            // Nothing ran: the device cannot go on, and asking again would not change that.
            break;
        }
        for (k, measure) in measured.iter().enumerate() {
            let held = stop(done, measure)?;
            done += 1;
            if held {
                if k + 1 < measured.len() {
                    device.replay(k + 1)?;
                }
                return Ok((done, true));
            }
        }
    }
    Ok((done, false))
}

#[cfg(test)]
mod tests {
    use std::convert::Infallible;

    use super::*;

    /// A counter that halves a value every iteration, cut short after
    /// `halt_at` iterations of a batch when set.
    struct Halving {
        value: f32,
        start: f32,
        halt_at: Option<usize>,
        replays: Vec<usize>,
    }

    impl Batches for Halving {
        type Measure = f32;
        type Error = Infallible;

        fn run(&mut self, _: usize, count: usize) -> Result<Vec<f32>, Infallible> {
            self.start = self.value;
            let ran = self.halt_at.map_or(count, |h| h.min(count));
            Ok((0..ran)
                .map(|_| {
                    self.value *= 0.5;
                    self.value
                })
                .collect())
        }

        fn replay(&mut self, count: usize) -> Result<(), Infallible> {
            self.value = self.start * 0.5f32.powi(count as i32);
            self.replays.push(count);
            Ok(())
        }
    }

    fn halving(halt_at: Option<usize>) -> Halving {
        Halving {
            value: 1.0,
            start: 1.0,
            halt_at,
            replays: Vec::new(),
        }
    }

    #[test]
    fn a_batched_run_stops_where_a_one_at_a_time_run_stops() {
        let below = |_: usize, v: &f32| Ok::<_, Infallible>(*v < 1e-3);
        let mut single = halving(None);
        let Ok((iterations, stopped)) = run_batched(&mut single, 100, 1, below);
        assert!(stopped);
        assert_eq!(iterations, 10);
        for (batch, halt_at) in [(4, None), (8, None), (8, Some(3)), (64, None)] {
            let mut device = halving(halt_at);
            let Ok(run) = run_batched(&mut device, 100, batch, below);
            assert_eq!(run, (iterations, true), "batch {batch}, halt {halt_at:?}");
            assert_eq!(
                device.value, single.value,
                "batch {batch}, halt {halt_at:?}"
            );
        }
        // 10 = 8 + 2: the second batch of 8 is replayed to its second iteration.
        let mut device = halving(None);
        let Ok(_) = run_batched(&mut device, 100, 8, below);
        assert_eq!(device.replays, [2]);
        // Halted after 3 of each batch of 8: 3 + 3 + 3 + 1, replayed to 1.
        let mut device = halving(Some(3));
        let Ok(_) = run_batched(&mut device, 100, 8, below);
        assert_eq!(device.replays, [1]);
    }

    #[test]
    fn growing_batches_stop_where_full_ones_do_and_replay_less() {
        let below = |_: usize, v: &f32| Ok::<_, Infallible>(*v < 0.2);
        // Three iterations: batches of 2 and 4, the second replayed to one.
        let mut growing = halving(None);
        let Ok(run) = run_batched_from(&mut growing, 100, 2, 8, below);
        let mut full = halving(None);
        let Ok(full_run) = run_batched(&mut full, 100, 8, below);
        assert_eq!((run, growing.value), (full_run, full.value));
        assert_eq!(run, (3, true));
        assert_eq!((growing.replays, full.replays), (vec![1], vec![3]));
        // Longer runs: 2, 4, 8, 8, ... and the same stop as one at a time.
        let far = |_: usize, v: &f32| Ok::<_, Infallible>(*v < 1e-6);
        let mut single = halving(None);
        let Ok(expected) = run_batched(&mut single, 100, 1, far);
        // The tracker's first batch (docs/METHOD.md, "Frames and batches").
        assert_eq!(crate::stage2::FIRST_BATCH, 2);
        for (first, batch) in [(2, 8), (1, 8), (3, 4), (8, 8), (16, 8)] {
            let mut device = halving(None);
            let Ok(run) = run_batched_from(&mut device, 100, first, batch, far);
            assert_eq!(
                (run, device.value),
                (expected, single.value),
                "{first}, {batch}"
            );
        }
    }

    #[test]
    fn a_batched_run_stops_at_the_cap_without_replaying() {
        let never = |_: usize, _: &f32| Ok::<_, Infallible>(false);
        let mut device = halving(None);
        let Ok(run) = run_batched(&mut device, 13, 8, never);
        assert_eq!(run, (13, false));
        assert!(device.replays.is_empty());
        assert_eq!(device.value, 0.5f32.powi(13));
    }
}
