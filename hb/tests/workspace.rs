//! The HB workspace: a solve through a warm workspace allocates nothing and gives the iterates
//! of the plain solve bit for bit; the receptance cache follows the linear part, not the
//! element parameters or the forcing.
//!
//! Its own test binary: the counting allocator sees every allocation of the process, so the
//! counted section runs in one test function.

use nlsim_fixtures::build;
use nlsim_hb::{ForceTerm, Forcing, HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Param, Parameterized};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting allocations.
struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards every call to the system allocator unchanged.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract is passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract is passed on.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract is passed on.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.load(Ordering::Relaxed)
}

/// The ECL beam (cubic spring) and the bump-stop cantilever (clearance law), 6 modes, H = 5.
fn systems() -> Vec<(HbSystem, f64)> {
    ["ecl_beam", "bumpstop_cantilever"]
        .iter()
        .map(|name| {
            let model = build(name, &[]).unwrap().model;
            let red = reduce(
                &model,
                &ReductionConfig {
                    eigen: EigenConfig {
                        selection: ModeSelection::Lowest(6),
                        ..EigenConfig::default()
                    },
                    ..ReductionConfig::default()
                },
            )
            .unwrap();
            let w1 = red.modes.omega()[0];
            let sys = HbSystem::from_model(
                &model,
                &red,
                HarmonicSet::new(5, 1).unwrap(),
                HbConfig::default(),
            )
            .unwrap();
            (sys, w1)
        })
        .collect()
}

#[test]
fn warm_workspace_solves_without_allocating_and_match_the_plain_solve() {
    for (sys, w1) in systems() {
        let name = sys.elements()[0].name().to_string();
        // A point near the first resonance where Newton needs several iterations (on the
        // bump stop: in contact), the first such of a fixed list.
        let (omega, scale, start, plain, rep_plain) = [0.98, 1.02, 0.95, 1.05]
            .iter()
            .flat_map(|at| [1.0, 4.0, 16.0].map(|sc| (at * w1, sc)))
            .find_map(|(omega, scale)| {
                let start = sys.linear_guess(omega, scale);
                let (x, rep) = sys.solve(omega, scale, &start).unwrap();
                (rep.converged() && rep.iterations >= 3).then_some((omega, scale, start, x, rep))
            })
            .unwrap_or_else(|| panic!("{name}: no point needing 3 Newton iterations"));

        let mut ws = sys.workspace(1 << 20);
        let mut x = start.clone();
        let rep = sys.solve_with(&mut ws, omega, scale, &mut x).unwrap();
        assert_eq!(rep, rep_plain, "{name}");
        assert_eq!(x, plain, "{name}: the iterates differ from the plain solve");
        assert_eq!(ws.cache_counts(), (0, 1));

        // Warm: the same frequency from the same start, counted.
        let mut x = start.clone();
        let before = allocations();
        let rep = sys.solve_with(&mut ws, omega, scale, &mut x).unwrap();
        let during = allocations() - before;
        assert_eq!(during, 0, "{name}: a warm solve allocated {during} times");
        assert_eq!(rep, rep_plain, "{name}");
        assert_eq!(x, plain, "{name}");
        assert_eq!(ws.cache_counts(), (1, 1));
    }
}

#[test]
fn the_cache_follows_the_linear_part_not_the_elements_or_the_forcing() {
    let (mut sys, w1) = systems().remove(0);
    let omega = 0.97 * w1;
    let mut ws = sys.workspace(1 << 20);
    let solve = |sys: &HbSystem, ws: &mut nlsim_hb::HbWorkspace| {
        let mut x = sys.linear_guess(omega, 1.0);
        let rep = sys.solve_with(ws, omega, 1.0, &mut x).unwrap();
        let (plain, rep_plain) = sys
            .solve(omega, 1.0, &sys.linear_guess(omega, 1.0))
            .unwrap();
        assert_eq!(rep, rep_plain);
        assert_eq!(x, plain, "a cached solve differs from a fresh one");
    };
    solve(&sys, &mut ws);
    assert_eq!(ws.cache_counts(), (0, 1));

    // An element parameter: the receptances stay.
    let k3 = sys.parameters()[0].clone();
    assert!(matches!(k3, Param::Element { .. }), "{k3}");
    let v = sys.param(&k3).unwrap();
    sys.set_param(&k3, 1.5 * v).unwrap();
    solve(&sys, &mut ws);
    assert_eq!(ws.cache_counts(), (1, 1));

    // The forcing (the measured force of a test step): the receptances stay.
    let input = 0;
    sys.set_forcing(Forcing {
        terms: vec![ForceTerm {
            input,
            harmonic: 1,
            amplitude: faer::c64::new(0.3, -0.2),
        }],
    })
    .unwrap();
    solve(&sys, &mut ws);
    assert_eq!(ws.cache_counts(), (2, 1));

    // A modal parameter changes the linear part: computed again.
    let f1 = Param::ModalFrequency(0);
    let v = sys.param(&f1).unwrap();
    sys.set_param(&f1, 1.01 * v).unwrap();
    solve(&sys, &mut ws);
    assert_eq!(ws.cache_counts(), (2, 2));

    // A clone of the system shares the linear part; a clone of the workspace starts empty.
    let copy = sys.clone();
    solve(&copy, &mut ws);
    assert_eq!(ws.cache_counts(), (3, 2));
    let mut fresh = ws.clone();
    solve(&copy, &mut fresh);
    assert_eq!(fresh.cache_counts(), (0, 1));
}

#[test]
fn the_cache_is_bounded_by_its_budget() {
    let (sys, w1) = systems().remove(0);
    let n = sys.n_unknowns();
    let per = 8 * (n * n + n * sys.inputs().len() * sys.harmonics().len()) + 64;
    let mut ws = sys.workspace(3 * per);
    assert_eq!(ws.capacity(), 3);
    for i in 0..5 {
        let omega = w1 * (0.9 + 0.01 * i as f64);
        let mut x = sys.linear_guess(omega, 1.0);
        sys.solve_with(&mut ws, omega, 1.0, &mut x).unwrap();
    }
    // The two oldest were dropped: the first frequency misses again, the last one hits.
    let mut x = sys.linear_guess(0.9 * w1, 1.0);
    sys.solve_with(&mut ws, 0.9 * w1, 1.0, &mut x).unwrap();
    assert_eq!(ws.cache_counts(), (0, 6));
    let last = w1 * (0.9 + 0.01 * 4.0);
    let mut x = sys.linear_guess(last, 1.0);
    sys.solve_with(&mut ws, last, 1.0, &mut x).unwrap();
    assert_eq!(ws.cache_counts(), (1, 6));
    assert_eq!(sys.workspace(0).capacity(), 1);
}
