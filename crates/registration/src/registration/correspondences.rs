//! Correspondences of non-rigid ICP (thesis alg. 3, eq. 5.4): each model source point is
//! paired with its nearest cloud point and with the cloud points that chose it, pairs are
//! pruned by the thesis's mean + kσ rule, and the two directions are blended into one imposed
//! displacement per source. Lengths in metres.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::NeighbourGrid;

/// Points whose `k`-th neighbour distance sets [`IndexedPoints::nearest_k_all`]'s cell edge.
const GRID_EDGE_SAMPLES: usize = 16;

/// [`IndexedPoints::nearest_k_all`]'s cell edge over the sampled median `k`-th neighbour
/// distance (`cargo bench --bench neighbour_lists`, 680 points, k = 32: 0.7 / 1.0 / 1.3 / 1.7
/// → 586 / 477 / 423 / 591 µs).
const GRID_EDGE_FACTOR: f64 = 1.3;

/// A point set with a k-d tree for nearest-neighbour queries.
pub struct IndexedPoints {
    /// The points, metres.
    pub points: Vec<Point3<f64>>,
    tree: ImmutableKdTree<f64, 3>,
}

impl std::fmt::Debug for IndexedPoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IndexedPoints")
            .field("points", &self.points.len())
            .finish_non_exhaustive()
    }
}

