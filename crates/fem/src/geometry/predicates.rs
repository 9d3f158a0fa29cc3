//! Robust 2D orientation predicate (exact sign) and its symbolic perturbation.
//!
//! `orient2d(a, b, p) = (a − p) × (b − p)` is twice the signed area of the triangle `(a, b, p)`:
//! positive when the three points turn counter-clockwise. The sign is computed exactly: a
//! floating-point filter (Shewchuk 1997) decides almost every case, the rest is evaluated with
//! error-free transformations (two-product via FMA, expansion sums).

/// Half machine epsilon, 2⁻⁵³.
const EPS: f64 = f64::EPSILON * 0.5;
/// Shewchuk's `ccwerrboundA`: bound on the relative error of the filtered determinant.
const CCW_ERR_BOUND_A: f64 = (3.0 + 16.0 * EPS) * EPS;

/// `orient2d(a, b, p)` in floating point together with its exact sign (−1, 0 or +1).
///
/// The value is the plain floating-point evaluation (useful for interpolation); the sign is
/// exact for finite inputs (barring underflow of products below ~1e-292).
#[inline]
pub(crate) fn orient2d(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> (f64, i8) {
    let detleft = (a[0] - p[0]) * (b[1] - p[1]);
    let detright = (a[1] - p[1]) * (b[0] - p[0]);
    let det = detleft - detright;
    let bound = CCW_ERR_BOUND_A * (detleft.abs() + detright.abs());
    if det > bound {
        (det, 1)
    } else if -det > bound {
        (det, -1)
    } else {
        (det, orient2d_exact_sign(a, b, p))
    }
}

/// Sign of `orient2d(a, b, p)` with `p` symbolically perturbed to `(p.x + ε, p.y + ε²)`
/// (0 < ε infinitesimal), together with the floating-point value of the unperturbed
/// determinant.
///
/// The sign is never 0 unless `a == b`. The perturbation is the same for every edge, so it is
/// consistent across triangles: it amounts to moving the query point off every line through
/// two input points, and sign(a, b, p) = −sign(b, a, p) always holds.
#[inline]
pub(crate) fn orient2d_perturbed(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> (f64, i8) {
    let (det, s) = orient2d(a, b, p);
    if s != 0 {
        return (det, s);
    }
    // orient2d(a, b, p + (ε, ε²)) = det − (b.y − a.y) ε + (b.x − a.x) ε².
    let s = if b[1] != a[1] {
        if a[1] > b[1] {
            1
        } else {
            -1
        }
    } else if b[0] > a[0] {
        1
    } else if b[0] < a[0] {
        -1
    } else {
        0
    };
    (det, s)
}

/// Error-free product: `a * b = hi + lo` exactly.
#[inline]
fn two_product(a: f64, b: f64) -> (f64, f64) {
    let hi = a * b;
    (hi, a.mul_add(b, -hi))
}

/// Error-free sum (Knuth): `a + b = s + e` exactly.
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

/// Exact sign of `orient2d(a, b, p)`, expanded as
/// `a.x b.y − a.x p.y − p.x b.y − a.y b.x + a.y p.x + p.y b.x`, each product split exactly
/// into two doubles and all twelve summed into a non-overlapping expansion
/// (Shewchuk's Grow-Expansion with zero elimination).
fn orient2d_exact_sign(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> i8 {
    let products = [
        two_product(a[0], b[1]),
        two_product(-a[0], p[1]),
        two_product(-p[0], b[1]),
        two_product(-a[1], b[0]),
        two_product(a[1], p[0]),
        two_product(p[1], b[0]),
    ];
    let mut e = [0.0f64; 12];
    let mut n = 0;
    for (hi, lo) in products {
        for term in [lo, hi] {
            let mut q = term;
            let mut m = 0;
            for i in 0..n {
                let (s, h) = two_sum(q, e[i]);
                if h != 0.0 {
                    e[m] = h;
                    m += 1;
                }
                q = s;
            }
            if q != 0.0 {
                e[m] = q;
                m += 1;
            }
            n = m;
        }
    }
    // The most significant component is the last one.
    if n == 0 {
        0
    } else if e[n - 1] > 0.0 {
        1
    } else {
        -1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_sign_on_nearly_collinear_points() {
        // Points exactly on the line y = x and one ulp above/below it: the exact sign follows the
        // true geometry.
        let a = [0.1, 0.1];
        let b = [0.7, 0.7];
        for k in 0..200 {
            let x = 0.3 + k as f64 * 0.001_7;
            let p = [x, x];
            assert_eq!(orient2d(a, b, p).1, 0, "x = {x}");
            let up = [x, f64::from_bits(x.to_bits() + 1)];
            assert_eq!(orient2d(a, b, up).1, 1);
            let down = [x, f64::from_bits(x.to_bits() - 1)];
            assert_eq!(orient2d(a, b, down).1, -1);
        }
        // Non-trivial collinear triple in binary: 0.1 + t (0.3 − 0.1) is not representable in
        // general, so compare with an exact rational check on integers scaled by 2^-10.
        let s = 1.0 / 1024.0;
        let a = [3.0 * s, 5.0 * s];
        let b = [7.0 * s, 13.0 * s];
        let p = [11.0 * s, 21.0 * s];
        assert_eq!(orient2d(a, b, p).1, 0);
        let above = f64::from_bits((21.0 * s).to_bits() + 1);
        assert_eq!(orient2d(a, b, [11.0 * s, above]).1, 1);
    }

    #[test]
    fn exact_sign_matches_integer_arithmetic() {
        // Coordinates k · 2^-30 with integer k < 2^45 are exact doubles; the i128 determinant of
        // the integers has the true sign. Points are built exactly on (or one unit off) the
        // line through a and b, where the floating-point filter cannot decide.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let scale = (-30f64).exp2();
        let mut zeros = 0;
        for _ in 0..20_000 {
            let r = |v: u64, bits: u32| (v >> (64 - bits)) as i64 - (1i64 << (bits - 1));
            let a = [r(next(), 40), r(next(), 40)];
            let d = [r(next(), 20), r(next(), 20)];
            let t = r(next(), 20);
            let b = [a[0] + d[0], a[1] + d[1]];
            let jitter = (next() % 3) as i64 - 1;
            let p = [a[0] + t * d[0] + jitter, a[1] + t * d[1]];
            let exact = {
                let (ax, ay, bx, by, px, py) = (
                    a[0] as i128,
                    a[1] as i128,
                    b[0] as i128,
                    b[1] as i128,
                    p[0] as i128,
                    p[1] as i128,
                );
                ((ax - px) * (by - py) - (ay - py) * (bx - px)).signum() as i8
            };
            let f = |v: [i64; 2]| [v[0] as f64 * scale, v[1] as f64 * scale];
            assert_eq!(orient2d(f(a), f(b), f(p)).1, exact, "{a:?} {b:?} {p:?}");
            zeros += usize::from(exact == 0);
        }
        assert!(zeros > 5_000);
    }

    #[test]
    fn antisymmetry_and_perturbation() {
        let a = [0.0, 0.0];
        let b = [1.0, 0.0];
        // On the horizontal edge: perturbation moves the point up (ε² in y).
        assert_eq!(orient2d_perturbed(a, b, [0.5, 0.0]).1, 1);
        assert_eq!(orient2d_perturbed(b, a, [0.5, 0.0]).1, -1);
        // On a non-horizontal edge: perturbation moves the point right (ε in x).
        let c = [0.0, 1.0];
        assert_eq!(orient2d_perturbed(b, c, [0.5, 0.5]).1, -1);
        assert_eq!(orient2d_perturbed(c, b, [0.5, 0.5]).1, 1);
        // At a vertex the perturbation still decides.
        assert_ne!(orient2d_perturbed(a, b, a).1, 0);
        assert_eq!(orient2d_perturbed(a, a, [3.0, 4.0]).1, 0);
    }
}
