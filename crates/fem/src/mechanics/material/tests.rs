//! Cross-law tests: finite-difference consistency, part splitting, objectivity,
//! small-strain limit, S/P consistency, error handling, parameter validation and the
//! moduli read back (the timing of `response()` is the `material_response` benchmark).

use super::*;
use nalgebra::{Rotation3, Unit, Vector3};

const LAWS: [LawKind; 5] = LawKind::ALL;
const PARTS: [Part; 3] = [Part::Full, Part::Shear, Part::Volumetric];

/// The crate's seeded generator with the samples these tests draw: vectors, matrices and
/// rotations with uniform entries or angles.
struct Rng(crate::random::Rng);

impl Rng {
    fn seeded(seed: u64) -> Self {
        Self(crate::random::Rng::new(seed))
    }
    /// Uniform in [a, b).
    fn uniform(&mut self, a: f64, b: f64) -> f64 {
        self.0.uniform_in(a, b)
    }
    fn vec3(&mut self, a: f64, b: f64) -> Vector3<f64> {
        Vector3::new(self.uniform(a, b), self.uniform(a, b), self.uniform(a, b))
    }
    fn mat3(&mut self, a: f64, b: f64) -> Mat3 {
        Mat3::from_fn(|_, _| self.uniform(a, b))
    }
    /// Random rotation by `angle` about a random axis.
    fn rotation_by(&mut self, angle: f64) -> Mat3 {
        let mut axis = self.vec3(-1.0, 1.0);
        if axis.norm() < 1e-3 {
            axis = Vector3::z();
        }
        *Rotation3::from_axis_angle(&Unit::new_normalize(axis), angle).matrix()
    }
    fn rotation(&mut self) -> Mat3 {
        let angle = self.uniform(0.0, std::f64::consts::PI);
        self.rotation_by(angle)
    }
}

fn diag(a: f64, b: f64, c: f64) -> Mat3 {
    Mat3::from_diagonal(&Vector3::new(a, b, c))
}

/// Deformation gradients near and far from I, all with det F > 0.
fn sample_fs(rng: &mut Rng) -> Vec<(&'static str, Mat3)> {
    let i = Mat3::identity();
    let mut out = Vec::new();
    for _ in 0..3 {
        out.push(("near I", i + rng.mat3(-0.05, 0.05)));
    }
    let (q1, q2) = (rng.rotation(), rng.rotation());
    out.push(("stretch 1.8", q1 * diag(1.8, 0.8, 0.72) * q2));
    out.push((
        "stretch 1.8 axis",
        diag(1.8, 1.0 / 1.8f64.sqrt(), 1.0 / 1.8f64.sqrt()),
    ));
    let (q1, q2) = (rng.rotation(), rng.rotation());
    out.push(("compression 0.5", q1 * diag(0.5, 1.2, 1.1) * q2));
    out.push((
        "compression 0.5 axis",
        diag(0.5, 1.3, 1.3) + rng.mat3(-0.02, 0.02),
    ));
    let mut shear = i;
    shear[(0, 1)] = 0.6;
    out.push(("shear 0.6", shear));
    out.push(("shear 0.6 perturbed", shear + rng.mat3(-0.05, 0.05)));
    let q80 = rng.rotation_by(80f64.to_radians());
    out.push(("rotation 80°", q80));
    out.push(("rotation 80° + strain", q80 * (i + rng.mat3(-0.1, 0.1))));
    let (q1, q2) = (rng.rotation(), rng.rotation());
    let d = rng.vec3(0.5, 1.8);
    out.push(("random far", q1 * Mat3::from_diagonal(&d) * q2));
    let (q1, q2) = (rng.rotation(), rng.rotation());
    out.push(("strongly anisotropic", q1 * diag(2.0, 0.4, 0.15) * q2));
    out
}

/// Inverted gradients (det F < 0), distinct singular values: valid for every
/// law except neo-Hookean.
fn inverted_fs(rng: &mut Rng) -> Vec<(&'static str, Mat3)> {
    let (q1, q2) = (rng.rotation(), rng.rotation());
    vec![
        ("inverted", q1 * diag(1.3, 0.9, -0.6) * q2),
        (
            "inverted mild",
            diag(1.1, 1.0, -0.2) + rng.mat3(-0.03, 0.03),
        ),
    ]
}

fn materials() -> Vec<Material> {
    LAWS.iter()
        .flat_map(|&law| {
            [
                Material::from_young_poisson(law, 4500.0, 0.45).unwrap(),
                Material::from_young_poisson(law, 1.0, 0.3).unwrap(),
            ]
        })
        .collect()
}