impl IndexedPoints {
    /// Indexes `points` (all finite; `None` when empty or when the tree cannot be built).
    pub fn new(points: Vec<Point3<f64>>) -> Option<Self> {
        if points.is_empty() {
            return None;
        }
        let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&coords).ok()?;
        Some(Self { points, tree })
    }

    /// Index of the point nearest to `p` and its distance, metres.
    pub fn nearest(&self, p: &Point3<f64>) -> (usize, f64) {
        let nn = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        (nn.item as usize, nn.distance.sqrt())
    }

    /// Indices and distances (metres) of the `k` points nearest to `p`, nearest first
    /// (`p` itself included when it is one of the points).
    pub fn nearest_k(&self, p: &Point3<f64>, k: usize) -> Vec<(usize, f64)> {
        let Some(k) = std::num::NonZeroUsize::new(k.min(self.points.len())) else {
            return Vec::new();
        };
        self.tree
            .query(&[p.x, p.y, p.z])
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute()
            .into_iter()
            .map(|nn| (nn.item as usize, nn.distance.sqrt()))
            .collect()
    }

    /// [`IndexedPoints::nearest_k`] of every point of the set, in the set's order (on the
    /// rayon pool). On a [`NeighbourGrid`] whose cell edge is 1.3 times the
    /// median `k`-th neighbour distance of a few sampled points (exact whatever the edge; 1.7×
    /// faster than a tree query per point for the change test's 32 neighbours of a camera's
    /// patch, slower for 9: use it for long lists); per point on the tree when the set's box
    /// is too large for a grid (far outliers). Ties at equal distance are ordered by index.
    pub fn nearest_k_all(&self, k: usize) -> Vec<Vec<(usize, f64)>> {
        let n = self.points.len();
        let k = k.min(n);
        if k == 0 {
            return vec![Vec::new(); n];
        }
        let stride = n.div_ceil(GRID_EDGE_SAMPLES);
        let mut reach: Vec<f64> = (0..n)
            .step_by(stride)
            .filter_map(|i| self.nearest_k(&self.points[i], k).last().map(|nn| nn.1))
            .collect();
        let mid = reach.len() / 2;
        let edge = *reach.select_nth_unstable_by(mid, f64::total_cmp).1;
        match NeighbourGrid::new(&self.points, GRID_EDGE_FACTOR * edge) {
            Some(grid) => (0..n)
                .into_par_iter()
                .map_init(Vec::new, |scratch, i| grid.k_nearest_of(i, k, scratch))
                .collect(),
            None => self
                .points
                .par_iter()
                .map(|p| self.nearest_k(p, k))
                .collect(),
        }
    }

    /// Which points lie on the rim of the sampled patch: a point whose `k` nearest neighbours
    /// have their centroid farther from it than `ratio` × their mean distance lies with its
    /// neighbours on one side, i.e. on the patch's border (inside a uniformly sampled patch
    /// the centroid offset is a small fraction of the neighbour distance). Non-rigid ICP drops
    /// model points whose nearest cloud point is on the rim (Amberg et al. 2007): with a
    /// partial cloud they belong to the unseen part, and pairing them with the rim would drag
    /// the unseen surface onto it.
    pub fn rim_mask(&self, k: usize, ratio: f64) -> Vec<bool> {
        (0..self.points.len())
            .map(|i| self.is_rim(i, k, ratio))
            .collect()
    }

    /// Whether point `i` lies on the rim of the sampled patch ([`IndexedPoints::rim_mask`]).
    pub fn is_rim(&self, i: usize, k: usize, ratio: f64) -> bool {
        let p = &self.points[i];
        let nn = self.nearest_k(p, k + 1);
        let others: Vec<&(usize, f64)> = nn.iter().filter(|n| n.1 > 0.0).collect();
        if others.len() < 3 {
            return true;
        }
        let m = others.len() as f64;
        let centroid = others
            .iter()
            .fold(Vector3::zeros(), |acc, n| acc + self.points[n.0].coords)
            / m;
        let mean_d = others.iter().map(|n| n.1).sum::<f64>() / m;
        (centroid - p.coords).norm() > ratio * mean_d
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are no points (never true for a built index).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// How correspondences are formed and pruned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairingRule {
    /// Blending α of eq. 5.4: weight of the source's own nearest cloud point; `1 − α` goes to
    /// the mean of the cloud points whose nearest source it is.
    pub alpha: f64,
    /// Pairs farther than centre + this × spread (of the pair distances of the same
    /// direction) are outliers; the thesis uses 2 with the mean and standard deviation.
    pub outlier_sigma: f64,
    /// Centre and spread are the median and the normal-consistent median absolute deviation
    /// (1.4826 MAD) instead of the mean and standard deviation; see [`robust_threshold`].
    pub robust: bool,
    /// Pairs farther than this, metres, are dropped too (`None`: no cap).
    pub max_pair_distance: Option<f64>,
    /// Pairs no farther than this, metres, are never outliers, whatever the spread (0: no
    /// floor). Once a registration has converged on a noise-free cloud every pair is a few
    /// micrometres long, and centre + k × spread of those lengths cuts off the longest third
    /// of them: pairs the model already fits. Dropped, they stop pulling and drift away, and
    /// the next frame drops them again.
    pub min_outlier_distance: f64,
    /// With a visibility mask (cloud → surface pairing from a camera): a cloud point that
    /// lies within this distance (m) of the model surface where the mask says it is hidden,
    /// and farther than that from every visible triangle by more than this again, pairs with
    /// the hidden surface point instead of a distant visible one. The camera saw more than the
    /// model predicted; the point shows where the surface is (an offset of a noise's size),
    /// not a motion towards the visible part. `None`: only visible triangles pair.
    pub hidden_match: Option<f64>,
    /// Cloud → surface pairing keeps pairs beyond the outlier threshold whose cloud
    /// neighbours lie as far off the surface (a coherent region: a deformation not yet
    /// followed), and pulls up model vertices that lie beyond it below the cloud's interior
    /// (`registration::surface_anchors`). False: the threshold alone decides.
    pub keep_coherent: bool,
}

impl PairingRule {
    /// The outlier threshold (m) of the pair lengths `d` (m): centre + `outlier_sigma` ×
    /// spread, at least `min_outlier_distance`, at most `max_pair_distance`.
    pub fn limit(&self, d: &[f64]) -> f64 {
        if self.robust {
            robust_threshold(d, self.outlier_sigma)
        } else {
            rejection_threshold(d, self.outlier_sigma)
        }
        .max(self.min_outlier_distance)
        .min(self.max_pair_distance.unwrap_or(f64::INFINITY))
    }
}

