//! The nalgebra-sparse and sprs adapters give the matrix that assembling the same entries
//! gives, whatever the source's layout (CSC, CSR, COO/triplets; whole or one triangle), and a
//! model built on them validates like any other. Run with
//! `cargo test -p nlsim-kernel --features nalgebra-sparse,sprs --test adapters`.
#![cfg(all(feature = "nalgebra-sparse", feature = "sprs"))]

use nlsim_kernel::nalgebra_sparse::{CooMatrix, CscMatrix, CsrMatrix};
use nlsim_kernel::sprs::{CsMat, TriMat};
use nlsim_kernel::{DofMap, Model, SparseSym, Stored, ValidationConfig};

/// A fixed-free chain of `n` springs (k_i = 1e4 (1 + i/n) N/m) as (row, col, value), both
/// triangles, with the diagonal split in two repeated entries to exercise summing.
fn chain(n: usize) -> Vec<(usize, usize, f64)> {
    let mut t = Vec::new();
    for i in 0..n {
        let k = 1e4 * (1.0 + i as f64 / n as f64);
        // Spring i joins DOF i-1 (ground for i = 0) and DOF i.
        t.push((i, i, 0.5 * k));
        t.push((i, i, 0.5 * k));
        if i > 0 {
            t.push((i - 1, i - 1, k));
            t.push((i - 1, i, -k));
            t.push((i, i - 1, -k));
        }
    }
    t
}

fn same(a: &SparseSym, b: &SparseSym) {
    assert_eq!(a.n(), b.n());
    let (da, db) = (a.to_dense(), b.to_dense());
    for i in 0..a.n() {
        for j in 0..a.n() {
            assert_eq!(da[(i, j)], db[(i, j)], "entry ({i}, {j})");
        }
    }
}

#[test]
fn every_layout_gives_the_assembled_matrix() {
    let n = 7;
    let t = chain(n);
    let want = SparseSym::from_triplets("K", n, &t).unwrap();
    let lower: Vec<_> = t.iter().copied().filter(|e| e.0 >= e.1).collect();
    let upper: Vec<_> = t.iter().copied().filter(|e| e.0 <= e.1).collect();

    let coo = |entries: &[(usize, usize, f64)]| {
        let mut c = CooMatrix::new(n, n);
        for &(r, col, v) in entries {
            c.push(r, col, v);
        }
        c
    };
    let tri = |entries: &[(usize, usize, f64)]| {
        let mut m = TriMat::new((n, n));
        for &(r, c, v) in entries {
            m.add_triplet(r, c, v);
        }
        m
    };
    for (entries, stored) in [
        (&t, Stored::Both),
        (&lower, Stored::OneTriangle),
        (&upper, Stored::OneTriangle),
    ] {
        let c = coo(entries);
        same(
            &SparseSym::from_nalgebra_coo("K", &c, stored).unwrap(),
            &want,
        );
        same(
            &SparseSym::from_nalgebra_csc("K", &CscMatrix::from(&c), stored).unwrap(),
            &want,
        );
        same(
            &SparseSym::from_nalgebra_csr("K", &CsrMatrix::from(&c), stored).unwrap(),
            &want,
        );
        let s = tri(entries);
        same(
            &SparseSym::from_sprs_triplets("K", &s, stored).unwrap(),
            &want,
        );
        let csc: CsMat<f64> = s.to_csc();
        same(&SparseSym::from_sprs("K", &csc, stored).unwrap(), &want);
        let csr: CsMat<f64> = s.to_csr();
        same(&SparseSym::from_sprs("K", &csr, stored).unwrap(), &want);
    }
}

#[test]
fn bad_sources_are_refused_with_the_entry() {
    let n = 4;
    // Both triangles passed as one: refused, naming an entry on each side.
    let mut c = CooMatrix::new(n, n);
    for (r, col, v) in chain(n) {
        c.push(r, col, v);
    }
    let e = SparseSym::from_nalgebra_csc("K", &CscMatrix::from(&c), Stored::OneTriangle)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("below the diagonal") && e.contains("Stored::Both"),
        "{e}"
    );
    // Not square.
    let e = SparseSym::from_sprs("M", &CsMat::<f64>::zero((3, 4)), Stored::Both)
        .unwrap_err()
        .to_string();
    assert!(e.contains("M columns"), "{e}");
    // A NaN, named by its position.
    let mut t = TriMat::new((n, n));
    t.add_triplet(2, 1, f64::NAN);
    let e = SparseSym::from_sprs_triplets("K", &t, Stored::OneTriangle)
        .unwrap_err()
        .to_string();
    assert!(e.contains("row 2, column 1"), "{e}");
    // An asymmetric whole matrix passes the adapter and is caught by the model's validation.
    let mut c = CooMatrix::new(n, n);
    for (r, col, v) in chain(n) {
        c.push(r, col, if (r, col) == (0, 1) { 2.0 * v } else { v });
    }
    let k = SparseSym::from_nalgebra_csc("K", &CscMatrix::from(&c), Stored::Both).unwrap();
    let m = SparseSym::diagonal("M", &[1.0; 4]).unwrap();
    let e = Model::builder("chain", DofMap::scalar(n), m, k)
        .validation(Some(ValidationConfig::default()))
        .build()
        .unwrap_err()
        .to_string();
    assert!(e.contains("symmetric"), "{e}");
}

#[test]
fn a_model_on_adapted_matrices_has_the_closed_form_modes() {
    // Two equal masses (1 kg) on springs of 1e4 N/m (ground–1, 1–2): ω² = (3 ∓ √5)/2 · 1e4.
    let k = CsMat::new_csc(
        (2, 2),
        vec![0, 2, 4],
        vec![0, 1, 0, 1],
        vec![2e4, -1e4, -1e4, 1e4],
    );
    let m = TriMat::from_triplets((2, 2), vec![0, 1], vec![0, 1], vec![1.0, 1.0]);
    let model = Model::builder(
        "two masses",
        DofMap::scalar(2),
        SparseSym::from_sprs_triplets("M", &m, Stored::Both).unwrap(),
        SparseSym::from_sprs("K", &k, Stored::Both).unwrap(),
    )
    .build()
    .unwrap();
    let d = nlsim_kernel::linalg::dense_generalized_eigen_low(
        model.stiffness().to_dense().as_ref(),
        model.mass().to_dense().as_ref(),
    )
    .unwrap();
    let s5 = 5f64.sqrt();
    for (got, want) in d
        .values
        .iter()
        .zip([(3.0 - s5) / 2.0 * 1e4, (3.0 + s5) / 2.0 * 1e4])
    {
        assert!((got - want).abs() <= 1e-12 * want, "{got} vs {want}");
    }
}