fn fs_for(law: LawKind, rng: &mut Rng) -> Vec<(&'static str, Mat3)> {
    let mut fs = sample_fs(rng);
    if !matches!(law, LawKind::NeoHookean | LawKind::MooneyRivlin) {
        fs.extend(inverted_fs(rng));
    }
    fs
}

/// Stress floor for relative comparisons: errors are measured against
/// `max(|X|, 1e-3 (λ + 2μ))`, the stress of a 1e-3 strain. It only matters
/// where the exact value is ~0 (rigid rotations), where a pure relative
/// error would be dominated by rounding.
fn stress_floor(m: &Material) -> f64 {
    1e-3 * m.wave_speed_modulus()
}

/// Energy floor for relative comparisons. Energies are evaluated from
/// invariants of size ~(λ + 2μ)|F|² that cancel near rigid motions, so their
/// absolute rounding is ~ε(λ + 2μ); comparisons use `max(|W|, 1e-3 (λ + 2μ))`.
fn energy_floor(m: &Material) -> f64 {
    1e-3 * m.wave_speed_modulus()
}

fn unit(k: usize, l: usize) -> Mat3 {
    let mut e = Mat3::zeros();
    e[(k, l)] = 1.0;
    e
}

/// Test 1: P = central FD of W, ∂P/∂F = central FD of P, for every law, part
/// and sample F; `response` agrees with `energy`/`pk1`; tangent symmetric.
#[test]
fn finite_differences_energy_stress_tangent() {
    let mut rng = Rng::seeded(0x5EED_0001);
    let h = 1e-6;
    let mut worst = (0.0f64, 0.0f64);
    for m in materials() {
        for (name, f) in fs_for(m.law, &mut rng) {
            for part in PARTS {
                let ctx = format!("{:?} {part:?} {name}", m.law);
                let r = m.response(&f, part).unwrap();
                let p = m.pk1(&f, part).unwrap();
                let w = m.energy(&f, part).unwrap();
                let floor = stress_floor(&m);
                let wfloor = energy_floor(&m);
                assert!((r.energy - w).abs() <= 1e-12 * w.abs().max(wfloor), "{ctx}");
                assert!((r.pk1 - p).amax() <= 1e-12 * p.amax().max(floor), "{ctx}");
                let (w2, p2) = m.energy_pk1(&f, part).unwrap();
                assert!(w2 == w && p2 == p, "{ctx}: energy_pk1 differs");

                let mut p_fd = Mat3::zeros();
                let mut a_fd = Tangent9::zeros();
                for k in 0..3 {
                    for l in 0..3 {
                        let e = unit(k, l) * h;
                        let (fp, fm) = (f + e, f - e);
                        p_fd[(k, l)] = (m.energy(&fp, part).unwrap()
                            - m.energy(&fm, part).unwrap())
                            / (2.0 * h);
                        let dp =
                            (m.pk1(&fp, part).unwrap() - m.pk1(&fm, part).unwrap()) / (2.0 * h);
                        for i in 0..3 {
                            for j in 0..3 {
                                a_fd[(3 * i + j, 3 * k + l)] = dp[(i, j)];
                            }
                        }
                    }
                }
                let pe = (p - p_fd).amax() / p.amax().max(floor);
                let ae = (r.tangent - a_fd).amax() / r.tangent.amax();
                worst = (worst.0.max(pe), worst.1.max(ae));
                assert!(pe <= 1e-6, "{ctx}: P vs FD(W) rel err {pe:e}");
                assert!(ae <= 1e-6, "{ctx}: A vs FD(P) rel err {ae:e}");
                let asym = (r.tangent - r.tangent.transpose()).amax() / r.tangent.amax();
                assert!(asym <= 1e-12, "{ctx}: tangent asymmetry {asym:e}");
            }
        }
    }
    println!("worst rel err: P {:e}, A {:e}", worst.0, worst.1);
}