/// Neighbours examined by [`IndexedPoints::rim_mask`] in non-rigid ICP.
pub(crate) const RIM_NEIGHBOURS: usize = 12;
/// Centroid offset ratio of [`IndexedPoints::rim_mask`] in non-rigid ICP.
pub(crate) const RIM_RATIO: f64 = 0.4;

/// The imposed displacements of one ICP iteration.
#[derive(Debug, Clone, PartialEq)]
pub struct Correspondences {
    /// Model surface vertex of each kept source.
    pub sources: Vec<usize>,
    /// Unit surface normal of each kept source when pairing was point-to-plane (the blended
    /// displacement is then its component along the normal, and the spring acts along it
    /// only); `None` for point-to-point pairs.
    pub normals: Option<Vec<Vector3<f64>>>,
    /// Where each kept source is to go (current position + imposed displacement), metres.
    pub targets: Vec<Point3<f64>>,
    /// RMS of the kept source → nearest-cloud-point distances, metres.
    pub rms: f64,
    /// Cloud points that paired back with a kept source.
    pub cloud_used: usize,
}

impl Correspondences {
    /// The pairs whose source is flagged in `mask` (indexed by surface vertex); all of them
    /// when fewer than 3 would remain.
    pub fn restricted_to(self, mask: &[bool]) -> Self {
        let keep: Vec<usize> = (0..self.sources.len())
            .filter(|&s| mask[self.sources[s]])
            .collect();
        if keep.len() < 3 || keep.len() == self.sources.len() {
            return self;
        }
        Self {
            sources: keep.iter().map(|&s| self.sources[s]).collect(),
            normals: self.normals.map(|n| keep.iter().map(|&s| n[s]).collect()),
            targets: keep.iter().map(|&s| self.targets[s]).collect(),
            rms: self.rms,
            cloud_used: self.cloud_used,
        }
    }
}

/// Mean + `sigma` × standard deviation of `d` (population).
pub fn rejection_threshold(d: &[f64], sigma: f64) -> f64 {
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    mean + sigma * var.sqrt()
}

/// Median + `sigma` × 1.4826 × median absolute deviation of `d`: the robust counterpart of
/// [`rejection_threshold`] (1.4826 MAD estimates the standard deviation of normal data). Gross
/// outliers move the mean and inflate the standard deviation — with 30 % of a cloud uniform in
/// a box around the organ, mean + 2σ of the cloud→model distances lies beyond most outliers and
/// keeps them — while the median and the MAD stay those of the inliers up to 50 % outliers.
pub fn robust_threshold(d: &[f64], sigma: f64) -> f64 {
    if d.is_empty() {
        return 0.0;
    }
    let median = |v: &mut Vec<f64>| {
        let m = v.len() / 2;
        let (_, x, _) = v.select_nth_unstable_by(m, f64::total_cmp);
        *x
    };
    let mut v = d.to_vec();
    let med = median(&mut v);
    let mut dev: Vec<f64> = d.iter().map(|x| (x - med).abs()).collect();
    let mad = median(&mut dev);
    med + sigma * 1.4826 * mad
}

