//! The sweep over one task's particles: eight at a time in the lanes of AVX2 vectors
//! ([`block8`]) where the CPU has AVX2 and FMA, the rest of those that start in fluid cells in
//! groups of four whose common case (one substep into a fluid cell) runs side by side, then the
//! others one at a time; every path moves a particle bit for bit as the one-at-a-time path.

#[cfg(target_arch = "x86_64")]
use super::block8;
use super::kernel::{ClassSums, Kernel, Resume, Task, GROUP, KEEP};

/// Moves the particles of `task` with `k`; adds the clarity's cone weights of those that stay
/// to `sums` and returns how many left (their fate is not KEEP).
pub(super) fn sweep(k: &Kernel<'_>, task: Task<'_>, sums: &mut ClassSums) -> usize {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        return unsafe { sweep_avx2(k, task, sums) };
    }
    sweep_portable::<false>(k, task, sums)
}

/// [`sweep_portable`] compiled for AVX2 and FMA (the fluid stages' SIMD style: the same
/// portable code, a second time with the wider instruction set).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn sweep_avx2(k: &Kernel<'_>, task: Task<'_>, sums: &mut ClassSums) -> usize {
    // The FMA sampler (`Sampler::sample`): only instantiated here, where the CPU has both.
    sweep_portable::<true>(k, task, sums)
}

/// Eight at a time in the lanes of AVX2 vectors ([`block8`], with `FMA`), the rest of the
/// particles whose start needs no check in groups of four, then the others one at a time.
#[inline(always)]
fn sweep_portable<const FMA: bool>(k: &Kernel<'_>, task: Task<'_>, sums: &mut ClassSums) -> usize {
    let Task {
        offset,
        pos,
        slip,
        class,
        fate,
    } = task;
    let mut left = 0;
    let n = pos.len().min(slip.len()).min(class.len()).min(fate.len());
    // Groups of GROUP particles whose starts need no check: the common case (one substep
    // into a fluid cell) for all of them at once, so the independent samples overlap; the
    // others one at a time.
    let grouped = if offset + n <= k.check_from {
        n
    } else {
        k.check_from.saturating_sub(offset).min(n)
    } / GROUP
        * GROUP;
    let (pos, pos_rest) = pos[..n].split_at_mut(grouped);
    let (slip, slip_rest) = slip[..n].split_at_mut(grouped);
    let (class, class_rest) = class[..n].split_at(grouped);
    let (fate, fate_rest) = fate[..n].split_at_mut(grouped);
    // Particles of the groups that need more substeps (or met a wall): collected until there
    // are GROUP of them, whose substeps then run side by side (their samples overlap too).
    let mut waiting = [Resume::default(); GROUP];
    let mut count = 0;
    // Eight at a time, each particle in a lane of its own (`block8`), where it can; the rest
    // (fewer than eight) in groups of four.
    #[cfg(target_arch = "x86_64")]
    let from = if FMA && k.blocks() {
        // SAFETY: `FMA` only in `sweep_avx2` (the CPU has AVX2 and FMA).
        let (l, moved) = unsafe { block8::run(k, grouped, pos, slip, class, fate, sums) };
        left += l;
        moved
    } else {
        0
    };
    #[cfg(not(target_arch = "x86_64"))]
    let from = 0;
    for g in (from..grouped).step_by(GROUP) {
        let p: Result<&mut [[f32; 3]; GROUP], _> = (&mut pos[g..g + GROUP]).try_into();
        let w: Result<&mut [[f32; 3]; GROUP], _> = (&mut slip[g..g + GROUP]).try_into();
        let c: Result<&[u8; GROUP], _> = class[g..g + GROUP].try_into();
        let (Ok(p), Ok(w), Ok(c)) = (p, w, c) else {
            continue;
        };
        let more = k.advance_group::<FMA>(&mut *p, w, c);
        let ends = *p;
        for l in 0..GROUP {
            match more[l] {
                None => {
                    fate[g + l] = KEEP;
                    left += k.tally(KEEP, c[l], ends[l], sums);
                }
                Some(r) => {
                    waiting[count] = Resume { at: g + l, ..r };
                    count += 1;
                    if count == GROUP {
                        left += k.resume::<FMA>(&waiting, pos, class, fate, sums);
                        count = 0;
                    }
                }
            }
        }
    }
    left += k.resume::<FMA>(&waiting[..count], pos, class, fate, sums);
    for (m, (((p, w), &c), f)) in pos_rest
        .iter_mut()
        .zip(slip_rest)
        .zip(class_rest)
        .zip(fate_rest)
        .enumerate()
    {
        let check = offset + grouped + m >= k.check_from;
        *f = k.advance_one::<FMA>(p, w, c, check);
        left += k.tally(*f, c, *p, sums);
    }
    left
}
