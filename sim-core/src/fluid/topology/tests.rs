use super::faces::*;
use super::rows::*;
use super::*;
use crate::fluid::grid::FluidGrid;
use crate::fluid::sample::Layout;
use crate::fluid::CellLabel;

fn fresh(grid: &FluidGrid, layout: &Layout, c: usize) -> FaceSet {
    let mut set = FaceSet::default();
    set.rebuild(grid, layout, c);
    set
}

fn tracked(set: &FaceSet) -> Vec<u32> {
    let fixed = set.fixed.iter().map(|f| f[0]);
    let mut all: Vec<u32> = set.active.iter().copied().chain(fixed).collect();
    all.extend(set.ext1.iter().chain(&set.ext2));
    all.sort_unstable();
    all
}

/// One random relabelling of the kinds a moving wall makes: scattered cells, a whole x row or
/// a plane (a row emptying or filling entirely), a slab of the box's first or last rows (the
/// edges, where periodic axes wrap), or a wall advancing by one layer of cells.
fn relabel(grid: &mut FluidGrid, rng: &mut fastrand::Rng, labels: &[CellLabel]) {
    let dims = grid.dims();
    let l = labels[rng.usize(..labels.len())];
    let mut set = |cell: [usize; 3], l: CellLabel| grid.set_label(cell, l).unwrap();
    let edge = |rng: &mut fastrand::Rng, n: usize| if rng.bool() { 0 } else { n - 1 };
    match rng.u8(..6) {
        0 => {
            for _ in 0..rng.usize(1..12) {
                let cell = dims.map(|n| rng.usize(..n));
                set(cell, labels[rng.usize(..labels.len())]);
            }
        }
        1 => {
            let (j, k) = (rng.usize(..dims[1]), rng.usize(..dims[2]));
            for i in 0..dims[0] {
                set([i, j, k], l);
            }
        }
        2 | 3 => {
            // A plane normal to a random axis, on the box's edge half of the time.
            let a = rng.usize(..3);
            let at = if rng.bool() {
                edge(rng, dims[a])
            } else {
                rng.usize(..dims[a])
            };
            for n in 0..dims.iter().product::<usize>() {
                let cell = grid_coords(dims, n);
                if cell[a] == at {
                    set(cell, l);
                }
            }
        }
        4 => {
            // A wall advancing along y or z: each column's first non-wall cell becomes wall.
            let a = 1 + rng.usize(..2);
            let wall = [CellLabel::Solid, CellLabel::Velocity][rng.usize(..2)];
            let (b, nb) = if a == 1 { (2, dims[2]) } else { (1, dims[1]) };
            for i in 0..dims[0] {
                for t in 0..nb {
                    let mut cell = [i, 0, 0];
                    cell[b] = t;
                    let first_open = (0..dims[a]).find(|&x| {
                        cell[a] = x;
                        !grid.label(cell).unwrap().is_wall()
                    });
                    if let Some(x) = first_open {
                        cell[a] = x;
                        grid.set_label(cell, wall).unwrap();
                    }
                }
            }
        }
        _ => {
            // A block of fluid opening somewhere (the fluid region appearing).
            let lo = dims.map(|n| rng.usize(..n));
            let hi = [0, 1, 2].map(|a| (lo[a] + rng.usize(1..4)).min(dims[a]));
            for k in lo[2]..hi[2] {
                for j in lo[1]..hi[1] {
                    for i in lo[0]..hi[0] {
                        set([i, j, k], CellLabel::Fluid);
                    }
                }
            }
        }
    }
}

fn grid_coords(dims: [usize; 3], n: usize) -> [usize; 3] {
    [
        n % dims[0],
        (n / dims[0]) % dims[1],
        n / (dims[0] * dims[1]),
    ]
}