/// Pairs the candidate vertices `candidates` (indices into `x`, current positions in metres)
/// with `cloud` both ways and blends the directions by eq. 5.4:
/// `d(i) = α [c(N(i)) − x(i)] + (1 − α) mean_{j ∈ V(i)} [c(j) − x(i)]`, with `N(i)` the nearest
/// cloud point of source `i` and `V(i)` the cloud points whose nearest kept source is `i`
/// (`d(i) = c(N(i)) − x(i)` when `V(i)` is empty). `None` when fewer than 3 sources survive.
/// Sources whose nearest cloud point is flagged in `rim` (when given) are dropped first.
///
/// With `normals` (unit outward normals of the current surface at every vertex of `x`), the
/// pairing is point-to-plane: the blended displacement is replaced by its normal component
/// `n (n · d(i))`. With a sparse cloud (a few points per cm², as far apart as the model's
/// vertices) the tangential part of `d(i)` is mostly sampling noise — the nearest sample lies
/// anywhere within half the sample spacing — and pulling along it distorts the surface.
/// Sources with a zero normal are dropped.
pub(crate) fn pair(
    x: &[Point3<f64>],
    normals: Option<&[Vector3<f64>]>,
    candidates: &[usize],
    cloud: &IndexedPoints,
    rim: Option<&[bool]>,
    rule: &PairingRule,
) -> Option<Correspondences> {
    let forward: Vec<(usize, usize, f64)> = candidates
        .iter()
        .map(|&i| {
            let (j, d) = cloud.nearest(&x[i]);
            (i, j, d)
        })
        .filter(|&(i, j, _)| {
            !rim.is_some_and(|r| r[j]) && !normals.is_some_and(|n| n[i] == Vector3::zeros())
        })
        .collect();
    let dists: Vec<f64> = forward.iter().map(|p| p.2).collect();
    let limit = rule.limit(&dists);
    let kept: Vec<(usize, usize, f64)> = forward.into_iter().filter(|p| p.2 <= limit).collect();
    if kept.len() < 3 {
        return None;
    }
    let sources = IndexedPoints::new(kept.iter().map(|p| x[p.0]).collect())?;
    let back: Vec<(usize, f64)> = cloud.points.iter().map(|q| sources.nearest(q)).collect();
    let back_dists: Vec<f64> = back.iter().map(|b| b.1).collect();
    let back_limit = rule.limit(&back_dists);
    let mut sum = vec![Vector3::zeros(); kept.len()];
    let mut count = vec![0usize; kept.len()];
    let mut cloud_used = 0;
    for (j, &(s, d)) in back.iter().enumerate() {
        if d <= back_limit {
            sum[s] += cloud.points[j] - sources.points[s];
            count[s] += 1;
            cloud_used += 1;
        }
    }
    let targets = kept
        .iter()
        .enumerate()
        .map(|(s, &(i, j, _))| {
            let own = cloud.points[j] - x[i];
            let d = if count[s] > 0 {
                own * rule.alpha + (sum[s] / count[s] as f64) * (1.0 - rule.alpha)
            } else {
                own
            };
            match normals {
                Some(n) => x[i] + n[i] * n[i].dot(&d),
                None => x[i] + d,
            }
        })
        .collect();
    let rms = (kept.iter().map(|p| p.2 * p.2).sum::<f64>() / kept.len() as f64).sqrt();
    Some(Correspondences {
        normals: normals.map(|n| kept.iter().map(|p| n[p.0]).collect()),
        sources: kept.iter().map(|p| p.0).collect(),
        targets,
        rms,
        cloud_used,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// Every point's lists from the grid equal the tree's own queries (the independent
    /// reference): on a noisy curved patch, and on the same patch with far outliers, whose box
    /// is too large for a grid (the per-point fallback).
    #[test]
    fn all_lists_at_once_equal_one_tree_query_per_point() {
        let mut rng = Rng::new(3);
        let mut points: Vec<Point3<f64>> = (0..700)
            .map(|_| {
                let (x, y) = (rng.uniform_in(0.0, 0.12), rng.uniform_in(0.0, 0.09));
                let z = 0.03 * (25.0 * x).sin() * (15.0 * y).cos() + 0.0015 * rng.gaussian();
                Point3::new(x, y, z)
            })
            .collect();
        for outliers in [false, true] {
            if outliers {
                points.push(Point3::new(40.0, -3.0, 7.0));
                points.push(Point3::new(-25.0, 12.0, 0.5));
            }
            let cloud = IndexedPoints::new(points.clone()).unwrap();
            for k in [1, 9, 32] {
                let all = cloud.nearest_k_all(k);
                assert_eq!(all.len(), points.len());
                for (p, list) in points.iter().zip(&all) {
                    assert_eq!(*list, cloud.nearest_k(p, k), "k {k}, outliers {outliers}");
                }
            }
        }
        let few = IndexedPoints::new(points[..3].to_vec()).unwrap();
        assert!(few.nearest_k_all(5).iter().all(|l| l.len() == 3));
        assert!(few.nearest_k_all(0).iter().all(|l| l.is_empty()));
    }

    fn rule(alpha: f64) -> PairingRule {
        PairingRule {
            alpha,
            outlier_sigma: 2.0,
            robust: false,
            max_pair_distance: None,
            min_outlier_distance: 0.0,
            hidden_match: None,
            keep_coherent: false,
        }
    }

    #[test]
    fn converged_pairs_are_not_outliers_below_the_floor() {
        // Micrometre pair lengths of a converged, noise-free fit: centre + 2 × spread cuts off
        // the longest of them unless the floor keeps every pair under it.
        let d: Vec<f64> = (0..100)
            .map(|i| 1e-6 * (i as f64 / 100.0).powi(3))
            .collect();
        let mut r = rule(0.75);
        r.robust = true;
        let bare = r.limit(&d);
        assert!(
            d.iter().any(|x| *x > bare),
            "without a floor some pairs are cut"
        );
        r.min_outlier_distance = 6e-4;
        assert_eq!(r.limit(&d), 6e-4);
        // A noisy cloud's threshold lies above the floor and is unchanged by it.
        let noisy: Vec<f64> = (0..100)
            .map(|i| 1.5e-3 * (1.0 + (i as f64 * 0.37).sin()))
            .collect();
        let mut bare_rule = r;
        bare_rule.min_outlier_distance = 0.0;
        assert_eq!(r.limit(&noisy), bare_rule.limit(&noisy));
        // The cap still wins over the floor.
        r.max_pair_distance = Some(1e-4);
        assert_eq!(r.limit(&d), 1e-4);
    }

    /// With 30 % gross outliers the median/MAD limit stays at the inliers' scale while
    /// mean + 2σ admits most outliers; on outlier-free normal data the two agree (the MAD
    /// estimates σ).
    #[test]
    fn robust_threshold_ignores_gross_outliers() {
        // Inliers: half-normal distances, σ = 1 mm.
        let mut rng = crate::random::Rng::new(0x9E37_79B9_7F4A_7C15);
        let inliers: Vec<f64> = (0..700).map(|_| 1e-3 * rng.gaussian().abs()).collect();
        let outliers: Vec<f64> = (0..300).map(|i| 5e-3 + 45e-3 * i as f64 / 299.0).collect();
        let all: Vec<f64> = inliers.iter().chain(&outliers).copied().collect();
        let robust = robust_threshold(&all, 2.0);
        let classic = rejection_threshold(&all, 2.0);
        let kept = |limit: f64| outliers.iter().filter(|&&d| d <= limit).count();
        assert!(kept(robust) <= 15, "robust keeps {} outliers", kept(robust));
        assert!(kept(classic) >= 200, "mean + 2σ keeps {}", kept(classic));
        // Outlier-free: both limits estimate the same mean/median + 2σ within 25 %.
        let (r, c) = (
            robust_threshold(&inliers, 2.0),
            rejection_threshold(&inliers, 2.0),
        );
        assert!((r - c).abs() <= 0.25 * c, "robust {r} vs classic {c}");
        assert_eq!(robust_threshold(&[], 2.0), 0.0);
    }

    #[test]
    fn threshold_is_mean_plus_k_sigma() {
        // mean 2.5, population sd sqrt(1.25)
        let t = rejection_threshold(&[1.0, 2.0, 3.0, 4.0], 2.0);
        assert!((t - (2.5 + 2.0 * 1.25f64.sqrt())).abs() < 1e-15);
    }

    #[test]
    fn a_shifted_copy_imposes_the_shift() {
        // Sources on a grid, the cloud the same grid moved by a shift smaller than the spacing:
        // both directions agree, so every imposed displacement is the shift for any α.
        let x: Vec<Point3<f64>> = (0..25)
            .map(|k| Point3::new((k % 5) as f64, (k / 5) as f64, 0.0))
            .collect();
        let shift = Vector3::new(0.1, -0.2, 0.05);
        let cloud = IndexedPoints::new(x.iter().map(|p| p + shift).collect()).unwrap();
        let all: Vec<usize> = (0..x.len()).collect();
        for alpha in [0.0, 0.75, 1.0] {
            let c = pair(&x, None, &all, &cloud, None, &rule(alpha)).unwrap();
            assert_eq!(c.sources.len(), 25);
            for (&i, t) in c.sources.iter().zip(&c.targets) {
                assert!((t - (x[i] + shift)).norm() < 1e-12);
            }
            assert!((c.rms - shift.norm()).abs() < 1e-12);
        }
    }

    #[test]
    fn restriction_keeps_the_flagged_sources_with_their_targets() {
        let x: Vec<Point3<f64>> = (0..10).map(|k| Point3::new(k as f64, 0.0, 0.0)).collect();
        let cloud = IndexedPoints::new(
            (0..10)
                .map(|k| Point3::new(k as f64, 0.0, 0.1 * k as f64))
                .collect(),
        )
        .unwrap();
        let all: Vec<usize> = (0..10).collect();
        let p = pair(&x, None, &all, &cloud, None, &rule(1.0)).unwrap();
        let mask: Vec<bool> = (0..10).map(|k| k % 2 == 0).collect();
        let r = p.clone().restricted_to(&mask);
        assert_eq!(r.sources, vec![0, 2, 4, 6, 8]);
        for (&i, t) in r.sources.iter().zip(&r.targets) {
            assert!((t - Point3::new(i as f64, 0.0, 0.1 * i as f64)).norm() < 1e-12);
        }
        // Fewer than 3 left: nothing is dropped.
        let few: Vec<bool> = (0..10).map(|k| k < 2).collect();
        assert_eq!(p.clone().restricted_to(&few), p);
    }

    #[test]
    fn far_pairs_are_rejected_and_blending_weights_both_directions() {
        // 20 sources on a line with the cloud right above them, plus one far source.
        let mut x: Vec<Point3<f64>> = (0..20).map(|k| Point3::new(k as f64, 0.0, 0.0)).collect();
        x.push(Point3::new(10.0, 50.0, 0.0));
        let mut c: Vec<Point3<f64>> = (0..20).map(|k| Point3::new(k as f64, 0.0, 0.1)).collect();
        // An extra cloud point that chooses source 0 from the side: V(0) = {it, own}.
        c.push(Point3::new(-0.3, 0.0, 0.1));
        let cloud = IndexedPoints::new(c).unwrap();
        let all: Vec<usize> = (0..x.len()).collect();
        let p = pair(&x, None, &all, &cloud, None, &rule(0.75)).unwrap();
        assert!(!p.sources.contains(&20), "the far source is an outlier");
        // Blending, with pruning loose enough to keep the side point.
        let loose = PairingRule {
            outlier_sigma: 1e3,
            ..rule(0.75)
        };
        let p = pair(&x, None, &all[..20], &cloud, None, &loose).unwrap();
        let s0 = p.sources.iter().position(|&i| i == 0).unwrap();
        // own: (0,0,0.1); back mean: ((0,0,0.1) + (-0.3,0,0.1)) / 2 = (-0.15, 0, 0.1)
        let expect = Point3::new(0.25 * -0.15, 0.0, 0.1);
        assert!((p.targets[s0] - expect).norm() < 1e-12, "{}", p.targets[s0]);
        // a cap below the true distance removes everything
        let capped = PairingRule {
            max_pair_distance: Some(0.05),
            ..rule(0.75)
        };
        assert!(pair(&x, None, &all, &cloud, None, &capped).is_none());
    }

    #[test]
    fn point_to_plane_keeps_only_the_normal_offset_of_a_sparse_cloud() {
        // Sources on the plane z = 0 (normal +z); the cloud samples the plane z = 0.1 at
        // positions shifted in-plane by up to ±0.4: point-to-point pairs carry that in-plane
        // sampling offset, point-to-plane pairs impose exactly the 0.1 normal offset.
        let x: Vec<Point3<f64>> = (0..100)
            .map(|k| Point3::new((k % 10) as f64, (k / 10) as f64, 0.0))
            .collect();
        let shift = |k: usize| {
            let a = ((k * 7919) % 17) as f64 / 16.0 - 0.5;
            let b = ((k * 104_729) % 13) as f64 / 12.0 - 0.5;
            Vector3::new(0.8 * a, 0.8 * b, 0.1)
        };
        let cloud =
            IndexedPoints::new(x.iter().enumerate().map(|(k, p)| p + shift(k)).collect()).unwrap();
        let normals = vec![Vector3::z(); x.len()];
        let all: Vec<usize> = (0..x.len()).collect();
        let loose = PairingRule {
            outlier_sigma: 1e3,
            ..rule(0.75)
        };
        let plane = pair(&x, Some(&normals), &all, &cloud, None, &loose).unwrap();
        assert_eq!(plane.sources.len(), 100);
        assert_eq!(plane.normals.as_ref().map(Vec::len), Some(100));
        for (&i, t) in plane.sources.iter().zip(&plane.targets) {
            assert!((t - (x[i] + Vector3::new(0.0, 0.0, 0.1))).norm() < 1e-12);
        }
        let point = pair(&x, None, &all, &cloud, None, &loose).unwrap();
        assert!(point.normals.is_none());
        let tangential = point
            .sources
            .iter()
            .zip(&point.targets)
            .map(|(&i, t)| (t - x[i]).xy().norm())
            .fold(0.0, f64::max);
        assert!(
            tangential > 0.2,
            "point-to-point keeps the in-plane offsets"
        );
    }

    #[test]
    fn rim_of_a_jittered_square_patch_is_its_border() {
        // 30 × 30 samples of a plane with spacing 1 and ±0.2 jitter (a deterministic hash).
        let n = 30;
        let jitter = |i: usize, a: u64| {
            let h = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ a;
            ((h >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.4
        };
        let pts: Vec<Point3<f64>> = (0..n * n)
            .map(|k| {
                let (i, j) = (k % n, k / n);
                Point3::new(
                    i as f64 + jitter(k, 1),
                    j as f64 + jitter(k, 7),
                    jitter(k, 13) * 0.5,
                )
            })
            .collect();
        let cloud = IndexedPoints::new(pts).unwrap();
        let rim = cloud.rim_mask(RIM_NEIGHBOURS, RIM_RATIO);
        let border = |k: usize| {
            let (i, j) = (k % n, k / n);
            i == 0 || j == 0 || i == n - 1 || j == n - 1
        };
        let deep = |k: usize| {
            let (i, j) = (k % n, k / n);
            (3..n - 3).contains(&i) && (3..n - 3).contains(&j)
        };
        let border_hit = (0..n * n).filter(|&k| border(k) && rim[k]).count();
        let border_all = (0..n * n).filter(|&k| border(k)).count();
        let deep_false = (0..n * n).filter(|&k| deep(k) && rim[k]).count();
        assert_eq!(border_hit, border_all, "every border sample is on the rim");
        assert_eq!(deep_false, 0, "no sample 3 rows inside is on the rim");
    }
}
