//! Sequential point trees (Dachsbacher et al. 2003): flattening a hierarchy into arrays sorted by
//! the upper end of each element's threshold interval (spec §6.5, §10).
//!
//! Input is a forest given by each node's children and size (metres). Output gives every node
//!
//! - `leaf_first`, `leaf_count`: its run of leaves, with leaves numbered depth-first so that every
//!   node's leaves are contiguous;
//! - `size`: its size made monotone (a parent is never smaller than a child);
//! - `lo`: 0 for a leaf, `size` for an inner node; `hi`: the parent's `lo`, `+∞` for a root;
//! - its place in `order`: nodes sorted by `hi` descending, so the nodes a threshold `τ` may draw
//!   (`hi > τ`) form a prefix.
//!
//! For every `τ ≥ 0`, the nodes with `lo ≤ τ < hi` then cover each leaf exactly once.

/// One flattened node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SptNode {
    /// Monotone size, metres: `max(own size, children's sizes)`.
    pub size: f32,
    /// Lower end of the threshold interval: 0 for a leaf, `size` otherwise.
    pub lo: f32,
    /// Upper end: the parent's `lo`, `+∞` for a root.
    pub hi: f32,
    /// First leaf id (depth-first numbering) of the node's run.
    pub leaf_first: u32,
    /// Leaves in the run, `≥ 1`.
    pub leaf_count: u32,
}

/// A flattened forest.
#[derive(Clone, Debug, PartialEq)]
pub struct Spt {
    /// Per input node, in input order.
    pub nodes: Vec<SptNode>,
    /// Input node indices sorted by `hi` descending (ties: `leaf_first` ascending, then larger runs
    /// first), the order in which the records are written.
    pub order: Vec<u32>,
    /// Per input node: its leaf id if it is a leaf, `None` for inner nodes.
    pub leaf_id: Vec<Option<u32>>,
}

/// Why a forest cannot be flattened.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum FlattenError {
    /// `sizes` and `children` have different lengths.
    #[error("{sizes} sizes but {nodes} nodes")]
    LengthMismatch {
        /// Entries in `sizes`.
        sizes: usize,
        /// Entries in `children`.
        nodes: usize,
    },
    /// A child index is out of range.
    #[error("node {node} has child {child}, but there are {count} nodes")]
    ChildOutOfRange {
        /// The parent.
        node: usize,
        /// The bad child index.
        child: u32,
        /// Number of nodes.
        count: usize,
    },
    /// A node is the child of two parents, or of itself through a cycle.
    #[error("node {node} is reached twice (shared child or cycle)")]
    NotAForest {
        /// The node reached twice.
        node: usize,
    },
    /// A size is negative or not finite.
    #[error("node {node} has size {size}, sizes must be finite and >= 0")]
    BadSize {
        /// The node.
        node: usize,
        /// Its size.
        size: f32,
    },
    /// More than `u32::MAX` nodes.
    #[error("{0} nodes exceed the 2^32-1 records a section may hold")]
    TooLarge(usize),
}

