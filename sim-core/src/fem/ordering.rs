//! Geometric nested dissection of the mesh vertices: a fill-reducing elimination order for the
//! sparse factorization. Recursively split the vertex set at the median of its longest extent,
//! order both halves first and the separator (vertices of one half adjacent to the other) last.
//! On 3D meshes this keeps the factor several times smaller than minimum-degree orderings.

/// Vertex elimination order (`order[k]` = the vertex eliminated k-th) for vertices at `positions`
/// with symmetric adjacency lists `adj_ptr`/`adj_idx` (CSR).
pub fn nested_dissection(positions: &[[f64; 3]], adj_ptr: &[usize], adj_idx: &[u32]) -> Vec<u32> {
    let n = positions.len();
    let mut order = Vec::with_capacity(n);
    let mut mark = vec![0u32; n];
    let mut stamp = 0u32;
    let all: Vec<u32> = (0..n as u32).collect();
    // Explicit stack instead of recursion: (vertices, separator to emit after both halves).
    enum Task {
        Split(Vec<u32>),
        Emit(Vec<u32>),
    }
    let mut stack = vec![Task::Split(all)];
    while let Some(task) = stack.pop() {
        match task {
            Task::Emit(v) => order.extend(v),
            Task::Split(mut v) => {
                if v.len() <= 96 {
                    order.extend(v);
                    continue;
                }
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for &i in &v {
                    for k in 0..3 {
                        lo[k] = lo[k].min(positions[i as usize][k]);
                        hi[k] = hi[k].max(positions[i as usize][k]);
                    }
                }
                let axis = (0..3)
                    .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
                    .unwrap_or(0);
                let mid = v.len() / 2;
                v.select_nth_unstable_by(mid, |&a, &b| {
                    positions[a as usize][axis].total_cmp(&positions[b as usize][axis])
                });
                let right = v.split_off(mid);
                let left = v;
                stamp += 1;
                for &i in &left {
                    mark[i as usize] = stamp;
                }
                let (sep, rest): (Vec<u32>, Vec<u32>) = right.into_iter().partition(|&i| {
                    adj_idx[adj_ptr[i as usize]..adj_ptr[i as usize + 1]]
                        .iter()
                        .any(|&j| mark[j as usize] == stamp)
                });
                // Stack order: the separator is emitted after both halves.
                stack.push(Task::Emit(sep));
                stack.push(Task::Split(rest));
                stack.push(Task::Split(left));
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_is_a_permutation_with_separators_last() {
        // A 12 x 12 x 12 grid graph.
        let m = 12usize;
        let id = |x: usize, y: usize, z: usize| (x + m * (y + m * z)) as u32;
        let mut pos = Vec::new();
        let mut ptr = vec![0];
        let mut idx = Vec::new();
        for z in 0..m {
            for y in 0..m {
                for x in 0..m {
                    pos.push([x as f64, y as f64, z as f64]);
                    for (dx, dy, dz) in [
                        (-1i64, 0i64, 0i64),
                        (1, 0, 0),
                        (0, -1, 0),
                        (0, 1, 0),
                        (0, 0, -1),
                        (0, 0, 1),
                    ] {
                        let (a, b, c) = (x as i64 + dx, y as i64 + dy, z as i64 + dz);
                        if (0..m as i64).contains(&a)
                            && (0..m as i64).contains(&b)
                            && (0..m as i64).contains(&c)
                        {
                            idx.push(id(a as usize, b as usize, c as usize));
                        }
                    }
                    ptr.push(idx.len());
                }
            }
        }
        let order = nested_dissection(&pos, &ptr, &idx);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..(m * m * m) as u32).collect::<Vec<_>>());
        // The top separator is a plane of m*m vertices, eliminated last.
        let last = &order[order.len() - m * m..];
        let plane = (0..3).any(|axis| {
            last.iter()
                .all(|&i| pos[i as usize][axis] == pos[last[0] as usize][axis])
        });
        assert!(plane, "the last block is not a grid plane");
    }
}
