//! Output: a scan's points and runs of readings into the encoder, its frames into the
//! queue (a data frame only while a slot stays free for the trailer or abort), and the
//! frames that go ahead of a scan's.

use can_wire::{Distance, Frame, FrameSink, RunStop, ScanEncoder};

use super::{BridgeStats, Core, Phase};
use crate::pipeline::{Pipeline, Point};
use crate::queue::FrameQueue;

impl<const Q: usize> Core<Q> {
    /// The pipeline, the decimated-line buffer and the parts output points go through,
    /// borrowed apart.
    pub(super) fn split(
        &mut self,
    ) -> (
        &mut Pipeline,
        &mut [scip::Reading; super::BATCH_CELLS],
        Output<'_, Q>,
    ) {
        let Self {
            pipeline,
            decimated,
            encoder,
            queue,
            stats,
            overflow,
            filtered,
            ..
        } = self;
        let out = Output {
            encoder,
            queue,
            stats,
            overflow,
            filtered,
        };
        (pipeline, decimated, out)
    }

    /// A frame that goes ahead of queued scan frames (control answers, status). It never
    /// takes the last free slot while a scan is open (that one is the trailer's).
    pub(super) fn push_priority(&mut self, frame: Frame) {
        let reserve = if matches!(self.phase, Phase::Active(_)) {
            2
        } else {
            1
        };
        if self.queue.free() >= reserve && self.queue.push_front(frame).is_ok() {
            self.stats.frames = self.stats.frames.wrapping_add(1);
        } else {
            self.health.tx_overflows = self.health.tx_overflows.saturating_add(1);
        }
    }
}

/// A reading as the encoder takes it: its distance (range or error code, the run's rule
/// tells) and its second value as the intensity (0 for data sets without one, as the
/// decoder gives them), scaled to 16 bits (SPEC 4). A plain function, so that every run
/// of readings shares one compiled encoder loop per encoding.
fn reading_point(r: &scip::Reading) -> (u32, u16) {
    (r.distance, can_wire::IntensityEncoding::from_sensor(r.aux))
}

/// The parts of the engine a run of output points goes through.
pub(super) struct Output<'a, const Q: usize> {
    pub(super) encoder: &'a mut ScanEncoder,
    pub(super) queue: &'a mut FrameQueue<Q>,
    pub(super) stats: &'a mut BridgeStats,
    pub(super) overflow: &'a mut bool,
    pub(super) filtered: &'a mut bool,
}

impl<const Q: usize> Output<'_, Q> {
    /// One output point into the encoder; a full data frame into the queue, if two slots
    /// are free (one stays for the trailer or abort).
    pub(super) fn emit(&mut self, p: Point) {
        if *self.overflow {
            return;
        }
        let distance = match p.range_mm {
            Some(mm) => Distance::Mm(mm),
            None => Distance::Invalid,
        };
        let intensity = p
            .intensity
            .map_or(0, can_wire::IntensityEncoding::from_sensor);
        // A due data frame is built in a new back slot of the queue, not moved into it.
        let mut slots = DataSlots(self.queue);
        match push_point(self.encoder, distance, intensity, &mut slots) {
            Ok(run) => {
                self.stats.frames = self.stats.frames.wrapping_add(run.frames);
                if run.stop == Some(RunStop::NoSlot) {
                    *self.overflow = true;
                    self.stats.queue_overflows = self.stats.queue_overflows.wrapping_add(1);
                }
            }
            Err(_) => *self.filtered = true,
        }
    }

    /// Points the pipeline emitted, into the encoder in one run (what [`Output::emit`]
    /// does for each of them); returns how many it took, how many of those were no
    /// range and how many of those were ranges outside the rule's window. `checked`:
    /// the points are a filter's output, this many of them no range (with a
    /// fixed-width encoding `rule` is [`can_wire::RangeRule::at_least`] 1: distance 0
    /// no range, any other a range; [`ScanEncoder::push_checked_run`]). Inlined: its
    /// parts are the engine's fields, borrowed apart, not a struct built for a call.
    #[inline(always)]
    pub(super) fn encode_run(
        &mut self,
        points: &[scip::Reading],
        rule: can_wire::RangeRule,
        checked: Option<u32>,
    ) -> (usize, usize, usize) {
        let mut slots = DataSlots(self.queue);
        match push_readings(self.encoder, points, rule, checked, &mut slots) {
            Ok(run) => {
                self.stats.frames = self.stats.frames.wrapping_add(run.frames);
                match run.stop {
                    Some(RunStop::NoSlot) => {
                        *self.overflow = true;
                        self.stats.queue_overflows = self.stats.queue_overflows.wrapping_add(1);
                    }
                    Some(RunStop::TooManyPoints) => *self.filtered = true,
                    None => {}
                }
                let n = |x: u32| usize::try_from(x).unwrap_or(usize::MAX);
                (n(run.points), n(run.invalid), n(run.rejected))
            }
            Err(_) => {
                *self.filtered = true;
                (0, 0, 0)
            }
        }
    }
}