/// Test 2: Shear + Volumetric == Full for energy, P, tangent, S and ℂ.
#[test]
fn parts_sum_to_full() {
    let mut rng = Rng::seeded(0x5EED_0002);
    fn close<const R: usize, const C: usize>(
        a: &nalgebra::SMatrix<f64, R, C>,
        b: &nalgebra::SMatrix<f64, R, C>,
        full: &nalgebra::SMatrix<f64, R, C>,
        floor: f64,
    ) -> bool {
        let scale = a.amax().max(b.amax()).max(full.amax()).max(floor);
        (a + b - full).amax() <= 1e-12 * scale
    }
    for m in materials() {
        for (name, f) in fs_for(m.law, &mut rng) {
            let ctx = format!("{:?} {name}", m.law);
            let [rf, rs, rv] = PARTS.map(|p| m.response(&f, p).unwrap());
            let scale = (rf.energy.abs().max(rs.energy.abs()))
                .max(rv.energy.abs())
                .max(energy_floor(&m));
            let floor = stress_floor(&m);
            assert!(
                (rs.energy + rv.energy - rf.energy).abs() <= 1e-12 * scale,
                "{ctx}"
            );
            assert!(close(&rs.pk1, &rv.pk1, &rf.pk1, floor), "{ctx}");
            assert!(close(&rs.tangent, &rv.tangent, &rf.tangent, floor), "{ctx}");
            let [sf, ss, sv] = PARTS.map(|p| m.pk2(&f, p).unwrap());
            assert!(close(&ss, &sv, &sf, floor), "{ctx}");
            let [cf, cs, cv] = PARTS.map(|p| m.material_tangent(&f, p).unwrap());
            assert!(close(&cs, &cv, &cf, floor), "{ctx}");
        }
    }
}

/// Test 3: objectivity of SVK, neo-Hookean and corotated; zero energy and
/// stress under rigid rotations.
#[test]
fn rotation_invariance_and_rigid_motion() {
    let mut rng = Rng::seeded(0x5EED_0003);
    for m in materials() {
        if m.law == LawKind::Linear {
            continue;
        }
        let scale = m.wave_speed_modulus();
        for (name, f) in fs_for(m.law, &mut rng) {
            for _ in 0..3 {
                let q = rng.rotation();
                let ctx = format!("{:?} {name}", m.law);
                let a = m.response(&f, Part::Full).unwrap();
                let b = m.response(&(q * f), Part::Full).unwrap();
                assert!(
                    (a.energy - b.energy).abs() <= 1e-12 * a.energy.abs().max(energy_floor(&m)),
                    "{ctx}: W {} vs {}",
                    a.energy,
                    b.energy
                );
                assert!(
                    (q * a.pk1 - b.pk1).amax() <= 1e-12 * a.pk1.amax().max(stress_floor(&m)),
                    "{ctx}: P {:e} vs {:e}",
                    (q * a.pk1 - b.pk1).amax(),
                    a.pk1.amax()
                );
                // A(QF)_iJkL = Q_ia Q_kb A(F)_aJbL
                let qa = Tangent9::from_fn(|r, c| {
                    let (i, jj, k, ll) = (r / 3, r % 3, c / 3, c % 3);
                    let mut v = 0.0;
                    for aa in 0..3 {
                        for bb in 0..3 {
                            v += q[(i, aa)] * q[(k, bb)] * a.tangent[(3 * aa + jj, 3 * bb + ll)];
                        }
                    }
                    v
                });
                assert!(
                    (qa - b.tangent).amax() <= 1e-11 * a.tangent.amax(),
                    "{ctx}: A"
                );
            }
        }
        for angle_deg in [0.0, 10.0, 80.0, 135.0, 180.0] {
            let q = rng.rotation_by(f64::to_radians(angle_deg));
            for part in PARTS {
                let r = m.response(&q, part).unwrap();
                let ctx = format!("{:?} {part:?} rigid {angle_deg}°", m.law);
                assert!(r.energy.abs() <= 1e-13 * scale, "{ctx}: W = {}", r.energy);
                assert!(r.pk1.amax() <= 1e-12 * scale, "{ctx}: P = {}", r.pk1);
                assert!(m.pk2(&q, part).unwrap().amax() <= 1e-12 * scale, "{ctx}");
            }
        }
    }
    // The linear law is (expectedly) not objective: a rigid rotation stresses it.
    let m = Material::from_young_poisson(LawKind::Linear, 1.0, 0.3).unwrap();
    let q = rng.rotation_by(80f64.to_radians());
    assert!(m.pk1(&q, Part::Full).unwrap().amax() > 0.1);
}

