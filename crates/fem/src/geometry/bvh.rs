//! Bounding volume hierarchy over axis-aligned boxes (one box per primitive).

use super::aabb::Aabb;

/// One node of a [`Bvh`], stored in depth-first pre-order.
///
/// Every node covers the contiguous range `start..start + count` of [`Bvh::order`]; an inner
/// node's left child is the next node in the array and its right child is `right`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhNode {
    /// Bounding box of all primitive boxes below this node (length units).
    pub bounds: Aabb,
    /// First position in [`Bvh::order`] covered by this node.
    pub start: u32,
    /// Number of primitives below this node.
    pub count: u32,
    /// Index of the right child for inner nodes, [`BvhNode::LEAF`] for leaves.
    pub right: u32,
}

impl BvhNode {
    /// Marker stored in [`BvhNode::right`] for leaves.
    pub const LEAF: u32 = u32::MAX;

    /// True for leaves (nodes whose primitives are tested directly).
    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.right == Self::LEAF
    }
}

/// Binary bounding volume hierarchy over primitive boxes, built by median splits along the
/// longest axis of the primitive centres.
///
/// Used both for the fast winding number (per-node dipole data indexed like
/// [`Bvh::nodes`]) and for box–overlap queries. Depth is at most `⌈log2 n⌉ + 1`.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    nodes: Vec<BvhNode>,
    order: Vec<u32>,
    boxes: Vec<Aabb>,
}

impl Bvh {
    /// Builds the hierarchy over `boxes` (primitive `i` has box `boxes[i]`), with at most
    /// `max_leaf_size` (≥ 1) primitives per leaf. Boxes must be non-empty and finite.
    pub fn build(boxes: &[Aabb], max_leaf_size: usize) -> Self {
        let max_leaf = max_leaf_size.max(1);
        let n = boxes.len();
        assert!(n < u32::MAX as usize, "too many primitives for the BVH");
        let mut order: Vec<u32> = (0..n as u32).collect();
        let centres: Vec<[f64; 3]> = boxes
            .iter()
            .map(|b| {
                let c = b.center();
                [c.x, c.y, c.z]
            })
            .collect();
        let mut nodes = Vec::with_capacity(if n == 0 { 0 } else { 2 * n / max_leaf + 1 });
        if n > 0 {
            build_range(&mut nodes, &mut order, boxes, &centres, 0, n, max_leaf);
        }
        let sorted_boxes = order.iter().map(|&i| boxes[i as usize]).collect();
        Bvh {
            nodes,
            order,
            boxes: sorted_boxes,
        }
    }

    /// The nodes in depth-first pre-order; node 0 is the root (absent for an empty tree).
    pub fn nodes(&self) -> &[BvhNode] {
        &self.nodes
    }

    /// Primitive indices in leaf order: node `k` covers `order()[start..start + count]`.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Primitive boxes in leaf order (`sorted_boxes()[j]` is the box of `order()[j]`).
    pub fn sorted_boxes(&self) -> &[Aabb] {
        &self.boxes
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// True when the hierarchy holds no primitive.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Box of everything in the tree ([`Aabb::EMPTY`] when empty).
    pub fn bounds(&self) -> Aabb {
        self.nodes.first().map_or(Aabb::EMPTY, |n| n.bounds)
    }

    /// Calls `f(i)` for every primitive `i` whose box intersects the closed box `b`
    /// (touching counts), in leaf order.
    pub fn visit_overlapping(&self, b: &Aabb, mut f: impl FnMut(usize)) {
        if self.nodes.is_empty() || b.is_empty() {
            return;
        }
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if !node.bounds.intersects(b) {
                continue;
            }
            if node.is_leaf() {
                let range = node.start as usize..(node.start + node.count) as usize;
                for j in range {
                    if self.boxes[j].intersects(b) {
                        f(self.order[j] as usize);
                    }
                }
            } else {
                let idx = stack[top];
                stack[top] = node.right;
                stack[top + 1] = idx + 1;
                top += 2;
            }
        }
    }
}

/// Builds the subtree over `order[lo..hi]`, returns its node index.
fn build_range(
    nodes: &mut Vec<BvhNode>,
    order: &mut [u32],
    boxes: &[Aabb],
    centres: &[[f64; 3]],
    lo: usize,
    hi: usize,
    max_leaf: usize,
) -> u32 {
    let bounds = order[lo..hi]
        .iter()
        .fold(Aabb::EMPTY, |acc, &i| acc.union(&boxes[i as usize]));
    let index = nodes.len() as u32;
    nodes.push(BvhNode {
        bounds,
        start: lo as u32,
        count: (hi - lo) as u32,
        right: BvhNode::LEAF,
    });
    if hi - lo <= max_leaf {
        return index;
    }
    // Longest axis of the centre bounds.
    let mut cmin = [f64::INFINITY; 3];
    let mut cmax = [f64::NEG_INFINITY; 3];
    for &i in &order[lo..hi] {
        let c = &centres[i as usize];
        for a in 0..3 {
            cmin[a] = cmin[a].min(c[a]);
            cmax[a] = cmax[a].max(c[a]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (cmax[a] - cmin[a]).total_cmp(&(cmax[b] - cmin[b])))
        .unwrap_or(0);
    let mid = lo + (hi - lo) / 2;
    order[lo..hi].select_nth_unstable_by(mid - lo, |&i, &j| {
        centres[i as usize][axis].total_cmp(&centres[j as usize][axis])
    });
    build_range(nodes, order, boxes, centres, lo, mid, max_leaf);
    let right = build_range(nodes, order, boxes, centres, mid, hi, max_leaf);
    nodes[index as usize].right = right;
    index
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn boxes(n: usize) -> Vec<Aabb> {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut r = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let c = Point3::new(r() * 10.0, r() * 10.0, r() * 10.0);
                let h = nalgebra::Vector3::new(r(), r(), r()) * 0.3;
                Aabb::new(c - h, c + h)
            })
            .collect()
    }

    #[test]
    fn structure_is_consistent() {
        let b = boxes(1000);
        let bvh = Bvh::build(&b, 4);
        let mut seen = vec![false; b.len()];
        for &i in bvh.order() {
            assert!(!seen[i as usize]);
            seen[i as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        for (k, node) in bvh.nodes().iter().enumerate() {
            let range = node.start as usize..(node.start + node.count) as usize;
            for j in range {
                assert!(node.bounds.contains_box(&b[bvh.order()[j] as usize]));
            }
            if node.is_leaf() {
                assert!(node.count <= 4);
            } else {
                let l = &bvh.nodes()[k + 1];
                let r = &bvh.nodes()[node.right as usize];
                assert_eq!(l.start, node.start);
                assert_eq!(l.count + r.count, node.count);
                assert_eq!(r.start, l.start + l.count);
            }
        }
    }

    #[test]
    fn overlap_query_matches_brute_force() {
        let b = boxes(2000);
        let bvh = Bvh::build(&b, 4);
        for q in boxes(200) {
            let q = q.expanded(0.5);
            let mut got = Vec::new();
            bvh.visit_overlapping(&q, |i| got.push(i));
            got.sort_unstable();
            let want: Vec<usize> = (0..b.len()).filter(|&i| b[i].intersects(&q)).collect();
            assert_eq!(got, want);
        }
        let empty = Bvh::build(&[], 4);
        assert!(empty.is_empty());
        empty.visit_overlapping(&b[0], |_| panic!("empty tree reported a primitive"));
    }
}
