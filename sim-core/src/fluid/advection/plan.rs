//! The advection's work list: the active faces of the three components as runs of consecutive
//! faces along x in one concatenated compact array, cut into blocks (the tasks of a pass).

use super::super::sample::Layout;

/// Faces per task (a block of the concatenated active faces).
pub(crate) const BLOCK: usize = 2048;

/// Consecutive active faces of one component along x.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Run {
    /// Component.
    pub c: u32,
    /// Face coordinates of the first face.
    pub f: [u32; 3],
    /// Full index of the first face.
    pub full: u32,
    /// Position of the first face in the concatenated compact array.
    pub compact: u32,
    /// Number of faces.
    pub len: u32,
}

/// The runs of all three components, cut so none crosses a block boundary.
#[derive(Default, Debug)]
pub(crate) struct Plan {
    pub runs: Vec<Run>,
    /// First run of each block, and the number of runs at the end.
    pub block_runs: Vec<u32>,
    /// Start of each component in the concatenated compact array, and the total.
    pub offset: [usize; 4],
}

impl Plan {
    /// Rebuilds the runs from each component's runs of active faces (`[full, compact, len]`,
    /// ascending, each a whole run of consecutive faces of one x row: [`FaceSet::runs`]) and
    /// its number of active faces.
    ///
    /// [`FaceSet::runs`]: super::topology::FaceSet::runs
    pub fn rebuild(&mut self, layout: &Layout, runs: [&[[u32; 3]]; 3], counts: [usize; 3]) {
        self.runs.clear();
        self.block_runs.clear();
        let mut pos = 0usize;
        for (c, list) in runs.iter().enumerate() {
            self.offset[c] = pos;
            for &[first, n, len] in list.iter() {
                let (start, len) = (pos + n as usize, len as usize);
                // Cut at block boundaries.
                let mut done = 0usize;
                while done < len {
                    let at = start + done;
                    let room = BLOCK - at % BLOCK;
                    let take = room.min(len - done);
                    let f = layout.face_coords(c, (first as usize) + done);
                    self.runs.push(Run {
                        c: c as u32,
                        f: f.map(|v| v as u32),
                        full: first + done as u32,
                        compact: at as u32,
                        len: take as u32,
                    });
                    done += take;
                }
            }
            pos += counts[c];
        }
        self.offset[3] = pos;
        let blocks = pos.div_ceil(BLOCK);
        let mut r = 0usize;
        for b in 0..blocks {
            while r < self.runs.len() && (self.runs[r].compact as usize) < b * BLOCK {
                r += 1;
            }
            self.block_runs.push(r as u32);
        }
        self.block_runs.push(self.runs.len() as u32);
    }
}

/// The block at which `len` compact faces split into two halves on two threads, if `parallel` and
/// there are at least two blocks.
pub(super) fn split_block(len: usize, parallel: bool) -> Option<usize> {
    let blocks = len.div_ceil(BLOCK);
    (parallel && blocks >= 2).then_some(blocks / 2)
}

/// Copies the compact values of every run back into the full face arrays.
pub(crate) fn scatter(plan: &Plan, compact: &[f32], u: &mut [Vec<f32>; 3]) {
    for run in &plan.runs {
        let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
        u[run.c as usize][f..f + len].copy_from_slice(&compact[n..n + len]);
    }
}

/// Gathers the active faces of the full arrays into the concatenated compact order.
pub(crate) fn gather(plan: &Plan, u: [&[f32]; 3], compact: &mut [f32]) {
    for run in &plan.runs {
        let (f, n, len) = (run.full as usize, run.compact as usize, run.len as usize);
        compact[n..n + len].copy_from_slice(&u[run.c as usize][f..f + len]);
    }
}