/// A run of readings into the encoder ([`ScanEncoder::push_run`], or with `checked`
/// [`ScanEncoder::push_checked_run`], by [`ScanEncoder::push_run_with`]), its frames
/// into `sink`. Not generic (the queue is a `dyn` sink, one call per frame) and never
/// inlined: the encoder's loops are compiled here, in this crate, at its optimisation
/// level (the boards build their own crates for size; a copy instantiated there for the
/// board's queue ran the DL loops about 40 % slower on the Cortex-M4).
#[inline(never)]
fn push_readings(
    encoder: &mut ScanEncoder,
    points: &[scip::Reading],
    rule: can_wire::RangeRule,
    checked: Option<u32>,
    sink: &mut dyn FrameSink,
) -> Result<can_wire::Run, can_wire::Error> {
    encoder.push_run_with(points, rule, checked, reading_point, sink)
}

/// One point into the encoder ([`ScanEncoder::push_point_to`]): like [`push_readings`],
/// compiled here once for every queue.
#[inline(never)]
fn push_point(
    encoder: &mut ScanEncoder,
    distance: Distance,
    intensity: u16,
    sink: &mut dyn FrameSink,
) -> Result<can_wire::Run, can_wire::Error> {
    encoder.push_point_to(distance, intensity, sink)
}

/// The queue as the encoder's [`FrameSink`]: a data frame gets a slot when two are free
/// (one stays for the scan's trailer or abort).
struct DataSlots<'a, const Q: usize>(&'a mut FrameQueue<Q>);

impl<const Q: usize> FrameSink for DataSlots<'_, Q> {
    #[inline]
    fn data_slot(&mut self) -> Option<&mut Frame> {
        data_slot(self.0)
    }

    /// Up to `n` back slots, all but one of those free (the one stays for the scan's
    /// trailer or abort), as many as lie before the ring's end.
    #[inline]
    fn data_slots(&mut self, n: usize) -> &mut [Frame] {
        let room = self.0.free().saturating_sub(1);
        self.0.push_back_slots(n.min(room))
    }
}

/// A back slot for a data frame, if two are free.
#[inline]
fn data_slot<const Q: usize>(queue: &mut FrameQueue<Q>) -> Option<&mut Frame> {
    if queue.free() >= 2 {
        queue.push_back_slot()
    } else {
        None
    }
}

/// A scan's header, trailer or abort frame at the back of the queue, if there is room,
/// counted. Copied once, from where the encoder left it into its slot (a frame is 76
/// bytes: moved by value, it was copied twice more). Out of line, so that the frame
/// and the slot are distinct to the compiler, which copies with `memcpy` (inlined, it
/// called `memmove`, 1.5 KB of M4 code nothing else needs).
#[inline(never)]
pub(super) fn push<const Q: usize>(queue: &mut FrameQueue<Q>, f: &Frame, stats: &mut BridgeStats) {
    if let Some(slot) = queue.push_back_slot() {
        slot.clone_from(f);
        stats.frames = stats.frames.wrapping_add(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The data slots the queue hands the encoder, for every fill of a 4-slot queue:
    /// all the free ones but one (the trailer's), none when one or none is free,
    /// counted by hand.
    #[test]
    fn data_slots_keep_one_free_slot() {
        // Free slots -> data slots for a request of 3 (at most 3, all but one free).
        for (free, want) in [(0, 0), (1, 0), (2, 1), (3, 2), (4, 3)] {
            let mut q = FrameQueue::<4>::new();
            for _ in 0..4 - free {
                q.push_back(Frame::default()).unwrap();
            }
            assert_eq!(q.free(), free);
            let got = DataSlots(&mut q).data_slots(3).len();
            assert_eq!(got, want, "{free} free");
            // The single-slot path agrees: a slot only when two are free.
            let mut q = FrameQueue::<4>::new();
            for _ in 0..4 - free {
                q.push_back(Frame::default()).unwrap();
            }
            assert_eq!(DataSlots(&mut q).data_slot().is_some(), free >= 2);
        }
    }
}