/// The update recomputes only the faces near the changed cells and carries the others
/// over: after every relabelling of a random sequence (including rows emptying and
/// filling, walls advancing and the box's edges) it must equal a build from scratch, field
/// by field, and report as dropped exactly the faces no longer tracked.
#[test]
fn an_update_after_relabelling_equals_a_fresh_build() {
    let labels = [
        CellLabel::Fluid,
        CellLabel::Solid,
        CellLabel::Velocity,
        CellLabel::Outflow,
    ];
    // Small boxes (most faces on an end of the array) and a larger one (interior faces).
    for (seed, (periodic, dims)) in [
        ([false; 3], [9, 7, 6]),
        ([true, false, true], [9, 7, 6]),
        ([false, true, false], [9, 7, 6]),
        ([false; 3], [16, 13, 12]),
        ([true, true, false], [14, 12, 11]),
        ([false, true, true], [11, 9, 10]),
        ([false; 3], [5, 4, 3]),
        ([false, true, false], [7, 1, 6]),
        ([false, true, false], [7, 2, 6]),
        ([true, false, true], [1, 5, 2]),
    ]
    .into_iter()
    .enumerate()
    {
        let mut rng = fastrand::Rng::with_seed(11 + seed as u64);
        let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
        // Start mostly solid: a sparse fluid region, as in the uterine scene.
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let l = if rng.f32() < 0.6 {
                        CellLabel::Solid
                    } else {
                        labels[rng.usize(..labels.len())]
                    };
                    grid.set_label([i, j, k], l).unwrap();
                }
            }
        }
        let layout = Layout::new(dims, periodic);
        let mut rows = Vec::new();
        let mut diff = LabelDiff::default();
        let mut sets: [FaceSet; 3] = Default::default();
        for step in 0..120 {
            if step > 0 {
                relabel(&mut grid, &mut rng, &labels);
            }
            let diffed = diff.update(grid.labels(), dims[0]);
            assert_eq!(diffed, step > 0);
            update_open_row_ranges(&grid, diffed.then(|| diff.rows()), &mut rows);
            let changed = diffed.then(|| diff.cells());
            let mut want_rows = Vec::new();
            open_row_ranges(&grid, &mut want_rows);
            assert_eq!(rows, want_rows, "open row ranges, step {step}");
            for (c, set) in sets.iter_mut().enumerate() {
                let before = tracked(set);
                set.update(&grid, &layout, c, changed);
                let want = fresh(&grid, &layout, c);
                let at = format!("component {c}, {periodic:?} {dims:?}, step {step}");
                assert_eq!(set.class, want.class, "class, {at}");
                assert_eq!(set.compact, want.compact, "compact, {at}");
                assert_eq!(set.active, want.active, "active, {at}");
                assert_eq!(set.active_cells, want.active_cells, "{at}");
                assert_eq!(set.fixed, want.fixed, "fixed, {at}");
                assert_eq!(set.fixed_moving, want.fixed_moving, "{at}");
                assert_eq!(set.stencil, want.stencil, "stencil, {at}");
                assert_eq!(set.diag, want.diag, "diag, {at}");
                assert_eq!(set.nbr, want.nbr, "nbr, {at}");
                assert_eq!(set.self_diag, want.self_diag, "{at}");
                assert_eq!(set.runs, want.runs, "runs, {at}");
                assert_eq!(set.regular, want.regular, "{at}");
                assert_eq!(
                    format!("{:?}", set.irregular),
                    format!("{:?}", want.irregular),
                    "irregular, {at}"
                );
                assert_eq!(set.ghosts, want.ghosts, "ghosts, {at}");
                assert_eq!(set.ext1, want.ext1, "ext1, {at}");
                assert_eq!(set.ext2, want.ext2, "ext2, {at}");
                assert_eq!(set.ext_pos, want.ext_pos, "layer positions, {at}");
                assert_eq!(set.ext_start, want.ext_start, "{at}");
                assert_eq!(set.ext_src, want.ext_src, "ext sources, {at}");
                for (a, b) in set
                    .ext_groups
                    .iter()
                    .flatten()
                    .zip(want.ext_groups.iter().flatten())
                {
                    assert_eq!(a, b, "{at}");
                }
                let now = tracked(set);
                let mut dropped = set.dropped.clone();
                dropped.sort_unstable();
                let expected: Vec<u32> = before
                    .into_iter()
                    .filter(|f| now.binary_search(f).is_err())
                    .collect();
                assert_eq!(dropped, expected, "dropped faces, {at}");
            }
        }
    }
}