/// Test 4: small-strain limit — every law reproduces linear σ for
/// F = I + εG, ε = 1e-7, and all tangents at F = I equal the linear one.
#[test]
fn small_strain_limit() {
    let mut rng = Rng::seeded(0x5EED_0004);
    for m in materials() {
        let lin = Material {
            law: LawKind::Linear,
            ..m
        };
        for _ in 0..5 {
            let g = rng.mat3(-1.0, 1.0);
            let f = Mat3::identity() + g * 1e-7;
            for part in PARTS {
                let sigma = lin.pk1(&f, part).unwrap();
                let p = m.pk1(&f, part).unwrap();
                let err = (p - sigma).amax() / sigma.amax();
                assert!(err <= 1e-5, "{:?} {part:?}: rel err {err:e}", m.law);
            }
        }
        let i = Mat3::identity();
        for part in PARTS {
            let a_lin = lin.response(&i, part).unwrap().tangent;
            let a = m.response(&i, part).unwrap().tangent;
            assert!(
                (a - a_lin).amax() <= 1e-12 * a_lin.amax(),
                "{:?} {part:?}\n{a}\n{a_lin}",
                m.law
            );
            let c_lin = lin.material_tangent(&i, part).unwrap();
            let c = m.material_tangent(&i, part).unwrap();
            assert!((c - c_lin).amax() <= 1e-12 * c_lin.amax(), "{:?}", m.law);
            let r = m.response(&i, part).unwrap();
            assert!(r.energy.abs() < 1e-300 || r.energy.abs() <= 1e-14 * m.mu);
            assert!(r.pk1.amax() <= 1e-14 * m.wave_speed_modulus());
        }
    }
    // explicit linear-elasticity tensor entries at F = I
    let m = Material {
        law: LawKind::NeoHookean,
        mu: 2.0,
        lambda: 5.0,
    };
    let c = m.material_tangent(&Mat3::identity(), Part::Full).unwrap();
    assert_eq!(c[(0, 0)], 9.0);
    assert_eq!(c[(0, 1)], 5.0);
    assert_eq!(c[(3, 3)], 2.0);
    assert_eq!(c[(0, 3)], 0.0);
}

/// Symmetric square root via eigen-decomposition (test helper).
fn sqrtm_spd(m: &Mat3) -> Mat3 {
    let eig = nalgebra::SymmetricEigen::new(*m);
    let d = eig.eigenvalues.map(|x| {
        assert!(x > 0.0);
        x.sqrt()
    });
    eig.eigenvectors * Mat3::from_diagonal(&d) * eig.eigenvectors.transpose()
}

/// Test 5: P = F·S, and the Voigt `material_tangent` equals the central FD of
/// S with respect to E (F = Q·sqrtm(I + 2E)).
#[test]
fn pk2_and_material_tangent_consistency() {
    let mut rng = Rng::seeded(0x5EED_0005);
    let h = 1e-6;
    for m in materials() {
        // P = F S (linear: pk2 is σ = pk1)
        for (name, f) in fs_for(m.law, &mut rng) {
            for part in PARTS {
                let p = m.pk1(&f, part).unwrap();
                let s = m.pk2(&f, part).unwrap();
                let floor = stress_floor(&m);
                assert!((s - s.transpose()).amax() <= 1e-12 * s.amax().max(floor));
                let expect = if m.law == LawKind::Linear { s } else { f * s };
                assert!(
                    (p - expect).amax() <= 1e-12 * p.amax().max(floor),
                    "{:?} {part:?} {name}",
                    m.law
                );
            }
        }
        let mut es: Vec<Mat3> = vec![Mat3::zeros()];
        if m.law != LawKind::Linear {
            for scale in [0.02, 0.2, 0.4] {
                // random symmetric E with I + 2E safely positive definite
                loop {
                    let g = rng.mat3(-scale, scale);
                    let e = (g + g.transpose()) * 0.5;
                    let c = Mat3::identity() + e * 2.0;
                    if nalgebra::SymmetricEigen::new(c).eigenvalues.min() > 0.2 {
                        es.push(e);
                        break;
                    }
                }
            }
            es.push(diag(-0.3, 0.5, 0.1)); // stretches ≈ 0.63, 1.41, 1.10
        }
        for e in es {
            // the linear law is not objective: no rotation for it
            let q = if m.law == LawKind::Linear {
                Mat3::identity()
            } else {
                rng.rotation()
            };
            let f_of = |e: &Mat3| q * sqrtm_spd(&(Mat3::identity() + e * 2.0));
            for part in PARTS {
                let c = m.material_tangent(&f_of(&e), part).unwrap();
                let mut c_fd = Voigt6::zeros();
                for (b, &(k, l)) in VOIGT.iter().enumerate() {
                    // unit engineering strain component b
                    let mut de = Mat3::zeros();
                    if k == l {
                        de[(k, k)] = h;
                    } else {
                        de[(k, l)] = 0.5 * h;
                        de[(l, k)] = 0.5 * h;
                    }
                    let sp = m.pk2(&f_of(&(e + de)), part).unwrap();
                    let sm = m.pk2(&f_of(&(e - de)), part).unwrap();
                    let ds = (sp - sm) / (2.0 * h);
                    for (a, &(i, j)) in VOIGT.iter().enumerate() {
                        c_fd[(a, b)] = ds[(i, j)];
                    }
                }
                let err = (c - c_fd).amax() / c.amax();
                assert!(err <= 1e-6, "{:?} {part:?} E={e}: rel err {err:e}", m.law);
                assert!((c - c.transpose()).amax() <= 1e-11 * c.amax());
            }
        }
    }
}

