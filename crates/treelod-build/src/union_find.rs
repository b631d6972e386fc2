//! Union–find over element ids (`parent[v]` is `v` for a root), the lower id the representative:
//! a set's root is its smallest element whatever the order of the unions, so what is keyed or
//! ordered by roots is deterministic. Used to find connected pieces of meshes (classification,
//! branch lines, ambient occlusion's leaf cards).

/// Every id in `0..n` its own set.
#[must_use]
pub(crate) fn singletons(n: usize) -> Vec<u32> {
    #[expect(clippy::cast_possible_truncation, reason = "element ids (vertices) fit u32")]
    (0..n as u32).collect()
}

/// The root of `v`'s set (path splitting on the way).
pub(crate) fn find(parent: &mut [u32], mut v: u32) -> u32 {
    while parent[v as usize] != v {
        let p = parent[v as usize];
        parent[v as usize] = parent[p as usize];
        v = p;
    }
    v
}

/// Joins the sets of `a` and `b`; the lower root becomes the root of both.
pub(crate) fn union(parent: &mut [u32], a: u32, b: u32) {
    let (a, b) = (find(parent, a), find(parent, b));
    if a < b {
        parent[b as usize] = a;
    } else if b < a {
        parent[a as usize] = b;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_are_the_smallest_member_whatever_the_order() {
        for pairs in [[(4, 2), (2, 7), (5, 6)], [(5, 6), (7, 2), (2, 4)]] {
            let mut parent = singletons(8);
            for (a, b) in pairs {
                union(&mut parent, a, b);
            }
            let roots: Vec<u32> = (0..8).map(|v| find(&mut parent, v)).collect();
            assert_eq!(roots, [0, 1, 2, 3, 2, 5, 5, 2]);
        }
    }
}