#[test]
fn neighbour_index_and_coords_step_one_face_and_wrap_on_periodic_axes() {
    for periodic in [[false; 3], [true, true, true], [true, false, true]] {
        let layout = Layout::new([4, 3, 5], periodic);
        for c in 0..3 {
            for idx in 0..layout.face_count(c) {
                let f = layout.face_coords(c, idx);
                for d in 0..3 {
                    let n = layout.fdims[c][d] as i64;
                    for dir in [-1i32, 1] {
                        let g = f[d] as i64 + dir as i64;
                        let want = if (0..n).contains(&g) || periodic[d] {
                            let mut h = f;
                            h[d] = g.rem_euclid(n) as usize;
                            Some(layout.face_index(c, h))
                        } else {
                            None
                        };
                        assert_eq!(neighbour_index(&layout, c, f, idx, d, dir), want);
                        if let Some(w) = want {
                            let g = neighbour_coords(&layout, c, f, d, dir);
                            assert_eq!(layout.face_index(c, g), w);
                        }
                    }
                }
            }
        }
    }
}

/// The scan a fresh build makes: every face of the array classified (the reference the
/// row-restricted classification must match).
#[test]
fn the_row_restricted_classification_matches_a_scan_of_every_face() {
    for periodic in [[false; 3], [true, true, true]] {
        let mut rng = fastrand::Rng::with_seed(3);
        let dims = [6, 5, 4];
        let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
        for n in 0..grid.cell_count() {
            let cell = grid.coords(n);
            let l = [
                CellLabel::Fluid,
                CellLabel::Solid,
                CellLabel::Outflow,
                CellLabel::Velocity,
            ][rng.usize(..4)];
            grid.set_label(cell, l).unwrap();
        }
        let layout = Layout::new(dims, periodic);
        for c in 0..3 {
            let set = fresh(&grid, &layout, c);
            for idx in 0..layout.face_count(c) {
                let (lo, up) = face_cells(&grid, c, layout.face_coords(c, idx));
                let (ll, _) = label_of(&grid, lo);
                let (ul, _) = label_of(&grid, up);
                let open = |l: CellLabel| matches!(l, CellLabel::Fluid | CellLabel::Outflow);
                let want_active = !ll.is_wall()
                    && !ul.is_wall()
                    && (ll == CellLabel::Fluid || ul == CellLabel::Fluid);
                let want_fixed = (ll.is_wall() || ul.is_wall()) && (open(ll) || open(ul));
                assert_eq!(set.class[idx] == ACTIVE, want_active, "face {idx} c {c}");
                assert_eq!(set.class[idx] == FIXED, want_fixed, "face {idx} c {c}");
                if let Ok(n) = set.active.binary_search(&(idx as u32)) {
                    let (_, li) = label_of(&grid, lo);
                    let (_, ui) = label_of(&grid, up);
                    assert_eq!(set.active_cells()[n], [li, ui], "face {idx} c {c}");
                }
            }
        }
    }
}