/// Flattens a forest: `children[i]` lists node `i`'s children (empty for a leaf), `sizes[i]` its
/// size in metres. Roots are the nodes that are nobody's child, taken in index order.
///
/// # Errors
/// [`FlattenError`] if the input is not a forest or a size is invalid.
pub fn flatten(children: &[Vec<u32>], sizes: &[f32]) -> Result<Spt, FlattenError> {
    let count = children.len();
    if sizes.len() != count {
        return Err(FlattenError::LengthMismatch { sizes: sizes.len(), nodes: count });
    }
    if u32::try_from(count).is_err() {
        return Err(FlattenError::TooLarge(count));
    }
    if let Some((node, &size)) = sizes.iter().enumerate().find(|(_, s)| !(s.is_finite() && **s >= 0.0)) {
        return Err(FlattenError::BadSize { node, size });
    }
    let mut parent = vec![None::<u32>; count];
    for (node, kids) in children.iter().enumerate() {
        for &child in kids {
            let slot = parent.get_mut(child as usize).ok_or(FlattenError::ChildOutOfRange { node, child, count })?;
            if slot.is_some() || child as usize == node {
                return Err(FlattenError::NotAForest { node: child as usize });
            }
            #[expect(clippy::cast_possible_truncation, reason = "count fits u32, checked above")]
            let p = node as u32;
            *slot = Some(p);
        }
    }

    let mut nodes = vec![SptNode { size: 0.0, lo: 0.0, hi: f32::INFINITY, leaf_first: 0, leaf_count: 0 }; count];
    let mut leaf_id = vec![None; count];
    let mut visited = vec![false; count];
    let mut next_leaf = 0u32;
    // Iterative post-order DFS from each root: leaves numbered in visiting order, sizes and runs
    // folded upwards when a node's children are done.
    let mut stack: Vec<(u32, bool)> = Vec::new();
    for root in (0..count).filter(|&n| parent[n].is_none()) {
        #[expect(clippy::cast_possible_truncation, reason = "count fits u32")]
        stack.push((root as u32, false));
        while let Some((node, expanded)) = stack.pop() {
            let n = node as usize;
            let kids = &children[n];
            if expanded {
                let first = nodes[kids[0] as usize].leaf_first;
                let mut size = sizes[n];
                let mut leaves = 0u32;
                for &k in kids {
                    size = size.max(nodes[k as usize].size);
                    leaves += nodes[k as usize].leaf_count;
                }
                nodes[n] = SptNode { size, lo: size, hi: f32::INFINITY, leaf_first: first, leaf_count: leaves };
                continue;
            }
            if visited[n] {
                return Err(FlattenError::NotAForest { node: n });
            }
            visited[n] = true;
            if kids.is_empty() {
                nodes[n] = SptNode { size: sizes[n], lo: 0.0, hi: f32::INFINITY, leaf_first: next_leaf, leaf_count: 1 };
                leaf_id[n] = Some(next_leaf);
                next_leaf += 1;
            } else {
                stack.push((node, true));
                // Reversed so the first child is numbered first.
                stack.extend(kids.iter().rev().map(|&k| (k, false)));
            }
        }
    }
    if let Some(n) = visited.iter().position(|v| !v) {
        // Unvisited nodes all lie on cycles (every other node is reachable from a root).
        return Err(FlattenError::NotAForest { node: n });
    }
    for (n, p) in parent.iter().enumerate() {
        if let Some(p) = p {
            nodes[n].hi = nodes[*p as usize].lo;
        }
    }
    #[expect(clippy::cast_possible_truncation, reason = "count fits u32")]
    let mut order: Vec<u32> = (0..count as u32).collect();
    order.sort_by(|&a, &b| {
        let (x, y) = (&nodes[a as usize], &nodes[b as usize]);
        y.hi.total_cmp(&x.hi)
            .then(x.leaf_first.cmp(&y.leaf_first))
            .then(y.leaf_count.cmp(&x.leaf_count))
            .then(a.cmp(&b))
    });
    Ok(Spt { nodes, order, leaf_id })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Random forest: each node after the first few picks a parent among earlier inner candidates.
    fn forest() -> impl Strategy<Value = (Vec<Vec<u32>>, Vec<f32>)> {
        (1usize..60).prop_flat_map(|n| {
            (proptest::collection::vec(any::<prop::sample::Index>(), n), proptest::collection::vec(0.0f32..10.0, n))
                .prop_map(move |(picks, sizes)| {
                    let mut children = vec![Vec::new(); n];
                    for (i, pick) in picks.iter().enumerate().skip(1) {
                        // Node 0 and about one node in five are extra roots.
                        if pick.index(5) == 0 {
                            continue;
                        }
                        let parent = pick.index(i);
                        children[parent].push(i as u32);
                    }
                    (children, sizes)
                })
        })
    }

    /// The nodes drawn at threshold `tau`.
    fn drawn(spt: &Spt, tau: f32) -> Vec<usize> {
        (0..spt.nodes.len()).filter(|&n| spt.nodes[n].lo <= tau && tau < spt.nodes[n].hi).collect()
    }

    proptest! {
        #[test]
        fn every_threshold_draws_each_leaf_exactly_once((children, sizes) in forest(), tau in 0.0f32..12.0) {
            let spt = flatten(&children, &sizes).unwrap();
            let leaves = spt.leaf_id.iter().flatten().count();
            let mut cover = vec![0u32; leaves];
            for n in drawn(&spt, tau) {
                let node = spt.nodes[n];
                for leaf in node.leaf_first..node.leaf_first + node.leaf_count {
                    cover[leaf as usize] += 1;
                }
            }
            prop_assert!(cover.iter().all(|&c| c == 1), "cover {cover:?} at tau {tau}");
        }

        #[test]
        fn drawn_nodes_are_a_prefix_of_the_order((children, sizes) in forest(), tau in 0.0f32..12.0) {
            let spt = flatten(&children, &sizes).unwrap();
            let prefix = spt.order.partition_point(|&n| spt.nodes[n as usize].hi > tau);
            let mut in_prefix: Vec<usize> = spt.order[..prefix].iter().map(|&n| n as usize).collect();
            in_prefix.retain(|&n| spt.nodes[n].lo <= tau);
            in_prefix.sort_unstable();
            prop_assert_eq!(in_prefix, drawn(&spt, tau));
        }

        #[test]
        fn sizes_are_monotone_and_runs_nest((children, sizes) in forest()) {
            let spt = flatten(&children, &sizes).unwrap();
            for (p, kids) in children.iter().enumerate() {
                let parent = spt.nodes[p];
                for &k in kids {
                    let child = spt.nodes[k as usize];
                    prop_assert!(child.size <= parent.size);
                    prop_assert!(child.leaf_first >= parent.leaf_first);
                    prop_assert!(child.leaf_first + child.leaf_count <= parent.leaf_first + parent.leaf_count);
                }
            }
        }
    }

    #[test]
    fn a_single_leaf_is_drawn_at_every_threshold() {
        let spt = flatten(&[vec![]], &[0.5]).unwrap();
        assert_eq!(spt.nodes[0], SptNode { size: 0.5, lo: 0.0, hi: f32::INFINITY, leaf_first: 0, leaf_count: 1 });
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        assert_eq!(flatten(&[vec![1], vec![0]], &[1.0, 1.0]), Err(FlattenError::NotAForest { node: 0 }));
        assert_eq!(flatten(&[vec![0]], &[1.0]), Err(FlattenError::NotAForest { node: 0 }));
        assert_eq!(flatten(&[vec![7]], &[1.0]), Err(FlattenError::ChildOutOfRange { node: 0, child: 7, count: 1 }));
        assert_eq!(
            flatten(&[vec![]], &[f32::NAN]).unwrap_err().to_string(),
            "node 0 has size NaN, sizes must be finite and >= 0"
        );
        assert_eq!(flatten(&[vec![], vec![]], &[1.0]), Err(FlattenError::LengthMismatch { sizes: 1, nodes: 2 }));
    }
}