/// Test 6 (part): NaN / ∞ input → `NonFinite` from every entry point, never
/// NaN output. (Neo-Hookean `Inverted` is tested in `neo_hookean.rs`.)
#[test]
fn non_finite_input_is_rejected() {
    for m in materials() {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for idx in [0, 4, 7] {
                let mut f = Mat3::identity();
                f[idx] = bad;
                for part in PARTS {
                    let e = MaterialError::NonFinite;
                    assert_eq!(m.energy(&f, part), Err(e));
                    assert_eq!(m.pk1(&f, part), Err(e));
                    assert_eq!(m.energy_pk1(&f, part), Err(e));
                    assert_eq!(m.pk2(&f, part), Err(e));
                    assert_eq!(m.material_tangent(&f, part), Err(e));
                    assert!(matches!(
                        m.response(&f, part),
                        Err(MaterialError::NonFinite)
                    ));
                }
            }
        }
    }
    assert_eq!(
        MaterialError::NonFinite.to_string(),
        "non-finite deformation gradient"
    );
}

/// Test 8: parameter validation and conversion.
#[test]
fn from_young_poisson_validates() {
    let m = Material::from_young_poisson(LawKind::Svk, 1.0, 0.3).unwrap();
    assert!((m.mu - 1.0 / 2.6).abs() < 1e-15);
    assert!((m.lambda - 0.3 / (1.3 * 0.4)).abs() < 1e-15);
    assert!((m.wave_speed_modulus() - (m.lambda + 2.0 * m.mu)).abs() < 1e-15);
    assert!(Material::from_young_poisson(LawKind::Svk, 3000.0, -0.99).is_ok());
    assert!(Material::from_young_poisson(LawKind::Svk, 3000.0, 0.4999).is_ok());
    let bad: [(f64, f64, &str); 9] = [
        (1.0, 0.5, "0.5"),
        (1.0, 0.7, "0.7"),
        (1.0, -1.0, "-1"),
        (1.0, -2.5, "-2.5"),
        (1.0, f64::NAN, "NaN"),
        (0.0, 0.3, "E = 0"),
        (-3.0, 0.3, "-3"),
        (f64::NAN, 0.3, "NaN"),
        (f64::INFINITY, 0.3, "inf"),
    ];
    for (e, nu, needle) in bad {
        let msg = Material::from_young_poisson(LawKind::NeoHookean, e, nu).unwrap_err();
        assert!(msg.contains(needle), "E={e} ν={nu}: {msg}");
        let which = if e.is_finite() && e > 0.0 {
            "Poisson"
        } else {
            "Young"
        };
        assert!(msg.contains(which), "{msg}");
    }
}

/// Serde names of [`LawKind`].
#[test]
fn law_kind_serde_names() {
    for (law, name) in [
        (LawKind::Linear, "\"linear\""),
        (LawKind::Corotated, "\"corotated\""),
        (LawKind::Svk, "\"svk\""),
        (LawKind::NeoHookean, "\"neo-hookean\""),
        (LawKind::MooneyRivlin, "\"mooney-rivlin\""),
    ] {
        assert_eq!(serde_json::to_string(&law).unwrap(), name);
        assert_eq!(serde_json::from_str::<LawKind>(name).unwrap(), law);
    }
    assert!(serde_json::from_str::<LawKind>("\"NeoHookean\"").is_err());
}

/// Young's modulus and Poisson's ratio read back from the Lamé parameters they made, over
/// the range the scenes use (soft tissue, compressible to nearly incompressible).
#[test]
fn young_and_poisson_read_back_from_the_lame_parameters() {
    for (e, nu) in [
        (4500.0, 0.49),
        (20_000.0, 0.45),
        (3000.0, 0.3),
        (1.0e6, 0.0),
    ] {
        let m = Material::from_young_poisson(LawKind::NeoHookean, e, nu).unwrap();
        assert!((m.young_modulus() - e).abs() <= 1e-12 * e, "E {e}");
        assert!((m.poisson_ratio() - nu).abs() <= 1e-12, "ν {nu}");
    }
}