/// The stencils and extrapolation layers by the definitions, face by face over the whole
/// array (cells by [`face_cells`], neighbours by [`neighbour_index`] and
/// [`neighbour_coords`]): the reference for the rebuild's shortcuts (kept cells shifted to a
/// tangential neighbour, plain offsets off the array's ends, layers found from the inside).
#[test]
fn stencils_and_layers_match_their_definitions() {
    for (periodic, dims) in [
        ([false; 3], [12, 10, 9]),
        ([true, false, true], [10, 9, 8]),
        ([false, true, true], [9, 11, 10]),
    ] {
        let mut rng = fastrand::Rng::with_seed(17);
        let mut grid = FluidGrid::new(dims, 1e-3, [0.0; 3], periodic).unwrap();
        for n in 0..grid.cell_count() {
            let l = if rng.f32() < 0.3 {
                CellLabel::Fluid
            } else {
                [CellLabel::Solid, CellLabel::Velocity, CellLabel::Outflow][rng.usize(..3)]
            };
            grid.set_label(grid.coords(n), l).unwrap();
        }
        let layout = Layout::new(dims, periodic);
        for c in 0..3 {
            let set = fresh(&grid, &layout, c);
            let labels_of = |f: [usize; 3]| {
                let (lo, up) = face_cells(&grid, c, f);
                (label_of(&grid, lo), label_of(&grid, up))
            };
            let nf = layout.face_count(c);
            for (n, &idx) in set.active.iter().enumerate() {
                let idx = idx as usize;
                let f = layout.face_coords(c, idx);
                let (mut st, mut diag) = ([NONE; 6], 6.0f32);
                for (slot, entry_of_slot) in st.iter_mut().enumerate() {
                    let (d, dir) = (slot / 2, if slot % 2 == 0 { -1 } else { 1 });
                    let Some(gi) = neighbour_index(&layout, c, f, idx, d, dir) else {
                        diag += 1.0;
                        continue;
                    };
                    let cl = set.class[gi];
                    let entry = |cl| match cl {
                        ACTIVE => gi as u32,
                        _ => CONST_BIT | gi as u32,
                    };
                    if d == c {
                        match cl {
                            ACTIVE | FIXED => *entry_of_slot = entry(cl),
                            _ => diag -= 1.0,
                        }
                        continue;
                    }
                    let ((ll, _), (ul, _)) = labels_of(neighbour_coords(&layout, c, f, d, dir));
                    if ll.is_wall() && ul.is_wall() {
                        diag += 1.0;
                    } else if ll == CellLabel::Fluid || ul == CellLabel::Fluid {
                        *entry_of_slot = entry(cl);
                    } else {
                        diag -= 1.0;
                    }
                }
                assert_eq!(set.stencil[n], st, "stencil of face {idx}, c {c}");
                assert_eq!(set.diag[n], diag, "diagonal of face {idx}, c {c}");
            }
            // Layers: faces neither active nor fixed beside the layer inside, in index order,
            // with their sources in slot order.
            let nbrs = |idx: usize| {
                let f = layout.face_coords(c, idx);
                (0..6).filter_map(move |slot| {
                    let dir = if slot % 2 == 0 { -1 } else { 1 };
                    neighbour_index(&layout, c, f, idx, slot / 2, dir)
                })
            };
            let tracked = |i: usize| matches!(set.class[i], ACTIVE | FIXED);
            let ext1: Vec<u32> = (0..nf)
                .filter(|&i| !tracked(i) && nbrs(i).any(|g| set.class[g] == ACTIVE))
                .map(|i| i as u32)
                .collect();
            let in1 = |i: usize| ext1.binary_search(&(i as u32)).is_ok();
            let ext2: Vec<u32> = (0..nf)
                .filter(|&i| !tracked(i) && !in1(i) && nbrs(i).any(in1))
                .map(|i| i as u32)
                .collect();
            assert_eq!(set.ext1, ext1, "ext1, c {c}, {periodic:?}");
            assert_eq!(set.ext2, ext2, "ext2, c {c}, {periodic:?}");
            let mut src = Vec::new();
            let mut start = vec![0u32];
            for &i in &ext1 {
                src.extend(nbrs(i as usize).filter(|&g| tracked(g)).map(|g| g as u32));
                start.push(src.len() as u32);
            }
            for &i in &ext2 {
                src.extend(nbrs(i as usize).filter(|&g| in1(g)).map(|g| g as u32));
                start.push(src.len() as u32);
            }
            assert_eq!(set.ext_src, src, "sources, c {c}, {periodic:?}");
            assert_eq!(set.ext_start, start, "source starts, c {c}, {periodic:?}");
        }
    }
}
